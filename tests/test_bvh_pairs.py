"""A large mesh's BVH built over its quads (:mod:`rstrace_engine.accel.bvh_cluster`): the
items pair exactly the consecutive triangles that share an edge, each pair is opened by the
two-primitive SAH rule of the triangle build, and on meshes whose triangles are not in
quad order (shuffled, a random soup) the tree keeps its invariants and hits what brute
force hits."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine.accel import bvh_bins, bvh_build, bvh_cluster, bvh_mesh
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Material, Mesh, Scene
from tests.test_bvh_boxes32 import check_tree

#: past bvh_build.PARALLEL_MIN: the paired build
BIG = 70_000


def _lumpy():
    m = shapes.lumpy_sphere(BIG, name="big")
    return (np.ascontiguousarray(m.vertices, np.float64),
            np.ascontiguousarray(m.triangles, np.int32))


def _soup(rng, m: int):
    """``m`` random small triangles in a unit cube, every third one followed by a
    neighbour across one of its edges (a few pairs, most triangles alone)."""
    centres = rng.random((m, 3))
    tv = centres[:, None, :] + rng.normal(scale=0.004, size=(m, 3, 3))
    for i in range(0, m - 1, 3):  # triangle i + 1 shares the edge (0, 1) of triangle i
        tv[i + 1, 0], tv[i + 1, 1] = tv[i, 1], tv[i, 0]
        tv[i + 1, 2] = tv[i, 0] + tv[i, 1] - tv[i, 2]
    return tv.reshape(-1, 3).copy(), np.arange(3 * m, dtype=np.int32).reshape(m, 3)


def _shared_positions(verts, tris, i: int, j: int) -> int:
    a, b = verts[tris[i]], verts[tris[j]]
    return int(sum(np.any(np.all(b == p, axis=1)) for p in a))


def _pair_starts(verts, tris) -> list[int]:
    """The reference item starts of :func:`.bvh_cluster.pair_items`: pairs (2h, 2h + 1)
    with two vertex positions in common are one item, other triangles one item each."""
    want = []
    for h in range(0, len(tris), 2):
        if h + 1 < len(tris) and _shared_positions(verts, tris, h, h + 1) >= 2:
            want.append(h)
        else:
            want.extend([h, h + 1] if h + 1 < len(tris) else [h])
    return want + [len(tris)]


def test_items_pair_the_consecutive_triangles_that_share_an_edge():
    rng = np.random.default_rng(4)
    verts, tris = _lumpy()
    shuffled = tris[rng.permutation(len(tris))]
    for v, t in ((verts, tris), (verts, shuffled), _soup(rng, 20_001)):
        pb = bvh_mesh.indexed_boxes(v, t)
        starts, boxes, _, _ = bvh_cluster.pair_items(v, t, pb, 1.0)
        assert starts.tolist() == _pair_starts(v, t)
        for k in range(len(boxes)):
            a, b = starts[k], starts[k + 1]
            assert np.array_equal(boxes[k, :3], pb[a:b, :3].min(axis=0))
            assert np.array_equal(boxes[k, 3:], pb[a:b, 3:].max(axis=0))
    assert len(bvh_cluster.pair_items(verts, tris, bvh_mesh.indexed_boxes(verts, tris), 1.0)[1]) \
        == len(tris) // 2  # a quad mesh: every item a quad


def test_each_pair_is_opened_by_the_two_primitive_sah_rule():
    """An item of two triangles ends as one leaf of both exactly where the triangle
    build, given those two triangles as a node, makes them one leaf."""
    verts, tris = _lumpy()
    pb = bvh_mesh.indexed_boxes(verts, tris)
    bounds, child, perm, _ = bvh_cluster.build_paired(verts, tris, pb)
    leaf_of = {}  # triangle -> the size of its leaf
    stack = [0]
    while stack:
        node = stack.pop()
        for s in range(2):
            c = int(child[node, s])
            if c >= 0:
                stack.append(c)
            elif (~c) & 7:
                start, count = (~c) >> 3, (~c) & 7
                for t in perm[start:start + count]:
                    leaf_of[int(t)] = count
    assert sorted(leaf_of) == list(range(len(tris)))
    rng = np.random.default_rng(2)
    both = {1: 0, 2: 0}
    for h in rng.choice(len(tris) // 2, 400, replace=False):
        a = 2 * int(h)
        b2, c2, _, _ = bvh_build.build_flat_boxes(pb[a:a + 2].copy(), packed=False)
        one_leaf = bool(b2[0, 6] > b2[0, 9])  # a root that is one leaf: child 1 empty
        assert (leaf_of[a] == 2) == one_leaf and leaf_of[a] == leaf_of[a + 1]
        both[leaf_of[a]] += 1
    assert both[1] and both[2]  # (both outcomes are checked)


def _inner_rows(child) -> np.ndarray:
    """The inner rows a walk from the root reaches (a row reached twice listed twice): the
    only rows of an unpacked build that are set (``build_flat_boxes(packed=False)``)."""
    seen, stack = [0], [0]
    while stack:
        for c in child[stack.pop()]:
            if c >= 0:
                seen.append(int(c))
                stack.append(int(c))
    return np.asarray(seen, np.int64)


def _poisoned(monkeypatch, value):
    """Make every row of the item tree's arrays that no child index reaches hold
    ``value`` (``bounds`` NaN) when :func:`.bvh_cluster.build_paired` gets them: what
    ``np.empty`` hands out on pages a freed array left (the rows the opened pairs then
    write included). Fresh pages are zero, below the opened rows, so only a reused heap
    shows a read of an unset row (a test that read them failed in the first run after
    a BVH change, session 33)."""
    real = bvh_cluster.build_flat_boxes

    def build(*args, **kwargs):
        bounds, child, perm, sah = real(*args, **kwargs)
        unset = np.ones(len(child), bool)
        unset[_inner_rows(child)] = False
        child[unset] = value
        bounds[unset] = np.nan
        return bounds, child, perm, sah

    monkeypatch.setattr(bvh_cluster, "build_flat_boxes", build)


@pytest.mark.parametrize("unset", ["as_allocated", "poisoned"])
def test_split_pairs_nodes_are_packed_after_the_item_tree(monkeypatch, unset):
    """The inner nodes of the opened pairs are the rows right after the item tree's own,
    one per pair that ``pair_items`` marks as split, in leaf order (session 38: the walk
    that opens them runs on every thread; main numbered them as one walk met them): no
    row is touched for a pair that stays one leaf (at 4M triangles a row per item made
    96 MB of fresh pages for about a tenth of them). Only the rows a walk from the root
    reaches are looked at (the others are unset: ``poisoned`` fills them with a row
    index of the opened nodes), and the tree they make is the same whatever the unset
    rows hold."""
    verts, tris = _lumpy()
    pb = bvh_mesh.indexed_boxes(verts, tris)
    starts, _, how, _ = bvh_cluster.pair_items(verts, tris, pb, bvh_build.SAH_TRAVERSAL_COST)
    n_items, n_split = len(starts) - 1, int(np.count_nonzero(how))
    assert 0 < n_split < n_items // 2
    assert set(np.unique(how).tolist()) == {bvh_cluster.OPEN_LEAF, bvh_cluster.OPEN_SPLIT,
                                            bvh_cluster.OPEN_SPLIT_SWAPPED}
    clean = bvh_cluster.build_paired(verts, tris, pb)
    if unset == "poisoned":
        _poisoned(monkeypatch, n_items)
    bounds, child, perm, sah = bvh_cluster.build_paired(verts, tris, pb)
    assert len(child) <= n_items + n_split
    rows = _inner_rows(child)
    # a tree: every row reached once; the item tree (one item a leaf: n_items - 1 inner
    # nodes) below n_items, the opened pairs' rows n_items .. in leaf order
    item_rows, opened = rows[rows < n_items], rows[rows >= n_items]
    diag = (f"n_items {n_items} n_split {n_split} rows {len(child)} reached {len(rows)} "
            f"distinct {len(np.unique(rows))} item rows {len(item_rows)} opened "
            f"{len(opened)} [{opened.min(initial=-1)}, {opened.max(initial=-1)}]")
    assert len(np.unique(rows)) == len(rows), diag
    assert len(item_rows) == n_items - 1, diag
    assert np.array_equal(np.sort(opened), np.arange(n_items, n_items + n_split)), diag
    first = (~child[np.sort(opened), 0].astype(np.int64)) >> 3  # (their first leaf's row)
    assert np.all(np.diff(first) > 0), diag
    # the tree is the one built over whatever the unset rows held
    assert np.array_equal(perm, clean[2]) and sah == clean[3]
    assert np.array_equal(child[rows], clean[1][rows])
    assert np.array_equal(bounds[rows].view(np.int32), clean[0][rows].view(np.int32))
    # each opened node holds two leaves of one triangle, in the order ``how`` says
    for node in opened[:: max(n_split // 300, 1)]:
        a, b = (perm[(~int(c)) >> 3] for c in child[node])
        assert child[node, 0] < 0 and (~int(child[node, 0])) & 7 == 1
        k = int(np.searchsorted(starts, min(a, b), side="right")) - 1
        assert starts[k] == min(a, b) and abs(int(a) - int(b)) == 1
        assert (a > b) == (how[k] == bvh_cluster.OPEN_SPLIT_SWAPPED)


@pytest.mark.parametrize("kind", ["shuffled", "soup"])
def test_unpaired_meshes_keep_the_invariants_and_hit_what_brute_force_hits(kind):
    rng = np.random.default_rng(9)
    if kind == "shuffled":
        verts, tris = _lumpy()
        tris = tris[rng.permutation(len(tris))]
    else:
        verts, tris = _soup(rng, BIG)
    assert len(tris) >= bvh_build.PARALLEL_MIN
    mb = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    check_tree(mb, verts[tris])
    s = Scene()
    s.add_material(Material("m"))
    s.add_instance(s.add_mesh(Mesh("big", verts, tris), key="big"), np.eye(4), key="Big")
    sa = s.arrays()
    n = 3000
    o = np.concatenate([rng.normal(size=(n, 3)) * 3, rng.random((n, 3)),
                        verts[rng.integers(0, len(verts), n)] * 1.0001])
    d = rng.normal(size=(3 * n, 3))
    got = create_accelerator("BVH", sa).closest_hit(o, d, 0.0, np.inf)
    want = create_accelerator("BRUTE_FORCE", sa).closest_hit(o, d, 0.0, np.inf)
    assert np.count_nonzero(want.prim >= 0) > n // 2
    for a, w in zip(got, want, strict=True):
        assert np.array_equal(a, w)


def _tie_grid(n: int):
    """A flat grid of n x n unit quads (integer coordinates), each split on its diagonal
    a-c into triangles 2k, 2k+1 (a quad's pair); with dyadic ray targets every edge and
    vertex hit is an exact tie between the triangles meeting there."""
    xs = np.arange(n + 1, dtype=np.float64)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    verts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    a, b = i * (n + 1) + j, (i + 1) * (n + 1) + j
    c, d = b + 1, a + 1
    tris = np.stack([np.stack([a, b, c], 1), np.stack([a, c, d], 1)], 1).reshape(-1, 3)
    return verts, tris.astype(np.int32)


@pytest.mark.parametrize("n", [40, 200])  # 3,200 triangles (main's build), 80,000 (paired)
def test_exact_ties_go_to_the_highest_triangle_in_any_tree(n):
    """Rays through shared diagonals, edges and vertices hit two or more triangles at the
    same t: the closest hit is the highest triangle id among them (what the brute-force
    oracle, testing triangles in id order, reports), whatever the tree tested first -- the
    paired build (over 65,536 triangles) orders a quad's triangles unlike the triangle
    build, so a rule of "the last tested" gave another triangle, u and v (review)."""
    verts, tris = _tie_grid(n)
    s = Scene()
    s.add_material(Material("m"))
    s.add_instance(s.add_mesh(Mesh("grid", verts, tris), key="grid"), np.eye(4), key="Grid")
    sa = s.arrays()
    rng = np.random.default_rng(1)
    m = 3000
    qi, qj = (rng.integers(0, n, m).astype(np.float64) for _ in range(2))
    f = rng.integers(1, 8, m) / 8.0
    z = np.zeros(m)
    targets = np.concatenate([np.stack([qi + f, qj + f, z], 1),  # on a diagonal
                              np.stack([qi, qj, z], 1),  # on a vertex
                              np.stack([qi + f, qj, z], 1)])  # on an axis edge
    k = len(targets)
    d = np.concatenate([np.tile([0.0, 0.0, -1.0], (k, 1)),
                        rng.integers(-4, 5, (k, 3)) / 8.0 + np.array([0.0, 0.0, -1.0])])
    t = np.concatenate([targets, targets])
    o = t - 4.0 * d
    got = create_accelerator("BVH", sa).closest_hit(o, d, 0.0, np.inf)
    want = create_accelerator("BRUTE_FORCE", sa).closest_hit(o, d, 0.0, np.inf)
    assert np.count_nonzero(want.prim >= 0) > 0.9 * len(o)
    for field in ("t", "inst", "prim", "u", "v"):
        a, b = np.asarray(getattr(got, field)), np.asarray(getattr(want, field))
        assert np.array_equal(a, b), (field, int(np.count_nonzero(a != b)))


def test_a_large_meshs_item_build_bins_every_node_on_its_long_axes():
    """The item build (:func:`bvh_cluster.build_paired`) applies the cheap rule
    (``bvh_bins._node_bins``: binned only on the axes whose extent is at least
    ``CHEAP_AXIS_FRAC`` of the longest's) to every node, not only those of at most
    ``CHEAP_MAX`` primitives (session 37). Two rows of quads along x, 4 apart in z, more
    than ``CHEAP_MAX`` items: the root splits across x (z not binned); the triangle
    build of the same boxes (``build_flat_boxes``) still splits between the rows. Fails
    on main."""
    q = bvh_bins.CHEAP_MAX // 2 + 500  # quads per row: > CHEAP_MAX items in all
    x = np.linspace(0.0, 10.0, q + 1)
    verts, tris = [], []
    for z in (0.0, 4.0):
        v0 = len(verts)
        verts += [(xi, y, z) for xi in x for y in (0.0, 0.01)]
        for i in range(q):
            a, b, c, d = v0 + 2 * i, v0 + 2 * i + 2, v0 + 2 * i + 3, v0 + 2 * i + 1
            tris += [(a, b, c), (a, c, d)]
    verts, tris = np.array(verts, np.float64), np.array(tris, np.int32)
    pb = bvh_mesh.indexed_boxes(verts, tris)
    b, ch, perm, sah = bvh_cluster.build_paired(verts, tris, pb.copy())
    z_extent = b[0, 5] - b[0, 2], b[0, 11] - b[0, 8]  # the root's two children
    assert min(z_extent) > 3.0, z_extent
    b, ch, perm, sah = bvh_build.build_flat_boxes(pb.astype(np.float64))
    assert max(b[0, 5] - b[0, 2], b[0, 11] - b[0, 8]) < 1.0
