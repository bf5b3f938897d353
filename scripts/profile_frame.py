"""Where a warm base-tracer frame spends its time: per stage and depth level, and cProfile.

``NUMBA_NUM_THREADS=1 python scripts/profile_frame.py SCENE [--width W] [--height H]
[--top 18]``

Renders ``scenes.SCENE`` (default RenderSettings, BVH) once to warm it, then profiles a
second frame: the numba kernels are opaque to cProfile (their time lands in the Python
function that calls them), so the stage functions ``whitted.trace`` calls, and the
accelerator's queries, are wrapped with process-time timers keyed by depth level (``L0`` the
camera rays' points, ``L-1`` their query before ``trace``). Prints the stages' split of the
frame's process CPU time, then cProfile's top functions by own time. Used for
docs/bench-frame.md ("Frame hot spots"). Run it from the checkout it should measure, with
``PYTHONPATH=.`` (a script's directory, not the current one, comes first on ``sys.path``).
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import io
import pstats
import sys
import time
from collections import defaultdict

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import soft_lights, whitted

#: (module, name) of what trace() calls per level, timed where it is looked up
STAGES = [(whitted, n) for n in ("surfaces", "shadow_rays", "soft_direct", "proven_rows",
                                 "_shade_level", "seen", "node_seeds", "_next_front",
                                 "scatter_add", "camera_rays", "accumulate")]
STAGES += [(soft_lights, "_soft_kernel")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--width", type=int, default=None)
    ap.add_argument("--height", type=int, default=None)
    ap.add_argument("--top", type=int, default=18)
    ap.add_argument("--samples", type=int, default=None, help="pixel samples")
    ap.add_argument("--glossy-samples", type=int, default=None)
    ap.add_argument("--max-depth", type=int, default=None)
    a = ap.parse_args()
    size = [v for v in (a.width, a.height) if v is not None]
    scene = getattr(scenes, a.scene)(*size)
    given = {"samples": a.samples, "glossy_samples": a.glossy_samples, "max_depth": a.max_depth}
    st = RenderSettings(**{k: v for k, v in given.items() if v is not None}).validated()
    accel = create_accelerator(st.accelerator, scene.arrays(), **st.accelerator_options())
    whitted.render(scene, st, accel=accel)  # warm: kernels loaded, caches filled

    spent: dict = defaultdict(float)
    calls: dict = defaultdict(int)
    rays: dict = defaultdict(int)  # the accelerator queries' rays
    level = [-1]

    def timed(f, name, bump=False):
        @functools.wraps(f)
        def g(*args, **kw):
            if bump:
                level[0] += 1
            t = time.process_time()
            if name in ("closest_hit", "any_hit"):
                rays[name, level[0]] += len(args[0])
            try:
                return f(*args, **kw)
            finally:
                spent[name, level[0]] += time.process_time() - t
                calls[name, level[0]] += 1
        return g

    for mod, name in STAGES:
        setattr(mod, name, timed(getattr(mod, name), name, bump=name == "surfaces"))
    for name in ("closest_hit", "any_hit"):
        setattr(accel, name, timed(getattr(accel, name), name))
    trace = whitted.trace

    def per_batch(*args, **kw):
        level[0] = -1
        return trace(*args, **kw)
    whitted.trace = per_batch

    prof = cProfile.Profile(time.process_time)
    t0 = time.process_time()
    prof.enable()
    frame = whitted.render(scene, st, accel=accel)
    prof.disable()
    cpu = time.process_time() - t0
    lines = [f"{a.scene} {frame.radiance.shape[1]}x{frame.radiance.shape[0]}: {cpu:.2f} s "
             f"CPU, {frame.stats['rays_traced']} rays (stages nest: soft_direct holds "
             f"_soft_kernel and its any_hit calls)"]
    for key in sorted(spent, key=lambda k: -spent[k]):
        if spent[key] >= 0.005 * cpu:
            lines.append(f"  {key[0]:>14} L{key[1]:<2} {spent[key]:8.3f} s "
                         f"{100 * spent[key] / cpu:5.1f}%  ({calls[key]} calls"
                         + (f", {rays[key]} rays)" if key in rays else ")"))
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(a.top)
    lines.append(out.getvalue()[out.getvalue().find("   ncalls"):])
    sys.stdout.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
