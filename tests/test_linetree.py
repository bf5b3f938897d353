"""Face-pair line parameterisation, linetrees and quadrilinear interpolation."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.frame import CLASS_FAIL_SHADOW
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Material, Scene
from rstrace_engine.interpolants.linetree import (
    EMPTY,
    LATTICE_DEPTH,
    Linetrees,
    corner_weights,
    descend,
    dominant_face,
    expanded_boxes,
    fail_class,
    fail_code,
    lattice_lines,
    line_points,
    local_coords,
    parameterize,
)


def _one_object_scene(mesh, matrix=None) -> Scene:
    s = Scene()
    m = s.add_material(Material("m"))
    s.add_instance(s.add_mesh(mesh), np.eye(4) if matrix is None else matrix, [m])
    return s


def _line(box, inst, face, abcd):
    F = np.empty(3)
    B = np.empty(3)
    line_points(box, inst, face, *abcd, F, B)
    return F, B


def _collinear(F, B, o, d):
    """Distance of points F and B from the line through o along d, relative to |B - F|."""
    u = d / np.linalg.norm(d)
    out = []
    for p in (F, B):
        w = p - o
        out.append(np.linalg.norm(w - u * (w @ u)))
    return max(out) / np.linalg.norm(B - F)


@pytest.fixture(scope="module")
def sphere_box():
    sc = _one_object_scene(shapes.icosphere(1), shapes.transform((3.0, -2.0, 1.0), 1.5))
    return sc.arrays(), expanded_boxes(sc.arrays())


def test_rays_through_the_object_cross_both_faces_and_round_trip(sphere_box):
    sa, box = sphere_box
    rng = np.random.default_rng(1)
    n = 4000
    centre = np.array([3.0, -2.0, 1.0])
    target = centre + rng.uniform(-1.4, 1.4, (n, 3))
    d = rng.normal(size=(n, 3))
    o = target - d * rng.uniform(2.0, 50.0, (n, 1))
    face = np.empty(n, np.int8)
    abcd = np.empty((n, 4))
    inst = np.zeros(n, np.int32)
    parameterize(box, inst, o, d, face, abcd)
    assert np.all((abcd >= 0) & (abcd <= 1))
    k = face // 2
    assert np.all(np.abs(d[np.arange(n), k]) >= np.abs(d).max(axis=1))
    worst = max(_collinear(*_line(box, 0, face[r], abcd[r]), o[r], d[r]) for r in range(n))
    assert worst < 1e-9
    # the line reaches the front face first: the direction agrees with the ray's
    for r in range(0, n, 97):
        F, B = _line(box, 0, face[r], abcd[r])
        assert (B - F) @ d[r] > 0


def test_zero_thickness_objects_get_a_padded_box():
    sc = _one_object_scene(shapes.plane(4.0))  # z-extent exactly 0
    sa = sc.arrays()
    box = expanded_boxes(sa)
    thick = box[0, 1, 2] - box[0, 0, 2]
    assert thick > 0 and thick < 1e-2 * sa.scene_extent
    # a ray straight down onto the plane, and one grazing it
    o = np.array([[0.3, -0.2, 5.0], [-10.0, 0.5, 1e-3]])
    d = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -1e-4]])
    face = np.empty(2, np.int8)
    abcd = np.empty((2, 4))
    parameterize(box, np.zeros(2, np.int32), o, d, face, abcd)
    assert np.all(np.isfinite(abcd)) and list(face) == [5, 0]
    for r in range(2):
        assert _collinear(*_line(box, 0, face[r], abcd[r]), o[r], d[r]) < 1e-9


def test_face_pair_ties_and_boundaries(sphere_box):
    sa, box = sphere_box
    assert dominant_face(1.0, 1.0, 0.5) == 0  # ties go to the lower axis
    assert dominant_face(-1.0, 1.0, 1.0) == 1
    assert dominant_face(0.0, -2.0, 2.0) == 3
    assert dominant_face(0.0, 0.0, -1.0) == 5
    # rays with |dx| == |dy| (== |dz|) exactly: the chosen pair parameterises them, and so
    # does the other pair of the tie (both faces are sized for such lines)
    centre = np.array([3.0, -2.0, 1.0])
    dirs = np.array([[1.0, 1.0, 0.3], [1.0, -1.0, 1.0], [-1.0, -1.0, -1.0], [0.5, 0.2, -0.5]])
    for d in dirs:
        o = centre - 7.0 * d
        face = np.empty(1, np.int8)
        abcd = np.empty((1, 4))
        parameterize(box, np.zeros(1, np.int32), o[None], d[None], face, abcd)
        assert _collinear(*_line(box, 0, face[0], abcd[0]), o, d) < 1e-9
        for f in range(6):
            k = f // 2
            if abs(d[k]) == np.abs(d).max() and (d[k] > 0) == (f % 2 == 0):
                # parameterise with the other tied face by hand
                F, B = _line(box, 0, f, [0.5] * 4)
                front, back = F[k], B[k]
                tf, tb = (front - o[k]) / d[k], (back - o[k]) / d[k]
                pf, pb = o + tf * d, o + tb * d
                i, j = (k + 1) % 3, (k + 2) % 3
                lo = box[0, 0] - (box[0, 1, k] - box[0, 0, k])
                w = box[0, 1] - box[0, 0] + 2 * (box[0, 1, k] - box[0, 0, k])
                abcd2 = [(pf[i] - lo[i]) / w[i], (pf[j] - lo[j]) / w[j], (pb[i] - lo[i]) / w[i],
                         (pb[j] - lo[j]) / w[j]]
                assert all(-1e-12 <= x <= 1 + 1e-12 for x in abcd2)


def test_quadrilinear_reproduces_multilinear_radiance():
    rng = np.random.default_rng(7)
    coef = rng.normal(size=(16, 3))  # f(u) = sum over subsets S of c_S prod_{m in S} u_m
    bits = (np.arange(16)[:, None] >> np.arange(4)[None, :]) & 1

    def f(u):
        mono = np.prod(np.where(bits[None] == 1, u[:, None, :], 1.0), axis=2)
        return mono @ coef

    corners = f(bits.astype(float))  # radiance at the 16 corner lines
    u = rng.random((500, 4))
    np.testing.assert_allclose(corner_weights(u) @ corners, f(u), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(corner_weights(bits.astype(float)), np.eye(16), atol=0)
    assert np.allclose(corner_weights(u).sum(axis=1), 1.0)


def test_descend_cell_boundaries_and_local_coordinates():
    lt = Linetrees(1)
    root = lt.get_roots(np.array([0]), np.array([2]))[0]
    lt.split(np.array([root]))
    first = lt.arrays.child[root]
    lt.split(np.array([first + 0b1010]))  # child with b and d in the upper half
    abcd = np.array([[0.5, 0.5, 0.5, 0.5],  # exactly on the mid boundary: upper cell
                     [0.0, 0.0, 0.0, 0.0],
                     [1.0, 1.0, 1.0, 1.0],  # the last cell keeps 1.0
                     [0.25, 0.75, 0.25, 0.75],  # boundary inside the deeper cell
                     [0.49999999, 0.5, 0.1, 0.5]])
    out = np.empty(len(abcd), np.int32)
    lt.arrays.leaf[first + 0b1010] = fail_code(CLASS_FAIL_SHADOW)  # split after failing
    inherited = np.full(len(abcd), EMPTY, np.int32)
    descend(lt.arrays, np.full(len(abcd), root, np.int32), abcd, out, inherited)
    assert list(inherited) == [EMPTY, EMPTY, EMPTY] + [fail_code(CLASS_FAIL_SHADOW)] * 2
    a = lt.arrays
    for r in range(len(abcd)):
        nd = out[r]
        assert a.child[nd] == -1 and a.tree[nd] == 2
        lo = a.coord[nd] / 2.0 ** a.depth[nd]
        hi = (a.coord[nd] + 1) / 2.0 ** a.depth[nd]
        assert np.all(lo <= abcd[r]) and np.all(abcd[r] <= hi)
        u = np.empty(4)
        local_coords(int(a.depth[nd]), a.coord[nd], abcd[r], u)
        assert np.all((u >= 0) & (u <= 1))
        np.testing.assert_allclose(lo + u * (hi - lo), abcd[r], atol=1e-15)
    assert out[0] == first + 15 and out[1] == first and out[2] == first + 15
    assert a.depth[out[3]] == 2 and list(a.coord[out[3]]) == [1, 3, 1, 3]
    assert a.depth[out[4]] == 2 and list(a.coord[out[4]]) == [1, 2, 0, 2]


def test_split_collapse_recycles_blocks_and_restores_fail_states():
    lt = Linetrees(3, capacity=16)
    roots = lt.get_roots(np.array([0, 2, 2, 0]), np.array([1, 5, 5, 1]))
    assert roots[0] == roots[3] and roots[1] == roots[2] and roots[0] != roots[1]
    a = lt.arrays
    a.leaf[roots[0]] = fail_code(CLASS_FAIL_SHADOW)
    assert fail_class(a.leaf[roots[0]]) == CLASS_FAIL_SHADOW and fail_code(0) < EMPTY
    lt.split(np.unique(roots))
    a = lt.arrays
    kids = a.child[roots[0]]
    lt.split(np.array([kids + 3]))
    nodes_before = lt.n_nodes
    assert lt.live_nodes == 2 + 3 * 16
    with pytest.raises(ValueError):
        lt.split(np.array([roots[0]]))  # not a leaf
    assert lt.collapse() == 3  # the grandchildren block, then both root blocks
    a = lt.arrays
    assert a.child[roots[0]] == -1 and fail_class(a.leaf[roots[0]]) == CLASS_FAIL_SHADOW
    assert a.leaf[roots[1]] == EMPTY and lt.live_nodes == 2
    lt.split(np.array([roots[1]]))
    assert lt.n_nodes == nodes_before  # a freed block was reused
    a = lt.arrays
    a.leaf[a.child[roots[1]] + 5] = 0  # an interpolant keeps its block alive
    assert lt.collapse() == 0


def test_lattice_lines_match_cells():
    sc = scenes.three_spheres(16, 12, subdivisions=1)
    sa = sc.arrays()
    box = expanded_boxes(sa)
    n = 6
    inst = np.arange(n, dtype=np.int32) % len(sa.inst_mesh)
    face = (np.arange(n) % 6).astype(np.int8)
    lat = np.random.default_rng(3).integers(0, 1 << LATTICE_DEPTH, (n, 4))
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    lattice_lines(box, inst, face, lat, o, d)
    for r in range(n):
        F, B = _line(box, inst[r], face[r], lat[r] / 2.0 ** LATTICE_DEPTH)
        np.testing.assert_allclose(o[r], F)
        np.testing.assert_allclose(o[r] + d[r], B)
