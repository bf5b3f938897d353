"""The RI-tree's 4D kd-trees: node and sample pools, splits, LRU pruning (seed 004, 2.2-2.3).

Lines are parameterised as in the linetrees (:mod:`..interpolants.linetree`): face pair
``f`` of an object's expanded box, coordinates ``(a, b, c, d)`` in ``[0, 1]^4`` (front-face
intercept ``(a, b)``, back-face intercept ``(c, d)``). One kd-tree per (instance, face pair),
created on demand; its root cell is the whole ``[0, 1]^4``.

A node is a 4D box ``lo <= abcd <= hi`` with the ids of its 16 *corner samples* (corner
``q``: bit ``m`` set = upper end of coordinate ``m``). Splitting a leaf cuts its longest
axis (measured in world units on the faces) at the midpoint: the two children are allocated
as a pair (``child`` and ``child + 1``, the lower half first), each inherits the 8 parent
corners on its side and both share 8 new samples on the cut. A leaf is ``OPEN`` (its
subdivision is not finished: the next query through it continues it) or ``FINAL`` (it
passed the distance test or reached the depth constraint; its patch classes and angular test
are recorded with it, :mod:`.patches`). Samples live in a pool of their own and are shared
between nodes by id.

LRU: every query stamps the nodes on its path with the query batch's counter, so a node's
stamp is the newest of its subtree. :meth:`KdForest.prune` keeps the most recently used
nodes: it cuts every pair of children whose stamps are both older than a cut-off (the parent
becomes an ``OPEN`` leaf again, its corners kept), drops trees whose root is older, and frees
every sample no live node references.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np
from numba import njit

log = logging.getLogger(__name__)

N_FACES = 6
DEAD, OPEN, FINAL, INNER = -1, 0, 1, 2


class Nodes(NamedTuple):
    """The node pool of all kd-trees of one cache (capacity ``N``)."""

    lo: np.ndarray  # (N, 4) float64 cell lower corner in line coordinates
    hi: np.ndarray  # (N, 4) float64 upper corner
    corner: np.ndarray  # (N, 16) int32 sample ids of the 16 corners
    child: np.ndarray  # (N,) int32 first of the two children, -1 for a leaf
    parent: np.ndarray  # (N,) int32, -1 for a root
    axis: np.ndarray  # (N,) int8 split axis of an inner node
    depth: np.ndarray  # (N,) int16
    state: np.ndarray  # (N,) int8 DEAD, OPEN, FINAL or INNER
    stamp: np.ndarray  # (N,) int64 last query batch that passed through the node
    tree: np.ndarray  # (N,) int32 instance * 6 + face pair
    nclass: np.ndarray  # (N,) int8 patch classes among the corners of a FINAL leaf (1, 2, 3+)
    cls: np.ndarray  # (N, 2) int32 the (first) two classes
    ang_ok: np.ndarray  # (N,) uint8 bit k: class k passes the angular threshold
    visits: np.ndarray  # (N,) int32 queries that reached the node while it was an OPEN leaf


def _alloc_nodes(cap: int) -> Nodes:
    return Nodes(np.zeros((cap, 4)), np.ones((cap, 4)), np.full((cap, 16), -1, np.int32),
                 np.full(cap, -1, np.int32), np.full(cap, -1, np.int32),
                 np.zeros(cap, np.int8), np.zeros(cap, np.int16),
                 np.full(cap, DEAD, np.int8), np.zeros(cap, np.int64),
                 np.full(cap, -1, np.int32), np.zeros(cap, np.int8),
                 np.full((cap, 2), -1, np.int32), np.zeros(cap, np.uint8),
                 np.zeros(cap, np.int32))


#: bytes of one node (the fields of :class:`Nodes`)
NODE_BYTES = 32 + 32 + 64 + 4 + 4 + 1 + 2 + 1 + 8 + 4 + 1 + 8 + 1 + 4


# ----------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True)
def descend(nd, start, abcd, stamp, out):
    """Leaf holding each line: from node ``start[r]`` (a root) down by ``abcd[r]``.

    start (n,) int32; abcd (n, 4) float64; stamps every node passed with ``stamp``;
    out (n,) int32 leaves. A coordinate on a cut goes to the upper child.
    """
    for r in range(start.shape[0]):
        x = start[r]
        nd.stamp[x] = stamp
        while nd.child[x] >= 0:
            m = nd.axis[x]
            mid = 0.5 * (nd.lo[x, m] + nd.hi[x, m])
            x = nd.child[x] + (1 if abcd[r, m] >= mid else 0)
            nd.stamp[x] = stamp
        out[r] = x


@njit(cache=True, nogil=True)
def split_leaves(nd, parents, first, new_ids, wscale, lines):
    """Split each leaf ``parents[q]`` at the midpoint of its longest axis.

    first (k,) int32 id of the children pair (``first``, ``first + 1``); new_ids (k, 8)
    int32 the 8 new samples on the cut; wscale (k, 4) float64 world length of one unit of
    each coordinate (the face widths). Outputs lines (k, 8, 4) float64: the new samples'
    line coordinates (the caller traces them).
    """
    for q in range(parents.shape[0]):
        p = parents[q]
        best = -1.0
        m = 0
        for a in range(4):
            ln = (nd.hi[p, a] - nd.lo[p, a]) * wscale[q, a]
            if ln > best:
                best = ln
                m = a
        mid = 0.5 * (nd.lo[p, m] + nd.hi[p, m])
        c0 = np.int64(first[q])
        c1 = c0 + 1
        nd.child[p] = c0
        nd.axis[p] = m
        nd.state[p] = INNER
        for c in (c0, c1):
            nd.child[c] = -1
            nd.parent[c] = p
            nd.depth[c] = nd.depth[p] + 1
            nd.state[c] = OPEN
            nd.stamp[c] = nd.stamp[p]
            nd.tree[c] = nd.tree[p]
            nd.nclass[c] = 0
            nd.ang_ok[c] = 0
            nd.visits[c] = 0
            for a in range(4):
                nd.lo[c, a] = nd.lo[p, a]
                nd.hi[c, a] = nd.hi[p, a]
        nd.hi[c0, m] = mid
        nd.lo[c1, m] = mid
        for corner in range(16):
            # index of this corner's position on the cut among the 8 new samples
            r = 0
            k = 0
            for a in range(4):
                if a != m:
                    r |= ((corner >> a) & 1) << k
                    k += 1
            upper = (corner >> m) & 1
            sid = new_ids[q, r]
            if upper == 0:
                nd.corner[c0, corner] = nd.corner[p, corner]
                nd.corner[c1, corner] = sid
                for a in range(4):
                    if a == m:
                        lines[q, r, a] = mid
                    else:
                        lines[q, r, a] = nd.hi[p, a] if (corner >> a) & 1 else nd.lo[p, a]
            else:
                nd.corner[c1, corner] = nd.corner[p, corner]
                nd.corner[c0, corner] = sid


@njit(cache=True, nogil=True)
def _kill_subtree(nd, root, freed, nf):
    """Mark ``root``'s subtree DEAD; the first ids of freed child pairs go to ``freed``."""
    stack = [np.int64(root)]
    while len(stack):
        x = stack.pop()
        c = np.int64(nd.child[x])
        if c >= 0:
            freed[nf] = c
            nf += 1
            stack.append(c)
            stack.append(c + 1)
        nd.state[x] = DEAD
        nd.child[x] = -1
    return nf


