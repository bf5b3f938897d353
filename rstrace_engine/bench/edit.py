"""Edits: invalidation and incremental frames after an edit, against fresh frames.

``python -m rstrace_engine.bench edit [--json] [--width W] [--height H]
[--scenes museum,three_spheres] [--modes BASE,INTERPOLANT] [--out DIR] [--threads N]
[--clock wall|cpu] [--rows ROW,...] [--soak N [--soak-mode BASE|INTERPOLANT]]``

For each scene (640x480, ray depth 5) and mode (BASE, INTERPOLANT at epsilon 0.01), one
session renders the scene's camera, then takes the edits below one after another, rendering
a frame after each (the camera fixed, except in ``camera_step``). Each frame is compared
with a *fresh* session's frame of the edited scene, rendered in the same run (its time is
``full_frame_s``; for INTERPOLANT it builds every interpolant it needs, as a first frame
does). Rows (what the edit is on each scene):

=================  ===========================================  ===========================
row                museum                                       three_spheres
=================  ===========================================  ===========================
``delete_top``     delete a sculpture (the top of a plinth)     the same (a ball on a plinth)
``delete_bottom``  delete another sculpture's plinth            delete that plinth
``move_cube_in``   a green cube moves in from out of view       the same
``move_small``     move a sculpture 0.15 m                      move the blue sphere 0.1 m
``recolor``        recolour a material one sculpture uses       recolour the red material
``recolor_shared`` recolour marble (500 sculptures)             recolour the floor
``light_power``    halve a ceiling light's power                halve the key light
``light_colour``   warm that light's colour                     the same
``world_colour``   the world's colour (a background only)       the same
``move_light``     move a ceiling light 1 m                     move the fill light 1 m
``add_light``      add a point light (a new light slot)         the same
``add_soft_light`` that light as a sphere light, radius 0.5       the same
``delete_light``   delete a ceiling light                       delete the key light
``add_object``     add a ball on a plinth                       add a small sphere
``camera_step``    camera steps forward (0.5% of the scene)     the same
=================  ===========================================  ===========================

``studio`` (soft light: an area light, a sphere light, a world that lights; issue 20) has
the same rows: delete the torus / the vase, move the mirror ball 0.1 m, recolour the red
material / the floor, the light rows on the soft box and the sphere light, add a small
ball. Its goal: moving a small object >= 20x faster than a fresh frame in BASE, exact.

Columns: ``rst_query_ms`` (RST traversal + membership + invalidation, INTERPOLANT),
``records_query_ms`` (finding the dirty pixels in the per-pixel records), ``apply_ms``
(everything ``Session.apply`` did), ``invalidated_interpolants``, ``dirty_fraction``
(pixels traced again), ``reshaded_fraction`` (BASE under soft light: kept pixels whose soft
lights' terms were shaded again, tracing/shadow_reshade.py),
``full_frame_s``, ``incremental_frame_s`` (the session's frame after the edit),
``speedup`` (full / incremental), ``max_error_vs_fresh`` and ``frac_over_epsilon`` (display
space, epsilon 0.01, against the fresh frame of the same mode), for INTERPOLANT also
``max_error_vs_base`` / ``frac_over_epsilon_vs_base`` (against the fresh BASE frame),
``rst_memory_mb`` and ``records_mb``. Writes ``DIR/edit.md`` and one
``DIR/edit_<scene>_<row>.png`` per edit: the frame after the edit with its dirty pixels
tinted magenta (BASE; INTERPOLANT rows add ``_interpolant``). ``--soak N`` instead runs N
random edit batches (every kind, and camera moves) on the small soak scenes checking after
each that the BASE frame equals a fresh session's, bit for bit; with ``--soak-mode
INTERPOLANT`` it runs them in an INTERPOLANT session on soft-lit scenes, each frame within
epsilon of a fresh BASE frame (:func:`.soak.interpolant_soak`).

``soft_room`` (the soak's room with sphere, sun-with-angle and area lights and a world that
lights, at the bench's size) and ``museum_soft`` (two area lights, a spot with a radius, a
sun with an angle through a skylight and a world that lights; the light rows on
``Ceiling0``, the spot moved, the sun deleted) have the light rows only, plus
``resize_area_light``. ``--rows light_power,world_colour`` runs those rows alone. BASE light
rows relight the frame from its per-light records (``tracing.light_records``): the
``relight_s`` and ``light_records_mb`` columns.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import image, scenes
from ..frame import RenderSettings
from ..geometry import shapes
from ..geometry.edits import (
    CameraChange,
    LightDelete,
    LightSet,
    MaterialSet,
    ObjectAdd,
    ObjectDelete,
    ObjectTransform,
    WorldColor,
)
from ..geometry.scene import Light, Material, Scene
from ..session import Session
from .trade import moved_cameras

EPSILON = 0.01
ROWS = ("delete_top", "delete_bottom", "move_cube_in", "move_small", "recolor",
        "recolor_shared", "light_power", "light_colour", "world_colour", "move_light",
        "resize_area_light", "add_light", "add_soft_light", "delete_light", "add_object",
        "camera_step")
#: the rows that edit lights or the world only (BASE relights them)
LIGHT_ROWS = ("light_power", "light_colour", "world_colour", "move_light",
              "resize_area_light", "add_light", "add_soft_light", "delete_light")
JSON_KEYS = ("scene", "edit", "mode", "rst_query_ms", "records_query_ms", "apply_ms",
             "invalidated_interpolants", "dirty_fraction", "full_frame_s",
             "incremental_frame_s", "speedup", "max_error_vs_fresh", "frac_over_epsilon",
             "max_error_vs_base", "frac_over_epsilon_vs_base", "rst_memory_mb", "records_mb",
             "light_records_mb", "relight_s", "goal")
CLOCK = time.perf_counter

# --------------------------------------------------------------------------- the scenes


def _cube_positions(scene: Scene, depth: float, inside: float, outside: float, z: float):
    """A point in view on the right of the camera and one further right, out of view."""
    m = scene.camera.matrix
    eye, right = m[:3, 3], m[:3, 0] / np.linalg.norm(m[:3, 0])
    fwd = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    flat = np.array([fwd[0], fwd[1], 0.0]) / np.linalg.norm(fwd[:2])
    base = eye + flat * depth
    pin = base + right * inside
    pout = base + right * outside
    pin[2] = pout[2] = z
    return pin, pout


def setup(name: str, width: int, height: int) -> tuple[Scene, dict]:
    """The bench scene (the built-in scene plus a green cube out of view and, on museum, a
    material of its own on one sculpture) and the edit of every row."""
    if name == "museum":
        s = scenes.museum(width, height)
        s.add_material(Material("highlight", diffuse=(0.8, 0.8, 0.78), specular=(0.15,) * 3,
                                roughness=0.1), key="highlight")
        s.set_instance_materials(s.instance_slot("Sculpture0205"), [s.material_id("highlight")])
        pin, pout = _cube_positions(s, 12.0, 4.0, 13.0, 2.0)  # above the plinths
        pout = np.clip(pout, (-19.0, -14.0, 0.0), (19.0, 14.0, 8.0))
        size, small_key, small_step = 1.0, "Sculpture0166", 0.15
        top, bottom = "Sculpture0088", "Plinth0090"
        recolor = ("highlight", Material("highlight", diffuse=(0.2, 0.7, 0.3),
                                         specular=(0.15,) * 3, roughness=0.1))
        shared = ("marble", Material("marble", diffuse=(0.75, 0.7, 0.6), specular=(0.15,) * 3,
                                     roughness=0.1))
        light_key, moved_light = "Ceiling0", "Ceiling4"
        plinth = s.instances[s.instance_slot("Plinth0167")]["matrix"]
        add = ObjectAdd("NewBall", "sculpture_ico",
                        shapes.transform(plinth[:3, 3] + (0.0, 0.0, 0.85), 0.6),
                        ("bronze",))
    elif name == "three_spheres":
        s = scenes.three_spheres(width, height)
        pin, pout = _cube_positions(s, 7.0, 2.2, 6.5, 0.3)
        pout = np.clip(pout, (-5.5, -5.5, 0.0), (5.5, 5.5, 2.0))
        size, small_key, small_step = 0.6, "BlueSphere", 0.1
        # a small plinth with a ball on it, as the museum's sculptures
        stone = s.add_material(Material("stone", diffuse=(0.5, 0.5, 0.52)), key="stone")
        s.add_mesh(shapes.box((0.5, 0.5, 0.6), name="plinth"), key="plinth")
        s.add_instance(s.mesh_id("plinth"), shapes.transform((-0.4, 1.6, 0.3)), [stone],
                       name="Plinth")
        s.add_instance(s.mesh_id("sphere"), shapes.transform((-0.4, 1.6, 0.85), 0.25),
                       [s.material_id("blue")], name="Top")
        top, bottom = "Top", "Plinth"
        recolor = ("red", Material("red", diffuse=(0.2, 0.6, 0.15), specular=(0.25,) * 3,
                                   roughness=0.15))
        shared = ("floor", Material("floor", diffuse=(0.45, 0.5, 0.55), specular=(0.1,) * 3,
                                    roughness=0.25))
        light_key, moved_light = "Key", "Fill"
        add = ObjectAdd("NewBall", "sphere", shapes.transform((-0.6, 1.2, 0.3), 0.3),
                        ("blue",))
    elif name == "studio":  # soft light: an area light, a sphere light, a world (issue 20)
        s = scenes.studio(width, height)
        pin, pout = _cube_positions(s, 6.0, 1.6, 5.5, 0.25)
        pout = np.clip(pout, (-6.5, -6.5, 0.0), (6.5, 6.5, 2.0))
        size, small_key, small_step = 0.5, "MirrorBall", 0.1
        top, bottom = "Torus", "Vase"
        recolor = ("red", Material("red", diffuse=(0.2, 0.6, 0.15), specular=(0.2,) * 3,
                                   roughness=0.2))
        shared = ("floor", Material("floor", diffuse=(0.45, 0.5, 0.55), specular=(0.05,) * 3,
                                    roughness=0.4))
        light_key, moved_light = "SoftBox", "Bulb"
        add = ObjectAdd("NewBall", "sphere", shapes.transform((1.9, -0.4, 0.3), 0.3),
                        ("blue",))
    elif name == "soft_room":
        from .soak import soft_room

        s = soft_room(width, height)
        return s, _light_edits(s, "Lamp", "Lamp", "Sun")
    elif name == "museum_soft":
        s = scenes.museum_soft(width, height)
        return s, _light_edits(s, "Ceiling0", "Spot", "Sun")
    else:
        raise ValueError(f"edit bench: unknown scene {name!r}")
    s.add_material(Material("green", diffuse=(0.1, 0.6, 0.15)), key="green")
    s.add_mesh(shapes.box((size, size, size), name="green_cube"), key="green_cube")
    s.add_instance(s.mesh_id("green_cube"), shapes.transform(pout), [s.material_id("green")],
                   name="GreenCube")
    small = s.instances[s.instance_slot(small_key)]["matrix"].copy()
    small[0, 3] += small_step
    step = moved_cameras(s)["step"]
    edits = {
        "delete_top": [ObjectDelete(top)],
        "delete_bottom": [ObjectDelete(bottom)],
        "move_cube_in": [ObjectTransform("GreenCube", shapes.transform(pin))],
        "move_small": [ObjectTransform(small_key, small)],
        "recolor": [MaterialSet(*recolor)],
        "recolor_shared": [MaterialSet(*shared)],
        "add_object": [add],
        "camera_step": [CameraChange(step)],
    }
    edits.update(_light_edits(s, light_key, moved_light, light_key))
    return s, edits


def _light_edits(s: Scene, light_key: str, moved_light: str, deleted: str) -> dict:
    """The light rows' edits (see the module doc)."""
    li = s.lights[s.light_slot(light_key)]
    ml = s.lights[s.light_slot(moved_light)]
    box = s.arrays().scene_aabb
    centre = 0.5 * (box[0] + box[1])
    top = (centre[0] + 0.2 * (box[1][0] - box[0][0]), centre[1],
           box[0][2] + 0.8 * (box[1][2] - box[0][2]))
    edits = {
        "light_power": [LightSet(light_key, replace(li, power=li.power * 0.5))],
        "light_colour": [LightSet(light_key, replace(li, power=li.power * 0.5,
                                                     color=(1.0, 0.75, 0.5)))],
        # the world's colour as a background (a world that lights keeps lighting)
        "world_colour": [WorldColor((0.1, 0.12, 0.2), lights=None if s.world_lights
                                    and np.any(s.world_color > 0) else False)],
        "move_light": [LightSet(moved_light, replace(
            ml, position=tuple(np.asarray(ml.position) + (1.0, 0.0, 0.0))))],
        "add_light": [LightSet("BenchLight", Light("BenchLight", "POINT",
                                                   power=2.0 * li.power, position=top))],
        # the same light with an extent: a sphere light of radius 0.5
        "add_soft_light": [LightSet("BenchSoft", Light("BenchSoft", "POINT",
                                                       power=2.0 * li.power, position=top,
                                                       radius=0.5))],
        "delete_light": [LightDelete(deleted)],
    }
    areas = [k for k, j in s.light_keys.slot.items() if s.lights[j].kind == "AREA"]
    if areas:
        a = s.lights[s.light_slot(areas[0])]
        edits["resize_area_light"] = [LightSet(areas[0], replace(
            a, size=(1.5 * a.size[0], 1.2 * a.size[1])))]
    return edits


