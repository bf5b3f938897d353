"""Cost of a light drag's steps (docs/RELIGHT.md): museum BASE at WIDTH x HEIGHT, a first
full frame that keeps the per-light records, then MOVES consecutive 5 cm moves of
``Ceiling4``, each relit; prints ``wall/CPU`` milliseconds of ``Session.apply`` and
``Session.render`` per move (CPU: the process's, every thread), then the median split of a
step (wall ms): the edit's apply, the relight's stages (``frame.stats["relight_split_s"]``:
the surfaces, the light's states and shadow rays' set-up, the drag's ball proof, its
shadow rays, the shade kernel, the terms replaced, the pixel records' light bits, the
recombination) and the rest of the render, and the shadow rays traced and skipped (proven)
per move. ``linked``: ``Ceiling4`` lights every object but the mirror wall and every
object but the hall casts its shadow (light and shadow linking); the script then also
times a fresh frame of the moved scene (the move's speedup). Run it from two checkouts to
compare them.
``PYTHONPATH=. python scripts/relight_drag.py WIDTH HEIGHT MOVES [linked]``."""

import sys
import time
from dataclasses import replace

import numpy as np

import rstrace_engine
from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import edits as E
from rstrace_engine.session import Session

LIGHT = "Ceiling4"


def main(width: int, height: int, moves: int, linked: bool = False) -> None:
    scene = scenes.museum(width, height)
    if linked:
        j = scene.light_slot(LIGHT)
        scene.set_light(j, replace(scene.lights[j], receivers=(("MirrorWall", False),),
                                   blockers=(("Room", False),)))
    sess = Session(scene, RenderSettings(mode="BASE"))
    sess.light_terms = True
    sess.render()
    out, splits, rays = [], [], []
    relit = 0
    for _ in range(moves):
        li = sess.scene.lights[sess.scene.light_slot(LIGHT)]
        x, y, z = li.position
        t0, c0 = time.perf_counter(), time.process_time()
        sess.apply([E.LightSet(LIGHT, replace(li, position=(x + 0.05, y, z)))])
        t1 = time.perf_counter()
        frame = sess.render()
        t2 = time.perf_counter()
        out.append((t2 - t0, time.process_time() - c0))
        relit += bool(frame.stats.get("relit"))
        split = {"apply": t1 - t0}
        split.update(frame.stats.get("relight_split_s", {}))
        split["render rest"] = (t2 - t1) - sum(v for k, v in split.items() if k != "apply")
        splits.append(split)
        rays.append((frame.stats.get("relight_shadow_rays", 0),
                     frame.stats.get("relight_shadow_skipped", 0)))
    sys.stdout.write(f"{rstrace_engine.__file__}: light records "
                     f"{frame.stats.get('light_records_mb', 0.0):.1f} MB, relit "
                     f"{relit}/{moves}, wall/CPU ms per move: "
                     + " ".join(f"{w * 1e3:.0f}/{c * 1e3:.0f}" for w, c in out) + "\n")
    keys = list(dict.fromkeys(k for s in splits for k in s))
    sys.stdout.write("median wall ms: " + ", ".join(
        f"{k} {1e3 * np.median([s.get(k, 0.0) for s in splits]):.1f}" for k in keys)
        + f"; step {1e3 * np.median([w for w, _ in out]):.1f}\n")
    sys.stdout.write("shadow rays traced/skipped per move: "
                     + " ".join(f"{a}/{b}" for a, b in rays) + "\n")
    if linked:
        t0, c0 = time.perf_counter(), time.process_time()
        ref = Session(sess.scene.copy(), RenderSettings(mode="BASE")).render()
        w, c = time.perf_counter() - t0, time.process_time() - c0
        same = np.array_equal(ref.radiance, frame.radiance)
        med = np.median([c for _, c in out[1:]])
        sys.stdout.write(f"fresh frame of the moved scene: wall/CPU {w * 1e3:.0f}/"
                         f"{c * 1e3:.0f} ms (the last move's frame equal: {same}); "
                         f"speedup (CPU, median move 2-{moves}): {c / med:.1f}x\n")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]),
         len(sys.argv) > 4 and sys.argv[4] == "linked")
