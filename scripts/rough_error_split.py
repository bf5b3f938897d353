"""Where the rough_materials frame's error lies (issue 24, session 33): the bench row's
``rel`` (mean over pixels of |L - L_ref| / (L_ref + 0.01), luminance) split by what each
pixel sees and into the glossy samples' noise and the rest (pixel centres, the models).

Regions, from rstrace frames of the same scene: ``edges`` (the 16 jittered samples of a
pixel see different materials or the background), ``background`` (all of them see it),
``floor lit`` / ``floor shadow`` (the floor, the point light visible from the pixel's
centre point or not), ``box``, and each rough ball split in ``highlight`` (the point
light's own lobe at the camera hit is at least half the converged pixel) and
``reflected`` (the rest: what the glossy and refracted rays bring). Terms per
region, each its share of the frame's ``rel`` (the shares sum to the row):

* ``defaults``: rstrace's frame at S x G (pixel samples x glossy samples) seed 0;
* ``glossy conv.``: the same pixels with 256 glossy samples (the lobe converged: what is
  left is the pixel centre and the models' bias);
* ``noise`` (rms over ``--seeds`` seeds of the relative deviation from their mean, its
  share the mean over the region's pixels / n): the glossy lobe's sampling noise.

With ``--own-reference`` (session 44) the reference is rstrace's own converged frame (64 x
64, seed 7, cached as ``rough_equal_time.py --own-reference`` caches it), so each share is
rstrace's sampling error alone, the error that the equal-time ratio measures; Mitsuba is not
needed then. ``floor shadow edge``: floor pixels whose direct light over 16 jittered samples
differs from the pixel centre's by over 10% (a hard shadow's edge; a lit floor varies by
under 1% across a pixel), ``floor lit`` the other lit ones.

Reproduce: ``DRJIT_LIBLLVM_PATH=<libLLVM.so >= 16> NUMBA_NUM_THREADS=1 PYTHONPATH=.
python scripts/rough_error_split.py [--samples 1 --glossy 16 --seeds 4 --ref-spp 4096]
[--own-reference]``.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

import numpy as np

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench import frame_rough as fr
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing.whitted import render


def say(line: str) -> None:
    sys.stdout.write(line + "\n")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--glossy", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--own-reference", action="store_true",
                    help="against rstrace's own converged frame (docstring)")
    ap.add_argument("--cache", default="/tmp/ownref-cache", help="where it is kept")
    a = ap.parse_args()
    scene = scenes.rough_materials(a.width, a.height)
    acc = create_accelerator("BVH", scene.arrays())
    st = RenderSettings(max_depth=5, samples=a.samples, glossy_samples=a.glossy).validated()
    frames = [render(scene, replace(st, seed=s), accel=acc).radiance for s in range(a.seeds)]
    conv = render(scene, replace(st, glossy_samples=256), accel=acc).radiance
    ref = own_reference(scene, acc, a) if a.own_reference else mitsuba_reference(scene, a)
    lum = fr._luminance
    lr = lum(ref)

    def rel(img):
        return np.abs(lum(img) - lr) / (lr + fr.REL_EPS)

    # regions
    jit = RenderSettings(max_depth=5, samples=16, glossy_samples=1).validated()
    names = [m.name for m in scene.materials if m is not None]
    # a material's pixels at 16 jittered samples: every sample white (> 0.5 is "any"), so
    # a pixel wholly on it is 1.0; take those as its own, the rest are edges
    own, cover = {}, {}
    for n in names:
        cov = fr.material_cover(scene, n, jit, acc)
        own[n] = cov > 1.0 - 1e-6  # (radiance is float32)
        cover[n] = cov
    anything = np.sum(np.stack(list(cover.values())), axis=0) > 0.0
    edges = anything & ~np.any(np.stack(list(own.values())), axis=0)
    direct = render(scene, replace(st, max_depth=0), accel=acc).radiance
    lit = lum(direct) > 1e-6
    high = lum(direct) >= 0.5 * lum(conv)
    # the floor's pixels whose 16 jittered samples disagree with the centre (a shadow edge)
    dl = lum(render(scene, replace(jit, max_depth=0), accel=acc).radiance)
    dl_centre = lum(render(scene, replace(jit, samples=1, max_depth=0), accel=acc).radiance)
    shadow_edge = own["floor"] & (dl > 1e-6) & (np.abs(dl - dl_centre) > 0.1 * dl)
    regions = {"edges": edges, "floor shadow edge": shadow_edge,
               "floor lit": own["floor"] & lit & ~shadow_edge,
               "floor shadow": own["floor"] & ~lit & ~shadow_edge, "box": own["red"]}
    for n in ("metal", "glass", "plastic"):
        regions[f"{n} highlight"] = own[n] & high
        regions[f"{n} reflected"] = own[n] & ~high
    regions["background"] = ~anything
    npx = lr.size
    stack = np.stack([lum(f) for f in frames])
    noise = np.sqrt(np.mean((stack - stack.mean(axis=0)) ** 2, axis=0) * a.seeds
                    / max(a.seeds - 1, 1)) / (lr + fr.REL_EPS)
    e_def, e_conv = rel(frames[0]), rel(conv)
    say(f"rough_materials {a.width}x{a.height}, rstrace {a.samples} x {a.glossy}, "
          f"{a.seeds} seeds, " + ("rstrace's own reference (64 x 64)" if a.own_reference
                                  else f"Mitsuba reference {a.ref_spp} spp"))
    say(f"{'region':16s} {'pixels':>6s} {'defaults':>9s} {'glossy conv.':>12s} "
          f"{'noise':>7s} {'noise/px':>8s}")
    tot = np.zeros(3)
    for name, m in regions.items():
        v = np.array([e_def[m].sum(), e_conv[m].sum(), noise[m].sum()]) / npx
        tot += v
        per = noise[m].mean() if m.any() else 0.0
        say(f"{name:16s} {int(m.sum()):6d} {v[0]:9.4f} {v[1]:12.4f} {v[2]:7.4f} "
              f"{per:8.4f}")
    say(f"{'all':16s} {npx:6d} {tot[0]:9.4f} {tot[1]:12.4f} {tot[2]:7.4f}")


def mitsuba_reference(scene, a) -> np.ndarray:
    mi, why = fr.mitsuba_llvm()
    if mi is None:
        raise SystemExit(why)
    ms = mi.load_dict(fr.rough_scene_dict(scene, mi, a.width, a.height, 5, 1))
    return fr._mitsuba_render(mi, ms, a.ref_spp, seed=1)[0]


def own_reference(scene, acc, a) -> np.ndarray:
    """rstrace's 64 x 64 frame, seed 7 (``rough_equal_time.py --own-reference``'s, from its
    cache when there)."""
    path = f"{a.cache}/rstrace_{a.width}x{a.height}_64x64.npy"
    if os.path.exists(path):
        return np.load(path)
    st = RenderSettings(max_depth=5, samples=64, glossy_samples=64, seed=7).validated()
    img = render(scene, st, accel=acc).radiance.astype(np.float64)
    os.makedirs(a.cache, exist_ok=True)
    np.save(path, img)
    return img


if __name__ == "__main__":
    main()