# --------------------------------------------------------------------------- running


def _dirty_png(path: Path, frame, dirty) -> None:
    disp = image.to_display(frame.radiance)
    if dirty is not None:
        tint = np.array([0.95, 0.15, 0.9])
        disp = np.where(dirty[..., None], 0.35 * disp + 0.65 * tint, 0.6 * disp)
    image.write_png(path, image.to_uint8(disp[::2, ::2]))


def run_scene(name: str, width: int, height: int, depth: int, modes, out: Path | None,
              log=print, rows_wanted=ROWS) -> list[dict]:
    rows: list[dict] = []
    base_frames: dict[str, np.ndarray] = {}
    for mode in modes:
        settings = RenderSettings(mode=mode, epsilon=EPSILON, max_depth=depth)
        fresh_settings = settings
        scene, edits = setup(name, width, height)
        sess = Session(scene, settings)
        # an editing session that keeps the per-light terms from its first frame (the
        # default starts at the first light edit, whose frame is then a full one)
        sess.light_terms = True
        t0 = CLOCK()
        sess.render()
        log(f"{name} {mode}: first frame {CLOCK() - t0:.2f} s")
        for row in ROWS:
            if row not in edits or row not in rows_wanted:
                continue
            rep = sess.apply(edits[row])
            dirty = sess.dirty_mask
            t0 = CLOCK()
            frame = sess.render()
            inc_s = CLOCK() - t0
            fresh_sess = Session(sess.scene.copy(), fresh_settings)
            t0 = CLOCK()
            fresh = fresh_sess.render()
            full_s = CLOCK() - t0
            cmp = image.compare(frame.radiance, fresh.radiance, EPSILON)
            r = dict(scene=name, edit=row, mode=mode, rst_query_ms=rep.rst_query_ms,
                     records_query_ms=rep.records_query_ms, apply_ms=rep.apply_ms,
                     invalidated_interpolants=rep.invalidated_interpolants,
                     rescaled_interpolants=rep.rescaled_interpolants,
                     interpolated_pct=100.0 * frame.stats.get("interpolated_fraction", 0.0),
                     dirty_fraction=(frame.stats["dirty_fraction"]),
                     full_frame_s=full_s, incremental_frame_s=inc_s,
                     speedup=full_s / inc_s if inc_s > 0 else math.inf,
                     max_error_vs_fresh=cmp["max_error"], frac_over_epsilon=cmp["frac_over"],
                     max_linear_diff=float(np.abs(frame.radiance - fresh.radiance).max()),
                     rst_memory_mb=_rst_mb(sess), records_mb=sess.records_bytes / 1e6,
                     light_records_mb=frame.stats.get("light_records_mb", 0.0),
                     relight_s=frame.stats.get("relight_s", 0.0),
                     reshaded_fraction=(frame.stats.get("reshaded_pixels", 0)
                                        / max(frame.pixel_class.size, 1)),
                     incremental=bool(frame.stats.get("incremental")))
            if mode == "BASE":
                base_frames[row] = fresh.radiance
            elif row in base_frames:
                vb = image.compare(frame.radiance, base_frames[row], EPSILON)
                r.update(max_error_vs_base=vb["max_error"],
                         frac_over_epsilon_vs_base=vb["frac_over"])
            r["goal"] = goal(r)
            rows.append(r)
            if out is not None:
                suffix = "" if mode == "BASE" else "_interpolant"
                _dirty_png(out / f"edit_{name}_{row}{suffix}.png", frame, dirty)
            log(f"  {row:15s} dirty {r['dirty_fraction']:.4f} re-shaded "
                f"{r['reshaded_fraction']:.4f} incr {inc_s:.3f} s full "
                f"{full_s:.2f} s x{r['speedup']:.1f} err {r['max_error_vs_fresh']:.2e} "
                f"rst {r['rst_query_ms']:.2f} ms rec {r['records_query_ms']:.1f} ms "
                f"inval {r['invalidated_interpolants']} resc {r['rescaled_interpolants']} "
                f"interp {r['interpolated_pct']:.1f}% rec {r['records_mb']:.2f} MB "
                f"rst {r['rst_memory_mb']:.2f} MB light rec {r['light_records_mb']:.1f} MB "
                f"relight {r['relight_s']:.3f} s apply {rep.apply_ms:.1f} ms")
    return rows


