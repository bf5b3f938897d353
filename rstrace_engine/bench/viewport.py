"""The viewport session without Blender: edit -> first coarse image -> full image.

``python -m rstrace_engine.bench viewport [--json] [--width W] [--height H] [--threads N]
[--modes BASE,INTERPOLANT] [--repeat R] [--no-cold] [--edits light]``

On *museum* (640x480, 2 threads by default) a :class:`~rstrace_engine.interactive.
ViewportWorker` renders the view; after it has refined its frame, one edit is submitted
and the benchmark records the time from the submission to the first coarse image and to
the first full-resolution image (best of ``--repeat``, and the median), for "move one small
object", "change a material colour", "orbit the camera 2 degrees" and "drag a light"
(2 x ``--repeat`` consecutive 5 cm moves of one of museum's six lights after a first light
edit, each step's full image relit from the per-light records in BASE: ``relit`` counts
them, ``split_ms`` gives the median of each relight stage, :data:`~rstrace_engine.tracing.
light_reshade.SPLIT` with the light bits and the recombination, and of the rest of the step;
no interrupt measured). The interrupt latency is the
time from a submission made while a full frame is being rendered to the worker abandoning
that frame. ``cold_start_s`` / ``warm_start_s``: a fresh Python process from import to the
first viewport image, with an empty numba cache directory (everything compiled) and with
the cache this run filled.

``--json`` prints ``{"rows": [{"scene", "edit", "mode", "first_image_ms",
"full_image_ms", "full_image_median_ms", "interrupt_ms", "relit", "split_ms"}],
"cold_start_s": ...,
"warm_start_s": ...}``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace

import numpy as np

from .. import scenes
from ..frame import RenderSettings
from ..geometry import edits as E
from ..geometry import shapes
from ..interactive import ViewportWorker
from ..session import Session

#: museum keys (the core's default keys are the names): a sculpture near the camera, the
#: bronze of every other sculpture
SMALL_OBJECT, MATERIAL = "Sculpture0462", "bronze"
#: the light the drag row moves (museum's ceiling light over the middle of the hall)
DRAG_LIGHT = "Ceiling4"
EDITS = ("move one small object", "change a material colour", "orbit the camera 2°",
         "drag a light")


def _orbit(camera, degrees: float, target=(2.0, 4.0, 1.0)):
    return replace(camera, matrix=shapes.orbit_z(degrees, target) @ camera.matrix)


def _edit(session, name: str, step: int):
    """The edits (or the new camera) of benchmark edit ``name``, step ``step``."""
    scene = session.scene
    if name == EDITS[0]:
        m = scene.instances[scene.instance_slot(SMALL_OBJECT)]["matrix"].copy()
        m[0, 3] += 0.05 if step % 2 == 0 else -0.05
        return [E.ObjectTransform(SMALL_OBJECT, m)], None
    if name == EDITS[1]:
        old = scene.materials[scene.material_id(MATERIAL)]
        colour = (0.35, 0.22, 0.1) if step % 2 else (0.2, 0.3, 0.5)
        return [E.MaterialSet(MATERIAL, replace(old, diffuse=colour))], None
    if name == EDITS[3]:
        # consecutive small moves (a drag: 5 cm per step, one way)
        li = scene.lights[scene.light_slot(DRAG_LIGHT)]
        x, y, z = li.position
        return [E.LightSet(DRAG_LIGHT, replace(li, position=(x + 0.05, y, z)))], None
    return None, _orbit(scene.camera, 2.0 * (step + 1))


def measure(scene_name: str, mode: str, width: int, height: int, repeat: int,
            edits: tuple = EDITS) -> list[dict]:
    scene = scenes.build(scene_name, width, height)
    settings = RenderSettings(mode=mode)
    session = Session(scene, settings)
    lock = threading.Lock()
    worker = ViewportWorker(lock, samples=4)
    camera = scene.camera
    try:
        worker.submit(session=session, camera=camera, settings=settings)
        worker.wait_idle(600)  # warm: compile/load, build interpolants
        rows = []
        for name in edits:
            firsts, fulls, interrupts, relights, splits = [], [], [], [], []
            drag = name == EDITS[3]
            if drag:
                # the session's first light edit: a full frame that starts keeping the
                # per-light records (Session.light_terms); the drag's steps relight
                worker.wait_idle(600)
                session.submit(_edit(session, name, 0)[0])
                worker.submit()
                worker.wait_idle(600)
            for step in range(2 * repeat if drag else repeat):
                worker.wait_idle(600)
                edits, new_cam = _edit(session, name, step)
                worker.stats["stages"].clear()
                session.submit(edits or ())  # (applied on the worker)
                job = worker.submit(camera=new_cam)
                if new_cam is not None:
                    camera = new_cam
                worker.wait_idle(600)
                # the worker's own clock: from this submission to each stage's image
                st = worker.stats["stages"]
                if worker.latest().job == job and "full_ms" in st:
                    firsts.append(st.get("coarse_ms", st["full_ms"]))  # (relit: no preview)
                    fulls.append(st["full_ms"])
                    fs = worker.last_frame.stats if worker.last_frame is not None else {}
                    relights.append(bool(fs.get("relit")))
                    if fs.get("relit"):
                        # where a relit step's time goes: the relight's stages, and the rest
                        # of the full image's (the edit applied, the frame finished, the
                        # image handed to the host)
                        sp = {k: 1e3 * v for k, v in fs.get("relight_split_s", {}).items()}
                        sp["other"] = st["full_ms"] - 1e3 * fs.get("relight_s", 0.0)
                        splits.append(sp)
                if drag:
                    continue  # (consecutive moves: no interrupt between them)
                # interrupt: re-submit while the next full frame is being rendered
                worker.wait_idle(600)
                n_before = len(worker.stats["interrupts"])
                job = worker.submit(camera=_orbit(camera, 0.5))
                worker.wait_for(lambda im, j=job: im.job == j, 60)
                time.sleep(0.5 * max(worker.stats["stages"].get("full_ms", 20.0)
                                     - worker.stats["stages"].get("coarse_ms", 0.0), 2.0)
                           / 1e3)
                worker.submit(camera=camera)
                worker.wait_idle(600)
                if len(worker.stats["interrupts"]) > n_before:
                    interrupts.append(1e3 * worker.stats["interrupts"][-1])
            rows.append(dict(scene=scene_name, edit=name, mode=mode,
                             first_image_ms=_best(firsts), full_image_ms=_best(fulls),
                             interrupt_ms=_worst(interrupts),
                             full_image_median_ms=_median(fulls),
                             relit=f"{sum(relights)}/{len(relights)}",
                             split_ms={k: _median([sp.get(k, 0.0) for sp in splits])
                                       for k in dict.fromkeys(k for sp in splits for k in sp)}
                             or None))
        return rows
    finally:
        worker.stop()


def picture(path, scene_name: str = "museum", width: int = 320, height: int = 240) -> dict:
    """A strip for the README: the coarse first image (1/8 resolution, stretched), the full
    image, and the frame after moving one sculpture with its dirty pixels in white."""
    from ..image import to_display, write_png

    scene = scenes.build(scene_name, width, height)
    session = Session(scene, RenderSettings())
    worker = ViewportWorker(threading.Lock(), samples=1)
    try:
        job = worker.submit(session=session, camera=scene.camera, settings=session.settings)
        coarse = worker.wait_for(lambda im: im.job == job, 600)
        worker.wait_idle(600)
        full = worker.latest()
        near = "Sculpture0126"  # a sculpture near the camera, where the change shows
        m = session.scene.instances[session.scene.instance_slot(near)]["matrix"].copy()
        m[0, 3] += 0.4
        seen = {}
        # applied here, the worker idle, to read the dirty pixels before they are rendered
        with worker.lock:
            seen["report"] = session.apply([E.ObjectTransform(near, m)])
            seen["mask"] = session.dirty_mask
        worker.submit()
        worker.wait_idle(600)
        after = worker.latest()
    finally:
        worker.stop()
    f = max(1, width // coarse.rgba.shape[1])
    big = np.repeat(np.repeat(coarse.rgba[..., :3], f, axis=0), f, axis=1)
    panels = [to_display(big[:height, :width]), to_display(full.rgba[..., :3])]
    shown = to_display(after.rgba[..., :3]) * 0.4
    if seen.get("mask") is not None:
        shown[seen["mask"]] = 1.0
    panels.append(shown)
    gap = np.ones((height, 4, 3))
    strip = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)
    write_png(path, strip)
    rep = seen.get("report")
    return dict(coarse_stretch=f,
                dirty_fraction=None if rep is None else rep.dirty_fraction)


def _best(values):
    v = [x for x in values if not math.isnan(x)]
    return round(min(v), 1) if v else None


def _median(values):
    v = [x for x in values if not math.isnan(x)]
    return round(float(np.median(v)), 1) if v else None


def _worst(values):
    return round(max(values), 1) if values else None


_START = """
import time, sys, threading
t0 = time.perf_counter()
import numba
numba.set_num_threads({threads})
from rstrace_engine import scenes
from rstrace_engine.session import Session
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interactive import ViewportWorker
from rstrace_engine.warm_first import warm_viewport
lock = threading.Lock()
stop = []
# what the add-on does when RSTrace is selected: the background warm-up (first image's
# kernels first, then the rest a step at a time), sharing the render lock with the viewport
warm = threading.Thread(target=warm_viewport, args=("{mode}",), daemon=True,
                        kwargs=dict(lock=lock, cancel=lambda: bool(stop),
                                    processes={processes}))
