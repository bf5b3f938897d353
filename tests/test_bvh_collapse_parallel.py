"""The 4-wide collapse on every thread (session 40, issue 26):
:func:`.bvh_collapse.collapse4_parallel` makes :func:`.bvh_mesh.collapse4`'s tree (the same
boxes bit for bit, lanes and leaves, walked from the root; other rows, the unused ones
empty nodes), whatever the split into subtrees and the thread count, on tiny, degenerate
and large trees, and on trees whose subtrees outgrow their rooms. Fails on main (no
``bvh_collapse``, ``flatten`` took no ``tasks``)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rstrace_engine.accel import bvh_build, bvh_cluster, bvh_collapse, bvh_mesh
from rstrace_engine.geometry import shapes
from tests.test_bvh_parallel_walks import _threads


def _spy_parallel_collapse(monkeypatch) -> list:
    """Record each call :func:`.bvh_mesh.flatten` makes of
    :func:`.bvh_collapse.collapse4_parallel` (its number of subtrees), and run it."""
    calls = []
    real = bvh_collapse.collapse4_parallel

    def spy(*args):
        calls.append(len(args[-2]))
        return real(*args)

    monkeypatch.setattr(bvh_mesh, "collapse4_parallel", spy)
    return calls


def _boxes(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.concatenate([lo, hi], 1).astype(np.float64)


def _cases():
    rng = np.random.default_rng(40)
    out = {}
    for n in (1, 2, 3, 5, 17):
        lo = rng.normal(size=(n, 3))
        out[f"random{n}"] = _boxes(lo, lo + rng.random((n, 3)))
    same = np.tile([[0.5, -1.0, 2.0]], (40, 1))
    out["one box 40 times"] = _boxes(same, same + 1.0)
    out["points"] = _boxes(same, same)  # zero-size boxes, all at one place
    flat = rng.normal(size=(300, 3))
    flat[:, 2] = 0.0
    out["flat"] = _boxes(flat, flat + [0.1, 0.1, 0.0])  # zero thickness in z
    lo = rng.normal(size=(5000, 3)) * 100
    out["random5000"] = _boxes(lo, lo + rng.random((5000, 3)))
    return out


CASES = _cases()


def _walk(f: bvh_mesh.FlatBVH) -> tuple[np.ndarray, np.ndarray]:
    """The tree as a walk from the root reads it (depth first, lanes in order): each
    reached node's bounds' bits and child codes, inner ones as the walk's numbering."""
    order, stack = [], [0]
    while stack:
        r = stack.pop()
        order.append(r)
        stack.extend(int(c) for c in f.child[r][::-1] if c >= 0)
    order = np.asarray(order, np.int64)
    at = np.full(len(f.child), -1, np.int64)
    at[order] = np.arange(len(order))
    child = f.child[order].astype(np.int64)
    child[child >= 0] = at[child[child >= 0]]
    bits = f.bounds.view(np.int32 if f.bounds.dtype == np.float32 else np.int64)
    return bits[order], child


def _same(a: bvh_mesh.FlatBVH, b: bvh_mesh.FlatBVH) -> None:
    """The same tree: the same boxes (bit for bit), lanes and leaves, walked from the
    root (rows may differ: the parallel collapse leaves unreached rows)."""
    assert a.bounds.dtype == b.bounds.dtype
    (ba, ca), (bb, cb) = _walk(a), _walk(b)
    assert np.array_equal(ba, bb) and np.array_equal(ca, cb)
    assert np.array_equal(a.perm, b.perm)
    for f in (a, b):  # rows no child reaches: empty nodes
        unreached = np.ones(len(f.child), bool)
        unreached[_reached(f.child)] = False
        assert np.all(f.child[unreached] == -1)
        assert np.all(f.bounds[unreached][:, :12] == np.inf)
        assert np.all(f.bounds[unreached][:, 12:] == -np.inf)


def _reached(child: np.ndarray) -> np.ndarray:
    inner = child[child >= 0]
    return np.concatenate([[0], inner]).astype(np.int64)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name", sorted(CASES))
