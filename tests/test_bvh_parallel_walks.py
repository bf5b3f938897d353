"""A large mesh's items opened on every thread (session 38): :func:`.bvh_cluster.open_items`
opens them as one walk from the root did (main's, in Python here), on any thread count and
any split of the tree into tasks. Fails on main (``item_leaves`` gave no node rows,
``open_items`` took no ``nodes``)."""

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
    starts, ib, how, _ = bvh_cluster.pair_items(verts, tris, pb, trav)
    n_items, n_split = len(ib), int(np.count_nonzero(how))
    b0, c0, iperm, _ = bvh_build.build_flat_boxes(
        ib, 1, grain=bvh_build.subtree_grain(len(tris)), packed=False, spare=n_split,
        cheap_max=bvh_cluster.CHEAP_ALL)
    region0 = max(n_items, 2)
    rb, rc = b0.copy(), c0.copy()
    want_perm = _open_reference(pb, starts, how, iperm, region0, trav, 1.0, rb, rc)
    want = bvh_mesh.flatten(rb, rc, want_perm, np.float32, tasks=0)
    rows, nodes = bvh_cluster.item_leaves(starts, iperm, how, np.empty(len(iperm), np.int32),
                                          np.empty(len(iperm), np.int32))
    assert np.array_equal(rows, np.concatenate([[0], np.cumsum(np.diff(starts)[iperm])])[:-1])
    assert np.array_equal(nodes, np.concatenate([[0], np.cumsum(how[iperm] != 0)])[:-1])
    sahs = []
    with _threads(threads):
        for ntask in (1, 2, 5, bvh_cluster.OPEN_TASKS, 100_000):
            b, c, perm = b0.copy(), c0.copy(), np.empty(len(tris), np.int32)
            sahs.append(bvh_cluster.open_items(pb, starts, how, iperm, rows, nodes, region0,
                                               trav, 1.0, b, c, perm, ntask))
            assert np.array_equal(perm, want_perm)
            got = bvh_mesh.flatten(b, c, perm, np.float32, tasks=0)
            assert np.array_equal(got.child, want.child)
            assert np.array_equal(got.bounds.view(np.int32), want.bounds.view(np.int32))
            # the split items' rows: region0 .. in leaf order (of their first triangle)
            opened = _inner_rows(c)
            opened = np.sort(opened[opened >= region0])
            assert np.array_equal(opened, np.arange(region0, region0 + n_split))
            first_row = (~c[opened, 0].astype(np.int64)) >> 3
            assert np.all(np.diff(first_row) > 0)
    assert np.allclose(sahs, sahs[0], rtol=1e-12, atol=0.0)


def _bounds_inputs():
    """Primitive boxes of many shapes: tiny, a chunk's edge, all one box, long and thin
    (one axis only), the extremes in the last chunk, float32 and float64, signed zeros
    in several chunks (:func:`_signed_zeros`)."""
    rng = np.random.default_rng(38)
    chunk = bvh_build.BIN_CHUNK
    for n in (1, 2, 7, chunk - 1, chunk, chunk + 1, 3 * chunk + 5):
        lo = rng.normal(size=(n, 3))
        yield np.concatenate([lo, lo + rng.random((n, 3))], axis=1)
    same = np.tile([1.0, 2.0, 3.0, 1.5, 2.5, 3.5], (2 * chunk + 3, 1))
    yield same
    t = np.linspace(-1e6, 1e6, 3 * chunk + 1)
    thin = np.zeros((len(t), 6))
    thin[:, 0], thin[:, 3] = t, t + 1e-9
    yield thin
    last = rng.random((4 * chunk, 6))
    last[:, 3:] += 1.0
    last[-1] = [-5.0, -6.0, -7.0, 9.0, 8.0, 7.0]
    yield last
    yield last.astype(np.float32)
    yield from _signed_zeros(chunk)


def _signed_zeros(chunk: int):
    """Boxes whose least (greatest) corner and centroid are 0.0 in one chunk and -0.0 in
    a later one (and the other way round): ``min`` / ``max`` keep the first of equal
    values, so only the one pass's order of combining gives one pass's bits."""
    for first, later in ((0.0, -0.0), (-0.0, 0.0)):
        pos = np.random.default_rng(5).random((3 * chunk, 6)) + 1.0
        pos[:, 3:] += 1.0
        pos[5], pos[chunk + 7], pos[2 * chunk + 1] = first, later, later
        yield pos
        neg = -pos[:, [3, 4, 5, 0, 1, 2]]  # (the greatest corner and centroid: zeros)
        yield neg


@pytest.mark.parametrize("threads", [1, 2])
def test_the_roots_bounds_in_chunks_are_one_threads(threads):
    """The root's box and centroid bounds of the top levels, per chunk on every thread
    (``_bounds_chunks``, session 38), are the values one pass finds, bit for bit. Fails on
    main (no ``_bounds_chunks``: the root's bounds were one serial pass)."""
    for pb in _bounds_inputs():
        want_box, want_cb = np.empty(6), np.empty(6)
        bvh_build._range_bounds(pb, 0, len(pb), want_box, want_cb)
        box, cb = np.empty(6), np.empty(6)
        with _threads(threads):
            bvh_build._bounds_chunks(pb, box, cb)
        assert box.tobytes() == want_box.tobytes()
        assert cb.tobytes() == want_cb.tobytes()


