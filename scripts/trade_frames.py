"""INTERPOLANT against BASE frame by frame, with and without the measured fallback.

::

    python scripts/trade_frames.py studio --spp 1,4 [--no-world] [--width 320 --height 240]
    python scripts/trade_frames.py glossy --width 640 --height 480 --fallback-only --rounds 3

For each count of samples per pixel and each of ``fallback`` off (cells built wherever they
may be) and on (the mode's default), renders ``bench trade``'s cameras (first frame from an
empty cache, camera step, pan) in INTERPOLANT mode, each timed right after a base frame of
the same camera (process CPU time, one numba thread), and prints one JSON line per setting:
per camera the speedup, the base frame's seconds, the interpolated percentage, the maximum
display error against that base frame and the pixels over epsilon + 1e-6. Unlike ``bench
trade`` it reports the frames without the fallback too (interpolated share and error), and
it runs unchanged on older checkouts (to compare a detached worktree of main with a branch,
run it in each, one after the other). ``--fallback-only --rounds R``: the fallback on only, its
kernels loaded by an untimed frame first, then ``R`` rounds of a fresh renderer each (the
fallback's decisions and ledger, ``added_s`` / ``saved_s`` / ``all_traced`` / ``compiled``,
in each camera's row): several rounds in one process, to be alternated with another
checkout's processes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rstrace_engine import image, scenes  # noqa: E402
from rstrace_engine.accel.accelerators import create_accelerator  # noqa: E402
from rstrace_engine.bench.trade import moved_cameras  # noqa: E402
from rstrace_engine.frame import RenderSettings  # noqa: E402
from rstrace_engine.interpolants.render import InterpolantRenderer  # noqa: E402
from rstrace_engine.tracing.whitted import render  # noqa: E402

#: Display-space slack of "over epsilon" (float32 frames), as the bound tests.
FLOAT_TOL = 1e-6


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scene")
    p.add_argument("--spp", default="1")
    p.add_argument("--epsilon", type=float, default=0.01)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    p.add_argument("--no-world", action="store_true",
                   help="the world's colour as a background only (the world does not light)")
    p.add_argument("--fallback-only", action="store_true",
                   help="the fallback on only (its kernels loaded by an untimed frame first)")
    p.add_argument("--rounds", type=int, default=1, help="fresh renderers per setting")
    args = p.parse_args(argv)
    numba.set_num_threads(1)
    clock = time.process_time
    sc = scenes.build(args.scene, args.width, args.height)
    if args.no_world:
        sc.set_world_color(tuple(sc.world_color), lights=False)
    accel = create_accelerator("BVH", sc.arrays())
    cams = moved_cameras(sc)
    for spp in (int(x) for x in args.spp.split(",")):
        bs = RenderSettings(samples=spp)
        st = RenderSettings(mode="INTERPOLANT", epsilon=args.epsilon, samples=spp)
        render(sc, bs, accel)  # compile / cache load, not timed
        fallbacks = (True,) if args.fallback_only else (False, True)
        if args.fallback_only:
            for fallback in (False, True):  # both paths' kernels, not timed
                r = InterpolantRenderer()
                r.auto_fallback = fallback
                r.render(sc, st, accel)
        for fallback, rnd in ((f, k) for f in fallbacks for k in range(args.rounds)):
            r = InterpolantRenderer()
            r.auto_fallback = fallback
            row = {}
            for key, cam in cams.items():
                sc.set_camera(cam)
                t = clock()
                b = render(sc, bs, accel)
                tb = clock() - t
                t = clock()
                f = r.render(sc, st, accel)
                ti = clock() - t
                err = np.abs(image.to_display(f.radiance)
                             - image.to_display(b.radiance)).max(axis=-1)
                row[key] = dict(speedup=round(tb / ti, 2), base_s=round(tb, 2),
                                interp=round(100 * f.stats["interpolated_fraction"], 1),
                                max_err=round(float(err.max()), 4),
                                over=int(np.count_nonzero(err > args.epsilon + FLOAT_TOL)))
                fb = f.stats.get("fallback", {})
                if fallback:
                    row[key].update(added=round(fb.get("added_s", 0.0), 3),
                                    saved=round(fb.get("saved_s", 0.0), 3),
                                    all=fb.get("all_traced"), comp=fb.get("compiled"))
            sys.stdout.write(json.dumps(dict(scene=args.scene, world=not args.no_world,
                                             spp=spp, fallback=fallback, round=rnd,
                                             cameras=row)) + "\n")
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
