"""Rows the packing hands back to an owned Mesh (packing.share_rows) must
not keep a packing alive that no scene holds any more. An owned Mesh whose vertices a
packing lays first (the scene's largest mesh, the first of equals) shares its triangles with
that packing's whole ``tris`` array; packed again where it is not first (another scene of
the export cache, or its own scene after a larger mesh came) its
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
    for m in (small, other):  # (as large as each other: the first one's vertices first)
        first.add_mesh(m)
    first._pack_meshes()
    assert _root(small.triangles) is _root(first._mesh_arrays["tris"])  # (handed back)
    del first
    gc.collect()
    second = Scene()  # the same cached meshes and a larger one (another first mesh)
    for m in (other, small, big):
        second.add_mesh(m)
    packed = second._pack_meshes()
    # (s33-int: the dropped scene's whole tris array, big's triangles included)
    held = _held(small, packed)
    assert held == 0, f"{held} bytes of a dropped packing"


def test_the_largest_mesh_is_laid_first_and_its_triangles_held_once():
    """The packing lays the vertices of the scene's largest mesh first, wherever its slot,
    so that its packed triangles are its own and are handed back: the owned Mesh's
    triangles are then a view of the packing (the process holds them once: 12 bytes a
    triangle, 46 MB at 4M), the smaller meshes' are not. Every triangle still reads its
    own mesh's vertices and vertex normals, bit for bit. On main the big mesh, in slot 1,
    kept a second copy of its triangles."""
    from rstrace_engine.geometry.attributes import ATTR_VERTEX

    meshes = []
    for name, n in (("small", 20), ("big", 4000), ("other", 60)):
        base = shapes.lumpy_sphere(n, name=name)
        v = np.asarray(base.vertices, np.float32)
        t = np.asarray(base.triangles, np.int32).copy()
        vn = np.random.default_rng(n).standard_normal((len(v), 3)).astype(np.float32)
        meshes.append(Mesh(name, v, t, vertex_normals=vn, smooth=True, owned=True))
    own = [(m.vertices.astype(np.float64), m.triangles.copy(), m.vertex_normals.copy())
           for m in meshes]
    scene = Scene()
    ids = [scene.add_mesh(m) for m in meshes]
    packed = scene._pack_meshes()
    small, big, other = meshes
    assert scene.meshes[ids[1]]["vert0"] == 0
    assert _root(big.triangles) is _root(packed["tris"])  # (held once)
    assert not np.shares_memory(small.triangles, packed["tris"])
    assert not np.shares_memory(other.triangles, packed["tris"])
    starts = packed["mesh_tri_start"]
    for k, (v, t, vn) in zip(ids, own, strict=True):
        tris = packed["tris"][starts[k]:starts[k + 1]]
        assert packed["verts"][tris].tobytes() == v[t].tobytes()
        mode, bias = packed["mesh_nrm"][k]
        assert mode == ATTR_VERTEX
        assert packed["normals"][bias + tris].tobytes() == vn[t].tobytes()
    assert np.array_equal(big.triangles, own[1][1])
