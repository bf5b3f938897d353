"""``scripts/trade_frames.py``'s sequence with the fallback on only, several rounds.

::

    NUMBA_NUM_THREADS=1 PYTHONPATH=TREE python scripts/fallback_rounds.py SCENE W H SPP ROUNDS TAG

Per process: a base frame and an INTERPOLANT frame of each kind (fallback off, on) to load
the kernels, then ROUNDS rounds of a fresh renderer's first frame, camera step and pan
(``bench trade``'s cameras), each INTERPOLANT frame timed right after the base frame of its
camera (process CPU, one thread, epsilon 0.01). One JSON line per round: per camera the
ratio ``x`` (base / INTERPOLANT CPU), the base seconds, the interpolated percentage, the
max display error against the base frame, and the fallback's ``added_s`` / ``saved_s``,
whether the whole frame is traced and whether the frame compiled (None on trees without
it). Alternate trees by process (A B B A) to compare them (docs/bench-trade-first-frames.md,
session 43); the tree is PYTHONPATH's (the script does not add its own).
"""

from __future__ import annotations

import json
import sys
import time

import numba
import numpy as np

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.trade import moved_cameras
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.whitted import render


def main(argv=None) -> int:
    a = sys.argv[1:] if argv is None else argv
    name, w, h, spp, rounds, tag = a[0], int(a[1]), int(a[2]), int(a[3]), int(a[4]), a[5]
    numba.set_num_threads(1)
    clock = time.process_time
    sc = scenes.build(name, w, h)
    accel = create_accelerator("BVH", sc.arrays())
    cams = moved_cameras(sc)
    bs = RenderSettings(samples=spp)
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.01, samples=spp)
    render(sc, bs, accel)
    for fallback in (False, True):  # (loads the kernels of both, not timed)
        r = InterpolantRenderer()
        r.auto_fallback = fallback
        r.render(sc, st, accel)
    for rnd in range(rounds):
        r = InterpolantRenderer()
        out = {}
        for key, cam in cams.items():
            sc.set_camera(cam)
            t = clock()
            b = render(sc, bs, accel)
            tb = clock() - t
            t = clock()
            f = r.render(sc, st, accel)
            ti = clock() - t
            err = np.abs(image.to_display(f.radiance) - image.to_display(b.radiance)).max()
            fb = f.stats.get("fallback", {})
            out[key] = dict(x=round(tb / ti, 3), base=round(tb, 3),
                            interp=round(100 * f.stats["interpolated_fraction"], 1),
                            err=round(float(err), 4), added=round(fb.get("added_s", 0.0), 3),
                            saved=round(fb.get("saved_s", 0.0), 3), all=fb.get("all_traced"),
                            comp=fb.get("compiled"))
        sys.stdout.write(json.dumps(dict(tag=tag, scene=name, spp=spp, rnd=rnd, **out)) + "\n")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