def test_the_parallel_collapse_makes_the_serial_ones_tree(name, threads):
    pb = CASES[name]
    for packed in (False, True):
        b, c, p, _ = bvh_build.build_flat_boxes(pb.copy(), packed=packed)
        for dtype in (np.float32, np.float64):
            want = bvh_mesh.flatten(b, c, p, dtype, tasks=0)
            with _threads(threads):
                for tasks in (1, 2, 3, 8, 64, 1000):
                    _same(bvh_mesh.flatten(b, c, p, dtype, tasks=tasks), want)


def test_the_tasks_are_disjoint_subtrees_below_the_root():
    """:func:`.bvh_collapse.collapse_tasks`: about as many 4-wide roots as asked, each an inner
    binary node, none inside another's subtree (else rows would be made twice)."""
    b, c, p, _ = bvh_build.build_flat_boxes(CASES["random5000"].copy(), packed=False)
    for want in (1, 4, 64, 256):
        t, n_top = bvh_collapse.collapse_tasks(b, c, True, want)
        assert n_top >= (0 if want == 1 else 1)
        assert len(t) >= min(want, 4) and np.all(np.diff(t) > 0) and np.all(t >= 0)
        seen = set()
        for r in t:  # the binary nodes under each task
            stack = [int(r)]
            while stack:
                n = stack.pop()
                assert n not in seen
                seen.add(n)
                stack.extend(int(x) for x in c[n] if x >= 0)


@pytest.mark.parametrize("threads", [1, 2])
def test_a_large_mesh_takes_the_parallel_collapse_and_gets_the_serial_tree(threads,
                                                                          monkeypatch):
    m = shapes.lumpy_sphere(70_000, name="x")
    verts = np.ascontiguousarray(m.vertices, np.float64)
    tris = np.ascontiguousarray(m.triangles, np.int32)
    pb = bvh_mesh.indexed_boxes(verts, tris)
    b, c, p, _ = bvh_cluster.build_paired(verts, tris, pb,
                                          grain=bvh_build.subtree_grain(len(tris)))
    assert len(c) >= bvh_collapse.COLLAPSE_PARALLEL_MIN
    want = bvh_mesh.flatten(b, c, p, np.float32, tasks=0)
    calls = _spy_parallel_collapse(monkeypatch)
    with _threads(threads):
        got = bvh_mesh.flatten(b, c, p, np.float32)
        _same(got, want)
        built = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    _same(built.bvh, want)
    # two threads: the parallel collapse, in tasks; one: the serial one
    assert (calls and min(calls) > 1) if threads == 2 else not calls


