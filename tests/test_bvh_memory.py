"""Memory per triangle of the BVH (issue 26): float32 node boxes rounded outward (each
contains its float64 box, so no hit is lost), leaves that read the scene's own vertices,
and a bound on the bytes held per unique triangle (counted from the arrays)."""

from __future__ import annotations

import numpy as np

from rstrace_engine.accel import bvh, bvh_build, bvh_cluster, bvh_mesh
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench import scale
from rstrace_engine.geometry import shapes

F32 = np.finfo(np.float32)
F64 = np.finfo(np.float64)


def _values() -> np.ndarray:
    """Bounds that round every way: float32-exact, halfway, subnormal in either precision,
    signed zeros, beyond float32's range, infinities; and random magnitudes."""
    rng = np.random.default_rng(11)
    special = [0.0, -0.0, 1.0, -1.0, 0.1, -0.1, 1.0 + 2.0 ** -24, 1.0 + 2.0 ** -30,
               -(1.0 + 2.0 ** -30), 1e-310, -1e-310, 5e-324, -5e-324, 1e-45, -1e-45, 2e-45,
               float(F32.tiny), -float(F32.tiny), float(F32.max), -float(F32.max),
               float(F32.max) * (1 + 2.0 ** -30), -float(F32.max) * (1 + 2.0 ** -30), 1e39,
               -1e39, float(F64.max), -float(F64.max), np.inf, -np.inf]
    rand = rng.normal(size=2000) * 10.0 ** rng.integers(-50, 50, 2000)
    with np.errstate(over="ignore"):
        near32 = rand.astype(np.float32).astype(np.float64)
    return np.concatenate([special, rand, near32[np.isfinite(near32)]])


def _lanes(b2: np.ndarray, dtype) -> np.ndarray:
    """The 4-wide node (24 bounds) :func:`collapse4` makes of a binary root whose two
    children are leaves with the boxes ``b2`` (12: lo, hi of each)."""
    c2 = np.array([[~(0 << 3 | 1), ~(1 << 3 | 1)]], np.int32)
    b4, c4, m = bvh_mesh.collapse4(b2.reshape(1, 12).copy(), c2, np.empty((1, 24), dtype),
                                   False)
    assert m == 1 and np.array_equal(c4[0, :2], c2[0])
    return b4[0]


