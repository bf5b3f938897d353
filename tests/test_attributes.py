"""Corner normals, uvs and material slots held per mesh only as finely as they vary
(:mod:`rstrace_engine.geometry.attributes`, :mod:`rstrace_engine.geometry.packing`): the
mode each kind of mesh gets, every corner read back bit for bit, and the bytes saved; the
interpolants' query scene reading the packed vertices."""

from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit

from rstrace_engine.bench import scale
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.attributes import (
    ATTR_CORNER,
    ATTR_FACE,
    ATTR_NONE,
    ATTR_VERTEX,
    corner_normals,
    corner_uvs,
    mesh_corners,
    scene_corners,
    slot_of,
)
from rstrace_engine.geometry.edits import _as_mesh
from rstrace_engine.geometry.mesh_math import flat_triangle_normals, vertex_normals
from rstrace_engine.geometry.mesh_topology import mesh_topology
from rstrace_engine.geometry.packing import mesh_slots, mesh_triangles
from rstrace_engine.geometry.scene import Material, Mesh, Scene
from rstrace_engine.interpolants.shafts import query_scene, tvx


def _sphere():
    return shapes.lumpy_sphere(600, name="s")


def _given(kind: str, mesh: Mesh, rng) -> dict:
    """Corner normals / uvs / slots of ``mesh`` varying as ``kind`` says."""
    v, t = mesh.vertices, mesh.triangles
    m = len(t)
    if kind == "vertex":
        vn = vertex_normals(v, t).astype(np.float32)
        uv = rng.random((len(v), 2)).astype(np.float32)
        return dict(corner_normals=vn[t], corner_uvs=uv[t], slots=np.full(m, 1, np.int32))
    if kind == "flat":
        n = np.zeros((m, 3, 3), np.float32)
        flat_triangle_normals(v, t, n)
        return dict(corner_normals=n, corner_uvs=np.zeros((m, 3, 2), np.float32))
    if kind == "face":
        n = rng.normal(size=(m, 1, 3)).astype(np.float32).repeat(3, axis=1)
        uv = rng.random((m, 1, 2)).astype(np.float32).repeat(3, axis=1)
        return dict(corner_normals=n, corner_uvs=uv, slots=np.arange(m, dtype=np.int32) % 3)
    n = rng.normal(size=(m, 3, 3)).astype(np.float32)
    n[0, 0] = (-0.0, 0.0, -0.0)  # signed zeros are kept apart
    n[0, 1] = (0.0, 0.0, 0.0)
    return dict(corner_normals=n, corner_uvs=rng.random((m, 3, 2)).astype(np.float32),
                slots=(np.arange(m, dtype=np.int32) // 7) % 2)


_MODES = {"vertex": (ATTR_VERTEX, ATTR_VERTEX, 1), "flat": (ATTR_NONE, ATTR_NONE, 0),
          "face": (ATTR_FACE, ATTR_FACE, -1), "corner": (ATTR_CORNER, ATTR_CORNER, -1)}


def _scene():
    """Meshes given in every mode, a tombstoned mesh slot between them, and the engine's
    own smooth and flat meshes; returns the scene and ``{mesh id: given arrays}``."""
    rng = np.random.default_rng(3)
    s = Scene()
    s.add_material(Material("a"))
    given = {}
    gone = s.add_mesh(shapes.icosphere(1, name="gone"))
    for kind in _MODES:
        base = _sphere()
        g = _given(kind, base, rng)
        given[s.add_mesh(dataclasses.replace(base, name=kind, **g), key=kind)] = g
    for smooth in (True, False):
        s.add_mesh(dataclasses.replace(_sphere(), name=f"own{smooth}", smooth=smooth),
                   key=f"own{smooth}")
    s.delete_mesh(gone)
    for k, m in enumerate(s.meshes):
        if m is not None:
            s.add_instance(k, np.eye(4), [0, 0, 0])
    return s, given


@njit(cache=True)
def _read_back(sa, meshes, tris, normals, uvs, slots):
    for q in range(len(tris)):
        n = corner_normals(sa, meshes[q], tris[q])
        c = corner_uvs(sa, meshes[q], tris[q])
        for j in range(3):
            for a in range(3):
                normals[q, j, a] = n[3 * j + a]
            for a in range(2):
                uvs[q, j, a] = c[2 * j + a]
        slots[q] = slot_of(sa, meshes[q], tris[q])


def _bits(a):
    return np.ascontiguousarray(a).view(np.uint64 if a.dtype == np.float64 else np.uint32)


def test_each_mesh_gets_the_coarsest_exact_mode():
    s, given = _scene()
    for kind, (nmode, uvmode, slot) in _MODES.items():
        m = s.meshes[s.mesh_id(kind)]
        assert (m["nmode"], m["uvmode"]) == (nmode, uvmode), kind
        assert m["slot"] == slot if slot >= 0 else m["slot"] == -1, kind
    own_smooth, own_flat = (s.meshes[s.mesh_id(k)] for k in ("ownTrue", "ownFalse"))
    assert own_smooth["nmode"] == ATTR_VERTEX and own_flat["nmode"] == ATTR_NONE
    assert own_smooth["uvmode"] == ATTR_NONE and own_smooth["slot"] == 0
    sa = s.arrays()
    # a vertex-mode mesh holds one normal row per vertex, a flat one none, no uvs none
    vertex = s.meshes[s.mesh_id("vertex")]
    assert vertex["normals"].shape == (len(vertex["verts"]), 3)
    assert len(own_flat["normals"]) == 0 and len(own_smooth["uvs"]) == 0
    assert len(sa.normals) < 3 * len(sa.tris)


def test_every_corner_reads_back_bit_for_bit():
    """The kernels' corner normals, uvs and slots are the float32 values given (as float64),
    bit for bit, in every mode; the engine's own flat normals are the numpy formula's."""
    s, given = _scene()
    sa = s.arrays()
    t = len(sa.tris)
    meshes = np.repeat(np.arange(len(s.meshes)), np.diff(sa.mesh_tri_start))
    normals, uvs = np.empty((t, 3, 3)), np.empty((t, 3, 2))
    slots = np.empty(t, np.int64)
    _read_back(sa, meshes, np.arange(t), normals, uvs, slots)
    for k, m in enumerate(s.meshes):
        if m is None:
            continue
        t0, t1 = sa.mesh_tri_start[k], sa.mesh_tri_start[k + 1]
        g = given.get(k)
        if g is None:  # the engine's own: the packing before held these
            v, tr = m["verts"], mesh_triangles(m)
            if m["nmode"] == ATTR_NONE:
                fn = np.cross(v[tr][:, 1] - v[tr][:, 0], v[tr][:, 2] - v[tr][:, 0])
                fn /= np.linalg.norm(fn, axis=1, keepdims=True)
                want_n = np.repeat(fn[:, None, :], 3, axis=1).astype(np.float32)
            else:
                want_n = vertex_normals(v, tr)[tr].astype(np.float32)
            g = dict(corner_normals=want_n, corner_uvs=np.zeros((t1 - t0, 3, 2), np.float32))
        assert np.array_equal(_bits(normals[t0:t1]),
                              _bits(g["corner_normals"].astype(np.float64))), m["name"]
        assert np.array_equal(_bits(uvs[t0:t1]),
                              _bits(g["corner_uvs"].astype(np.float64))), m["name"]
        want_slots = g.get("slots", np.zeros(t1 - t0, np.int32))
        assert np.array_equal(slots[t0:t1], want_slots), m["name"]
        # the host side gives the same arrays back
        assert np.array_equal(_bits(mesh_corners(m, "normals")), _bits(g["corner_normals"]))
        assert np.array_equal(mesh_slots(m), want_slots)
    assert np.array_equal(_bits(scene_corners(sa, "normals").astype(np.float64)),
                          _bits(normals))
    assert np.array_equal(_bits(scene_corners(sa, "uvs").astype(np.float64)), _bits(uvs))


def test_a_mesh_survives_repacking_and_the_round_trip_through_a_mesh():
    """Repacking after another mesh is added moves each mesh's rows (its triangles stay
    its own less its first vertex); a Mesh made back from a mesh dict (an edit's copy)
    validates to the same mode and rows."""
    s, _ = _scene()
    s.arrays()
    m = s.meshes[s.mesh_id("corner")]
    before = {k: np.array(m[k]) for k in ("normals", "uvs", "slots")}
    tris = mesh_triangles(m).copy()
    s.add_mesh(shapes.icosphere(2, name="late"))
    s.arrays()
    assert np.array_equal(mesh_triangles(m), tris)
    for k, v in before.items():
        assert np.array_equal(m[k], v)
    again = Scene()
    back = again.meshes[again.add_mesh(_as_mesh(m))]
    for k in ("normals", "nmode", "uvs", "uvmode", "slots", "slot"):
        assert np.array_equal(back[k], m[k]), k
    assert np.array_equal(mesh_triangles(back), tris)


def test_bytes_per_triangle_of_a_smooth_mesh():
    """``bench scale``'s dense scene: the packed arrays hold the vertices, triangles and
    one normal row per vertex (no uvs, no slot rows), and the model holds nothing of its
    own: 88 bytes a triangle packed and 12 in the model before."""
    s = scale.big_scene(20_000)
    sa = s.arrays()
    from rstrace_engine.accel.accelerators import create_accelerator
    mem = scale.memory(s, sa, create_accelerator("BVH", sa))
    assert mem["packed"] < 31.0  # verts 12 + tris 12 + normals ~6 + per-mesh rows
    assert mem["total"] < mem["packed"] + mem["bvh"] + 0.2  # the model's arrays are views


@njit(cache=True)
def _leaf_coords(qs, out):
    for t in range(out.shape[0]):
        for k in range(9):
            out[t, k] = tvx(qs, t, k)


def test_query_scene_reads_the_packed_vertices():
    """The interpolants' query scene holds its leaf triangles as vertex indices into the
    packing's vertices (12 bytes a triangle, where a float64 copy took 72): every leaf
    triangle's coordinates are its global triangle's, bit for bit."""
    s, _ = _scene()
    sa = s.arrays()
    qs = query_scene(sa, mesh_topology(sa))
    assert qs.verts is sa.verts and not hasattr(qs, "tv")
    assert qs.tvi.dtype == np.int32 and qs.tvi.shape == (len(sa.tris), 3)
    got = np.empty((len(qs.tri), 9))
    _leaf_coords(qs, got)
    want = sa.verts[sa.tris[qs.tri]].reshape(-1, 9)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64))


