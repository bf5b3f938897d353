"""The main job (`make demo`): render a Blender scene through RSTrace, edit it, render again.

In background ``bpy`` this builds the paper's Plate A scene with Blender's own data API (a
floor, a red sphere, a mirror sphere and a blue sphere, two point lights), selects the
RSTrace engine (the add-on is imported from the repository root as the package ``addon``
and registered, as any script may do), renders it, moves the red sphere, renders again
through the same persistent session, and writes into ``--out``:

* ``before.png``, ``after.png`` — the two frames (Blender's colour management applied);
* ``before.exr``, ``after.exr`` — multilayer EXRs with the linear Combined and the
  Interpolation (per-pixel class) passes;
* ``interpolated.png``, ``interpolated.exr`` — the edited scene again with radiance
  interpolants (epsilon 0.01); its Interpolation pass shows which pixels were interpolated;
* ``edits/NN_<edit>.png`` and ``edits/NN_<edit>_dirty.png`` — the edit loop: a sequence
  of edits made through ``bpy`` (move, rotate, material colour, light power, hide, show,
  duplicate linked, delete, undo), each rendered by F12 through the scene's persistent
  session (only the dirty pixels are re-rendered when the camera did not move); the
  ``_dirty`` image shows the re-rendered pixels in white over the dimmed frame, and
  ``edits/edits.txt`` lists per edit the edits the depsgraph gave, the dirty fraction and
  the times (sync, apply, render), as ``stats.json`` does;
* ``stats.json`` — export and render statistics of the renders, the edit, how many pixels it
  changed, and the interpolated frame's error against the base tracer's.

    python examples/demo.py --out out/demo [--width 320 --height 240 --samples 4]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


#: The interpolated frame must be within epsilon of the base frame at EVERY pixel, up to
#: this display-space slack for float32 images.
BOUND_FLOAT_TOL = 1e-6


def build_scene(bpy, width: int, height: int, samples: int, depth: int):
    """Plate A: three spheres (one a mirror) on a plane, two lights, a dim world."""
    import bmesh
    from mathutils import Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.name = "PlateA"

    def material(name, base, metallic=0.0, roughness=0.5):
        mat = bpy.data.materials.new(name)
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (*base, 1.0)
        bsdf.inputs["Metallic"].default_value = metallic
        bsdf.inputs["Roughness"].default_value = roughness
        mat.diffuse_color = (*base, 1.0)
        return mat

    def mesh(name, make):
        me = bpy.data.meshes.new(name)
        bm = bmesh.new()
        bm.loops.layers.uv.new("UVMap")
        make(bm)
        bm.to_mesh(me)
        bm.free()
        return me

    def obj(name, data, location=(0.0, 0.0, 0.0), mat=None, scale=1.0):
        ob = bpy.data.objects.new(name, data)
        ob.location = location
        ob.scale = (scale, scale, scale)
        if mat is not None:
            ob.data.materials.append(mat)
        sc.collection.objects.link(ob)
        return ob

    def sphere(name):
        me = mesh(name, lambda bm: bmesh.ops.create_uvsphere(
            bm, u_segments=48, v_segments=24, radius=1.0, calc_uvs=True))
        me.shade_smooth()
        return me

    obj("Ground", mesh("Ground", lambda bm: bmesh.ops.create_grid(
        bm, x_segments=1, y_segments=1, size=6.0, calc_uvs=True)),
        mat=material("Floor", (0.55, 0.55, 0.5), roughness=0.6))
    obj("RedSphere", sphere("Red"), (-1.6, 0.4, 1.0), material("Red", (0.7, 0.12, 0.1), 0.0, 0.35))
    obj("MirrorSphere", sphere("Mirror"), (0.6, -0.9, 1.0),
        material("Mirror", (0.92, 0.92, 0.92), 1.0, 0.0))
    obj("BlueSphere", sphere("Blue"), (1.5, 1.6, 0.8),
        material("Blue", (0.1, 0.2, 0.65), 0.0, 0.45), scale=0.8)
    for name, loc, power, colour in (("Key", (-3.0, -4.0, 6.0), 2500.0, (1.0, 1.0, 1.0)),
                                     ("Fill", (4.0, -2.0, 3.5), 900.0, (0.9, 0.95, 1.0))):
        light = bpy.data.lights.new(name, "POINT")
        light.energy, light.color, light.shadow_soft_size = power, colour, 0.0
        obj(name, light, loc)
    cam = obj("Camera", bpy.data.cameras.new("Camera"), (0.0, -8.5, 3.6))
    cam.data.lens = 35.0
    cam.rotation_euler = (Vector((0.0, 0.3, 0.8)) - cam.location).to_track_quat(
        "-Z", "Y").to_euler()
    sc.camera = cam
    world = bpy.data.worlds.new("World")
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.06, 0.08, 1)
    world.color = (0.05, 0.06, 0.08)
    # a background only (Diffuse and Glossy ray visibility off, in Cycles too): the world's
    # light would leave every interpolant cell traced and make every edit re-render each
    # surface it reaches (measured: 0% interpolated, 62% of the pixels per edit)
    sc.world = world  # first: Cycles' update of these flags tags the scene's world
    world.cycles_visibility.diffuse = world.cycles_visibility.glossy = False

    r = sc.render
    r.engine = "RSTRACE"
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    sc.rstrace.mode = "BASE"
    sc.rstrace.samples = samples
    sc.rstrace.max_ray_depth = depth
    return sc


def render(bpy, sc, out: Path, label: str) -> dict:
    """F12 to a multilayer EXR and a PNG; returns the render's statistics."""
    import addon

    r = sc.render
    ims = r.image_settings
    t0 = time.perf_counter()
    ims.media_type = "MULTI_LAYER_IMAGE"
    ims.color_depth, ims.exr_codec = "32", "ZIP"
    r.filepath = str(out / f"{label}.exr")
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - t0
    state = addon.session.state_for(sc)
    if state.error:
        raise SystemExit(f"render failed: {state.error}")
    stats = dict(state.stats, wall_seconds=seconds, messages=state.messages)
    # the PNG: the same frame again through the persistent session (nothing changed)
    ims.media_type = "IMAGE"
    ims.file_format, ims.color_mode, ims.color_depth = "PNG", "RGB", "8"
    r.filepath = str(out / f"{label}.png")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    stats["unchanged_rerender_seconds"] = time.perf_counter() - t0
    return stats


