"""The numba two-level BVH: structure, watertightness on adversarial rays, updates."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine.accel import bvh, bvh_build, bvh_mesh
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Material, Mesh, Scene

BACKENDS = ("BVH", "BRUTE_FORCE")


def one_object_scene(mesh: Mesh, matrix=None) -> Scene:
    s = Scene()
    s.add_material(Material("m"))
    s.add_instance(s.add_mesh(mesh), np.eye(4) if matrix is None else matrix, [0])
    return s


def mesh_points(mesh: Mesh):
    """Adversarial targets on a mesh: every vertex, every edge midpoint, points at 1/3 along
    every edge, and the centroid of every triangle (object space, (k, 3) float64)."""
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.triangles)
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]),
                              axis=1), axis=0)
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    return np.concatenate([v, 0.5 * (a + b), a + (b - a) / 3.0, v[f].mean(axis=1)])


def sphere_points(n: int, radius: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    return radius * d / np.linalg.norm(d, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- structure


@pytest.mark.parametrize("mesh", [shapes.icosphere(3), shapes.torus(1.0, 0.3, 24, 12),
                                  shapes.box(), shapes.plane(2.0)], ids=lambda m: m.name)
def test_mesh_bvh_structure(mesh):
    tv = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.triangles)]
    mb = bvh_mesh.build_mesh_bvh(tv)
    b, child = mb.bvh.bounds, mb.bvh.child
    assert b.dtype == np.float32 and child.dtype == np.int32
    assert b.shape[1] == 24 and child.shape[1] == 4
    seen = np.zeros(len(tv), np.int64)
    # walk the tree: every triangle in exactly one leaf, inside every box on its path
    stack = [(0, [])]
    depth_max = 0
    while stack:
        node, path0 = stack.pop()
        for lane in range(4):
            box = b[node, lane::4]  # lo x, lo y, lo z, hi x, hi y, hi z
            c = int(child[node, lane])
            if box[0] > box[3]:  # an unused lane
                assert c == -1
                continue
            path = path0 + [box]
            depth_max = max(depth_max, len(path))
            if c >= 0:
                assert c > node  # depth-first numbering
                stack.append((c, path))
                continue
            start, count = (~c) >> 3, (~c) & 7
            assert 1 <= count <= bvh_build.MAX_LEAF
            for p in range(start, start + count):
                seen[p] += 1
                tri = tv[mb.tri[p]]
                for bx in path:
                    assert np.all(tri >= bx[:3]) and np.all(tri <= bx[3:])
    assert np.all(seen == 1)
    assert sorted(mb.tri.tolist()) == list(range(len(tv)))
    assert depth_max <= bvh.STACK_SIZE
    assert mb.sah_cost > 0


def test_build_degenerate_centroids_and_depth():
    # 200 copies of one triangle: no SAH split exists, the builder must still terminate
    tv = np.tile(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float64), (200, 1, 1))
    mb = bvh_mesh.build_mesh_bvh(tv)
    assert sorted(mb.tri.tolist()) == list(range(200))
    # a very skewed size distribution (geometric), which tends to give deep SAH trees
    k = np.arange(300, dtype=np.float64)
    s = 2.0 ** (-k / 4)
    tv = np.stack([np.stack([s, s, s], 1), np.stack([2 * s, s, s], 1),
                   np.stack([s, 2 * s, s], 1)], 1)
    mb = bvh_mesh.build_mesh_bvh(tv)
    assert sorted(mb.tri.tolist()) == list(range(300))


# ----------------------------------------------------------------------------- watertight


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("mesh,inradius,matrix", [
    (shapes.icosphere(2), 0.75, None),
    (shapes.box((1.0, 2.0, 0.5)), 0.25, None),
    (shapes.icosphere(1, 3.0), 2.2, shapes.transform((1e3, -2e3, 5.0), (0.5, 2.0, 1.0), 30, 40)),
    (shapes.box(), 0.5, shapes.transform((0.1, 0.2, 0.3), 1e-3, 45, 45)),
], ids=["icosphere", "box", "icosphere-xformed", "box-tiny-rotated"])
def test_no_leaks_at_vertices_and_edges(backend, mesh, inradius, matrix):
    """Rays aimed exactly at vertices, edge points and centroids of a closed convex mesh,
    along lines that pass through its interior, all hit: from outside no later than the
    aimed-at point (they enter there or before), from inside exactly there.

    (A ray aimed at a vertex from an arbitrary direction may only touch the mesh at that
    vertex; whether such a tangent ray hits is undecidable in floating point, so the lines
    here are chosen to go through a ball inside the mesh.)
    """
    s = one_object_scene(mesh, matrix)
    sa = s.arrays()
    acc = create_accelerator(backend, sa)
    m = sa.inst_xform[0]
    local = mesh_points(mesh)
    targets = local @ m[:3, :3].T + m[:3, 3]
    lo, hi = sa.inst_aabb[0]
    length = 2.0 * np.linalg.norm(hi - lo)
    rng = np.random.default_rng(7)
    for _ in range(3):
        q = rng.normal(size=local.shape)
        q *= 0.9 * inradius * rng.uniform(0, 1, (len(q), 1)) / np.linalg.norm(q, axis=1)[:, None]
        q = q @ m[:3, :3].T + m[:3, 3]  # interior points, world space
        away = (targets - q) / np.linalg.norm(targets - q, axis=1)[:, None]
        o = targets + length * away
        d = targets - o  # t = 1 at the target
        h = acc.closest_hit(o, d, 0.0, np.inf)
        assert np.all(h.inst == 0), f"{np.sum(h.inst < 0)} rays leaked"
        assert np.all(h.t <= 1.0 + 1e-9)
        assert np.all(acc.any_hit(o, d, 0.0, np.inf))
        # from inside, outwards through the same points
        h = acc.closest_hit(q, targets - q, 0.0, np.inf)
        assert np.all(h.inst == 0), f"{np.sum(h.inst < 0)} rays leaked from inside"
        assert np.allclose(h.t, 1.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
def test_axis_and_diagonal_rays_through_box(backend):
    """Rays exactly along +-X/Y/Z and the diagonals through a unit box, including the
    planes of its face diagonals (the shared edge of each face's two triangles)."""
    s = one_object_scene(shapes.box())
    acc = create_accelerator(backend, s.arrays())
    g = np.linspace(-0.5, 0.5, 21)[1:-1]  # strictly inside the face, on the diagonals too
    u, v = np.meshgrid(g, g)
    u, v = u.ravel(), v.ravel()
    for axis in range(3):
        for sign in (1.0, -1.0):
            o = np.zeros((len(u), 3))
            o[:, axis] = -3.0 * sign
            o[:, (axis + 1) % 3] = u
            o[:, (axis + 2) % 3] = v
            d = np.zeros_like(o)
            d[:, axis] = sign
            h = acc.closest_hit(o, d, 0.0, np.inf)
            assert np.all(h.inst == 0)
            assert np.allclose(h.t, 2.5, rtol=0, atol=1e-12)
    # rays exactly along the box's boundary: the edges and faces of its silhouette, where a
    # box test that is not conservative would cull what the triangle test accepts
    xs = np.array([-0.5, -0.25, 0.0, 0.25, 0.5])
    X, Y = np.meshgrid(xs, xs)
    for axis in range(3):
        o = np.zeros((X.size, 3))
        o[:, axis] = 5.0
        o[:, (axis + 1) % 3] = X.ravel()
        o[:, (axis + 2) % 3] = Y.ravel()
        d = np.zeros_like(o)
        d[:, axis] = -1.0
        h = acc.closest_hit(o, d, 0.0, np.inf)
        assert np.all(h.inst == 0)  # the brute-force test is edge-inclusive: all hit
        assert np.allclose(h.t, 4.5, rtol=0, atol=1e-12)
    # diagonals through the corners: each enters at a vertex
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5)
                        for z in (-0.5, 0.5)])
    o = corners * 5.0
    h = acc.closest_hit(o, -corners, 0.0, np.inf)
    assert np.all(h.inst == 0)
    assert np.allclose(h.t, 4.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_plane_both_sides_and_grazing(backend):
    s = one_object_scene(shapes.plane(2.0, divisions=4))
    acc = create_accelerator(backend, s.arrays())
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.99, 0.99, (200, 2))
    for z in (1.0, -1.0):  # from above and from below
        o = np.column_stack([xy, np.full(200, z)])
        d = np.column_stack([rng.uniform(-0.3, 0.3, (200, 2)), np.full(200, -z)])
        target = xy + d[:, :2]
        inside = np.all(np.abs(target) < 1.0, axis=1)
        h = acc.closest_hit(o, d, 0.0, np.inf)
        assert np.array_equal(h.inst == 0, inside)
        assert np.allclose(h.t[inside], 1.0, atol=1e-12)
    # grazing: nearly parallel rays that cross z = 0 at x = 0.5 (inside) or 1.5 (outside)
    for slope in (1e-3, 1e-6, 1e-9):
        for cross, expect in ((0.5, True), (1.5, False)):
            o = np.array([[cross - 1.0, 0.1, slope]])
            d = np.array([[1.0, 0.0, -slope]])
            h = acc.closest_hit(o, d, 0.0, np.inf)
            assert (h.inst[0] == 0) == expect
            if expect:
                assert h.t[0] == pytest.approx(1.0, abs=1e-9)
    # rays lying in the plane itself touch it only edge-on: they must not crash or NaN
    h = acc.closest_hit(np.array([[-2.0, 0.0, 0.0], [-2.0, 0.5, 0.0]]),
                        np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), 0.0, np.inf)
    assert not np.any(np.isnan(h.t))


