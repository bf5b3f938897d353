"""The first render's serial work outside the BVH builds, on two threads where it is
independent (``rstrace_engine.beside``; docs/bench-scale-bpy.md, session 38): a large
mesh's checks, the packing's copies. Each gives what one thread gives, bit for bit, and
the first error one thread raised. Main ran them on one thread: no ``BESIDE_TRIANGLES`` /
``BESIDE_ROWS``."""

from __future__ import annotations

import re

import numba
import numpy as np
import pytest

from rstrace_engine import beside
from rstrace_engine.cancel import Cancelled
from rstrace_engine.geometry import mesh_check, mesh_math, packing, shapes
from rstrace_engine.geometry.scene import Mesh, Scene, SceneError


@pytest.fixture
def handed(monkeypatch):
    """The functions handed to ``Beside`` and whether they went to the pool thread."""
    seen: list = []

    class Recorded(beside.Beside):
        def __init__(self, fn, *args, when=True):
            super().__init__(fn, *args, when=when)
            seen.append((getattr(fn, "__name__", fn), self.started))

    class Shared(beside.Shared):
        def __init__(self, fn, *args, when=True):
            super().__init__(fn, *args, when=when)
            seen.append((getattr(fn, "__name__", fn), self.started))

    for module in (mesh_check, packing):
        monkeypatch.setattr(module, "Beside", Recorded)
    monkeypatch.setattr(mesh_math, "Shared", Shared)
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    if numba.get_num_threads() < 2:
        pytest.skip("one thread only here")
    yield seen
    numba.set_num_threads(before)


def _one_thread(fn, *args):
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return fn(*args)
    finally:
        numba.set_num_threads(before)


def _large(smooth: bool, degenerate: bool = False, owned: bool = True) -> Mesh:
    base = shapes.lumpy_sphere(2 * mesh_check.BESIDE_TRIANGLES, name="big")
    v = np.asarray(base.vertices, np.float32)
    t = np.asarray(base.triangles, np.int32).copy()
    if degenerate:
        t[::1000, 2] = t[::1000, 0]
    uv = np.random.default_rng(3).random((len(v), 2)).astype(np.float32)[t]
    uv[::7, 1] += 0.5  # (seams: CORNER rows)
    return Mesh("big", v, t, corner_uvs=uv, slots=np.arange(len(t), dtype=np.int32) % 3,
                smooth=smooth, owned=owned)


def _same_dict(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], np.ndarray):
            assert a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes(), k
        elif k != "source":
            assert a[k] == b[k], k


@pytest.mark.parametrize("smooth,degenerate", [(False, False), (True, False), (True, True)])
def test_a_large_meshs_checks_run_beside_and_give_the_one_thread_dict(handed, smooth,
                                                                      degenerate):
    """The vertices' pass beside the triangles', the area test's chunks taken by the pool
    thread while this one checks the attributes and computes their modes (again on the
    kept triangles where some are dropped), then by both (``beside.Shared``)."""
    counts: list = []
    got = mesh_check.checked_mesh(_large(smooth, degenerate), dropped_fn=counts.append)
    assert handed == [("_vertices", True), ("proper_chunk", True)]
    want = _one_thread(mesh_check.checked_mesh, _large(smooth, degenerate))
    _same_dict(got, want)
    assert counts == ([len(_large(smooth).triangles[::1000])] if degenerate else [])
    handed.clear()
    small = shapes.lumpy_sphere(500, name="small")
    mesh_check.checked_mesh(Mesh("small", np.asarray(small.vertices), small.triangles))
    assert handed == [("proper_chunk", False)]  # (run here)


def test_a_large_meshs_first_error_is_the_one_thread_ones(handed):
    """Where several checks fail, the one that ran first on one thread is raised: a NaN
    vertex before a triangle index out of range, that before a bad uv, a bad uv before
    the area test's verdict; a cancel during the area test still raises ``Cancelled``."""
    mesh = _large(False)
    v, t, uv = mesh.vertices.copy(), mesh.triangles.copy(), mesh.corner_uvs.copy()
    v[5, 1] = np.nan
    t[9, 0] = len(v)
    uv[4, 0, 0] = np.inf
    flat = v.copy()
    flat[:, 2] = 0.0
    flat[:, 1] = 0.0  # (every triangle degenerate)
    ok_v = mesh.vertices

    def add(**kw):
        given = dict(vertices=ok_v, triangles=mesh.triangles, corner_uvs=mesh.corner_uvs)
        given.update(kw)
        Scene().add_mesh(Mesh("big", owned=True, **given))

    for kw, message in ((dict(vertices=v, triangles=t, corner_uvs=uv), "1 NaN or infinite"),
                        (dict(triangles=t, corner_uvs=uv), "triangle index out of range"),
                        (dict(vertices=np.nan_to_num(flat), corner_uvs=uv),
                         "mesh uvs 'big': 1 NaN or infinite"),
                        (dict(vertices=np.nan_to_num(flat)), "are degenerate (zero area)")):
        with pytest.raises(SceneError, match=re.escape(message)):
            add(**kw)
    with pytest.raises(Cancelled):
        Scene().add_mesh(_large(False), cancel=lambda: True)


def test_the_packing_writes_a_large_meshs_rows_in_halves(handed):
    """The float64 vertices (and the triangles, normals and uvs where copied) in two
    halves, one beside: the same packing as one thread."""
    def packed():
        s = Scene()
        s.add_mesh(_large(True, owned=False))
        s.add_mesh(shapes.icosphere(2, name="small"))
        return s._pack_meshes()

    got = packed()
    assert ("rows", True) in handed  # (the small mesh's: here, no hand-off)
    want = _one_thread(packed)
    for k in want:
        assert got[k].dtype == want[k].dtype and got[k].tobytes() == want[k].tobytes(), k
