"""Heavy scenes through real F12 in bpy (background), beside Cycles in the same run.

    python scripts/bench_scale_bpy.py [--sizes 60k,1M,4M,dups] [--quick] [--json out.json]
                                      [--no-cycles] [--no-viewport] [--max-depth N]

Scenes (320x240, BASE, 1 sample, ray depth ``--max-depth`` (default 0: primary rays and
direct light, what Cycles renders with no bounces); the add-on registered as an installed
extension is):

* ``60k``, ``1M``, ``4M``: Suzanne subdivided to level 3, 5, 6 (62k, 991k, 3.96M triangles;
  the subdivision applied, as a scanned or sculpted asset is) beside a small sphere and a
  floor, a sun and a point light;
* ``dups``: 2,000 linked duplicates of one 20k-triangle sphere (one mesh datablock) on a
  floor (``--dups N`` for another count);
* ``--quick``: ``60k`` and 100 duplicates only.

Per scene: the first F12 (``bpy.ops.render.render()``, wall time, and the engine's own
split: sync = depsgraph walk, mesh export and diff; build = the session's structures (BVH);
render; in the first F12 of the process the kernels come from numba's cache: the add-on
loads them in the background once the scene renders with RSTrace, which ``--settle`` waits
for, as a user who presses F12 a second after making the scene would; without it the
first F12 comes at once and shares the CPU with that load); the F12
after moving the small sphere (wall, sync, meshes read); the scene's first F12 once more
after the add-on forgot everything (``again``: no session, mirror or kept BVH, the kernels
loaded: a new file later in the same Blender); the viewport's
update after moving it (``view_update``'s sync on the main thread, the time until the
worker has the first image of the edited scene, its coarse stage, and until it has all its
stages), when ``--no-viewport`` is not given; the session's memory
(``last_render_stats``' ``memory_mb``) and the process's peak RSS; Cycles' first render of
the same scene (CPU, 1 sample, direct light only: no bounces, no denoising) in the same
process. Every F12 and Cycles' render also give the CPU seconds of the whole process (all
threads: on a shared machine the steadier measure). Nothing is asserted: the numbers go to
``docs/bench-scale-bpy.md``.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

W, H = 320, 240
SUZANNE_LEVELS = {"60k": 3, "1M": 5, "4M": 6}


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _current_rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * resource.getpagesize() / 1e6
    except OSError:
        return float("nan")


def build(kind: str, dups: int, max_depth: int = 0):
    """A fresh file holding the scene ``kind``; returns the small sphere to move."""
    import bpy

    from tests.blender import builders as b

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = b.setup_render(W, H, samples=1, max_depth=max_depth)
    sc.rstrace.mode = "BASE"
    sc.render.image_settings.media_type = "IMAGE"
    sc.render.image_settings.file_format = "PNG"
    b.set_world((0.05, 0.05, 0.06), lights=False)
    grey = b.principled("Grey", (0.6, 0.6, 0.6), roughness=0.6)
    red = b.principled("Red", (0.7, 0.1, 0.1), roughness=0.4)
    b.add_object("Floor", b.grid("Floor", 40.0), material=grey)
    if kind in SUZANNE_LEVELS:
        bpy.ops.mesh.primitive_monkey_add(location=(0.0, 0.0, 1.2))
        monkey = bpy.context.object
        mod = monkey.modifiers.new("Subdivision", "SUBSURF")
        mod.levels = mod.render_levels = SUZANNE_LEVELS[kind]
        dg = bpy.context.evaluated_depsgraph_get()
        me = bpy.data.meshes.new_from_object(monkey.evaluated_get(dg))
        old = monkey.data
        monkey.modifiers.clear()
        monkey.data = me
        bpy.data.meshes.remove(old)
        me.materials.append(grey)
        target = (0.0, 0.0, 1.0)
        cam = ((0.0, -6.0, 2.5), target)
    else:
        ball = b.uv_sphere("Ball", 0.2, 128, 80)
        ball.materials.append(grey)
        side = int(dups ** 0.5) + 1
        for k in range(dups):
            b.add_object(f"Ball{k}", ball, (0.5 * (k % side), 0.5 * (k // side), 0.2))
        target = (side * 0.25, side * 0.25, 0.0)
        cam = ((side * 0.25, -side * 0.4, side * 0.35), target)
    small = b.add_object("Small", b.uv_sphere("SmallMesh", 0.25, 16, 8),
                         (target[0] + 1.4, target[1] - 1.0, 0.25), red)
    b.point_light("Key", (target[0] - 3.0, target[1] - 4.0, 6.0), 2500.0)
    b.camera(*cam)
    bpy.context.view_layer.update()
    return small


def _f12(addon, sc) -> dict:
    import bpy

    t0, c0 = time.perf_counter(), time.process_time()
    bpy.ops.render.render()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = addon.last_render_stats(sc)
    if not st:
        raise RuntimeError(f"RSTrace rendered nothing: {addon.session.peek_state(sc).error}")
    keep = ("sync_seconds", "apply_seconds", "accel_build_s", "render_seconds",
            "total_seconds", "meshes_read", "meshes_trusted", "triangles", "memory_mb",
            "edits", "new_session")
    out = {k: st.get(k) for k in keep}
    out["wall_seconds"] = wall
    out["cpu_seconds"] = cpu
    return out


def _viewport(addon, small) -> dict:
    """The rendered viewport's update after a move of ``small`` (after its first image)."""
    import bpy

    from tests.blender.test_viewport import _camera, _view

    vr = addon.viewport.ViewportRenderer()
    calls = []

    def handler(_scene, depsgraph):
        t = time.perf_counter()
        vr.view_update(None, depsgraph)
        calls.append(time.perf_counter() - t)

    try:
        t0 = time.perf_counter()
        vr.view_update(None, bpy.context.evaluated_depsgraph_get())
        vr.draw_view(_camera(_view(W, H)), None)
        if not vr.worker.wait_idle(600):
            raise RuntimeError("the viewport's first image did not come")
        first = time.perf_counter() - t0
        bpy.app.handlers.depsgraph_update_post.append(handler)
        before = vr.worker.latest()
        small.location.x += 0.3
        t1 = time.perf_counter()
        bpy.context.view_layer.update()
        t_update = time.perf_counter() - t1
        shown = None  # the first image of the edited scene (the coarse stage)
        while time.perf_counter() - t1 < 600:
            img = vr.worker.latest()
            if img is not None and before is not None and img.job > before.job:
                shown = (time.perf_counter() - t1, img.stage)
                break
            time.sleep(0.001)
        ok = vr.worker.wait_idle(600)
        image = time.perf_counter() - t1
        return dict(first_image_seconds=first, view_update_seconds=sum(calls),
                    depsgraph_update_seconds=t_update,
                    new_image_seconds=shown[0] if shown else None,
                    new_image_stage=shown[1] if shown else None,
                    image_seconds=image if ok else None,
                    edits=vr.last_edits, error=vr.error or vr.worker.error)
    finally:
        if handler in bpy.app.handlers.depsgraph_update_post:
            bpy.app.handlers.depsgraph_update_post.remove(handler)
        vr.free()


