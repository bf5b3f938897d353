"""Rows the packing hands back to an owned Mesh (packing.share_rows) must
not keep a packing alive that no scene holds any more. An owned Mesh packed first shares
its triangles with that packing's whole ``tris`` array; packed again where it is not first
(another scene of the export cache, or its own scene after a mesh took a lower slot) its
triangles are not handed back again, and it keeps the old packing's whole ``tris`` (12
bytes a triangle of every mesh of that scene) alive beside the new packing."""

from __future__ import annotations

import gc

import numpy as np

from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Mesh, Scene


def _owned(mesh: Mesh, name: str) -> Mesh:
    return Mesh(name, np.asarray(mesh.vertices, np.float32),
                np.asarray(mesh.triangles, np.int32).copy(), owned=True)


def _root(a: np.ndarray) -> np.ndarray:
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def _held(mesh: Mesh, packed: dict) -> int:
    """Bytes ``mesh.triangles`` keeps alive beyond its own values and ``packed``."""
    root = _root(mesh.triangles)
    if root is _root(packed["tris"]):
        return 0
    return root.nbytes - mesh.triangles.nbytes


def test_a_mesh_packed_first_then_not_first_holds_no_old_packing():
    small = _owned(shapes.lumpy_sphere(20, name="s"), "small")
    big = _owned(shapes.lumpy_sphere(4000, name="b"), "big")
    other = _owned(shapes.lumpy_sphere(20, name="o"), "other")
    first = Scene()
    for m in (small, big):
        first.add_mesh(m)
    first._pack_meshes()
    assert _root(small.triangles) is _root(first._mesh_arrays["tris"])  # (handed back)
    del first
    gc.collect()
    second = Scene()  # the same cached meshes, another order (another first mesh)
    for m in (other, small, big):
        second.add_mesh(m)
    packed = second._pack_meshes()
    # (s33-int: the dropped scene's whole tris array, big's triangles included)
    held = _held(small, packed)
    assert held == 0, f"{held} bytes of a dropped packing"
