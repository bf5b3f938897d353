"""The cell build compiled beside the frames (``interpolants/build_beside.py``), measured.

    NUMBA_CACHE_DIR=<an empty folder> python scripts/cell_build_beside.py [--chain-only]
                                      [--scene three_spheres --size 160x120] [--json out.json]

From an empty kernel cache, in one process: a BASE frame (compiles the tracer), then
INTERPOLANT frames with the measured fallback (the default): the first is the base tracer's
while the background process compiles the cell build's kernels; the script waits for that
process, then renders the next frame (a new seed) and counts the kernels it compiled and
loaded (``kernel_cache.counts``); ``--cells``: those frames with the fallback off (cells
built wherever the rays need them). ``--chain-only``: the background process compiles the
error predicate's chain alone (what it did first: ``warm_first.compile_predicate``), for
comparison. Reported: each frame's wall and process CPU time (this process's threads; the
background process's CPU separately), its kernels compiled / loaded, cells built, and
whether it was the base tracer's (``build_compiling``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

CHAIN_ONLY = ("from rstrace_engine.warm_first import compile_predicate; "
              "from rstrace_engine.warm_kernels import warm_scene; "
              "compile_predicate(warm_scene())")


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--chain-only", action="store_true")
    ap.add_argument("--scene", default="three_spheres")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--json", default=None)
    ap.add_argument("--cells", action="store_true",
                    help="the frames after the background compile with the fallback off "
                         "(cells built wherever the rays need them: what building them "
                         "still compiles)")
    args = ap.parse_args(argv)
    if not os.environ.get("NUMBA_CACHE_DIR"):
        sys.exit("set NUMBA_CACHE_DIR to an empty folder")
    from rstrace_engine import kernel_cache, scenes
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.interpolants import build_beside
    from rstrace_engine.session import Session

    if args.chain_only:
        build_beside._CODE = CHAIN_ONLY
    w, h = (int(x) for x in args.size.split("x"))
    rows = []

    def frame(label, session):
        mark, t0, c0 = kernel_cache.mark(), time.perf_counter(), _cpu()
        f = session.render()
        n = kernel_cache.counts(since=mark)
        fb = f.stats.get("fallback") or {}
        rows.append(dict(frame=label, wall_s=time.perf_counter() - t0, cpu_s=_cpu() - c0,
                         compiled=n["compiled"], loaded=n["loaded"],
                         cells_built=f.stats.get("cells_built"),
                         build_compiling=bool(fb.get("build_compiling"))))
        sys.stdout.write(f"{rows[-1]}\n")

    scene = scenes.build(args.scene, w, h)
    frame("BASE", Session(scene, RenderSettings(mode="BASE", samples=1, max_depth=3)))
    s = Session(scene, RenderSettings(mode="INTERPOLANT", samples=1, max_depth=3,
                                      epsilon=0.02))
    frame("INTERPOLANT 1", s)
    t0 = time.perf_counter()
    while build_beside.compiling():
        time.sleep(0.2)
    waited = dict(background_wall_s=time.perf_counter() - t0,
                  background_cpu_s=_children_cpu(), failed=build_beside._STATE["failed"])
    sys.stdout.write(f"{waited}\n")
    s.interpolants.auto_fallback = not args.cells
    s.settings.seed += 1
    frame("INTERPOLANT 2 (after the background compile)", s)
    s.settings.seed += 1
    frame("INTERPOLANT 3", s)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(chain_only=args.chain_only, cells=args.cells, frames=rows, **waited),
                      f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
