"""A probe, not a mode (issue 24, session 44; docs/glossy.md, "session 44 (rough)"): what
the rough frame's equal-time ratio against Mitsuba would be if the pixels on an *edge* took
jittered pixel samples and every other pixel kept the frame's own samples.

At one pixel sample rstrace traces the pixel centre (``cameras.pixel_jitter``), and half of
the 1 x 16 frame's error against its own converged reference is then in 3% of the pixels:
the silhouettes (every instance's outline) and the floor's hard-shadow edges, where the
centre's value is not the pixel's mean and no glossy sample changes it. An edge here is a
pixel whose centre *key* (the instance its camera ray hits, and whether the point light
lights that centre) differs from one of its four neighbours' (``--ring`` pixels away);
edge pixels are rendered again with ``--edges S:G`` (a box estimate: jittered Owen-scrambled
Sobol samples) through the base tracer's incremental frame (``render(pixels=, base=)``), the
others keep the ``--base`` frame. The composite is deterministic (the keys come from the
centre rays, no random numbers) and each edge pixel's estimate is the box's, unbiased.

Its CPU time is the two partial frames plus the key pass (camera rays, their closest hits
and a direct-light frame of the centres: an upper bound on what a tracer that read the
keys off its own first pass would pay). The ratio is measured as
``rough_equal_time.py --own-reference`` measures it (rstrace's frames, seeds 100..., against
its 64 x 64 reference, Mitsuba's fitted error at the same CPU against its 4096 spp one;
both cached in ``--cache``; the references must exist: run that script once first).

Reproduce: ``DRJIT_LIBLLVM_PATH=<libLLVM.so >= 16> NUMBA_NUM_THREADS=1 PYTHONPATH=.
python scripts/rough_edge_samples.py [--base 1:16] [--edges 16:1 8:2 4:4]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rough_equal_time as ret  # noqa: E402  (the ratio's own helpers)

from rstrace_engine import scenes  # noqa: E402
from rstrace_engine.accel.accelerators import create_accelerator  # noqa: E402
from rstrace_engine.bench import frame_rough as fr  # noqa: E402
from rstrace_engine.frame import RenderSettings  # noqa: E402
from rstrace_engine.geometry.cameras import camera_params, camera_rays  # noqa: E402
from rstrace_engine.tracing.whitted import render  # noqa: E402


def centre_keys(scene, acc) -> np.ndarray:
    """(h, w) int64: each pixel centre's key, ``2 instance + lit`` (the instance its camera
    ray hits, -1 a miss; lit: the centre's depth-0 radiance is above 0, the direct light
    where it hits, the background's colour where it misses)."""
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    pix = np.arange(w * h, dtype=np.int64)
    o, d, tmin, tmax = camera_rays(cp, pix, np.full((w * h, 2), 0.5))
    inst = acc.closest_hit(o, d, tmin, tmax).inst.reshape(h, w).astype(np.int64)
    lit = fr._luminance(render(scene, RenderSettings(max_depth=0, samples=1).validated(),
                               accel=acc).radiance) > 1e-6
    return inst * 2 + lit


def edges_of(key: np.ndarray, ring: int = 1) -> np.ndarray:
    """(h, w) bool: the pixels whose ``key`` differs from a 4-neighbour's ``ring`` pixels
    away; the frame's border (``ring`` pixels wide) counts as an edge."""
    edge = np.zeros(key.shape, bool)
    edge[ring:, :] |= key[ring:, :] != key[:-ring, :]
    edge[:-ring, :] |= key[:-ring, :] != key[ring:, :]
    edge[:, ring:] |= key[:, ring:] != key[:, :-ring]
    edge[:, :-ring] |= key[:, :-ring] != key[:, ring:]
    edge[:ring, :] = edge[-ring:, :] = True
    edge[:, :ring] = edge[:, -ring:] = True
    return edge


def edge_pixels(scene, acc, ring: int = 1) -> np.ndarray:
    """(h, w) bool: :func:`edges_of` the :func:`centre_keys`."""
    return edges_of(centre_keys(scene, acc), ring)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--base", default="1:16", help="S:G of every pixel's frame")
    ap.add_argument("--edges", nargs="+", default=["16:1", "8:2", "4:4"],
                    help="S:G of the edge pixels, one composite each")
    ap.add_argument("--ring", type=int, default=1)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cache", default="/tmp/ownref-cache")
    a = ap.parse_args()
    scene = scenes.rough_materials(a.width, a.height)
    acc = create_accelerator("BVH", scene.arrays())
    tag = f"{a.width}x{a.height}"
    rref = np.load(f"{a.cache}/rstrace_{tag}_64x64.npy")
    mref = np.load(f"{a.cache}/mitsuba_{tag}_4096.npy")
    mi, ms = fr.mitsuba_rough(scene, a.width, a.height)
    per_spp = fr.mitsuba_cpu_per_spp(mi, ms)
    spps = (12, 16, 24, 32, 48, 64, 96)
    errs = np.array([[fr.error_stats(fr._mitsuba_render(mi, ms, spp, seed=10 + k)[0], mref,
                                     None)["rel_mean"] for spp in spps] for k in range(6)])
    fits = [ret.power_fit(spps, e) for e in errs]
    s0, g0 = map(int, a.base.split(":"))
    st = RenderSettings(max_depth=5, samples=s0, glossy_samples=g0).validated()
    warm = render(scene, st, accel=acc)  # compiles; the base of the first partial frame
    edge = edge_pixels(scene, acc, a.ring).reshape(-1)
    ret.say(dict(load=os.getloadavg(), mitsuba_per_spp_cpu_s=round(per_spp, 6),
                 edge_pixels=int(edge.sum()), base=a.base))

    def frame(seed: int, edges: str | None):
        s1 = replace(st, seed=seed)
        if edges is None:
            return render(scene, s1, accel=acc)
        se, ge = map(int, edges.split(":"))
        e = edge_pixels(scene, acc, a.ring).reshape(-1)
        f = render(scene, s1, accel=acc, pixels=~e, base=warm)
        return render(scene, replace(s1, samples=se, glossy_samples=ge), accel=acc,
                      pixels=e, base=f)

    for rnd in range(a.rounds):
        for edges in [None, *a.edges]:
            ts, rs = [], []
            for k in range(a.seeds):
                c = time.process_time()
                f = frame(100 + k, edges)
                ts.append(time.process_time() - c)
                rs.append(fr.error_stats(f.radiance.astype(np.float64), rref, None)["rel_mean"])
            t = float(np.median(ts))
            mit = ret.mean_se([ret.power_at(f, t / per_spp) for f in fits])
            q = ret.ratio_se(ret.mean_se(rs), mit)
            ret.say(dict(round=rnd, edges=edges or "none", cpu_s=round(t, 4),
                         rstrace=round(float(np.mean(rs)), 5), mitsuba=round(mit[0], 5),
                         ratio=[round(q[0], 3), round(q[1], 3)],
                         load=[round(x, 2) for x in os.getloadavg()]))


if __name__ == "__main__":
    main()
