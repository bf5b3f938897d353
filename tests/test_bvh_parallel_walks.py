"""The mesh build's walks on every thread (session 38): :func:`.bvh_mesh.collapse4_par` makes
:func:`.bvh_mesh.collapse4`'s 4-wide rows bit for bit, and :func:`.bvh_cluster.open_items`
opens the items as one walk from the root did, on any thread count and any split of the
tree into tasks. Both fail on main (no ``collapse4_par``; ``item_leaves`` gave no node rows)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rstrace_engine.accel import bvh_build, bvh_cluster, bvh_mesh
from rstrace_engine.geometry import shapes


def _threads(n: int):
    """Run with ``n`` numba threads (at most the process's)."""
    class _Ctx:
        def __enter__(self):
            self.old = numba.get_num_threads()
            numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))

        def __exit__(self, *exc):
            numba.set_num_threads(self.old)
    return _Ctx()


def _random_tree(rng, n_leaves: int, skew: float, dtype, ties: bool = False):
    """A binary tree of ``n_leaves`` leaves (node 0 the root; child codes as the builder
    writes them, ``~(start << 3 | count)``), split ``skew`` of the way (1.0: a caterpillar,
    every node one leaf and the rest), its rows shuffled, random boxes (``ties``: a few
    sizes only, so that lanes tie on area). Rows no child reaches are left unset (NaN)."""
    rows = max(n_leaves - 1, 1)
    order = np.concatenate([[0], 1 + rng.permutation(rows - 1)])  # row of node i
    b2 = np.full((rows + 3, 12), np.nan, dtype)
    c2 = np.full((rows + 3, 2), 12345, np.int32)
    nxt, leaf = [1], [0]

    def box():
        lo = rng.integers(-4, 4, 3) if ties else rng.normal(size=3)
        ext = rng.integers(1, 3, 3) if ties else rng.random(3) * 2.0
        return np.concatenate([lo, lo + ext])

    stack = [(0, n_leaves)]
    while stack:
        node, count = stack.pop()
        r = order[node]
        for s, part in enumerate(_halves(rng, count, skew)):
            b2[r, 6 * s:6 * s + 6] = box()
            if part == 1:
                c2[r, s] = ~((leaf[0] << 3) | int(rng.integers(1, 5)))
                leaf[0] += 1
            else:
                c2[r, s] = order[nxt[0]]
                stack.append((nxt[0], part))
                nxt[0] += 1
    return b2, c2


def _halves(rng, count: int, skew: float):
    if skew >= 1.0:
        return (1, count - 1) if rng.random() < 0.5 else (count - 1, 1)
    left = int(np.clip(round(count * (0.5 + skew * (rng.random() - 0.5))), 1, count - 1))
    return left, count - left


def _same(b2, c2, pad, ntask):
    want = bvh_mesh.collapse4(b2, c2, np.empty((len(c2), 24), np.float32), pad)
    got = bvh_mesh.collapse4_par(b2, c2, np.empty((len(c2), 24), np.float32), pad, ntask)
    m = want[2]
    assert got[2] == m
    assert np.array_equal(got[1][:m], want[1][:m])
    assert np.array_equal(got[0][:m].view(np.int32), want[0][:m].view(np.int32))
    return m


@pytest.mark.parametrize("threads", [1, 2])
def test_the_parallel_collapse_makes_the_serial_collapses_rows(threads):
    """Random trees (balanced, lopsided, caterpillars deeper than the top levels it
    walks alone, tied areas, float32 and float64 boxes, padded or not), every split into
    tasks from one to more than the tree has nodes."""
    rng = np.random.default_rng(38)
    with _threads(threads):
        for n_leaves in (2, 3, 5, 9, 40, 300, 3000):
            for skew in (0.0, 0.6, 1.0):
                for dtype in (np.float32, np.float64):
                    b2, c2 = _random_tree(rng, n_leaves, skew, dtype, ties=n_leaves % 2 == 1)
                    for ntask in (1, 2, 7, 64, 4096):
                        _same(b2, c2, bool(rng.random() < 0.7), ntask)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_parallel_collapse_of_degenerate_trees(threads):
    """One item (the root one leaf, child 1 the empty box), every item in one leaf, and a
    caterpillar of 2,000 levels (one node a level: the walk's top levels end without
    finding tasks enough)."""
    rng = np.random.default_rng(1)
    with _threads(threads):
        for pb in (np.array([[0.0, 0, 0, 1, 1, 1]]), np.tile([0.0, 0, 0, 1, 1, 1], (4, 1))):
            b2, c2, _, _ = bvh_build.build_flat_boxes(pb, packed=False)
            assert c2[0, 0] < 0 and b2[0, 6] > b2[0, 9]  # one leaf at the root
            for ntask in (1, 128):
                assert _same(b2, c2, True, ntask) == 1
        b2, c2 = _random_tree(rng, 2000, 1.0, np.float32)
        for ntask in (1, 3, 128):
            assert _same(b2, c2, True, ntask) > 600


