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
    area test is not run again), in a dict of its own (the first scene's packing is not
    referenced); dropped degenerate triangles are still counted and reported by each
    scene."""
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
    calls = []
    monkeypatch.setattr(mesh_check, "proper_triangles",
                        lambda *a, **k: calls.append(1) or pytest.fail("checked again"))
    s2 = Scene()
    d2 = s2.meshes[s2.add_mesh(mesh)]
    dd2 = s2.meshes[s2.add_mesh(with_degenerate)]
    assert not calls and d2 is not d1 and dd2 is not dd
    assert d2["tris"] is t and d2["normals"] is vn and d2["verts"] is v
    assert not any(np.shares_memory(a, packed[k]) for a in (*d2.values(), *dd2.values())
                   if isinstance(a, np.ndarray) for k in packed
                   if isinstance(packed[k], np.ndarray))
    for s in (s1, s2):
        assert s.stats["degenerate_triangles"] == 1
        assert any("'d': dropped 1 degenerate" in w for w in s.warnings)
    again = s2._pack_meshes()
    assert all(np.array_equal(packed[k], again[k]) for k in ("verts", "tris", "normals"))


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
