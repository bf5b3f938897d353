"""The first F12 of ``bench_scale_bpy.py``'s heavy scene split into its parts, beside
Cycles' first render of the same scene in the same process.

    python scripts/first_f12_split.py [1M|4M|60k] [--json out.jsonl] [--root CHECKOUT]
                                      [--moves N] [--order ours-first|cycles-first]
                                      [--only ours|cycles]

Builds the scene (Suzanne subdivided beside a small sphere and a floor, 320x240, BASE, ray
depth 0), waits for the add-on's background kernel load (``--settle``), then times one F12
(``bpy.ops.render.render()``) with each part wrapped: the export (the mesh reads --
``foreach_get``, Blender's triangle corners, the per-corner gathers -- and the
fingerprints), the scene model (``build_scene``: ``Scene.add_mesh``'s checks, the packing),
the BVH (mesh keys, mesh builds, their leaves, the concatenation, the top level), the core
render, writing the result, and any kernel load or compile
(``Dispatcher._compile_for_args``); per part the wall seconds, the CPU seconds of the whole
process (all threads: the build thread and numba's) and of the calling thread alone (a part
run beside other work, e.g. the fingerprint's hash beside the mesh read), of which system
CPU, and the minor page faults (system CPU and faults are mostly fresh memory's first
touch) and the resident memory after it, and for the F12 its wall, CPU, system CPU, faults
and the process's peak RSS before and after. ``--moves N``: then N F12s after moving the
small sphere (wall, CPU, sync: the edit loop's goal). Then Cycles (CPU, 1 sample, no
bounces, no denoising) renders the same scene (``--order cycles-first``: Cycles first, then
the F12; ``--only ours|cycles``: one of them alone, in its own process: whichever renders
second reuses the pages the first one freed -- no first-touch faults -- so a fair
comparison alternates the order or runs each in a fresh process; the add-on is registered,
the scene built and the kernel load waited for in every mode, so the process before the
render is the same whichever renders). The JSON line also holds the SHA-1 of each F12's
radiance and pixel classes (``image_sha1``), to compare checkouts bit for bit, and the load
average. Nothing is asserted; the numbers go to ``docs/bench-scale-bpy.md``. ``--root``:
the checkout whose add-on, core and ``bench_scale_bpy.py`` run (default: this script's),
for A/B runs against another one.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (module attribute holder, name, label) of what is timed, in the order printed (a label
#: may wrap several holders' names: a function another module imports by name, in one
#: checkout or the other; a name a checkout lacks is left out)
PARTS = (("sync", "sync", "sync (export, scene model, packing, BVH)"),
         ("export", "read_scene", "export (all)"),
         ("export", "mesh_arrays", "  mesh read (foreach_get, corners, gathers)"),
         ("meshes", "mesh_arrays", "  mesh read (foreach_get, corners, gathers)"),
         ("export", "mesh_fingerprint", "  fingerprint"),
         ("meshes", "fingerprint_parts", "  fingerprint"),
         ("meshes", "fingerprint_digest", "  fingerprint"),
         ("export", "build_scene", "scene model (add_mesh, checks)"),
         ("scene.Scene", "arrays", "packing (Scene.arrays)"),
         ("accelerators.BVHAccelerator", "_build", "BVH (all)"),
         ("bvh_mesh", "mesh_key", "  mesh keys (hash)"),
         ("bvh_mesh", "build_mesh_bvh_indexed", "  mesh builds"),
         ("bvh.PlacedMesh", "built", "  leaves (direct_leaves)"),
         ("bvh", "concat_meshes", "  concatenation"),
         ("bvh_mesh", "build_top", "  top level"),
         ("core.Session", "render", "render (core)"),
         ("frames.FrameRenderer", "_write_result", "write result"),
         ("dispatcher.Dispatcher", "_compile_for_args", "kernel loads / compiles"))


def _usage() -> tuple[float, int]:
    """(system CPU seconds, minor page faults) of the whole process so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_stime, r.ru_minflt