def _rst_mb(sess: Session) -> float:
    c = sess.interpolants.cache
    fn = getattr(c, "rst_memory_bytes", None) if c is not None else None
    return fn() / 1e6 if fn is not None else 0.0


def goal(r: dict) -> str:
    """The issue's goal this row measures, and whether it was met ('' when none)."""
    notes = []
    if r["scene"] == "studio" and r["mode"] == "BASE" and r["edit"] == "move_small":
        ok = r["speedup"] >= 20.0 and r["max_linear_diff"] <= 1e-6
        notes.append(f"soft light: speedup >= 20x exact: {'met' if ok else 'MISSED'}")
    if r["mode"] == "BASE" and r["edit"] in ("light_power", "light_colour", "world_colour"):
        ok = r["speedup"] >= 50.0 and r["max_linear_diff"] == 0.0
        notes.append(f"speedup >= 50x exact: {'met' if ok else 'MISSED'}")
    if r["mode"] == "BASE" and r["edit"] in ("move_light", "resize_area_light"):
        ok = r["speedup"] >= 3.0 and r["max_linear_diff"] == 0.0
        notes.append(f"speedup >= 3x exact: {'met' if ok else 'MISSED'}")
    if r["scene"] == "museum":
        if r["mode"] == "BASE" and r["edit"] in ("move_small", "recolor"):
            ok = r["speedup"] >= 20.0 and r["max_linear_diff"] <= 1e-6
            notes.append(f"speedup >= 20x exact: {'met' if ok else 'MISSED'}")
        if r["mode"] == "INTERPOLANT" and r["edit"] in ("delete_top", "delete_bottom",
                                                        "move_cube_in", "move_small",
                                                        "recolor"):
            ok = r["rst_query_ms"] <= 2.0
            notes.append(f"RST query <= 2 ms: {'met' if ok else 'MISSED'}")
        if r["mode"] == "INTERPOLANT":
            ok = r["rst_memory_mb"] + r["records_mb"] <= 6.0
            notes.append(f"RST + records <= 6 MB: {'met' if ok else 'MISSED'}")
    return "; ".join(notes)