# ----------------------------------------------------------------------------- updates


def two_mesh_scene(offset=(0.0, 0.0, 0.0)) -> Scene:
    s = Scene()
    s.add_material(Material("m"))
    ico = s.add_mesh(shapes.icosphere(2))
    box = s.add_mesh(shapes.box())
    s.add_instance(ico, shapes.transform((-2.0, 0.0, 0.0)), [0], "A")
    s.add_instance(ico, shapes.transform(offset), [0], "B")
    s.add_instance(box, shapes.transform((2.0, 0.0, 0.0), 1.5, 30), [0], "C")
    return s


def rays_towards_origin(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    o = sphere_points(n, 8.0, seed)
    d = rng.uniform(-3.0, 3.0, (n, 3)) - o
    return o, d, np.zeros(n), np.full(n, np.inf)


def test_update_after_move_rebuilds_only_top_level():
    s = two_mesh_scene()
    acc = create_accelerator("BVH", s.arrays())
    assert acc.stats["meshes_built"] == 2
    rays = rays_towards_origin(3000)
    before = acc.closest_hit(*rays)
    s.set_instance_matrix(1, shapes.transform((0.3, 1.2, -0.4), 0.7, 20, 10))
    acc.update(s.arrays())
    assert acc.stats["meshes_built"] == 2  # nothing rebuilt below the top level
    after = acc.closest_hit(*rays)
    fresh = create_accelerator("BVH", s.arrays()).closest_hit(*rays)
    oracle = create_accelerator("BRUTE_FORCE", s.arrays()).closest_hit(*rays)
    for a, b in ((after, fresh), (after, oracle)):
        assert np.array_equal(a.inst, b.inst) and np.array_equal(a.prim, b.prim)
        assert np.array_equal(a.t, b.t)
    assert not np.array_equal(after.inst, before.inst)  # the move changed something


def test_update_reuses_unchanged_meshes_by_content():
    s = two_mesh_scene()
    acc = create_accelerator("BVH", s.arrays())
    # a new scene (new arrays) with the same two meshes plus a new one in front of them
    s2 = two_mesh_scene()
    tor = s2.add_mesh(shapes.torus(1.0, 0.3, 16, 8))
    s2.add_instance(tor, shapes.transform((0.0, 0.0, 3.0)), [0], "T")
    acc.update(s2.arrays())
    assert acc.stats["meshes_built"] == 3 and acc.stats["meshes_reused"] == 2
    rays = rays_towards_origin(2000, seed=1)
    got = acc.closest_hit(*rays)
    want = create_accelerator("BRUTE_FORCE", s2.arrays()).closest_hit(*rays)
    assert np.array_equal(got.prim, want.prim) and np.array_equal(got.inst, want.inst)
    assert np.any(got.inst == 3)