def _rss_mb() -> float:
    """The process's resident memory now (MB)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * resource.getpagesize() / 2 ** 20


def _frame_sha1(sc) -> str | None:
    """SHA-1 of the last F12's radiance and pixel classes (the session's Frame), for
    bit-for-bit comparisons between checkouts."""
    import addon

    state = addon.session.peek_state(sc)
    frame = None if state is None else state.frame
    if frame is None:
        return None
    h = hashlib.sha1(frame.radiance.tobytes())
    h.update(frame.pixel_class.tobytes())
    return h.hexdigest()


def _empty() -> list:
    """A part's totals: wall, process CPU, calls, system CPU, faults, resident MB after
    it, CPU of the thread that called it (a part run beside another thread's work: its own
    CPU; process CPU counts both threads)."""
    return [0.0, 0.0, 0, 0.0, 0, 0.0, 0.0]


def _wrap(holder, name: str, label: str, acc: dict) -> None:
    f = getattr(holder, name, None)
    if f is None:
        return

    def timed(*a, **k):
        t, c, (s, m) = time.perf_counter(), time.process_time(), _usage()
        tc = time.thread_time()
        try:
            return f(*a, **k)
        finally:
            s1, m1 = _usage()
            e = acc.setdefault(label, _empty())
            e[0] += time.perf_counter() - t
            e[1] += time.process_time() - c
            e[2] += 1
            e[3] += s1 - s
            e[4] += m1 - m
            e[5] = _rss_mb()
            e[6] += time.thread_time() - tc

    setattr(holder, name, timed)


def plan(order: str = "ours-first", only: str | None = None) -> tuple[str, ...]:
    """Which renderers render, in order: ``("ours", "cycles")``, ``("cycles", "ours")``
    (``order`` "cycles-first") or the one ``only`` names."""
    if only is not None:
        if only not in ("ours", "cycles"):
            raise ValueError(f"only: 'ours' or 'cycles', not {only!r}")
        return (only,)
    if order not in ("ours-first", "cycles-first"):
        raise ValueError(f"order: 'ours-first' or 'cycles-first', not {order!r}")
    return ("ours", "cycles") if order == "ours-first" else ("cycles", "ours")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("size", nargs="?", default="1M")
    p.add_argument("--json", type=Path, help="append one JSON line")
    p.add_argument("--root", type=Path, default=ROOT, help="the checkout to time")
    p.add_argument("--moves", type=int, default=0,
                   help="F12s after moving the small sphere, after the first")
    p.add_argument("--order", choices=("ours-first", "cycles-first"), default="ours-first",
                   help="which renders first when both do")
    p.add_argument("--only", choices=("ours", "cycles"),
                   help="render with one of them alone (a fresh process each)")
    args = p.parse_args(argv)
    root = args.root.resolve()
    sys.path[:0] = [str(root / "scripts"), str(root)]
    import bench_scale_bpy as bsb
    import bpy
    import numba.core.dispatcher as dispatcher

    import addon
    from addon import export, meshes, sync
    from addon import session as frames
    from rstrace_engine import session as core
    from rstrace_engine.accel import accelerators, bvh, bvh_mesh
    from rstrace_engine.geometry import scene

    addon.register()
    small = bsb.build(args.size, 0, 0)
    sc = bpy.context.scene
    addon.kernels.wait(600)
    names = dict(sync=sync, scene=scene, export=export, meshes=meshes,
                 accelerators=accelerators,
                 bvh_mesh=bvh_mesh, bvh=bvh, core=core, frames=frames, dispatcher=dispatcher)
    acc: dict = {}
    for path, name, label in PARTS:
        holder = names[path.split(".")[0]]
        for attr in path.split(".")[1:]:
            holder = getattr(holder, attr)
        _wrap(holder, name, label, acc)
    out: dict = dict(size=args.size, root=str(root), order=args.order, only=args.only,
                     load=list(os.getloadavg()))
    for who in plan(args.order, args.only):
        if who == "cycles":
            out["cycles"] = _cycles(bsb, sc)
        else:
            out.update(_ours(args, addon, bpy, sc, small, acc))
    addon.unregister()
    _report(bsb, out)
    if args.json:
        with open(args.json, "a") as fh:
            fh.write(json.dumps(out) + "\n")
    return 0


def _cycles(bsb, sc) -> dict:
    """Cycles' first render (``bench_scale_bpy._cycles``: wall and CPU seconds) with the
    system CPU and minor page faults of the process during it."""
    (s0, m0), rss0 = _usage(), _rss_mb()
    out = bsb._cycles(sc)
    s1, m1 = _usage()
    out.update(sys_seconds=s1 - s0, faults=m1 - m0, rss_mb=(rss0, _rss_mb()))
    return out


def _ours(args, addon, bpy, sc, small, acc: dict) -> dict:
    """The first F12, its parts, and ``args.moves`` F12s after moving ``small``."""
    r0, rss0 = resource.getrusage(resource.RUSAGE_SELF), _rss_mb()
    t, c = time.perf_counter(), time.process_time()
    bpy.ops.render.render()
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    parts = {label: acc.get(label, _empty()) for _, _, label in PARTS}
    acc.clear()
    st = addon.last_render_stats(sc)
    out = dict(f12_wall=wall, f12_cpu=cpu,
               f12_sys=r1.ru_stime - r0.ru_stime, f12_faults=r1.ru_minflt - r0.ru_minflt,
               peak_rss_mb=(r0.ru_maxrss / 1024.0, r1.ru_maxrss / 1024.0), rss_mb=rss0,
               parts=parts,
               triangles=st.get("triangles"), memory_mb=st.get("memory_mb"),
               image_sha1=_frame_sha1(sc))
    out["moves"] = moves = []
    for _ in range(args.moves):
        small.location.x += 0.2
        bpy.context.view_layer.update()
        t, c = time.perf_counter(), time.process_time()
        bpy.ops.render.render()
        mv = addon.last_render_stats(sc)
        moves.append(dict(wall=time.perf_counter() - t, cpu=time.process_time() - c,
                          sync=mv.get("sync_seconds"), meshes_read=mv.get("meshes_read"),
                          image_sha1=_frame_sha1(sc)))
    return out


def _report(bsb, out: dict) -> None:
    cy = out.get("cycles")
    cys = ("" if cy is None else f"Cycles' first render "
           f"({'alone' if out['only'] else out['order']}): wall {cy['wall_seconds']:.3f} s, "
           f"CPU {cy['cpu_seconds']:.3f} s (system {cy['sys_seconds']:.3f}, "
           f"{cy['faults']} faults)")
    if "f12_wall" not in out:
        bsb._say(cys)
        return
    wall, cpu = out["f12_wall"], out["f12_cpu"]
    bsb._say(f"resident before the F12: {out['rss_mb']:.0f} MB")
    for label, (w, cp, n, sy, mf, rss, tc) in out["parts"].items():
        bsb._say(f"{label:44s} wall {w:7.3f} s  CPU {cp:7.3f} s  thread {tc:6.3f} s  "
                 f"user {cp - sy:6.3f} s  system {sy:6.3f} s  "
                 f"faults {mf:7d}  resident after {rss:5.0f} MB  ({n} calls)")
    bsb._say(f"first F12: wall {wall:.3f} s, CPU {cpu:.3f} s (system {out['f12_sys']:.3f}, "
             f"{out['f12_faults']} faults; peak RSS {out['peak_rss_mb'][0]:.0f} -> "
             f"{out['peak_rss_mb'][1]:.0f} MB; memory_mb {out['memory_mb']:.1f}); "
             f"image {out['image_sha1']}")
    if cys:
        bsb._say(cys)
    for mv in out["moves"]:
        bsb._say(f"F12 after a move: wall {mv['wall']:.3f} s, CPU {mv['cpu']:.3f} s (sync "
                 f"{mv['sync']:.3f} s, meshes read {mv['meshes_read']}; image "
                 f"{mv['image_sha1']})")


if __name__ == "__main__":
    sys.exit(main())
