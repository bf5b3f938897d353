"""The add-on's mesh fingerprint (:func:`addon.meshes.mesh_fingerprint`): what decides
whether a cached mesh read is taken again where the journal cannot vouch for it (F12 and
animation frames). It must change whenever the exported triangles, normals, uvs or slots
would, and it hashes the faces (their offsets), not the edges."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest


def _heptagon_mesh(faces=((0, 1, 2), (3, 4, 5, 6))):
    """Seven vertices on a circle, ``faces`` -- (0 1 2) and (3 4 5 6), or (0 1 2 3) and
    (4 5 6) -- and every edge that either pair has (loose where the faces do not use it):
    the two meshes differ in where the second face starts, in their triangles, but in no
    edge, no corner's vertex and no count."""
    verts = [(math.cos(2 * math.pi * k / 7), math.sin(2 * math.pi * k / 7), 0.0)
             for k in range(7)]
    edges = [(0, 1), (1, 2), (0, 2), (2, 3), (0, 3), (3, 4), (4, 5), (5, 6), (3, 6),
             (4, 6)]
    me = bpy.data.meshes.new("Hept")
    me.from_pydata(verts, edges, [list(f) for f in faces])
    me.update()
    return me


def _edge_verts(me) -> np.ndarray:
    ev = np.empty(2 * len(me.edges), np.int32)
    me.edges.foreach_get("vertices", ev)
    return ev


def _corner_verts(me) -> np.ndarray:
    cv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", cv)
    return cv


def test_the_fingerprint_sees_a_face_boundary_moved_between_the_same_edges():
    """Moving where a face starts among the same corners (their vertices, the edges and
    every count unchanged) changes the triangles the export gives, so the fingerprint
    must change. Main's fingerprint hashed the edges' vertices, not the faces, and gave
    the same digest for both meshes (a stale cached read would have been taken). The
    fingerprint no longer reads the edges (Blender copies that array for the read)."""
    from addon.meshes import mesh_arrays, mesh_fingerprint

    me = _heptagon_mesh()
    raw: dict = {}
    before = mesh_fingerprint(me, raw)
    assert ".edge_verts" not in raw
    assert mesh_fingerprint(me) == before  # (an unchanged mesh: the same digest)
    other = _heptagon_mesh(((0, 1, 2, 3), (4, 5, 6)))
    assert [p.loop_total for p in other.polygons] == [4, 3]
    np.testing.assert_array_equal(_edge_verts(other), _edge_verts(me))
    np.testing.assert_array_equal(_corner_verts(other), _corner_verts(me))
    assert (len(other.vertices), len(other.edges), len(other.loops), len(other.polygons)) \
        == (len(me.vertices), len(me.edges), len(me.loops), len(me.polygons))
    tris = [sorted(map(tuple, np.sort(mesh_arrays(m, m.name).triangles, axis=1)))
            for m in (me, other)]
    assert tris[0] != tris[1]  # (the export differs)
    assert mesh_fingerprint(other) != before


def test_the_fingerprint_still_sees_positions_corners_and_uvs():
    """A guard (main passes it too): a moved vertex, a corner's vertex and a uv each
    change the digest; putting the values back gives the first digest again."""
    from addon.meshes import mesh_fingerprint

    me = _heptagon_mesh()
    me.uv_layers.new(name="UV")
    first = mesh_fingerprint(me)
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    moved = co.copy()
    moved[4] += 1e-3
    me.vertices.foreach_set("co", moved)
    me.update()
    assert mesh_fingerprint(me) != first
    me.vertices.foreach_set("co", co)
    me.update()
    assert mesh_fingerprint(me) == first
    cv = _corner_verts(me)
    swapped = cv.copy()
    swapped[[4, 5]] = swapped[[5, 4]]
    me.loops.foreach_set("vertex_index", swapped)
    me.update()
    assert mesh_fingerprint(me) != first
    me.loops.foreach_set("vertex_index", cv)
    me.update()
    assert mesh_fingerprint(me) == first
    uv = np.empty(2 * len(me.loops), np.float32)
    me.uv_layers["UV"].uv.foreach_get("vector", uv)
    uv[3] += 0.25
    me.uv_layers["UV"].uv.foreach_set("vector", uv)
    assert mesh_fingerprint(me) != first


def test_the_fingerprint_sees_free_custom_normals_per_vertex():
    """Blender 4.5+'s free custom normals on points (a ``custom_normal`` float vector
    attribute, Set Mesh Normal's Free mode): ``me.vertex_normals`` returns them and the
    export takes them, so changing them must change the digest (main's hashed only the
    positions, faces and corners in the POINT domain: the same digest, a stale cached read
    where the journal cannot vouch, an animated normal input in F12 frames)."""
    from addon.meshes import mesh_arrays, mesh_fingerprint

    me = _heptagon_mesh(((0, 1, 2, 3), (3, 4, 5, 6)))
    me.shade_smooth()
    me.attributes.new("custom_normal", "FLOAT_VECTOR", "POINT")
    me.update()
    assert me.normals_domain == "POINT"
    first, read = mesh_fingerprint(me), mesh_arrays(me, me.name)
    n = np.random.default_rng(1).standard_normal((len(me.vertices), 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    me.attributes["custom_normal"].data.foreach_set("vector", n.reshape(-1))
    me.update()
    assert not np.array_equal(mesh_arrays(me, me.name).vertex_normals, read.vertex_normals)
    assert mesh_fingerprint(me) != first
    assert mesh_fingerprint(me) == mesh_fingerprint(me)  # (unchanged: the same digest)


def test_a_large_meshs_fingerprint_is_hashed_beside_its_read(monkeypatch):
    """``meshes.read_mesh`` (the export's first read of a mesh) hashes the fingerprint on
    a second thread while it reads the mesh, whose positions are copied there too, beside
    the per-triangle gathers (from ``BESIDE_BYTES``): the same digest as
    ``mesh_fingerprint`` and the same Mesh as ``mesh_arrays``; a small mesh's are hashed
    and copied here; a given fingerprint is taken as it is. (Main has no ``read_mesh``: it
    hashed after the read, on the same thread, and copied the positions there.)"""
    import numba

    from addon import meshes

    if numba.get_num_threads() < 2:
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    if numba.get_num_threads() < 2:
        pytest.skip("one thread only here")
    handed = []

    class Recorded(meshes.Beside):
        def __init__(self, fn, *args, when=True):
            super().__init__(fn, *args, when=when)
            handed.append((fn, self.started))

    monkeypatch.setattr(meshes, "Beside", Recorded)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=300, y_subdivisions=300)
    me = bpy.context.object.data
    raw: dict = {}
    mesh, fp = meshes.read_mesh(me, me.name, raw)
    assert meshes.parts_bytes(meshes.fingerprint_parts(me)) >= meshes.BESIDE_BYTES
    assert 12 * len(me.vertices) >= meshes.BESIDE_BYTES
    assert handed == [(meshes.fingerprint_digest, True), (np.copy, True)]  # (pool thread)
    assert fp == meshes.mesh_fingerprint(me)
    assert meshes.same_mesh(mesh, meshes.mesh_arrays(me, me.name))
    assert meshes.read_mesh(me, me.name, {}, b"given")[1] == b"given"
    handed.clear()
    small = _heptagon_mesh()
    mesh, fp = meshes.read_mesh(small, small.name, {})
    assert handed in ([(meshes.fingerprint_digest, False), (np.copy, False)],
                      [(meshes.fingerprint_digest, False)])  # (here; positions maybe ours)
    assert fp == meshes.mesh_fingerprint(small)
