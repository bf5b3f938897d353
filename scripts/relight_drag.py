"""Cost of a light drag's steps (docs/RELIGHT.md): museum BASE at WIDTH x HEIGHT, a first
full frame that keeps the per-light records, then MOVES consecutive 5 cm moves of
``Ceiling4``, each relit; prints ``wall/CPU`` milliseconds of ``Session.render`` per move
(CPU: the process's, every thread). Run it from two checkouts to compare them.
``PYTHONPATH=. python scripts/relight_drag.py WIDTH HEIGHT MOVES``."""

import sys
import time
from dataclasses import replace

import rstrace_engine
from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import edits as E
from rstrace_engine.session import Session


def main(width: int, height: int, moves: int) -> None:
    sess = Session(scenes.museum(width, height), RenderSettings(mode="BASE"))
    sess.light_terms = True
    sess.render()
    out = []
    for _ in range(moves):
        li = sess.scene.lights[sess.scene.light_slot("Ceiling4")]
        x, y, z = li.position
        sess.apply([E.LightSet("Ceiling4", replace(li, position=(x + 0.05, y, z)))])
        t0, c0 = time.perf_counter(), time.process_time()
        frame = sess.render()
        out.append((time.perf_counter() - t0, time.process_time() - c0))
        assert frame.stats.get("relit"), frame.stats
    sys.stdout.write(f"{rstrace_engine.__file__}: light records "
                     f"{frame.stats['light_records_mb']:.1f} MB, wall/CPU ms per move: "
                     + " ".join(f"{w * 1e3:.0f}/{c * 1e3:.0f}" for w, c in out) + "\n")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
