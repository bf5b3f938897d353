"""Pixel sampler: per-pixel RMSE against a converged reference, the jittered grid this
project used until session 27 against the Owen-scrambled Sobol sampler of
:func:`rstrace_engine.geometry.cameras.pixel_jitter` (docs/accuracy.md, "Pixel samples").

``python scripts/pixel_sampler_numbers.py [--scenes three_spheres,museum,studio] [--size 96x72]
[--spp 4,16,64] [--seeds 4] [--first-seed 0] [--ref-spp 1024] [--ref-sampler sobol] [--time]
[--frames N]``

Both samplers trace the same number of rays; the reference is the mean of ``--ref-spp``
samples per pixel with the new sampler (both are unbiased; ``--ref-sampler grid`` draws it
with the grid instead). RMSE is over all pixels, and over the *edge* pixels (those whose
reference differs from the 1-sample centre frame by more than 0.01: geometry and highlight
edges, where the pixel's integral is not smooth).
``--time`` instead times the sampler itself for a tile of ``TILE_RAYS`` rays; ``--frames N``
times whole frames (one numba thread, process CPU time) with the two samplers alternated
(A/B/B/A..., ``N`` pairs per scene and sample count) and reports the per-pair ratios.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import cameras
from rstrace_engine.geometry.cameras import _mix64
from rstrace_engine.tracing import batches, whitted


def grid_jitter(pixels: np.ndarray, samples: int, seed: int = 0) -> np.ndarray:
    """The jittered grid of ``pixel_jitter`` before session 27 (ceil(sqrt(n))^2 cells, the
    offset in a cell a hash of (seed, pixel, sample)), kept here for the comparison."""
    pixels = np.asarray(pixels, np.int64)
    k = len(pixels)
    if samples <= 1:
        return np.full((1, k, 2), 0.5)
    g = int(np.ceil(np.sqrt(samples)))
    cells = np.arange(samples)
    s = _mix64(np.array([int(seed) & 0xFFFFFFFFFFFFFFFF], np.uint64)
               + np.uint64(0x3C6EF372FE94F82A))
    key = _mix64((pixels.astype(np.uint64)[None, :] * np.uint64(samples)
                  + cells.astype(np.uint64)[:, None]) ^ s)
    ux = (key >> np.uint64(11)).astype(np.float64) * 2.0 ** -53
    uy = (_mix64(key) >> np.uint64(11)).astype(np.float64) * 2.0 ** -53
    sx = (cells % g)[:, None] + ux
    sy = (cells // g % g)[:, None] + uy
    return np.stack([sx / g, sy / g], axis=-1)


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


SAMPLERS = {"grid": grid_jitter, "sobol": cameras.pixel_jitter}


def render(sc, acc, spp, seed, sampler):
    batches.pixel_jitter = SAMPLERS[sampler]
    try:
        f = whitted.render(sc, RenderSettings(samples=spp, seed=seed), accel=acc)
    finally:
        batches.pixel_jitter = cameras.pixel_jitter
    return np.asarray(f.radiance, np.float64)


def frame_times(a):
    import numba
    numba.set_num_threads(1)
    w, h = (int(v) for v in a.size.split("x"))
    for name in a.scenes.split(","):
        sc = getattr(scenes, name)(w, h)
        acc = create_accelerator("BVH", sc.arrays())
        for spp in (int(v) for v in a.spp.split(",")):
            render(sc, acc, spp, 0, "grid")  # warm
            t = {"grid": [], "sobol": []}
            for p in range(a.frames):
                for sampler in (("grid", "sobol") if p % 2 == 0 else ("sobol", "grid")):
                    t0 = time.process_time()
                    render(sc, acc, spp, p, sampler)
                    t[sampler].append(time.process_time() - t0)
            r = np.array(t["sobol"]) / np.array(t["grid"])
            _say(f"{name} {w}x{h} {spp} spp: grid {np.median(t['grid']):.3f} s, sobol "
                  f"{np.median(t['sobol']):.3f} s (median CPU); ratio sobol/grid median "
                  f"{np.median(r):.3f}, range {r.min():.3f} .. {r.max():.3f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="three_spheres,museum,studio")
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--spp", default="4,16,64")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--ref-sampler", default="sobol", choices=sorted(SAMPLERS))
    ap.add_argument("--time", action="store_true")
    ap.add_argument("--frames", type=int, default=0)
    a = ap.parse_args()
    if a.frames:
        frame_times(a)
        return
    if a.time:
        from rstrace_engine.tracing.batches import TILE_RAYS
        for spp in (4, 16, 64, 256):
            pix = np.arange(max(1, TILE_RAYS // spp), dtype=np.int64)
            for name, fn in SAMPLERS.items():
                fn(pix, spp, 1)
                t = []
                for _ in range(20):
                    t0 = time.process_time()
                    fn(pix, spp, 1)
                    t.append(time.process_time() - t0)
                _say(f"{name} spp {spp}: {len(pix) * spp} samples, {1e3 * np.median(t):.2f} ms "
                      "(median of 20, CPU time)")
        return
    w, h = (int(v) for v in a.size.split("x"))
    for name in a.scenes.split(","):
        sc = getattr(scenes, name)(w, h)
        acc = create_accelerator("BVH", sc.arrays())
        ref = render(sc, acc, a.ref_spp, 1000, a.ref_sampler)
        centre = render(sc, acc, 1, 0, "sobol")
        edge = np.abs(ref - centre).max(axis=-1) > 0.01
        _say(f"{name} {w}x{h}: reference {a.ref_spp} spp ({a.ref_sampler}); {edge.sum()} "
              f"edge pixels of {w * h}")
        for spp in (int(v) for v in a.spp.split(",")):
            row = {}
            for sampler in SAMPLERS:
                seeds = range(a.first_seed, a.first_seed + a.seeds)
                err = [render(sc, acc, spp, seed, sampler) - ref for seed in seeds]
                row[sampler] = (np.sqrt(np.mean([np.mean(e ** 2) for e in err])),
                                np.sqrt(np.mean([np.mean(e[edge] ** 2) for e in err])))
            g, s = row["grid"], row["sobol"]
            _say(f"  {spp:4d} spp: RMSE all grid {g[0]:.5f} sobol {s[0]:.5f} "
                  f"(ratio {s[0] / g[0]:.3f}); edges grid {g[1]:.5f} sobol {s[1]:.5f} "
                  f"(ratio {s[1] / g[1]:.3f})")


if __name__ == "__main__":
    main()
