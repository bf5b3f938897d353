"""What a viewport edit costs in the core beside a heavy scene: the worker's ``apply`` of
one moved object and its coarse image (``interactive.trace_view`` at 1/COARSE_FACTOR),
then a profile of one more edit.

    python scripts/view_edit_profile.py 1M | 4M | 60k | dups

``dups``: 2,000 linked duplicates of a 20k-triangle mesh (``bench scale``'s scenes).
Results: ``docs/bench-scale-bpy.md`` (Viewport update after the move).
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rstrace_engine.bench.scale import _count, big_scene, duplicates_scene  # noqa: E402
from rstrace_engine.frame import RenderSettings  # noqa: E402
from rstrace_engine.geometry import shapes  # noqa: E402
from rstrace_engine.geometry.edits import ObjectTransform  # noqa: E402
from rstrace_engine.interactive import coarse_camera, trace_view  # noqa: E402
from rstrace_engine.session import Session  # noqa: E402


def main(kind: str) -> None:
    dups = kind == "dups"
    scene = duplicates_scene(2000, 20_000) if dups else big_scene(_count(kind))
    name = "Pebble0000" if dups else "Small"
    session = Session(scene, RenderSettings(samples=1))
    cam = coarse_camera(scene.camera)
    settings = replace(session.settings, light_samples=1)
    trace_view(session, cam, settings)

    def edit(k: int) -> tuple[float, float]:
        session.submit([ObjectTransform(name, shapes.transform((1.5, -0.8 + 0.01 * k,
                                                                 -0.85)))])
        t0 = time.perf_counter()
        session.apply()
        t1 = time.perf_counter()
        trace_view(session, cam, settings)
        return 1e3 * (t1 - t0), 1e3 * (time.perf_counter() - t1)

    for k in range(3):  # warm
        edit(k)
    times = [edit(k) for k in range(3, 8)]
    sys.stdout.write(f"{kind}: apply ms, coarse image ms: "
                     f"{[(round(a, 1), round(b, 1)) for a, b in times]}\n")
    prof = cProfile.Profile()
    prof.runcall(edit, 20)
    pstats.Stats(prof).sort_stats("tottime").print_stats(12)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "1M")
