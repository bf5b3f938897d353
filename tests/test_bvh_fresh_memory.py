"""Less fresh memory in a large mesh's paired build (session 39, issue 26): the items'
triangle starts are int32, every item's ``how`` is written (no zero fill), each chunk of
pairs finds its first item from the chunks' counts (no (half,) int64 prefix), and the item
leaves' rows and nodes live in the item boxes' memory, dead once the item tree is built.
The tree stays the one fresh arrays give."""

from __future__ import annotations

import contextlib
import ctypes

import numba
import numpy as np
import pytest

from rstrace_engine.accel import bvh_build, bvh_cluster, bvh_mesh
from tests.test_bvh_pairs import _lumpy, _pair_starts, _soup

#: glibc's ``mallopt`` option: memory ``malloc`` returns (numba's ``np.empty`` too) is
#: filled with the given byte ^ 0xFF, so an unwritten element reads that, never a zero
#: a fresh page happened to hold.
_M_PERTURB = -6
_PERTURB = 0xA5  # (fresh bytes then read 0x5A = 90: no OPEN_* value)


@numba.njit
def _fresh(n):
    return np.empty(n, np.int8)


@contextlib.contextmanager
def _dirty_fresh_memory():
    """Yields True while every fresh allocation of this process is filled with
    ``_PERTURB ^ 0xFF`` (glibc's ``M_PERTURB``: checked on a numba ``np.empty``); False
    where the C library has no such option (nothing changed)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        yield False
        return
    if not mallopt(_M_PERTURB, _PERTURB):
        yield False
        return
    try:
        assert np.all(_fresh(1 << 20) == (_PERTURB ^ 0xFF))  # (a 1 MiB mmap'd block too)
        assert np.all(_fresh(3000) == (_PERTURB ^ 0xFF))
        yield True
    finally:
        mallopt(_M_PERTURB, 0)


def test_pair_items_starts_are_int32_and_every_how_is_written_across_chunks():
    """Over several chunks of pairs (:data:`.bvh_cluster.PAIR_CHUNK`), odd count, pairs
    and lone triangles mixed: the starts are the reference's, int32 (fails on main: int64),
    and a lone triangle's item is :data:`OPEN_LEAF`, a pair's one of the three ways. The
    items' fresh memory is filled with a byte no ``how`` takes (glibc), so a dropped
    write of any item's ``how`` fails here whatever the pages held (:data:`OPEN_LEAF` is
    0: fresh zero pages passed it before)."""
    rng = np.random.default_rng(39)
    verts, tris = _soup(rng, 3 * 2 * bvh_cluster.PAIR_CHUNK + 7)
    pb = bvh_mesh.indexed_boxes(verts, tris)
    with _dirty_fresh_memory():
        starts, boxes, how, _ = bvh_cluster.pair_items(verts, tris, pb, 1.0)
    assert starts.dtype == np.int32 and how.dtype == np.int8
    assert starts.tolist() == _pair_starts(verts, tris)
    cnt = np.diff(starts)
    assert np.all(how[cnt == 1] == bvh_cluster.OPEN_LEAF)
    assert set(np.unique(how[cnt == 2]).tolist()) <= {
        bvh_cluster.OPEN_LEAF, bvh_cluster.OPEN_SPLIT, bvh_cluster.OPEN_SPLIT_SWAPPED}
    a = starts[:-1]
    b = np.where(cnt == 2, a + 1, a)
    assert np.array_equal(boxes[:, :3], np.minimum(pb[a, :3], pb[b, :3]))
    assert np.array_equal(boxes[:, 3:], np.maximum(pb[a, 3:], pb[b, 3:]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_item_scratch_is_two_disjoint_int32_arrays_in_the_item_boxes(dtype):
    ib = np.empty((1001, 6), dtype)
    rows, nodes = bvh_cluster.item_scratch(ib)
    assert rows.dtype == nodes.dtype == np.int32 and len(rows) == len(nodes) == len(ib)
    assert np.shares_memory(rows, ib) and np.shares_memory(nodes, ib)
    assert not np.shares_memory(rows, nodes)
    with pytest.raises(ValueError, match="C-contiguous"):  # (a copy would not be ib's)
        bvh_cluster.item_scratch(np.empty((1001, 12), dtype)[:, :6])


def test_the_tree_over_reused_item_boxes_is_the_tree_over_fresh_arrays(monkeypatch):
    """``build_paired`` with the item leaves' rows and nodes in the item boxes' memory
    makes the tree (boxes, children, leaf order, SAH) that fresh arrays make."""
    verts, tris = _lumpy()
    assert len(tris) >= bvh_build.PARALLEL_MIN
    pb = bvh_mesh.indexed_boxes(verts, tris)
    reused = bvh_cluster.build_paired(verts, tris, pb.copy())
    monkeypatch.setattr(bvh_cluster, "item_scratch", lambda ib: (
        np.full(len(ib), -7, np.int32), np.full(len(ib), -7, np.int32)))
    fresh = bvh_cluster.build_paired(verts, tris, pb.copy())
    rows = _reached(fresh[1])
    assert np.array_equal(reused[1][rows], fresh[1][rows])
    assert np.array_equal(reused[0][rows].view(np.int32), fresh[0][rows].view(np.int32))
    assert np.array_equal(reused[2], fresh[2]) and reused[3] == fresh[3]


def _reached(child: np.ndarray) -> np.ndarray:
    """The rows a walk from row 0 reaches (the others are unset)."""
    out, todo = [], [0]
    while todo:
        r = todo.pop()
        out.append(r)
        todo.extend(int(c) for c in child[r] if c >= 0)
    return np.sort(np.array(out))