warm.start()
s = scenes.build("{scene}", {w}, {h})
wk = ViewportWorker(lock, samples=1)
wk.submit(session=Session(s, RenderSettings(mode="{mode}"), build=False), camera=s.camera,
          settings=RenderSettings(mode="{mode}"))
img = wk.wait_for(lambda im: True, 900)
t1 = time.perf_counter()
if {finish}:  # the cold run: the warm-up completes (the cache is then as a user has it)
    warm.join(1800)
stop.append(1)
wk.stop()
warm.join(120)
print(t1 - t0 if img is not None else -1.0)
"""


def start_time(scene: str, mode: str, w: int, h: int, threads: int,
               cache_dir: str | None, processes: int = 2, finish: bool = False) -> float:
    """Seconds from a fresh interpreter's import to its first viewport image, on the
    add-on's path (the background warm-up of :mod:`~rstrace_engine.warm_first` and a
    viewport worker sharing the render lock). ``finish``: let the warm-up complete before
    the process exits (a cold run, so that the next run finds the cache a user would)."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    code = _START.format(threads=threads, scene=scene, w=w, h=h, mode=mode,
                         processes=processes, finish=bool(finish))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=1800)
    try:
        return round(float(out.stdout.strip().splitlines()[-1]), 2)
    except (ValueError, IndexError):
        return -1.0


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine.bench viewport")
    p.add_argument("--json", action="store_true")
    p.add_argument("--scene", default="museum")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--modes", default="BASE,INTERPOLANT")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--no-cold", action="store_true", help="skip the cold-start measurement")
    p.add_argument("--edits", default=None,
                   help="only the edits whose names contain one of these (comma-separated), "
                        "e.g. 'light'")
    p.add_argument("--picture", default=None,
                   help="also write the README's strip (coarse | full | dirty after a move)")
    args = p.parse_args(argv)
    import numba

    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    rows = []
    edits = EDITS if args.edits is None else tuple(
        e for e in EDITS if any(w.strip() in e for w in args.edits.split(",")))
    for mode in args.modes.split(","):
        rows += measure(args.scene, mode, args.width, args.height, args.repeat, edits)
    result: dict = dict(rows=rows, threads=args.threads, width=args.width,
                        height=args.height)
    first_mode = args.modes.split(",")[0]
    if not args.no_cold:
        with tempfile.TemporaryDirectory() as cold:
            result["cold_start_s"] = start_time(args.scene, first_mode, args.width,
                                                args.height, args.threads, cold,
                                                finish=True)
            result["warm_start_s"] = start_time(args.scene, first_mode, args.width,
                                                args.height, args.threads, cold)
    else:
        result["warm_start_s"] = start_time(args.scene, first_mode, args.width, args.height,
                                            args.threads, None)
    if args.picture:
        result["picture"] = picture(args.picture, args.scene)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"viewport on {args.scene} {args.width}x{args.height}, {args.threads} threads")
    print(f"{'edit':28s} {'mode':12s} {'first ms':>9s} {'full ms':>9s} {'median':>9s} "
          f"{'interrupt ms':>13s} {'relit':>6s}")
    for r in rows:
        print(f"{r['edit']:28s} {r['mode']:12s} {r['first_image_ms']!s:>9s} "
              f"{r['full_image_ms']!s:>9s} {r['full_image_median_ms']!s:>9s} "
              f"{r['interrupt_ms']!s:>13s} {r['relit']:>6s}")
        if r.get("split_ms"):
            print(f"  {r['edit']}, median ms of a relit step: "
                  + ", ".join(f"{k} {v}" for k, v in r["split_ms"].items()))
    for k in ("cold_start_s", "warm_start_s"):
        if k in result:
            print(f"{k}: {result[k]}")
    return 0


__all__ = ["main", "measure", "start_time"]