def soak(steps: int, log=print) -> dict:
    """``steps`` random edit batches on the soak scenes, BASE checked against fresh frames."""
    from .soak import SOAK_SCENES, EditGenerator

    settings = RenderSettings(mode="BASE", max_depth=3)
    worst, fractions, done, relit_steps = 0.0, [], 0, 0
    per_scene = max(1, steps // len(SOAK_SCENES))
    for k, (name, build) in enumerate(sorted(SOAK_SCENES.items())):
        gen = EditGenerator(build(64, 48), seed=1000 + k,
                            extra=EditGenerator.EXTRA_KINDS + EditGenerator.SOFT_KINDS)
        sess = Session(gen.scene.copy(), settings)
        prev = sess.render()
        for _ in range(per_scene):
            sess.apply(gen.step())
            dirty = sess.dirty_mask
            if dirty is not None:  # (and the kept pixels whose soft lights are shaded again)
                dirty = dirty | sess.reshade_mask
            relit = sess.reuse.relight_due  # light edits: every kept pixel recombined
            frame = sess.render()
            fresh = Session(sess.scene.copy(), settings).render()
            diff = float(np.abs(frame.radiance - fresh.radiance).max())
            worst = max(worst, diff)
            relit_steps += relit
            if not np.array_equal(frame.radiance, fresh.radiance):
                raise AssertionError(f"soak {name}: incremental frame differs by {diff} "
                                     f"(BASE must equal a fresh frame bit for bit)")
            if dirty is not None and not relit:
                changed = np.any(prev.radiance != fresh.radiance, axis=2)
                if (changed & ~dirty).any():
                    raise AssertionError(f"soak {name}: a changed pixel was not dirty")
                fractions.append(float(dirty.mean()))
            if diff > 1e-6:
                raise AssertionError(f"soak {name}: incremental frame differs by {diff}")
            prev = frame
            done += 1
        log(f"soak {name}: {per_scene} steps, kinds {gen.kinds_done}")
    return dict(steps=done, max_diff=worst, incremental_steps=len(fractions),
                relit_steps=relit_steps,
                mean_dirty_fraction=float(np.mean(fractions)) if fractions else 1.0)


# --------------------------------------------------------------------------- output


def markdown(rows: list[dict], width: int, height: int, note: str) -> str:
    head = ("| scene | edit | mode | RST query ms | records query ms | invalidated | dirty % "
            "| full s | incremental s | speedup | max err vs fresh | over eps | RST MB "
            "| records MB | light records MB | goal |")
    lines = [f"Edits at {width}x{height}, epsilon {EPSILON} ({note})", "", head,
             "|" + "---|" * 16]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['edit']} | {r['mode']} | {r['rst_query_ms']:.2f} | "
            f"{r['records_query_ms']:.1f} | {r['invalidated_interpolants']} | "
            f"{100 * r['dirty_fraction']:.2f} | {r['full_frame_s']:.2f} | "
            f"{r['incremental_frame_s']:.3f} | {r['speedup']:.1f} | "
            f"{r['max_error_vs_fresh']:.1e} | {100 * r['frac_over_epsilon']:.2f}% | "
            f"{r['rst_memory_mb']:.2f} | {r['records_mb']:.2f} | "
            f"{r.get('light_records_mb', 0.0):.1f} | {r['goal']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine.bench edit")
    p.add_argument("--json", action="store_true")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--depth", type=int, default=5)
    p.add_argument("--scenes", default="museum,three_spheres")
    p.add_argument("--modes", default="BASE,INTERPOLANT")
    p.add_argument("--out", default="docs", help="directory for edit.md and the PNGs")
    p.add_argument("--threads", type=int, default=0, help="numba threads (0: all)")
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                   help="wall time, or this process's CPU time (with --threads 1 on a "
                        "shared machine)")
    p.add_argument("--rows", default=",".join(ROWS),
                   help="the rows to run, in the bench's order (default: all)")
    p.add_argument("--soak", type=int, default=0,
                   help="run this many random edit batches checked against fresh frames")
    p.add_argument("--soak-mode", choices=("BASE", "INTERPOLANT"), default="BASE",
                   help="BASE: bit for bit against fresh frames; INTERPOLANT: within epsilon "
                        "0.02 of fresh BASE frames (soft-lit scenes)")
    p.add_argument("--no-fallback", action="store_true",
                   help="INTERPOLANT: build cells wherever the predicate allows (the "
                        "measured fallback, which traces frames where cells did not pay, "
                        "off): the rows then compare the same interpolated frames")
    args = p.parse_args(argv)
    if args.no_fallback:
        from ..interpolants.render import InterpolantRenderer

        InterpolantRenderer.auto_fallback = False
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    if args.threads > 0:
        import numba

        numba.set_num_threads(args.threads)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if args.soak and args.soak_mode == "INTERPOLANT":
        from .soak import interpolant_soak

        res = interpolant_soak(args.soak, log=log)
        print(json.dumps(res) if args.json else
              f"interpolant soak: {res['steps']} steps, max error against fresh BASE frames "
              f"{res['max_error']:.2e} (epsilon {res['epsilon']}), mean interpolated "
              f"fraction {res['mean_interpolated_fraction']:.3f}")
        return 0
    if args.soak:
        res = soak(args.soak, log)
        print(json.dumps(res) if args.json else
              f"soak: {res['steps']} steps, {res['incremental_steps']} incremental, "
              f"{res['relit_steps']} relit, max "
              f"difference to fresh frames {res['max_diff']:.1e}, mean dirty fraction "
              f"{res['mean_dirty_fraction']:.3f}")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.scenes.split(","):
        rows += run_scene(name.strip(), args.width, args.height, args.depth,
                          [m.strip() for m in args.modes.split(",")], out, log,
                          [r.strip() for r in args.rows.split(",")])
    note = (f"{'process CPU time' if args.clock == 'cpu' else 'wall time'}, "
            f"{args.threads or 'all'} numba thread(s)")
    (out / "edit.md").write_text(markdown(rows, args.width, args.height, note))
    if args.json:
        clean = [{k: (None if isinstance(r.get(k), float) and not math.isfinite(r[k])
                      else r.get(k)) for k in JSON_KEYS} for r in rows]
        print(json.dumps({"rows": clean}))
    else:
        print(markdown(rows, args.width, args.height, note))
    return 0