def test_uv_modes_at_the_edges_of_their_shortcuts():
    """:func:`~.attributes.compact_uvs`' shortcuts give the exact mode: uvs that are zero
    but for one bit past the first words looked at are not NONE (the rest is looked at),
    all-zero uvs are, and a VERTEX answer's rows of vertices no corner names are zero
    (they are written at the end, not zero-filled first), whatever memory held before."""
    from rstrace_engine.geometry.attributes import HEAD_WORDS, compact_uvs

    m = HEAD_WORDS  # (m, 3, 2) float32: 6 words a triangle, past the head from m // 6
    tris = np.arange(3 * m, dtype=np.int32).reshape(m, 3)
    uvs = np.zeros((m, 3, 2), np.float32)
    assert compact_uvs(tris, 3 * m, uvs)[0] == ATTR_NONE
    uvs[-1, 2, 1] = -0.0  # (the sign bit alone, in the last word)
    mode, rows = compact_uvs(tris, 3 * m, uvs)
    assert mode == ATTR_VERTEX and np.array_equal(_bits(rows), _bits(uvs.reshape(-1, 2)))
    # vertices 0 and the odd ones past the triangles' name nothing: zero rows, though
    # the memory the kernel took may have held other bits (dirty it first)
    for _ in range(3):
        junk = np.full((4 * m, 2), 7.5, np.float32)
        compact_uvs(np.arange(3, 3 * m + 3, dtype=np.int32).reshape(m, 3), 3 * m + 3,
                    junk[:3 * m].reshape(m, 3, 2))
        del junk
        few = np.arange(3, 9, dtype=np.int32).reshape(2, 3) * 2
        vals = np.arange(1, 13, dtype=np.float32).reshape(2, 3, 2)
        mode, rows = compact_uvs(few, 40, vals)
        assert mode == ATTR_VERTEX and rows.shape == (40, 2)
        named = few.reshape(-1)
        assert np.array_equal(rows[named], vals.reshape(-1, 2))
        assert not np.any(_bits(np.delete(rows, named, axis=0)))