@njit(cache=True, nogil=True)
def prune_pass(nd, n_nodes, cutoff, freed):
    """Cut every pair of children both stamped before ``cutoff`` (see the module doc).

    Returns the number of child pairs freed (their first ids in ``freed``).
    """
    nf = 0
    for p in range(n_nodes):
        if nd.state[p] != INNER:
            continue
        c = nd.child[p]
        if nd.stamp[c] < cutoff and nd.stamp[c + 1] < cutoff:
            nf = _kill_subtree(nd, c, freed, nf)
            nf = _kill_subtree(nd, c + 1, freed, nf)
            freed[nf] = c
            nf += 1
            nd.child[p] = -1
            nd.state[p] = OPEN
    return nf


@njit(cache=True, nogil=True)
def mark_samples(nd, n_nodes, used):
    """used[s] = True for every sample a live node references."""
    for x in range(n_nodes):
        if nd.state[x] == DEAD:
            continue
        for q in range(16):
            s = nd.corner[x, q]
            if s >= 0:
                used[s] = True


# ----------------------------------------------------------------------------- the pools


class KdForest:
    """Owner of the node pool and of sample ids: roots, growth, free lists, pruning.

    The sample *attributes* are stored by the cache (:mod:`.sampling` defines them); this
    class hands out and takes back their ids (``sample_capacity`` grows with
    :meth:`alloc_samples`, the cache resizes its arrays to match).
    """

    def __init__(self, n_instances: int, capacity: int = 1024) -> None:
        self.roots = np.full((max(int(n_instances), 0), N_FACES), -1, np.int32)
        self.nodes = _alloc_nodes(max(int(capacity), 2))
        self.n_nodes = 0
        self._free_pairs: list[int] = []
        self._free_roots: list[int] = []
        self.n_samples = 0  # high-water mark of sample ids
        self._free_samples: list[int] = []
        self.stamp = 0

    # -- growth --------------------------------------------------------------------------

    def _reserve(self, extra: int) -> None:
        need = self.n_nodes + extra
        cap = len(self.nodes.child)
        if need <= cap:
            return
        new = _alloc_nodes(max(need, 2 * cap))
        for old, fresh in zip(self.nodes, new, strict=True):
            fresh[:cap] = old
        self.nodes = new

    def alloc_pairs(self, k: int) -> np.ndarray:
        """First ids of ``k`` child pairs: (k,) int32."""
        reuse = min(k, len(self._free_pairs))
        out = np.empty(k, np.int32)
        if reuse:
            out[:reuse] = self._free_pairs[-reuse:]
            del self._free_pairs[-reuse:]
        fresh = k - reuse
        self._reserve(2 * fresh)
        out[reuse:] = self.n_nodes + 2 * np.arange(fresh, dtype=np.int32)
        self.n_nodes += 2 * fresh
        return out

    def alloc_samples(self, k: int) -> np.ndarray:
        """``k`` sample ids: (k,) int32 (recycled ids first)."""
        reuse = min(k, len(self._free_samples))
        out = np.empty(k, np.int32)
        if reuse:
            out[:reuse] = self._free_samples[-reuse:]
            del self._free_samples[-reuse:]
        fresh = k - reuse
        out[reuse:] = self.n_samples + np.arange(fresh, dtype=np.int32)
        self.n_samples += fresh
        return out

    def new_roots(self, keys: np.ndarray, corner_ids: np.ndarray) -> np.ndarray:
        """Create the roots of trees ``keys`` (inst * 6 + face, unique, not existing) with
        corner samples ``corner_ids`` (k, 16). Returns their node ids."""
        k = len(keys)
        ids = np.empty(k, np.int32)
        for q in range(k):
            if self._free_roots:
                ids[q] = self._free_roots.pop()
            else:
                self._reserve(1)
                ids[q] = self.n_nodes
                self.n_nodes += 1
        nd = self.nodes
        nd.lo[ids] = 0.0
        nd.hi[ids] = 1.0
        nd.corner[ids] = corner_ids
        nd.child[ids] = -1
        nd.parent[ids] = -1
        nd.depth[ids] = 0
        nd.state[ids] = OPEN
        nd.stamp[ids] = self.stamp
        nd.tree[ids] = keys
        nd.nclass[ids] = 0
        nd.visits[ids] = 0
        self.roots.reshape(-1)[keys] = ids
        return ids

    # -- accounting ----------------------------------------------------------------------

    @property
    def live_nodes(self) -> int:
        return int(np.count_nonzero(self.nodes.state[:self.n_nodes] != DEAD))

    @property
    def live_samples(self) -> int:
        return self.n_samples - len(self._free_samples)

    # -- pruning and invalidation ----------------------------------------------------------

    def _drop_roots(self, root_ids: np.ndarray) -> None:
        nd = self.nodes
        freed = np.empty(max(self.n_nodes, 1), np.int32)
        flat = self.roots.reshape(-1)
        for x in root_ids:
            x = int(x)
            nf = _kill_subtree(nd, x, freed, 0)
            self._free_pairs.extend(int(c) for c in freed[:nf])
            flat[nd.tree[x]] = -1
            self._free_roots.append(x)

    def collect_samples(self, held=None) -> np.ndarray:
        """Free every sample no live node references (nor ``held``: ids the caller still
        uses, such as midpoints traced ahead); returns the freed ids."""
        used = np.zeros(max(self.n_samples, 1), np.bool_)
        mark_samples(self.nodes, self.n_nodes, used)
        if held is not None and len(held):
            used[np.asarray(held, np.int64)] = True
        free = np.zeros(max(self.n_samples, 1), np.bool_)
        if self._free_samples:
            free[np.asarray(self._free_samples)] = True
        dead = np.flatnonzero(~used[:self.n_samples] & ~free[:self.n_samples])
        self._free_samples.extend(int(s) for s in dead)
        return dead

    def prune(self, cutoff: int, held=None) -> None:
        """Cut everything last used before stamp ``cutoff`` (module doc); free samples
        (except ``held``, see :meth:`collect_samples`)."""
        nd = self.nodes
        flat = self.roots.reshape(-1)
        live = flat[flat >= 0]
        old = live[nd.stamp[live] < cutoff]
        if len(old):
            self._drop_roots(old)
        freed = np.empty(max(self.n_nodes, 1), np.int32)
        nf = prune_pass(nd, self.n_nodes, cutoff, freed)
        self._free_pairs.extend(int(c) for c in freed[:nf])
        self.collect_samples(held)

    def invalidate(self, instances) -> int:
        """Drop every tree of the given instance slots; returns the number of trees."""
        inst = np.asarray(list(instances), np.int64).reshape(-1)
        inst = inst[(inst >= 0) & (inst < len(self.roots))]
        ids = self.roots[inst].reshape(-1)
        ids = ids[ids >= 0]
        if len(ids):
            self._drop_roots(ids)
            self.collect_samples()
        return len(ids)

    def cutoff_for(self, keep_nodes: int) -> int:
        """The stamp cut-off that keeps about the ``keep_nodes`` most recently used nodes."""
        st = self.nodes.stamp[:self.n_nodes][self.nodes.state[:self.n_nodes] != DEAD]
        if keep_nodes <= 0 or len(st) == 0:
            return self.stamp + 1
        if keep_nodes >= len(st):
            return int(st.min())
        srt = np.sort(st)[::-1]
        return int(srt[keep_nodes - 1]) + (1 if np.count_nonzero(st >= srt[keep_nodes - 1])
                                           > keep_nodes else 0)
