"""A mesh BVH built over float32 primitive boxes (``bvh_mesh.indexed_boxes``, rounded
outward): the boxes contain their triangles, the tree keeps its invariants and its hits are
brute force's, and over float32 vertices (Blender's) it is the tree of float64 boxes, bit
for bit. The checks themselves are shown to fail on broken variants."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine.accel import bvh_build, bvh_cluster, bvh_mesh
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Material, Mesh, Scene

#: past bvh_build.PARALLEL_MIN: the indexed, parallel build
BIG = 70_000


def _mesh(n: int = BIG, float32: bool = False):
    m = shapes.lumpy_sphere(n, name="big")
    verts = np.ascontiguousarray(m.vertices, np.float64)
    if float32:
        verts = verts.astype(np.float32).astype(np.float64)
    return verts, np.ascontiguousarray(m.triangles, np.int32)


def _contains(pb: np.ndarray, tv: np.ndarray) -> bool:
    """Whether every box ``pb`` (n, 6) holds its triangle ``tv`` (n, 3, 3), compared in
    float64."""
    lo, hi = pb[:, :3].astype(np.float64), pb[:, 3:].astype(np.float64)
    return bool(np.all(lo <= tv.min(axis=1)) and np.all(hi >= tv.max(axis=1)))


def test_float32_boxes_hold_their_triangles_one_step_out_at_most():
    verts, tris = _mesh()
    tv = verts[tris]
    pb = bvh_mesh.indexed_boxes(verts, tris)
    assert pb.dtype == np.float32 and pb.shape == (len(tris), 6)
    assert _contains(pb, tv)
    # the tightest such float32 box: one step in is no longer outside
    inner = pb.copy()
    inner[:, :3] = np.nextafter(pb[:, :3], np.float32(np.inf))
    inner[:, 3:] = np.nextafter(pb[:, 3:], np.float32(-np.inf))
    lo_in = inner[:, :3].astype(np.float64) > tv.min(axis=1)
    hi_in = inner[:, 3:].astype(np.float64) < tv.max(axis=1)
    assert np.all(lo_in | (pb[:, :3].astype(np.float64) == tv.min(axis=1)))
    assert np.all(hi_in | (pb[:, 3:].astype(np.float64) == tv.max(axis=1)))
    # the numpy rounding of the small meshes' path gives the same bits
    assert np.array_equal(bvh_mesh.outward32(tv.min(axis=1), tv.max(axis=1)).view(np.int32),
                          pb.view(np.int32))
    # the check fails on boxes rounded to nearest (what a plain cast gives)
    nearest = np.concatenate([tv.min(axis=1), tv.max(axis=1)], 1).astype(np.float32)
    assert not _contains(nearest, tv)
    # float32 vertices: the boxes are exact
    v32, _ = _mesh(float32=True)
    exact = np.concatenate([v32[tris].min(axis=1), v32[tris].max(axis=1)], 1)
    assert np.array_equal(bvh_mesh.indexed_boxes(v32, tris).astype(np.float64), exact)


def test_float32_vertices_give_the_float64_boxes_tree_bit_for_bit():
    """Blender's vertices are float32: the float32 boxes are then the float64 ones, and the
    builder (centroids, bins and areas in float64) makes the tree the float64 boxes made."""
    verts, tris = _mesh(float32=True)
    tv = verts[tris]
    pb64 = np.concatenate([tv.min(axis=1), tv.max(axis=1)], 1)
    # (a large mesh: the tree over its quads, bvh_cluster)
    b64, c64, p64, sah64 = bvh_cluster.build_paired(
        verts, tris, pb64, grain=bvh_build.subtree_grain(len(tris)))
    want = bvh_mesh.flatten(b64, c64, p64, np.float32)
    got = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    assert np.array_equal(got.bvh.bounds.view(np.int32), want.bounds.view(np.int32))
    assert np.array_equal(got.bvh.child, want.child)
    assert np.array_equal(got.tri, want.perm)
    assert got.sah_cost == sah64
    # the small meshes' path (numpy boxes, one thread) likewise
    small = tris[:5000]
    pbs = np.concatenate([verts[small].min(axis=1), verts[small].max(axis=1)], 1)
    b, c, p, _ = bvh_build.build_flat_boxes(pbs, bvh_mesh.SMALL_MAX_LEAF,
                                            trav_cost=bvh_mesh.SMALL_TRAV_COST, packed=False)
    want = bvh_mesh.flatten(b, c, p, np.float32)
    got = bvh_mesh.build_mesh_bvh(verts[small])
    assert np.array_equal(got.bvh.bounds.view(np.int32), want.bounds.view(np.int32))
    assert np.array_equal(got.bvh.child, want.child)


def check_tree(mb: bvh_mesh.MeshBVH, tv: np.ndarray) -> None:
    """Every triangle in exactly one leaf (of 1..MAX_LEAF), every lane's box holding all of
    its subtree's triangle vertices (in float64), unused lanes empty, children after their
    parent (depth-first numbering)."""
    b, child, tri = mb.bvh.bounds, mb.bvh.child, mb.tri
    m = len(child)
    node_lo = np.full((m, 3), np.inf)
    node_hi = np.full((m, 3), -np.inf)
    seen = np.zeros(len(tv), np.int64)
    for k in range(m - 1, -1, -1):  # children are numbered after their parent
        for lane in range(4):
            box = b[k, lane::4].astype(np.float64)  # lo x, lo y, lo z, hi x, hi y, hi z
            c = int(child[k, lane])
            if c == -1:
                assert box[0] > box[3], "an unused lane's box is empty"
                continue
            if c >= 0:
                assert c > k
                lo, hi = node_lo[c], node_hi[c]
            else:
                start, count = (~c) >> 3, (~c) & 7
                assert 1 <= count <= bvh_build.MAX_LEAF
                ids = tri[start:start + count]
                seen[ids] += 1
                lo, hi = tv[ids].reshape(-1, 3).min(axis=0), tv[ids].reshape(-1, 3).max(axis=0)
            assert np.all(box[:3] <= lo) and np.all(box[3:] >= hi), (k, lane)
            node_lo[k] = np.minimum(node_lo[k], lo)
            node_hi[k] = np.maximum(node_hi[k], hi)
    assert np.all(seen == 1)


def test_large_float32_build_keeps_the_tree_invariants():
    verts, tris = _mesh()
    mb = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    assert len(tris) >= bvh_build.PARALLEL_MIN
    check_tree(mb, verts[tris])
    # ... and the check catches a box too small (its lo x two steps in: the boxes are
    # padded one step out) and a triangle listed twice
    b = mb.bvh.bounds.copy()
    lane = np.flatnonzero(mb.bvh.child[0] != -1)[0]
    for _ in range(2):  # lo x of the root's lane
        b[0, lane] = np.nextafter(b[0, lane], np.float32(np.inf))
    narrowed = mb._replace(bvh=mb.bvh._replace(bounds=b))
    tri = mb.tri.copy()
    tri[0] = tri[1]
    doubled = mb._replace(tri=tri)
    for broken in (narrowed, doubled):
        with pytest.raises(AssertionError):
            check_tree(broken, verts[tris])


def test_large_float32_build_hits_what_brute_force_hits():
    verts, tris = _mesh()
    s = Scene()
    s.add_material(Material("m"))
    s.add_instance(s.add_mesh(Mesh("big", verts, tris), key="big"), np.eye(4),
                   key="Big")
    sa = s.arrays()
    rng = np.random.default_rng(7)
    n = 3000
    # from outside, from inside (the sphere's centre region), and grazing the surface
    o = np.concatenate([rng.normal(size=(n, 3)) * 3, rng.normal(size=(n, 3)) * 0.2,
                        verts[rng.integers(0, len(verts), n)] * 1.0001])
    d = rng.normal(size=(3 * n, 3))
    got = create_accelerator("BVH", sa).closest_hit(o, d, 0.0, np.inf)
    want = create_accelerator("BRUTE_FORCE", sa).closest_hit(o, d, 0.0, np.inf)
    assert np.count_nonzero(want.prim >= 0) > n  # (most rays hit)
    for a, w in zip(got, want, strict=True):
        assert np.array_equal(a, w)


def test_small_meshes_build_on_float64_boxes_the_float32_boxes_tree(monkeypatch):
    """A mesh below PARALLEL_MIN is built over its float32 boxes' values held as float64
    (the signature the scene's top level builds with: one compile of the builder for a
    small scene), and that is the tree its float32 boxes give, bit for bit, over float64
    vertices (where the outward rounding moves the bounds)."""
    verts, tris = _mesh(3000)
    tv = verts[tris]
    seen = []

    def recorded(pb, *args, **kwargs):
        seen.append(pb.dtype)
        return bvh_build.build_flat_boxes(pb, *args, **kwargs)

    monkeypatch.setattr(bvh_mesh, "build_flat_boxes", recorded)
    got = bvh_mesh.build_mesh_bvh(tv)
    assert seen == [np.dtype(np.float64)]
    pb32 = bvh_mesh.outward32(tv.min(axis=1), tv.max(axis=1))
    assert not np.array_equal(pb32.astype(np.float64),
                              np.concatenate([tv.min(axis=1), tv.max(axis=1)], 1))
    b, c, p, sah = bvh_build.build_flat_boxes(pb32, bvh_mesh.SMALL_MAX_LEAF,
                                              trav_cost=bvh_mesh.SMALL_TRAV_COST, packed=False)
    want = bvh_mesh.flatten(b, c, p, np.float32)
    assert np.array_equal(got.bvh.bounds.view(np.int32), want.bounds.view(np.int32))
    assert np.array_equal(got.bvh.child, want.child)
    assert np.array_equal(got.tri, want.perm)
    assert got.sah_cost == sah