def test_float32_boxes_contain_the_float64_ones_and_are_the_nearest_that_do():
    x = _values()
    pairs = np.sort(np.resize(x, (len(x) // 12 + 1) * 12).reshape(-1, 6, 2), axis=2)
    lanes = [0, 4, 8, 12, 16, 20, 1, 5, 9, 13, 17, 21]  # lo xyz, hi xyz of lanes 0 and 1
    for row in pairs:
        b2 = np.concatenate([row[:3, 0], row[:3, 1], row[3:, 0], row[3:, 1]])
        b64 = _lanes(b2, np.float64)[lanes]
        assert np.array_equal(b64, b2)  # float64: the boxes as they are
        b32 = _lanes(b2, np.float32)[lanes]
        lo = np.array([True] * 3 + [False] * 3 + [True] * 3 + [False] * 3)
        f = b32.astype(np.float64)
        # contains the float64 box (inf to inf) ...
        assert np.all(f[lo] <= b2[lo]) and np.all(f[~lo] >= b2[~lo]), (b2, b32)
        # ... and is the tightest float32 box that does: one float32 step inward leaves it
        with np.errstate(over="ignore"):
            inward = np.where(lo, np.nextafter(b32, np.float32(np.inf)),
                              np.nextafter(b32, np.float32(-np.inf))).astype(np.float64)
        fin = np.isfinite(f)
        assert np.all(inward[lo & fin] > b2[lo & fin]), (b2, b32)
        assert np.all(inward[~lo & fin] < b2[~lo & fin]), (b2, b32)
        # a float32-exact bound is kept exactly (infinities included)
        with np.errstate(over="ignore"):
            exact = b2.astype(np.float32).astype(np.float64) == b2
        assert np.array_equal(f[exact], b2[exact])
        # beyond float32's range: the largest finite float32 inside, an infinity outside
        big = np.isfinite(b2) & (np.abs(b2) > float(F32.max))
        inner = big & (lo == (b2 > 0))
        assert np.all(np.abs(f[inner]) == float(F32.max))
        assert np.all(np.isinf(f[big & ~inner]))


def test_mesh_bvh_float32_boxes_contain_the_float64_tree():
    """The built tree's float32 boxes hold its float64 boxes lane by lane (the same
    tree, the boxes only rounded outward) and so every triangle of their subtree."""
    mesh = shapes.lumpy_sphere(bvh_build.PARALLEL_MIN + 2_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), mesh.triangles
    pb = bvh_mesh.indexed_boxes(verts, tris)
    # (a large mesh's tree is built over its quads: bvh_cluster)
    b64, child, perm, _ = bvh_cluster.build_paired(verts, tris, pb.copy())
    f64 = bvh_mesh.flatten(b64, child, perm)  # the same tree, float64 boxes
    mb = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    assert np.array_equal(mb.bvh.child, f64.child) and np.array_equal(mb.tri, f64.perm)
    b32 = mb.bvh.bounds.astype(np.float64)
    assert mb.bvh.bounds.dtype == np.float32
    assert np.all(b32[:, :12] <= f64.bounds[:, :12]) and np.all(b32[:, 12:] >= f64.bounds[:, 12:])
    assert np.any(b32 != f64.bounds)  # (rounded: not the float64 values)


def _own_bytes(acc, sa) -> int:
    """Bytes of the BVH's arrays that are not the scene's own (SceneArrays) buffers."""
    scene_arrays = [a for a in sa if isinstance(a, np.ndarray)]
    return sum(a.nbytes for a in acc.sb if isinstance(a, np.ndarray)
               and not any(np.shares_memory(a, b) for b in scene_arrays))


def test_bytes_per_unique_triangle_stay_bounded():
    """What ``bench scale`` reports, counted from the arrays held (a buffer shared by
    several counts once): the BVH's own arrays (4-wide float32 nodes, the triangle ids of
    the leaves that list theirs, the top level) and the total with the scene model and the
    packed arrays: at most 64 bytes a unique triangle on the dense scene, issue 26's goal.
    (230 in all before the float32 boxes: 130 of BVH, 72 of them a float64 copy of the
    leaves' vertices, 54 the float64 nodes; then 75, 16 of them the leaf-order vertex
    indices and triangle ids of every triangle.)"""
    scene = scale.big_scene(20_000)
    sa = scene.arrays()
    acc = create_accelerator("BVH", sa)
    unique = int(sa.mesh_tri_start[-1])
    mem = scale.memory(scene, sa, acc)
    assert mem["bvh"] <= 31.0, mem
    assert mem["total"] <= 64.0, mem
    # the same from the arrays themselves: the leaves read the scene's vertices and
    # vertex indices (no copy) and list the ids of a few triangles only (the leaves of
    # three of a small mesh's tree, session 42: 28% of them, for 10% fewer BVH bytes)
    assert acc.sb.verts is sa.verts and acc.sb.tris is sa.tris
    assert len(acc.sb.tri) <= 0.3 * unique, len(acc.sb.tri)
    own = _own_bytes(acc, sa)
    assert own <= 31.0 * unique, own / unique
    packed = sum(a.nbytes for a in (sa.verts, sa.tris, sa.normals, sa.uvs, sa.tri_slot))
    assert packed + own <= 64.0 * unique, (packed + own) / unique
    assert acc.stats["memory_mb"] * 2 ** 20 <= 31.0 * unique


def _walk(child, tri, node=0):
    """The leaves of a placed mesh tree in traversal-layout order: (box path, triangles)."""
    out = []
    for lane in range(4):
        c = int(child[node, lane])
        if c == -1:
            continue
        if c >= 0:
            out.extend(_walk(child, tri, c))
            continue
        start, kind = (~c) >> 3, (~c) & 7
        out.append([int(bvh_mesh.leaf_triangle(tri, start, kind, i))
                    for i in range(bvh_mesh.leaf_size(kind))])
    return out


def test_leaves_name_their_triangles_in_the_build_leaf_order():
    """A placed mesh tree (what the traversal reads) has the built tree's nodes and boxes,
    and its leaves give the built leaves' triangles in the same order (so the same hit
    wins a tie): a leaf of one triangle or of two neighbours names them in its code, in
    either order; the others list theirs."""
    for mesh in (shapes.lumpy_sphere(6_000), shapes.icosphere(3), shapes.torus(1.0, 0.3, 24, 12),
                 shapes.plane(2.0)):
        tv = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.triangles)]
        mb = bvh_mesh.build_mesh_bvh(tv)
        pm = bvh.PlacedMesh.built(mb)
        assert pm.bounds is mb.bvh.bounds
        inner = mb.bvh.child >= -1
        assert np.array_equal(pm.child[inner], mb.bvh.child[inner])
        built = [[int(mb.tri[p]) for p in range((~c) >> 3, ((~c) >> 3) + ((~c) & 7))]
                 for c in mb.bvh.child[~inner]]
        placed = [[int(bvh_mesh.leaf_triangle(pm.tri, (~c) >> 3, (~c) & 7, i))
                   for i in range(bvh_mesh.leaf_size((~c) & 7))] for c in pm.child[~inner]]
        assert placed == built, mesh.name
        assert np.array_equal(bvh_mesh.leaf_order(pm.child, pm.tri),
                              np.concatenate([np.array(x) for x in built]))
        kinds = ((~pm.child[~inner]) & 7)
        assert len(pm.tri) == sum(len(x) for x, k in zip(built, kinds, strict=True)
                                  if k <= bvh_mesh.LEAF_LISTED)
        if mesh.name.startswith("lumpy"):
            # each naming kind occurs on a triangulated surface, listing ones too, and
            # most triangles are named
            assert {5, 6, 7} <= set(kinds.tolist()) and np.any(kinds <= 4), set(kinds.tolist())
            assert len(pm.tri) < 0.3 * len(tv)  # (0.2 before the leaves of three)


def test_placed_leaves_move_with_their_mesh():
    """In a scene's concatenation a naming leaf's triangle moves by the mesh's first
    triangle, a listing leaf's start by the entries listed before it (two meshes, the
    second's tree checked leaf by leaf against its own build)."""
    a, b = shapes.icosphere(2), shapes.lumpy_sphere(3_000)
    tva, tvb = (np.asarray(m.vertices, np.float64)[np.asarray(m.triangles)] for m in (a, b))
    pa, pb = (bvh.PlacedMesh.built(bvh_mesh.build_mesh_bvh(tv)) for tv in (tva, tvb))
    start = np.array([0, len(tva), len(tva) + len(tvb)], np.int32)
    _, child, tri, roots, placed = bvh.concat_meshes([pa, pb], start)
    got = _walk(child, tri, int(roots[1]))
    want = [[t + len(tva) for t in leaf] for leaf in _walk(pb.child, pb.tri)]
    assert got == want and placed[1].tri_base == len(tva)
    assert sorted(t for leaf in got for t in leaf) == list(range(len(tva), start[-1]))


def test_a_small_mesh_tree_has_leaves_of_up_to_three_and_fewer_nodes():
    """A mesh below PARALLEL_MIN triangles is built at SAH node cost 2 with leaves of at
    most 3 (session 42, docs/bench-raycast.md "session 42 (tree)"): the rough frame's
    sphere (5120 triangles) has about a sixth fewer 4-wide nodes than the defaults' tree
    (leaves of 1-2), so its rays visit fewer nodes and enter fewer leaves."""
    mesh = shapes.icosphere(4)
    tv = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.triangles)]
    assert len(tv) == 5120
    mb = bvh_mesh.build_mesh_bvh(tv)
    pb = bvh_mesh.outward32(tv.min(axis=1), tv.max(axis=1)).astype(np.float64)
    b, c, p, _ = bvh_build.build_flat_boxes(pb, packed=False)  # the defaults: 1.0, 4
    default = bvh_mesh.flatten(b, c, p, np.float32)
    assert len(mb.bvh.child) < 0.9 * len(default.child), (len(mb.bvh.child),
                                                          len(default.child))
    sizes = ((~mb.bvh.child[mb.bvh.child < -1]) & 7)
    assert sizes.max() == 3 and np.count_nonzero(sizes == 3) > 0.2 * len(sizes)
