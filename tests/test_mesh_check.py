"""A mesh's validation (:mod:`rstrace_engine.geometry.mesh_check`): per-vertex normals handed
over as they are (Blender's POINT normals domain), arrays an ``owned`` mesh hands over kept
without a copy, its validation kept with it for a second scene, and bad input still named."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from rstrace_engine.geometry import mesh_check, shapes
from rstrace_engine.geometry.attributes import ATTR_NONE, ATTR_VERTEX, mesh_corners
from rstrace_engine.geometry.mesh_math import vertex_normals
from rstrace_engine.geometry.scene import Mesh, Scene, SceneError


def _exported(mesh: Mesh, **kw) -> Mesh:
    """``mesh`` as the add-on hands a smooth mesh over: float32 vertices, float32 vertex
    normals, corner uvs and slots."""
    v = np.asarray(mesh.vertices, np.float32)
    t = np.asarray(mesh.triangles, np.int32)
    vn = vertex_normals(v.astype(np.float64), t).astype(np.float32)
    uv = (np.random.default_rng(3).random((len(v), 2)).astype(np.float32))[t]
    return dataclasses.replace(mesh, vertices=v, triangles=t, vertex_normals=vn,
                               corner_normals=None, corner_uvs=uv,
                               slots=np.zeros(len(t), np.int32), **kw)


def _dict(mesh: Mesh) -> dict:
    s = Scene()
    return s.meshes[s.add_mesh(mesh)]


@pytest.mark.parametrize("shape", ["lumpy", "plane"])
def test_vertex_normals_give_what_their_corners_give(shape):
    """Per-vertex normals are stored as the corners ``vertex_normals[triangles]`` would be:
    the same mode (VERTEX for a curved mesh, NONE for a flat plane whose vertex normals
    are its triangles' own) and every corner the same bits."""
    base = (shapes.lumpy_sphere(800, name="m") if shape == "lumpy"
            else shapes.plane(2.0, divisions=3, name="m"))
    given = _exported(base)
    corners = dataclasses.replace(given, vertex_normals=None,
                                  corner_normals=given.vertex_normals[given.triangles])
    a, b = _dict(given), _dict(corners)
    assert a["nmode"] == b["nmode"] == (ATTR_VERTEX if shape == "lumpy" else ATTR_NONE)
    na, nb = mesh_corners(a, "normals"), mesh_corners(b, "normals")
    assert np.array_equal(na.view(np.uint32), nb.view(np.uint32))
    assert np.array_equal(na, given.vertex_normals[given.triangles])


def test_an_owned_mesh_is_kept_without_copies_and_checked_once(monkeypatch):
    """``owned=True``: the arrays of the stored dtype are the scene's own (no copy), and a
    second scene adding the same Mesh object takes its checked arrays without a check (the
    area test is not run again), in a dict of its own; dropped degenerate triangles are
    still counted and reported by each scene. The packing hands its rows back to the Mesh
    where they are the Mesh's own values (the first mesh's triangles, its vertex normals:
    the process then holds them once); a mesh whose triangles were dropped keeps its own
    (the packing's are fewer), and the second scene's dict references no other part of
    the first packing."""
    base = shapes.lumpy_sphere(800, name="m")
    v = np.asarray(base.vertices, np.float64)
    t = np.asarray(base.triangles, np.int32)
    vn = vertex_normals(v, t).astype(np.float32)
    mesh = Mesh("m", v, t, vertex_normals=vn, owned=True)
    with_degenerate = Mesh("d", v, np.concatenate([t, [[0, 0, 1]]]).astype(np.int32),
                           owned=True)
    s1 = Scene()
    d1 = s1.meshes[s1.add_mesh(mesh)]
    assert d1["verts"] is v and d1["tris"] is t and d1["normals"] is vn
    dd = s1.meshes[s1.add_mesh(with_degenerate)]
    packed = s1._pack_meshes()  # (the dicts' arrays are now views of the packing)
    # (handed back: the same values, the packing's memory; the degenerate one's are its own)
    assert mesh.triangles.base is packed["tris"] and np.array_equal(mesh.triangles, t)
    assert mesh.vertex_normals.base is packed["normals"]
    assert np.array_equal(mesh.vertex_normals, vn) and mesh.vertices is v
    assert with_degenerate.triangles.base is None
    calls = []
    monkeypatch.setattr(mesh_check, "start_proper_triangles",
                        lambda *a, **k: calls.append(1) or pytest.fail("checked again"))
    s2 = Scene()
    d2 = s2.meshes[s2.add_mesh(mesh)]
    dd2 = s2.meshes[s2.add_mesh(with_degenerate)]
    assert not calls and d2 is not d1 and dd2 is not dd
    assert d2["tris"] is mesh.triangles and d2["normals"] is mesh.vertex_normals
    assert d2["verts"] is v
    assert not any(np.shares_memory(a, packed[k]) for a in dd2.values()
                   if isinstance(a, np.ndarray) for k in packed
                   if isinstance(packed[k], np.ndarray))
    for s in (s1, s2):
        assert s.stats["degenerate_triangles"] == 1
        assert any("'d': dropped 1 degenerate" in w for w in s.warnings)
    again = s2._pack_meshes()
    assert all(np.array_equal(packed[k], again[k]) for k in ("verts", "tris", "normals"))


def test_owned_float32_vertices_are_converted_once_by_the_packing():
    """An owned mesh of float32 vertices (the add-on's) keeps them as they are in its dict
    until the packing, which converts them into its own float64 array (exactly: the values
    of a float64 copy, bit for bit); the check's float64 copy is not kept beside it, and a
    second scene taking the kept check converts nothing. The scene's box, the packing's
    other fields and a mesh given as float64 are as before."""
    given = _exported(shapes.lumpy_sphere(800, name="m"))
    v32 = given.vertices
    as64 = dataclasses.replace(given, vertices=v32.astype(np.float64), owned=True)
    given = dataclasses.replace(given, owned=True)
    packs = []
    for scene in (Scene(), Scene()):  # (the second takes the kept check)
        d = scene.meshes[scene.add_mesh(given)]
        assert d["verts"] is v32
        packed = scene._pack_meshes()
        assert d["verts"].dtype == np.float64 and np.shares_memory(d["verts"],
                                                                    packed["verts"])
        packs.append(packed)
    s64 = Scene()
    d64 = s64.meshes[s64.add_mesh(as64)]
    assert d64["verts"] is as64.vertices
    ref = s64._pack_meshes()
    for packed in packs:
        assert packed["verts"].tobytes() == v32.astype(np.float64).tobytes()
        for k in ("verts", "tris", "normals", "uvs", "mesh_nrm", "mesh_uv", "mesh_gen"):
            assert packed[k].tobytes() == ref[k].tobytes(), k


def test_the_packing_hands_its_rows_back_to_the_owned_mesh():
    """Where an owned Mesh's corner uvs, corner normals and slot rows are kept as given
    (CORNER rows, per-triangle slots), the packing hands its copy back: the Mesh and its
    kept check then hold views of the packing, bit for bit the values they held (the
    Mesh's own arrays are let go: the process holds them once); its triangles too, the
    scene's largest mesh, whose vertices the packing lays first wherever its slot. A later
    scene packs the same bits again."""
    rng = np.random.default_rng(5)
    base = shapes.lumpy_sphere(800, name="m")
    v = np.asarray(base.vertices, np.float32)
    t = np.asarray(base.triangles, np.int32)
    m = len(t)
    uv = rng.random((m, 3, 2)).astype(np.float32)
    cn = rng.standard_normal((m, 3, 3)).astype(np.float32)
    slots = rng.integers(0, 3, m).astype(np.int32)
    given = {"corner_uvs": uv, "corner_normals": cn, "slots": slots}
    small = Mesh("s", v[:3].copy(), np.array([[0, 1, 2]], np.int32), owned=True)
    for first in (True, False):
        mesh = Mesh("m", v, t.copy(), corner_normals=cn.copy(), corner_uvs=uv.copy(),
                    slots=slots.copy(), smooth=True, owned=True)
        own = {a: getattr(mesh, a) for a in ("triangles", *given)}
        scene = Scene()
        if not first:
            scene.add_mesh(small)
        d = scene.meshes[scene.add_mesh(mesh)]
        packed = scene._pack_meshes()
        for a, f in (("corner_uvs", "uvs"), ("corner_normals", "normals"),
                     ("slots", "tri_slot")):
            got = getattr(mesh, a)
            assert got.base is packed[f] and got.tobytes() == given[a].tobytes(), a
            assert got.shape == given[a].shape
        assert mesh.triangles.base is packed["tris"] and d["vert0"] == 0
        assert np.array_equal(mesh.triangles, t)
        kept = mesh._checked[0]
        assert not any(isinstance(x, np.ndarray) and x.ctypes.data == own[a].ctypes.data
                       for x in kept.values() for a in given)
        assert d["uvs"] is kept["uvs"] and d["normals"] is kept["normals"]
        again = Scene()
        if not first:
            again.add_mesh(small)
        again.add_mesh(mesh)
        repacked = again._pack_meshes()
        for k in ("verts", "tris", "normals", "uvs", "tri_slot", "mesh_nrm", "mesh_uv",
                  "mesh_slot"):
            assert repacked[k].tobytes() == packed[k].tobytes(), k
        assert mesh.corner_uvs.base is repacked["uvs"]


def test_a_mesh_not_owned_is_copied():
    """Without ``owned`` the scene copies what it keeps: the caller may change its arrays."""
    base = shapes.lumpy_sphere(800, name="m")
    v = np.array(base.vertices, np.float64)
    t = np.array(base.triangles, np.int32)
    vn = vertex_normals(v, t).astype(np.float32)
    d = _dict(Mesh("m", v, t, vertex_normals=vn))
    kept = [d["verts"].copy(), d["tris"].copy(), d["normals"].copy()]
    v += 1.0
    t[:] = 0
    vn[:] = 0.0
    assert all(np.array_equal(a, b) for a, b in zip(kept, [d["verts"], d["tris"],
                                                            d["normals"]], strict=True))


@pytest.mark.parametrize("owned", [False, True])
def test_bad_input_is_named(owned):
    base = shapes.lumpy_sphere(200, name="bad")
    v, t = np.asarray(base.vertices), np.asarray(base.triangles, np.int32)
    vn = vertex_normals(v, t).astype(np.float32)
    nan_v = v.copy()
    nan_v[3, 1] = np.nan
    nan_vn = vn.copy()
    nan_vn[[1, 5], 0] = np.inf
    out_of_range = t.copy()
    out_of_range[7, 2] = len(v)
    cases = [
        (dict(vertices=nan_v), "mesh 'bad': 1 NaN or infinite value"),
        (dict(vertices=v * 1e12), "vertex coordinates exceed"),
        (dict(triangles=out_of_range), "triangle index out of range"),
        (dict(vertex_normals=nan_vn), "mesh vertex normals 'bad': 2 NaN or infinite"),
        (dict(vertex_normals=vn[:-1]), f"{len(v) - 1} vertex normals for {len(v)} vertices"),
        (dict(vertex_normals=vn[:, :2]), "expected shape (n, 3)"),
        (dict(vertex_normals=vn, corner_normals=vn[t]), "not both"),
    ]
    for change, message in cases:
        mesh = Mesh("bad", owned=owned, **{"vertices": v, "triangles": t,
                                           "vertex_normals": vn, **change})
        with pytest.raises(SceneError, match=re.escape(message)):
            Scene().add_mesh(mesh)


def test_one_pass_checks_agree_with_numpy():
    """The checks' kernels: non-finite counts, the largest magnitude and the box of the
    vertices (the box numpy's min and max give, signed zeros included: a zero bound is
    theirs), the index range of the triangles, the non-finite float32 count."""
    rng = np.random.default_rng(5)
    v = rng.normal(size=(1000, 3)) * 7.0
    v[[4, 9], [0, 2]] = [np.inf, np.nan]
    bad, big, lo, hi = mesh_check._vertex_stats(v)
    finite = v[np.isfinite(v)]
    assert bad == 2 and big == np.abs(finite).max()
    good = np.delete(v, [4, 9], axis=0)
    np.testing.assert_array_equal(lo, good.min(axis=0))
    np.testing.assert_array_equal(hi, good.max(axis=0))
    for flat in (0.0, -0.0):  # a plane at zero: the box's zeros are numpy's, bit for bit
        w = good.copy()
        w[:, 2] = flat
        w[::2, 2] = -flat
        _, box_lo, box_hi = mesh_check._vertices("w", w, keep=True)
        want_lo, want_hi = w.min(axis=0), w.max(axis=0)
        assert box_lo.tobytes() == want_lo.tobytes() and box_hi.tobytes() == want_hi.tobytes()
        _, box_lo, box_hi = mesh_check._vertices("v", good, keep=True)
        assert box_lo.tobytes() == good.min(axis=0).tobytes()
        assert box_hi.tobytes() == good.max(axis=0).tobytes()
    t = rng.integers(-5, 900, size=3000).astype(np.int32)
    assert mesh_check._index_range(t) == (t.min(), t.max())
    f = rng.normal(size=500).astype(np.float32)
    f[[1, 2, 3]] = [np.nan, np.inf, -np.inf]
    assert mesh_check._non_finite32(f) == 3


def test_owned_float32_vertices_are_checked_without_a_float64_copy(monkeypatch):
    """The checks read an owned mesh's float32 vertices as they are (the add-on's: no
    float64 copy of a mesh's size, which cost 12 MB of fresh memory at 1M triangles), and
    answer what they answer on the float64 copy: the box, the limit, the degenerate
    triangles dropped."""
    from rstrace_engine.geometry import mesh_math

    rng = np.random.default_rng(11)
    v = (rng.normal(size=(500, 3)) * 3.0).astype(np.float32)
    t = rng.integers(0, 500, size=(2000, 3)).astype(np.int32)
    t[::7, 2] = t[::7, 0]  # degenerate ones
    v[5] = v[6]
    t[3] = [5, 6, 7]  # two coincident corners
    given = []
    real = mesh_check._vertex_stats
    monkeypatch.setattr(mesh_check, "_vertex_stats", lambda a: given.append(a) or real(a))
    proper = mesh_math.start_proper_triangles
    monkeypatch.setattr(mesh_check, "start_proper_triangles",
                        lambda a, *r, **k: given.append(a) or proper(a, *r, **k))
    d = mesh_check.checked_mesh(Mesh("m", v, t, smooth=False, owned=True))
    assert len(given) == 2 and all(a is v for a in given)
    v64 = v.astype(np.float64)
    ref = mesh_check.checked_mesh(Mesh("m", v64, t, smooth=False, owned=True))
    assert d["verts"] is v and d["tris"].tobytes() == ref["tris"].tobytes()
    assert d["lo"].dtype == np.float64 and d["lo"].tobytes() == ref["lo"].tobytes()
    assert d["hi"].tobytes() == ref["hi"].tobytes()
    for a, b in zip(real(v), real(v64), strict=True):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    # every triangle of a random mesh, tiny and huge coordinates too: the same answers
    w = (rng.normal(size=(300, 3)) * rng.choice([1e-30, 1e-3, 1.0, 1e6], size=(300, 1))
         ).astype(np.float32)
    u = rng.integers(0, 300, size=(5000, 3)).astype(np.int32)
    assert np.array_equal(proper(w, u).result(), proper(w.astype(np.float64), u).result())
    w[0, 0] = np.inf
    with pytest.raises(SceneError, match="NaN or infinite"):
        mesh_check.checked_mesh(Mesh("bad", w, u, owned=True))
