"""Bytes per unique triangle of every array the first render holds, one row per array.

``python scripts/memory_breakdown.py [--size 1M] [--kinds smooth,flat,blender]``

The scene is ``bench scale``'s dense scene (:func:`rstrace_engine.bench.scale.big_scene`):
a lumpy sphere of ``--size`` triangles beside a small icosphere and a floor, its sphere
given as

* ``smooth``: vertices and triangles only (the engine computes smooth vertex normals);
* ``flat``: the same with ``smooth=False`` (flat-shaded triangles);
* ``blender``: as the add-on exports a smooth mesh: float32-exact vertices, per-corner
  float32 normals (its vertex normals at every corner) and per-corner uvs (a
  latitude-longitude unwrap, one uv per vertex), and material slots.

Per array: the scene model's own (each mesh dict's arrays that are not views of the
packing), the packed scene arrays (:class:`~rstrace_engine.geometry.scene.SceneArrays`'
geometry fields) and the BVH's (:class:`~rstrace_engine.accel.bvh.SceneBVH`); a buffer
shared by several arrays is counted once, with the first that names it. Runs on any
checkout (it reads whatever fields the packing has).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.scale import _count, big_scene
from rstrace_engine.geometry import shapes

#: SceneArrays fields that are per-material, per-light or per-instance (not geometry)
_NOT_GEOMETRY = ("mat_", "light_", "tex_", "inst_", "world_", "scene_")


def dense_mesh(kind: str, triangles: int):
    mesh = shapes.lumpy_sphere(triangles, name="dense")
    if kind == "flat":
        return dataclasses.replace(mesh, smooth=False)
    if kind == "smooth":
        return mesh
    from rstrace_engine.geometry.mesh_math import vertex_normals
    v = mesh.vertices.astype(np.float32).astype(np.float64)
    f = mesh.triangles
    vn = vertex_normals(v, f).astype(np.float32)
    lon = np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi) + 0.5
    lat = np.arccos(np.clip(v[:, 2] / np.linalg.norm(v, axis=1), -1, 1)) / np.pi
    uv = np.stack([lon, lat], 1).astype(np.float32)
    return dataclasses.replace(mesh, vertices=v, corner_normals=vn[f], corner_uvs=uv[f],
                               slots=np.zeros(len(f), np.int32))


def _root(a):
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def breakdown(kind: str, triangles: int) -> list[tuple[str, float]]:
    scene = big_scene(0, dense=dense_mesh(kind, triangles))
    sa = scene.arrays()
    acc = create_accelerator("BVH", sa)
    unique = int(sa.mesh_tri_start[-1])
    rows, seen = [], set()

    def add(label, a):
        if not isinstance(a, np.ndarray):
            return
        r = _root(a)
        if id(r) in seen:
            return
        seen.add(id(r))
        rows.append((label, r.nbytes / unique))

    for f, a in sa._asdict().items():
        if not f.startswith(_NOT_GEOMETRY):
            add(f"packed.{f}", a)
    for m in scene.meshes:
        if m is None:
            continue
        for k, a in m.items():
            if isinstance(a, np.ndarray) and a.size > 6:
                rows_before = len(rows)
                add(f"model.{k}", a)
                if len(rows) > rows_before and rows[-1][1] < 0.05:
                    rows.pop()  # the small meshes' own arrays
    for f, a in acc.sb._asdict().items():
        add(f"bvh.{f}", a)
    rows = [(k, v) for k, v in rows if v >= 0.05]
    rows.append(("total", sum(v for _, v in rows)))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="1M")
    ap.add_argument("--kinds", default="smooth,flat,blender")
    args = ap.parse_args(argv)
    n = _count(args.size)
    for kind in args.kinds.split(","):
        sys.stdout.write(f"## {kind} ({args.size} triangles): bytes per unique triangle\n")
        for label, v in breakdown(kind, n):
            sys.stdout.write(f"  {label:24s} {v:6.1f}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