@pytest.mark.parametrize("threads", [1, 2])
def test_built_meshes_collapse_alike(threads):
    """A large mesh's tree (the paired build) and a small one's, shuffled or not."""
    m = shapes.lumpy_sphere(70_000, name="x")
    verts = np.ascontiguousarray(m.vertices, np.float64)
    tris = np.ascontiguousarray(m.triangles, np.int32)
    rng = np.random.default_rng(3)
    with _threads(threads):
        for t in (tris, tris[rng.permutation(len(tris))], tris[:5000]):
            pb = bvh_mesh.indexed_boxes(verts, t)
            if len(t) >= bvh_build.PARALLEL_MIN:
                b2, c2, _, _ = bvh_cluster.build_paired(verts, t, pb)
            else:
                b2, c2, _, _ = bvh_build.build_flat_boxes(pb, packed=False)
            for ntask in (1, 16, bvh_mesh.COLLAPSE_TASKS):
                _same(b2, c2, True, ntask)


def _inner_rows(child) -> np.ndarray:
    """The inner rows a walk from the root reaches."""
    seen, stack = [], [0]
    while stack:
        for c in child[stack.pop()]:
            if c >= 0:
                seen.append(int(c))
                stack.append(int(c))
    return np.asarray(seen, np.int64)


def _open_reference(pb, starts, how, iperm, region0, trav_cost, root_area, bounds, child):
    """Main's ``open_items`` (one walk from the root, the split items' rows in the walk's
    order), in Python: ``bounds``, ``child`` changed in place; returns ``perm``."""
    rows = np.concatenate([[0], np.cumsum(np.diff(starts)[iperm])])
    perm = np.empty(starts[-1], np.int32)
    stack, node = [0], region0
    while stack:
        parent = stack.pop()
        for slot in range(2):
            c = int(child[parent, slot])
            if c >= 0:
                stack.append(c)
                continue
            code = ~c
            if code & 7 == 0:
                continue
            pos = code >> 3
            k = iperm[pos]
            row = int(rows[pos])
            a, cnt = int(starts[k]), int(starts[k + 1] - starts[k])
            if cnt == 1:
                perm[row] = a
                child[parent, slot] = ~((row << 3) | 1)
            elif how[k] == bvh_cluster.OPEN_LEAF:
                perm[row], perm[row + 1] = a, a + 1
                child[parent, slot] = ~((row << 3) | 2)
            else:
                b = a + 1
                if how[k] == bvh_cluster.OPEN_SPLIT_SWAPPED:
                    a, b = b, a
                child[parent, slot] = node
                perm[row], perm[row + 1] = a, b
                bounds[node, :6], bounds[node, 6:] = pb[a], pb[b]
                child[node] = ~((row << 3) | 1), ~(((row + 1) << 3) | 1)
                node += 1
    return perm


@pytest.mark.parametrize("threads", [1, 2])
def test_items_open_as_one_walk_from_the_root_opened_them(threads):
    """The parallel opening (any number of tasks) makes the tree the serial walk made:
    the same leaves, the same opened nodes (rows numbered in leaf order, not the walk's:
    the 4-wide tree is numbered on its own), the same 4-wide rows; and SAH costs equal
    to a few ulps (summed per task)."""
    m = shapes.lumpy_sphere(70_000, name="x")
    verts = np.ascontiguousarray(m.vertices, np.float64)
    tris = np.ascontiguousarray(m.triangles, np.int32)
    pb = bvh_mesh.indexed_boxes(verts, tris)
    trav = bvh_build.SAH_TRAVERSAL_COST
    starts, ib, how = bvh_cluster.pair_items(verts, tris, pb, trav)
    n_items, n_split = len(ib), int(np.count_nonzero(how))
    b0, c0, iperm, _ = bvh_build.build_flat_boxes(
        ib, 1, grain=bvh_build.subtree_grain(len(tris)), packed=False, spare=n_split,
        cheap_max=bvh_cluster.CHEAP_ALL)
    region0 = max(n_items, 2)
    rb, rc = b0.copy(), c0.copy()
    want_perm = _open_reference(pb, starts, how, iperm, region0, trav, 1.0, rb, rc)
    want = bvh_mesh.flatten(rb, rc, want_perm, np.float32)
    rows, nodes = bvh_cluster.item_leaves(starts, iperm, how)
    assert np.array_equal(rows, np.concatenate([[0], np.cumsum(np.diff(starts)[iperm])])[:-1])
    assert np.array_equal(nodes, np.concatenate([[0], np.cumsum(how[iperm] != 0)])[:-1])
    sahs = []
    with _threads(threads):
        for ntask in (1, 2, 5, bvh_cluster.OPEN_TASKS, 100_000):
            b, c, perm = b0.copy(), c0.copy(), np.empty(len(tris), np.int32)
            sahs.append(bvh_cluster.open_items(pb, starts, how, iperm, rows, nodes, region0,
                                               trav, 1.0, b, c, perm, ntask))
            assert np.array_equal(perm, want_perm)
            got = bvh_mesh.flatten(b, c, perm, np.float32, parallel=True)
            assert np.array_equal(got.child, want.child)
            assert np.array_equal(got.bounds.view(np.int32), want.bounds.view(np.int32))
            # the split items' rows: region0 .. in leaf order (of their first triangle)
            opened = _inner_rows(c)
            opened = np.sort(opened[opened >= region0])
            assert np.array_equal(opened, np.arange(region0, region0 + n_split))
            first_row = (~c[opened, 0].astype(np.int64)) >> 3
            assert np.all(np.diff(first_row) > 0)
    assert np.allclose(sahs, sahs[0], rtol=1e-12, atol=0.0)