def render_interpolated(bpy, sc, out: Path, epsilon: float) -> tuple[dict, dict]:
    """The edited scene again in INTERPOLANT mode, compared with the base tracer's frame."""
    import addon
    from rstrace_engine.image import compare

    base = addon.session.state_for(sc).frame.radiance.copy()
    sc.rstrace.mode, sc.rstrace.epsilon = "INTERPOLANT", epsilon
    stats = render(bpy, sc, out, "interpolated")
    frame = addon.session.state_for(sc).frame
    accuracy = compare(frame.radiance, base, epsilon)
    sc.rstrace.mode = "BASE"
    return stats, accuracy


def edit_loop(bpy, sc, out: Path) -> list[dict]:
    """Edits through bpy, each followed by an incremental F12; images and numbers beside."""
    import numpy as np

    import addon
    from rstrace_engine.image import to_display, write_png, write_render_png

    red, blue = bpy.data.objects["RedSphere"], bpy.data.objects["BlueSphere"]
    mirror = bpy.data.objects["MirrorSphere"]
    key = bpy.data.objects["Key"]
    bsdf = blue.active_material.node_tree.nodes["Principled BSDF"]
    made = {}

    def duplicate():
        made["dup"] = dup = blue.copy()
        dup.location = (-0.4, 1.9, 0.8)
        sc.collection.objects.link(dup)

    steps = [
        ("move", "move RedSphere 0.4 m", lambda: setattr(red.location, "y", red.location.y + 0.4)),
        ("rotate", "rotate BlueSphere 30 degrees",
         lambda: setattr(blue.rotation_euler, "z", math.radians(30.0))),
        ("colour", "BlueSphere's material turns green",
         lambda: setattr(bsdf.inputs["Base Color"], "default_value", (0.1, 0.6, 0.15, 1.0))),
        # the session's first light edit: a full frame that starts keeping the per-light
        # records; the next light edits relight the frame from them (no ray traced for a
        # colour, only the moved light's shadow rays for a move)
        ("power", "Key light at half power", lambda: setattr(key.data, "energy", 1250.0)),
        ("warm", "Key light warmer", lambda: setattr(key.data, "color", (1.0, 0.8, 0.6))),
        ("drag", "Key light moved 0.3 m", lambda: setattr(key.location, "x",
                                                          key.location.x + 0.3)),
        ("hide", "hide MirrorSphere", lambda: setattr(mirror, "hide_render", True)),
        ("show", "show MirrorSphere", lambda: setattr(mirror, "hide_render", False)),
        ("duplicate", "duplicate BlueSphere (linked)", duplicate),
        ("delete", "delete the duplicate", lambda: bpy.data.objects.remove(made["dup"])),
        ("undo", "undo the delete", lambda: bpy.ops.ed.undo()),
    ]
    folder = out / "edits"
    folder.mkdir(exist_ok=True)
    rows, lines = [], []
    bpy.ops.render.render()  # the session holds the scene as it is now
    bpy.ops.ed.undo_push(message="demo start")
    for k, (name, what, change) in enumerate(steps, 1):
        change()
        if name != "undo":
            bpy.ops.ed.undo_push(message=what)
        t0 = time.perf_counter()
        bpy.ops.render.render()
        wall = time.perf_counter() - t0
        state = addon.session.state_for(bpy.context.scene)
        if state.error:
            raise SystemExit(f"render after '{what}' failed: {state.error}")
        st = state.stats
        frame = state.frame.radiance
        write_render_png(folder / f"{k:02d}_{name}.png", frame)
        mask = state.dirty_mask
        shown = to_display(frame) * 0.35
        if mask is None:
            mask = np.ones(frame.shape[:2], bool)
        shown[mask] = 1.0
        write_png(folder / f"{k:02d}_{name}_dirty.png", shown)
        row = dict(edit=what, depsgraph_edits=st.get("edit_kinds", {}),
                   incremental=bool(st.get("incremental")), relit=bool(st.get("relit")),
                   dirty_fraction=float(st.get("dirty_fraction", 1.0)),
                   sync_ms=1e3 * st.get("sync_seconds", 0.0),
                   apply_ms=1e3 * st.get("apply_seconds", 0.0),
                   render_ms=1e3 * st.get("render_seconds", 0.0), wall_ms=1e3 * wall)
        rows.append(row)
        kinds = ", ".join(f"{n} {v}" for n, v in row["depsgraph_edits"].items()) or "none"
        lines.append(f"{k:02d} {what:34s} edits: {kinds:45s} dirty "
                     f"{100 * row['dirty_fraction']:6.2f}%  sync {row['sync_ms']:6.1f} ms  "
                     f"apply {row['apply_ms']:6.1f} ms  render {row['render_ms']:7.1f} ms"
                     + ("  relit" if row["relit"] else ""))
        print("demo: " + lines[-1])
    (folder / "edits.txt").write_text("\n".join(lines) + "\n")
    return rows