def test_the_top_levels_are_the_same_on_one_and_two_threads_and_any_grain():
    """``split_top`` past one level (the root's bounds in chunks) gives the same top nodes,
    tasks and SAH on 1 and 2 threads, and the whole tree is the one-thread build's
    (``grain >= n``: the root's bounds in one pass) on long thin and tied inputs too."""
    for pb in _bounds_inputs():
        n = len(pb)
        if n < 64:
            continue
        seq = bvh_build.build_flat_boxes(pb.copy(), grain=n)
        ref = bvh_mesh.flatten(*seq[:3], tasks=0)
        for threads in (1, 2):
            with _threads(threads):
                got = bvh_build.build_flat_boxes(pb.copy(), grain=max(n // 8, 8))
            par = bvh_mesh.flatten(*got[:3], tasks=0)  # (numbered depth first, as ref)
            assert par.bounds.tobytes() == ref.bounds.tobytes()
            assert np.array_equal(par.child, ref.child)
            assert np.array_equal(par.perm, ref.perm)
            assert got[3] == pytest.approx(seq[3], rel=1e-12)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_items_root_bounds_are_one_pass_over_their_boxes(threads):
    """``pair_items`` gives the items' box and centroid bounds (per chunk of pairs, session
    38: the item build's root then needs no pass of its own), the values one pass over the
    items' boxes finds bit for bit, on 1, 2, 3 triangles, an odd count across chunks,
    shuffled, long thin, all-coincident meshes and signed zeros in several chunks, on 1
    and 2 threads. Fails on main
    (``pair_items`` gave three arrays)."""
    rng = np.random.default_rng(26)
    chunk = 2 * bvh_cluster.PAIR_CHUNK
    mesh = shapes.lumpy_sphere(40_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int32)
    cases = [(verts, tris[:k]) for k in (1, 2, 3, chunk - 1, chunk + 3)]
    cases.append((verts, tris[rng.permutation(len(tris))]))
    t = np.linspace(-1e6, 1e6, chunk + 5)
    thin = np.stack([t, 0 * t, 0 * t], 1)
    cases.append((np.concatenate([thin, thin + [1e-9, 1e-9, 0.0]]),
                  np.stack([np.arange(len(t) - 1), np.arange(1, len(t)),
                            len(t) + np.arange(len(t) - 1)], 1).astype(np.int32)))
    cases.append((np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]),
                  np.zeros((2 * chunk + 1, 3), np.int32) + [0, 1, 2]))
    # the items' least corner (and centroid) 0.0 in one chunk of pairs, -0.0 in a later one
    # (and the other way round): one pass's bits only from combining in chunk order
    far = np.concatenate([verts + 10.0, [[0.0, 0.0, 0.0], [-0.0, -0.0, -0.0]]])
    for first in (0, 1):
        tr = tris[np.arange(2 * chunk + 9) % len(tris)].copy()
        for row, z in ((3, first), (chunk + 11, 1 - first), (2 * chunk + 1, 1 - first)):
            tr[row] = len(verts) + z  # (a point at that zero)
        cases.append((far, tr))
    for e, (v, tr) in enumerate(cases):
        pb = bvh_mesh.indexed_boxes(v, tr)
        with _threads(threads):
            _, ib, _, root = bvh_cluster.pair_items(v, tr, pb, 1.0)
        box, cb = np.empty(6), np.empty(6)
        bvh_build._range_bounds(ib, 0, len(ib), box, cb)
        assert root.tobytes() == np.concatenate([box, cb]).tobytes()
        if v is far:  # (the zeros are the items' least corner: the first one's sign)
            assert root[0] == 0.0 and np.signbit(root[0]) == (e == len(cases) - 1)


def test_the_item_tree_over_pair_items_root_is_the_one_split_top_bounds_itself():
    """The item tree built with ``pair_items``' root bounds (session 38) is the tree
    ``split_top`` builds finding them itself (``root=None``), bit for bit, shuffled too,
    on 1 and 2 threads."""
    mesh = shapes.lumpy_sphere(70_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int32)
    rng = np.random.default_rng(38)
    for tr in (tris, tris[rng.permutation(len(tris))]):
        pb = bvh_mesh.indexed_boxes(verts, tr)
        _, ib, _, root = bvh_cluster.pair_items(verts, tr, pb, 1.0)
        grain = bvh_build.subtree_grain(len(tr))
        ref = bvh_mesh.flatten(*bvh_build.build_flat_boxes(ib.copy(), 1, grain=grain)[:3],
                               tasks=0)
        for threads in (1, 2):
            with _threads(threads):
                got = bvh_build.build_flat_boxes(ib.copy(), 1, grain=grain, root=root)
            par = bvh_mesh.flatten(*got[:3], tasks=0)
            assert par.bounds.tobytes() == ref.bounds.tobytes()
            assert np.array_equal(par.child, ref.child)
            assert np.array_equal(par.perm, ref.perm)
