"""The interpolants' mesh convexity test (``mesh_topology.is_convex``) over a box tree of
the vertices gives the brute-force answer (every vertex against every triangle's plane),
at the tolerance's edge too: a box is skipped only when the plane's bound leaves it
behind past its rounding."""

import numpy as np
import pytest

from rstrace_engine import tolerances as tol
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.mesh_topology import is_convex, vertex_boxes


def _brute(verts, tris, tol_abs) -> bool:
    """The test before the box tree: any vertex more than ``tol_abs`` in front of any
    triangle's plane (unit normal by the winding) -> not convex."""
    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1)
    ok = ln > 0.0
    a, n, ln = a[ok], n[ok], ln[ok]
    for t in range(len(a)):
        s = ((verts[:, 0] - a[t, 0]) * n[t, 0] + (verts[:, 1] - a[t, 1]) * n[t, 1]
             + (verts[:, 2] - a[t, 2]) * n[t, 2]) / ln[t]
        if np.any(s > tol_abs):
            return False
    return True


def _tol(verts) -> float:
    return tol.CONVEX_TOL_REL * float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))


def _pushed(mesh, vertex: int, by: float):
    """``mesh``'s vertices with one moved ``by`` along its direction from the centre."""
    v = np.array(mesh.vertices, np.float64)
    c = v.mean(axis=0)
    d = v[vertex] - c
    v[vertex] += by * d / np.linalg.norm(d)
    return v


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1e3, -2e3, 5e2)])
def test_box_tree_gives_the_brute_force_answer(offset):
    ico = shapes.icosphere(3)
    tris = np.asarray(ico.triangles, np.int64)
    v0 = np.asarray(ico.vertices, np.float64)
    cases = [(v0, tris), (np.asarray(shapes.box((1.0, 2.0, 0.5)).vertices, np.float64),
                          np.asarray(shapes.box((1.0, 2.0, 0.5)).triangles, np.int64))]
    tor = shapes.torus(1.0, 0.35, 24, 12)
    cases.append((np.asarray(tor.vertices, np.float64), np.asarray(tor.triangles, np.int64)))
    # one vertex pushed out or in: well past the sphere's curvature, and within it
    for k in (3, 100, 500):
        for by in (0.05, -0.05, 1e-3, -1e-3):
            cases.append((_pushed(ico, k, by), tris))
    # a flat grid (every vertex on every plane) with one vertex lifted or lowered: its
    # triangles' planes tilt, and the far vertices stand that height times the grid's
    # size over an edge (~35-70) in front of them; the smallest lifts stay within the
    # tolerance, the larger do not: the tolerance's edge
    grid = shapes.plane(2.0, divisions=24)
    gv = np.asarray(grid.vertices, np.float64)
    gt = np.asarray(grid.triangles, np.int64)
    g_tol = _tol(gv)
    for k in (0, 37, 300):
        for by in (0.005, 0.01, 0.02, 0.05, -0.005, -0.05, 2.0, -50.0):
            v = gv.copy()
            v[k, 2] += by * g_tol
            cases.append((v, gt))
    answers = []
    for verts, tr in cases:
        tol_abs = _tol(verts)
        verts = verts + np.asarray(offset)
        want = _brute(verts, tr, tol_abs)
        assert is_convex(verts, tr, tol_abs) == want
        answers.append(want)
    # both answers occur, at the tolerance's edge too
    edge = answers[-24:]
    assert edge.count(True) >= 3 and edge.count(False) >= 9
    assert answers.count(True) > 5 and answers.count(False) > 5


def test_box_tree_holds_every_vertex_once():
    v = np.random.default_rng(3).normal(size=(1001, 3))
    order, lo, hi, mag, first = vertex_boxes(v, 8)
    assert sorted(order.tolist()) == list(range(1001))
    assert len(first) >= 3 and first[-1] - first[-2] <= 8
    leaves = np.concatenate([order, np.repeat(order[-1:], (-1001) % 8)]).reshape(-1, 8)
    assert np.all(lo[:first[1]] <= v[leaves].min(axis=1))
    assert np.all(hi[:first[1]] >= v[leaves].max(axis=1))
    assert np.array_equal(mag, np.maximum(np.abs(lo), np.abs(hi)))
    # a parent's box holds its children's
    for lev in range(1, len(first) - 1):
        for j in range(first[lev], first[lev + 1]):
            c0 = first[lev - 1] + (j - first[lev]) * 8
            ch = slice(c0, min(c0 + 8, first[lev]))
            assert np.all(lo[j] <= lo[ch].min(axis=0)) and np.all(hi[j] >= hi[ch].max(axis=0))
