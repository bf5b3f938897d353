"""Cost of a light drag's steps (docs/RELIGHT.md): museum BASE at WIDTH x HEIGHT, a first
full frame that keeps the per-light records, then MOVES consecutive 5 cm moves of
``Ceiling4``, each relit; prints ``wall/CPU`` milliseconds of ``Session.apply`` and
``Session.render`` per move (CPU: the process's, every thread), then the median split of a
step (wall ms): the edit's apply, the relight's stages (``frame.stats["relight_split_s"]``:
the surfaces, the light's states and shadow rays' set-up, its shadow rays, the shade
kernel, the terms replaced, the pixel records' light bits, the recombination) and the rest
of the render. Run it from two checkouts to compare them.
``PYTHONPATH=. python scripts/relight_drag.py WIDTH HEIGHT MOVES``."""

import sys
import time
from dataclasses import replace

import numpy as np

import rstrace_engine
from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import edits as E
from rstrace_engine.session import Session


def main(width: int, height: int, moves: int) -> None:
    sess = Session(scenes.museum(width, height), RenderSettings(mode="BASE"))
    sess.light_terms = True
    sess.render()
    out, splits = [], []
    for _ in range(moves):
        li = sess.scene.lights[sess.scene.light_slot("Ceiling4")]
        x, y, z = li.position
        t0, c0 = time.perf_counter(), time.process_time()
        sess.apply([E.LightSet("Ceiling4", replace(li, position=(x + 0.05, y, z)))])
        t1 = time.perf_counter()
        frame = sess.render()
        t2 = time.perf_counter()
        out.append((t2 - t0, time.process_time() - c0))
        assert frame.stats.get("relit"), frame.stats
        split = {"apply": t1 - t0}
        split.update(frame.stats.get("relight_split_s", {}))
        split["render rest"] = (t2 - t1) - sum(v for k, v in split.items() if k != "apply")
        splits.append(split)
    sys.stdout.write(f"{rstrace_engine.__file__}: light records "
                     f"{frame.stats['light_records_mb']:.1f} MB, wall/CPU ms per move: "
                     + " ".join(f"{w * 1e3:.0f}/{c * 1e3:.0f}" for w, c in out) + "\n")
    keys = list(dict.fromkeys(k for s in splits for k in s))
    sys.stdout.write("median wall ms: " + ", ".join(
        f"{k} {1e3 * np.median([s.get(k, 0.0) for s in splits]):.1f}" for k in keys)
        + f"; step {1e3 * np.median([w for w, _ in out]):.1f}\n")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
