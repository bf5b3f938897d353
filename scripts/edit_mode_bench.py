"""What a walk costs when an object in Edit Mode is instanced many times (bpy, background).

    python scripts/edit_mode_bench.py [--instances 900] [--walks 5] [--repo PATH]

A sphere of 40,194 vertices instanced ``--instances`` times by a geometry-nodes instancer
(Instance on Points over a grid, Object Info As Instance) and a camera. Timed: the CPU time
(``time.process_time``) of one :func:`addon.export.read_scene` with a warm
:class:`~addon.export.ExportCache` (the mesh read by an earlier walk), ``--walks`` times, in
Object Mode and then with the sphere in Edit Mode (every walk converts the edit mesh:
``to_mesh``). ``--repo``: the checkout whose ``addon`` is timed (default: this one; a
baseline worktree of main for an A/B).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def build(instances: int):
    import bmesh
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    me = bpy.data.meshes.new("Big")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=256, v_segments=158, radius=0.4)
    bm.to_mesh(me)
    bm.free()
    big = bpy.data.objects.new("Big", me)
    sc.collection.objects.link(big)
    ng = bpy.data.node_groups.new("GN", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    side = max(int(round(instances ** 0.5)), 1)
    grid = ng.nodes.new("GeometryNodeMeshGrid")
    grid.inputs["Vertices X"].default_value = side
    grid.inputs["Vertices Y"].default_value = max(instances // side, 1)
    grid.inputs["Size X"].default_value = grid.inputs["Size Y"].default_value = float(side)
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = big
    info.inputs["As Instance"].default_value = True
    iop = ng.nodes.new("GeometryNodeInstanceOnPoints")
    ng.links.new(grid.outputs["Mesh"], iop.inputs["Points"])
    ng.links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    ng.links.new(iop.outputs[0], ng.nodes.new("NodeGroupOutput").inputs[0])
    holder = bpy.data.objects.new("Instancer", bpy.data.meshes.new("Empty"))
    sc.collection.objects.link(holder)
    holder.modifiers.new("GN", "NODES").node_group = ng
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    sc.collection.objects.link(cam)
    cam.location = (0.0, -40.0, 20.0)
    sc.camera = cam
    bpy.context.view_layer.update()
    return big


def walks(label: str, n: int) -> list[float]:
    import bpy

    from addon import export

    cache = export.ExportCache()
    snap = export.read_scene(bpy.context.evaluated_depsgraph_get(), cache)
    ts = []
    for _ in range(n):
        t0 = time.process_time()
        export.read_scene(bpy.context.evaluated_depsgraph_get(), cache)
        ts.append(time.process_time() - t0)
    sys.stdout.write(f"{label}: {len(snap.objects)} objects, CPU s a walk "
                     + " ".join(f"{t:.3f}" for t in ts) + f" (min {min(ts):.3f})\n")
    sys.stdout.flush()
    return ts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=900)
    ap.add_argument("--walks", type=int, default=5)
    ap.add_argument("--repo", default=str(Path(__file__).resolve().parents[1]))
    args = ap.parse_args()
    sys.path.insert(0, args.repo)
    import bpy

    big = build(args.instances)
    sys.stdout.write(f"{args.repo}: a sphere of {len(big.data.vertices):,} vertices\n")
    walks("object mode", args.walks)
    layer = bpy.context.view_layer
    for ob in layer.objects:
        ob.select_set(ob is big)
    layer.objects.active = big
    bpy.ops.object.mode_set(mode="EDIT")
    walks("edit mode", args.walks)


if __name__ == "__main__":
    main()