def changed_fraction(bpy, a: Path, b: Path) -> float:
    import numpy as np

    def pixels(path):
        img = bpy.data.images.load(str(path))
        px = np.empty(len(img.pixels), np.float32)
        img.pixels.foreach_get(px)
        bpy.data.images.remove(img)
        return px.reshape(-1, 4)[:, :3]

    return float(np.mean(np.abs(pixels(a) - pixels(b)).max(axis=1) > 1.5 / 255))


#: What ``--warm-cache`` compiles: the kernels of this scene's BASE renders (the BVH, hard
#: lights, a perspective camera, no textures). Not INTERPOLANT's: on a cold cache the
#: interpolated frame is the base tracer's while the cell build's kernels compile in a
#: background process (``rstrace_engine.interpolants.build_beside``, stopped when the demo
#: ends); on a cache that has them it builds and walks cells, loading its kernels.
WARM_CACHE_ARGS = ("warm-cache", "--modes", "BASE", "--accelerators", "BVH",
                   "--no-soft-light", "--no-textures")


def start_warm_cache(env=None):
    """``python -m rstrace_engine warm-cache`` of this checkout in the background, in its own
    process group (its parts with it), printing its progress to this stdout."""
    import os
    import subprocess

    env = dict(os.environ if env is None else env)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get(
        "PYTHONPATH", "").split(os.pathsep) if p])
    posix = hasattr(os, "killpg")
    return subprocess.Popen([sys.executable, "-m", "rstrace_engine", *WARM_CACHE_ARGS],
                            cwd=str(ROOT), env=env, stdin=subprocess.DEVNULL,
                            start_new_session=posix)


