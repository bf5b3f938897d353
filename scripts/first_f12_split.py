"""The first F12 of ``bench_scale_bpy.py``'s heavy scene split into its parts, beside
Cycles' first render of the same scene in the same process.

    python scripts/first_f12_split.py [1M|4M|60k] [--json out.jsonl] [--root CHECKOUT]

Builds the scene (Suzanne subdivided beside a small sphere and a floor, 320x240, BASE,
ray depth 0), waits for the add-on's background kernel load (``--settle``), then times one
F12 (``bpy.ops.render.render()``) with each part wrapped: the export (the mesh reads --
``foreach_get``, Blender's triangle corners, the per-corner gathers -- and the
fingerprints), the scene model (``build_scene``: ``Scene.add_mesh``'s checks, the
packing), the BVH (mesh keys, mesh builds, their leaves, the concatenation, the top
level), the core render, writing the result, and any kernel load or compile
(``Dispatcher._compile_for_args``); per part the wall seconds and the CPU seconds of the
whole process (all threads: the build thread and numba's), and for the F12 its wall, CPU
and system CPU (page faults of fresh memory). Then Cycles (CPU, 1 sample, no bounces, no
denoising) renders the same scene. Nothing is asserted; the numbers go to
``docs/bench-scale-bpy.md``. ``--root``: the checkout whose add-on, core and
``bench_scale_bpy.py`` run (default: this script's), for A/B runs against another one.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (module attribute holder, name, label) of what is timed, in the order printed
PARTS = (("export", "read_scene", "export (all)"),
         ("export", "mesh_arrays", "  mesh read (foreach_get, corners, gathers)"),
         ("export", "mesh_fingerprint", "  fingerprint"),
         ("export", "build_scene", "scene model (add_mesh, checks, packing)"),
         ("accelerators.BVHAccelerator", "_build", "BVH (all)"),
         ("bvh_mesh", "mesh_key", "  mesh keys (hash)"),
         ("bvh_mesh", "build_mesh_bvh_indexed", "  mesh builds"),
         ("bvh.PlacedMesh", "built", "  leaves (direct_leaves)"),
         ("bvh", "concat_meshes", "  concatenation"),
         ("bvh_mesh", "build_top", "  top level"),
         ("core.Session", "render", "render (core)"),
         ("frames.FrameRenderer", "_write_result", "write result"),
         ("dispatcher.Dispatcher", "_compile_for_args", "kernel loads / compiles"))


def _wrap(holder, name: str, label: str, acc: dict) -> None:
    f = getattr(holder, name)

    def timed(*a, **k):
        t, c = time.perf_counter(), time.process_time()
        try:
            return f(*a, **k)
        finally:
            e = acc.setdefault(label, [0.0, 0.0, 0])
            e[0] += time.perf_counter() - t
            e[1] += time.process_time() - c
            e[2] += 1

    setattr(holder, name, timed)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("size", nargs="?", default="1M")
    p.add_argument("--json", type=Path, help="append one JSON line")
    p.add_argument("--root", type=Path, default=ROOT, help="the checkout to time")
    args = p.parse_args(argv)
    root = args.root.resolve()
    sys.path[:0] = [str(root / "scripts"), str(root)]
    import bench_scale_bpy as bsb
    import bpy
    import numba.core.dispatcher as dispatcher

    import addon
    from addon import export
    from addon import session as frames
    from rstrace_engine import session as core
    from rstrace_engine.accel import accelerators, bvh, bvh_mesh

    addon.register()
    bsb.build(args.size, 0, 0)
    sc = bpy.context.scene
    addon.kernels.wait(600)
    names = dict(export=export, accelerators=accelerators, bvh_mesh=bvh_mesh, bvh=bvh,
                 core=core, frames=frames, dispatcher=dispatcher)
    acc: dict = {}
    for path, name, label in PARTS:
        holder = names[path.split(".")[0]]
        for attr in path.split(".")[1:]:
            holder = getattr(holder, attr)
        _wrap(holder, name, label, acc)
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    t, c = time.perf_counter(), time.process_time()
    bpy.ops.render.render()
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    parts = {label: acc.get(label, [0.0, 0.0, 0]) for _, _, label in PARTS}
    acc.clear()
    st = addon.last_render_stats(sc)
    out = dict(size=args.size, root=str(root), f12_wall=wall, f12_cpu=cpu,
               f12_sys=r1.ru_stime - r0.ru_stime, parts=parts,
               triangles=st.get("triangles"), memory_mb=st.get("memory_mb"),
               cycles=bsb._cycles(sc))
    addon.unregister()
    for label, (w, cp, n) in parts.items():
        bsb._say(f"{label:44s} wall {w:7.3f} s  CPU {cp:7.3f} s  ({n} calls)")
    cy = out["cycles"]
    bsb._say(f"first F12: wall {wall:.3f} s, CPU {cpu:.3f} s (system {out['f12_sys']:.3f}) | "
             f"Cycles' first render: wall {cy['wall_seconds']:.3f} s, "
             f"CPU {cy['cpu_seconds']:.3f} s")
    if args.json:
        with open(args.json, "a") as fh:
            fh.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
