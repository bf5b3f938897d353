"""The add-on's hand-over of a mesh and ``Scene.add_mesh`` (its checks and the packing),
CPU seconds; runs on any checkout, to compare two in turn.

``python scripts/mesh_handover_bench.py [TRIANGLES] [REPEATS]`` (default 1e6, 3), one JSON
line. The mesh: ``shapes.lumpy_sphere`` exported as the add-on exports a Blender mesh (float32
vertices, per-corner uvs from one uv per vertex, slots), smooth (normals domain POINT) and
flat (FACE). On a checkout whose ``Mesh`` has no ``owned`` field the hand-over is the old
one: the vertex normals gathered to every corner, or each triangle's flat normal written to
its corners (``flat_triangle_normals``); on a newer one the vertex normals as they are, or
none and ``smooth=False``, the arrays owned. Per kind: ``first`` the hand-over, ``add_mesh``
and the packing, best of REPEATS; ``again`` the same Mesh object added to a second scene.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time

import numpy as np

from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.mesh_math import flat_triangle_normals, vertex_normals
from rstrace_engine.geometry.scene import Mesh, Scene


def main() -> None:
    n = int(float(sys.argv[1])) if len(sys.argv) > 1 else 1_000_000
    reps = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    new = "owned" in {f.name for f in dataclasses.fields(Mesh)}
    base = shapes.lumpy_sphere(n, name="dense")
    v32 = base.vertices.astype(np.float32)
    t = np.ascontiguousarray(base.triangles, np.int32)
    vn = vertex_normals(v32.astype(np.float64), t).astype(np.float32)
    lon = np.arctan2(v32[:, 1], v32[:, 0]) / (2 * np.pi) + 0.5
    uvv = np.stack([lon, lon * 0.5], 1).astype(np.float32)

    def handover(kind: str) -> Mesh:
        """What the add-on makes after its reads (fresh arrays every time)."""
        uvs = np.empty((len(t), 3, 2), np.float32)
        np.take(uvv, t, axis=0, out=uvs)
        slots = np.zeros(len(t), np.int32)
        if new:
            normals = dict(vertex_normals=vn.copy()) if kind == "smooth" else dict(smooth=False)
            return Mesh("m", v32.copy(), t.copy(), corner_uvs=uvs, slots=slots, owned=True,
                        **normals)
        corners = np.empty((len(t), 3, 3), np.float32)
        if kind == "smooth":
            np.take(vn, t, axis=0, out=corners)
        else:
            corners[:] = 0.0
            flat_triangle_normals(v32, t, corners)
        return Mesh("m", v32.copy(), t.copy(), corner_normals=corners, corner_uvs=uvs,
                    slots=slots)

    out = {"new": new, "triangles": len(t)}
    for kind in ("smooth", "flat"):
        Scene().add_mesh(handover(kind))  # (kernels loaded)
        first, again = [], []
        for _ in range(reps):
            c0 = time.process_time()
            mesh = handover(kind)
            s = Scene()
            s.add_mesh(mesh)
            s._pack_meshes()
            c1 = time.process_time()
            Scene().add_mesh(mesh)
            c2 = time.process_time()
            first.append(c1 - c0)
            again.append(c2 - c1)
        out[kind] = dict(first=round(min(first), 4), again=round(min(again), 4),
                         nmode=int(s.meshes[0]["nmode"]))
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