def stop_warm_cache(proc) -> bool:
    """Stop the background warm-up and its parts if still running (True then): the kernels
    it has not reached are ones this demo did not call (it compiled any it needed first
    itself); what it cached stays cached."""
    import os
    import signal
    import subprocess

    if proc.poll() is not None:
        return False
    proc.terminate()  # warm-cache stops its parts and waits for them (a second or two)
    try:
        proc.wait(timeout=30.0)
    except subprocess.TimeoutExpired:
        if hasattr(os, "killpg"):
            os.killpg(proc.pid, signal.SIGKILL)  # its own group: the parts too
        else:
            proc.kill()
        proc.wait()
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "demo")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--depth", type=int, default=4)
    ap.add_argument("--no-warmup", action="store_true",
                    help="no background kernel warm-up in the add-on (make demo warmed the "
                         "kernels of this scene with warm-cache first; the add-on's warm-up "
                         "would add those of soft light and orthographic cameras)")
    ap.add_argument("--warm-cache", action="store_true",
                    help="compile this scene's kernels in a background warm-cache (one process "
                         "per core) while the demo starts Blender, builds the scene and "
                         "renders (its renders load what the warm-up compiled and compile what "
                         "it has not reached yet, each kernel once); stopped when the demo is "
                         "done (make demo); implies --no-warmup")
    args = ap.parse_args(argv)
    warming = start_warm_cache() if args.warm_cache else None
    try:
        return _demo(args)
    finally:
        if warming is not None and stop_warm_cache(warming):
            print("demo: background warm-up stopped (the demo is done; the kernels it had "
                  "not reached compile on first use)")


def _demo(args) -> int:
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)

    sys.path.insert(0, str(ROOT))
    import bpy

    import addon

    addon.register()
    if args.no_warmup or args.warm_cache:
        addon.kernels.skip_warmup()
    try:
        sc = build_scene(bpy, args.width, args.height, args.samples, args.depth)
        print(f"demo: rendering {args.width}x{args.height}, {args.samples} samples, depth "
              f"{args.depth} (the first render compiles or loads the numba kernels)")
        before = render(bpy, sc, out, "before")
        print(f"demo: before.png in {before['wall_seconds']:.2f} s")
        red = bpy.data.objects["RedSphere"]
        old = tuple(red.location)
        red.location.x += 0.9
        red.location.y -= 0.6
        after = render(bpy, sc, out, "after")
        print(f"demo: moved RedSphere, after.png in {after['wall_seconds']:.2f} s")
        new_location = tuple(red.location)
        loop = edit_loop(bpy, sc, out)
        sc = bpy.context.scene  # (undo in the loop replaced the ID references)
        interpolated, accuracy = render_interpolated(bpy, sc, out, epsilon=0.01)
        compiling = (interpolated.get("fallback") or {}).get("build_compiling")
        print(f"demo: interpolated.png (radiance interpolants, epsilon 0.01) in "
              f"{interpolated['wall_seconds']:.2f} s: "
              f"{interpolated.get('interpolated_fraction', 0.0):.1%} of pixels interpolated"
              + (" (the base tracer's frame: the cell build's kernels were compiling in the "
                 "background, a first run)" if compiling else "")
              + f", max display error {accuracy['max_error']:.4f}, "
              f"{accuracy['frac_over']:.3%} of pixels over epsilon")
        report = dict(
            scene="Plate A: three spheres (one a mirror) on a plane, two point lights",
            resolution=[args.width, args.height], samples=args.samples,
            max_ray_depth=args.depth,
            edit=dict(object="RedSphere", kind="transform", old_location=old,
                      new_location=new_location),
            renders=dict(before=before, after=after, interpolated=interpolated),
            interpolated_vs_base=accuracy, edit_loop=loop,
            changed_pixels_fraction=changed_fraction(bpy, out / "before.png",
                                                     out / "after.png"),
            files=sorted(p.name for p in out.iterdir() if p.suffix in (".png", ".exr")),
        )
        (out / "stats.json").write_text(json.dumps(report, indent=2, default=_json))
        print(f"demo: {report['changed_pixels_fraction']:.1%} of the pixels changed; "
              f"wrote {', '.join(report['files'])} and stats.json to {out}")
        if accuracy["max_error"] > 0.01 + BOUND_FLOAT_TOL:
            print(f"demo: FAILED: the interpolated frame exceeds epsilon 0.01 (max display "
                  f"error {accuracy['max_error']:.5f}, {accuracy['n_over']} pixels)")
            return 1
    finally:
        addon.unregister()
    return 0


def _json(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return str(value)


if __name__ == "__main__":
    sys.exit(main())