def _cycles(sc) -> dict:
    import bpy

    sc.render.engine = "CYCLES"
    c = sc.cycles
    c.device = "CPU"
    c.samples = 1
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 0
    c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 0
    c.transparent_max_bounces = c.volume_bounces = 0
    t0, c0 = time.perf_counter(), time.process_time()
    bpy.ops.render.render()
    out = dict(wall_seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0)
    sc.render.engine = "RSTRACE"
    return out


def run(kind: str, args) -> dict:
    import bpy

    import addon

    rss0 = _current_rss_mb()
    small = build(kind, args.dups, args.max_depth)
    sc = bpy.context.scene
    row: dict = dict(scene=kind, objects=len(sc.objects))
    # the add-on loads the kernels in the background once the scene renders with RSTrace
    # (addon/kernels.py): busy at the first F12 when it comes right after the scene is made
    row["kernels_loading"] = not addon.kernels.wait(0)
    if args.settle:
        t0 = time.perf_counter()
        addon.kernels.wait(600)
        row["settle_seconds"] = time.perf_counter() - t0
    row["first"] = _f12(addon, sc)
    row["rss_after_first_mb"] = _current_rss_mb() - rss0
    moves = []
    for _ in range(args.moves):
        small.location.x += 0.2
        bpy.context.view_layer.update()
        moves.append(_f12(addon, sc))
    row["move"] = min(moves, key=lambda m: m["wall_seconds"])
    row["moves"] = moves
    if args.again:
        # the scene's first F12 once more, from nothing (no session, mirror or kept BVHs)
        # but with the kernels loaded: what a new file costs later in the same Blender
        addon.session.forget_all()
        small.location.x += 0.2
        bpy.context.view_layer.update()
        row["again"] = _f12(addon, sc)
    if args.viewport:
        row["viewport"] = _viewport(addon, small)
    if args.cycles:
        row["cycles"] = _cycles(sc)
    row["peak_rss_mb"] = _rss_mb()
    addon.session.forget_all()
    return row


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _print(row: dict) -> None:
    f, m = row["first"], row["move"]
    build = f.get("accel_build_s")
    if "settle_seconds" in row:
        _say(f"       (waited {row['settle_seconds']:.2f} s for the background kernel load)")
    elif row.get("kernels_loading"):
        _say("       (the background kernel load was still running at the first F12)")
    _say(f"{row['scene']:>5}: {f['triangles']:,} tris, {row['objects']} objects | first F12 "
          f"{f['wall_seconds']:.2f} s, CPU {f['cpu_seconds']:.2f} s (sync "
          f"{f['sync_seconds']:.2f}, build "
          f"{build if build is None else round(build, 2)}, apply {f['apply_seconds']:.2f}, "
          f"render {f['render_seconds']:.2f}) | move F12 {m['wall_seconds']:.3f} s "
          f"(sync {m['sync_seconds']:.3f}, engine {m['total_seconds']:.3f}, meshes read "
          f"{m['meshes_read']}) | memory {f['memory_mb']:.0f} MB")
    a = row.get("again")
    if a:
        _say(f"       first F12 again, kernels loaded: {a['wall_seconds']:.2f} s, CPU "
             f"{a['cpu_seconds']:.2f} s (sync {a['sync_seconds']:.2f}, build "
             f"{a['accel_build_s']:.2f}, apply {a['apply_seconds']:.2f}, render "
             f"{a['render_seconds']:.2f})")
    v = row.get("viewport")
    if v:
        first = v["new_image_seconds"]
        _say(f"       viewport: view_update {1e3 * v['view_update_seconds']:.1f} ms, first "
             f"new image {first if first is None else round(1e3 * first, 1)} ms "
             f"({v['new_image_stage']}), all stages {v['image_seconds']:.2f} s (first view "
             f"{v['first_image_seconds']:.2f} s)")
    if "cycles" in row:
        c = row["cycles"]
        _say(f"       Cycles first render {c['wall_seconds']:.2f} s, CPU {c['cpu_seconds']:.2f} s")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", default="60k,1M,4M,dups")
    p.add_argument("--dups", type=int, default=2000)
    p.add_argument("--moves", type=int, default=3, help="F12s after a move (the best kept)")
    p.add_argument("--quick", action="store_true", help="60k and 100 duplicates only")
    p.add_argument("--no-cycles", dest="cycles", action="store_false")
    p.add_argument("--no-viewport", dest="viewport", action="store_false")
    p.add_argument("--no-again", dest="again", action="store_false",
                   help="skip the second first F12 (from nothing, the kernels loaded)")
    p.add_argument("--max-depth", type=int, default=0,
                   help="RSTrace's ray depth (0: direct light, as Cycles' no bounces)")
    p.add_argument("--settle", action="store_true",
                   help="wait for the add-on's background kernel load before the first F12 "
                        "(a user who presses F12 a second or more after making the scene)")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    if args.quick:
        args.sizes, args.dups = "60k,dups", 100
    import bpy  # noqa: F401

    import addon

    addon.register()
    rows = []
    for kind in args.sizes.split(","):
        rows.append(run(kind.strip(), args))
        _print(rows[-1])
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str))
    addon.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