def _complete_tree(depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A complete binary tree of ``depth`` inner levels over one-box leaves (numbered
    breadth first, left to right): the 4-wide nodes open two levels at a time, those of
    an odd depth's last level one binary node each: 1.5 inner binary nodes a 4-wide node,
    far fewer than a mesh's tree has (about 2)."""
    n = (1 << depth) - 1
    leaf_lo = np.zeros((n + 1, 3))  # unit boxes in a row: a node's area halves a level
    leaf_lo[:, 0] = np.arange(n + 1)
    leaf_hi = leaf_lo + 1.0
    child = np.empty((n, 2), np.int32)
    b2 = np.empty((n, 12))
    lo = np.empty((2 * n + 1, 3))
    hi = np.empty((2 * n + 1, 3))
    for i in range(n, 2 * n + 1):  # heap numbering: node i's children 2i+1, 2i+2
        lo[i], hi[i] = leaf_lo[i - n], leaf_hi[i - n]
    for i in range(n - 1, -1, -1):
        for j, c in enumerate((2 * i + 1, 2 * i + 2)):
            child[i, j] = c if c < n else ~((c - n) << 3 | 1)
            b2[i, 6 * j:6 * j + 3], b2[i, 6 * j + 3:6 * j + 6] = lo[c], hi[c]
        lo[i], hi[i] = np.minimum(lo[2 * i + 1], lo[2 * i + 2]), np.maximum(
            hi[2 * i + 1], hi[2 * i + 2])
    return b2, child, np.arange(n + 1, dtype=np.int32)


def _two_trees(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A root over :func:`_complete_tree` ``a`` (left) and ``b`` (right, its leaves
    further along x)."""
    (b2a, ca, _), (b2b, cb, _) = _complete_tree(a), _complete_tree(b)
    na, nb = len(ca), len(cb)
    b2b = b2b.copy()
    b2b[:, [0, 3, 6, 9]] += na + 1
    shift = lambda c, rows, leaves: np.where(c >= 0, c + rows, ~((~c) + (leaves << 3)))  # noqa: E731
    child = np.concatenate([[[1, 1 + na]], shift(ca, 1, 0), shift(cb, 1 + na, na + 1)])
    root = np.concatenate([b2a[0, :3].clip(max=b2a[0, 6:9]), b2a[0, 9:12]]), \
        np.concatenate([b2b[0, :3].clip(max=b2b[0, 6:9]), b2b[0, 9:12]])
    b2 = np.concatenate([[np.concatenate(root)], b2a, b2b])
    return b2, child.astype(np.int32), np.arange(na + nb + 2, dtype=np.int32)


@pytest.mark.parametrize("threads", [1, 2])
def test_a_subtree_past_its_room_is_made_again_after_the_others(threads):
    """Subtrees the first rooms (:func:`.bvh_collapse._room`: a mesh's ratio) are too small
    for (complete trees of odd depth: 1.5 binary nodes a 4-wide one) are made again in
    rooms after the others'; the tree is the serial one. Where even that would not fit
    (every subtree past its room), the serial collapse makes it."""
    for b2, c2, perm, want_tasks, redone in (_two_trees(10, 9) + (8, True),
                                             _complete_tree(11) + (8, False)):
        want = bvh_mesh.flatten(b2, c2, perm, np.float32, tasks=0)
        with _threads(threads):
            tb, n_top = bvh_collapse.collapse_tasks(b2, c2, True, want_tasks)
            room = np.array([bvh_collapse._room(bvh_collapse._inner_count(c2, t)) for t in tb])
            fits = bvh_collapse._subtrees(b2, c2, np.empty((len(c2), 24), np.float32),
                                      np.empty((len(c2), 4), np.int32), True, tb,
                                      np.zeros(len(tb), np.int64), room) >= 0
            assert not fits.all()
            *_, m = bvh_collapse.collapse4_parallel(
                b2, c2, np.empty((len(c2), 24), np.float32), True, tb, n_top)
            assert (m > 0) if redone else (m == -1)
            _same(bvh_mesh.flatten(b2, c2, perm, np.float32, tasks=want_tasks), want)


def test_a_build_below_parallel_min_starts_no_parallel_collapse(monkeypatch):
    """Below :data:`.bvh_build.PARALLEL_MIN` primitives a build runs on one thread with no
    parallel region (:func:`.bvh_mesh.build_mesh_bvh`, :func:`.bvh_mesh.build_top`; the
    parallel collapse's kernels are :data:`.bvh_build.LARGE_BUILD_KERNELS`, not the first
    image's), though the builder's unpacked arrays there have a row a primitive: a mesh of
    40,000 triangles (or a top level of 40,000 objects) has 40,000 rows, past
    :data:`.bvh_collapse.COLLAPSE_PARALLEL_MIN`. Fails on s40-int (flatten counted rows)."""
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one numba thread: the collapse is serial whatever the size")
    m = shapes.lumpy_sphere(40_000, name="x")
    tv = np.asarray(m.vertices, np.float64)[m.triangles]
    assert bvh_collapse.COLLAPSE_PARALLEL_MIN <= len(tv) < bvh_build.PARALLEL_MIN
    rng = np.random.default_rng(7)
    lo = rng.normal(size=(40_000, 3)) * 50
    boxes = np.stack([lo, lo + rng.random((40_000, 3))], axis=1)
    calls = _spy_parallel_collapse(monkeypatch)
    with _threads(2):
        mb = bvh_mesh.build_mesh_bvh(tv)
        top = bvh_mesh.build_top(boxes)
    assert not calls
    # (one thread's tree: every row reached from the root, none left empty)
    for f in (mb.bvh, top):
        assert len(_reached(f.child)) == len(f.child)
