"""Traced lines of the interpolant builder, keyed by their lattice point.

A *sample* is one lattice line of an object's face pair, ``(instance, face pair, a, b, c, d)``
with the coordinates on the lattice of :data:`~.linetree.LATTICE_DEPTH`: its slab crossing,
its radiance and its ray tree (per node: path, instance, surface class, occluder per light,
point). Neighbouring cells, parents and children share samples through a numba hash map from
the key pair ``(instance * 8 + face, packed coordinates)`` (:class:`KeyMap`). The
:class:`SampleStore` owns growth and compaction; :class:`LineCrossings` holds crossings found
during one build before they are shaded.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..accel.accelerators import Hits
from ..tracing.shading import dot3, geometric_normal, spawn_offset
from .predicate import SampleArrays


@njit(cache=True, nogil=True, inline="always")
def _slot(k1, k2, mask):
    h = np.uint64(k1) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(k2) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= h >> np.uint64(31)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(29)
    return np.int64(h & np.uint64(mask))


@njit(cache=True, nogil=True)
def _map_lookup(tk1, tk2, tval, k1, k2, out):
    mask = tk1.shape[0] - 1
    for r in range(k1.shape[0]):
        s = _slot(k1[r], k2[r], mask)
        out[r] = -1
        while tk1[s] != -1:
            if tk1[s] == k1[r] and tk2[s] == k2[r]:
                out[r] = tval[s]
                break
            s = (s + 1) & mask


@njit(cache=True, nogil=True)
def _map_insert(tk1, tk2, tval, k1, k2, vals):
    mask = tk1.shape[0] - 1
    for r in range(k1.shape[0]):
        s = _slot(k1[r], k2[r], mask)
        while tk1[s] != -1 and not (tk1[s] == k1[r] and tk2[s] == k2[r]):
            s = (s + 1) & mask
        tk1[s] = k1[r]
        tk2[s] = k2[r]
        tval[s] = vals[r]


@njit(cache=True, nogil=True)
def unique_keys(k1, k2):
    """First occurrences of key pairs, in order of appearance (no sort): returns
    ``(first (u,) int64 indices, inverse (m,) int32)``."""
    m = k1.shape[0]
    cap = 16
    while cap < 2 * m:
        cap *= 2
    tk1 = np.full(cap, -1, np.int64)
    tk2 = np.zeros(cap, np.int64)
    tval = np.zeros(cap, np.int32)
    first = np.empty(m, np.int64)
    inv = np.empty(m, np.int32)
    u = 0
    mask = cap - 1
    for r in range(m):
        s = _slot(k1[r], k2[r], mask)
        while tk1[s] != -1 and not (tk1[s] == k1[r] and tk2[s] == k2[r]):
            s = (s + 1) & mask
        if tk1[s] == -1:
            tk1[s] = k1[r]
            tk2[s] = k2[r]
            tval[s] = u
            first[u] = r
            u += 1
        inv[r] = tval[s]
    return first[:u], inv


class KeyMap:
    """An append-only numba hash map from key pairs (int64, int64) to their insertion index."""

    def __init__(self) -> None:
        self.n = 0
        self.k1 = np.empty(0, np.int64)
        self.k2 = np.empty(0, np.int64)
        self._table(1024)

    def _table(self, cap: int) -> None:
        self.tk1 = np.full(cap, -1, np.int64)
        self.tk2 = np.zeros(cap, np.int64)
        self.tval = np.zeros(cap, np.int32)
        if self.n:
            _map_insert(self.tk1, self.tk2, self.tval, self.k1[:self.n], self.k2[:self.n],
                        np.arange(self.n, dtype=np.int32))

    @property
    def table_bytes(self) -> int:
        return 20 * len(self.tk1)

    def lookup(self, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        """Index of each key, -1 when absent: (m,) int32."""
        out = np.empty(len(k1), np.int32)
        _map_lookup(self.tk1, self.tk2, self.tval, np.ascontiguousarray(k1, np.int64),
                    np.ascontiguousarray(k2, np.int64), out)
        return out

    def add(self, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        """Append new (unique, absent) keys; returns their indices."""
        m = len(k1)
        s0, s1 = self.n, self.n + m
        self.k1 = _grow(self.k1, s1)
        self.k2 = _grow(self.k2, s1)
        self.k1[s0:s1] = k1
        self.k2[s0:s1] = k2
        self.n = s1
        if 2 * s1 > len(self.tk1):
            self._table(1 << int(math.ceil(math.log2(4 * s1))))
        else:
            _map_insert(self.tk1, self.tk2, self.tval, self.k1[s0:s1], self.k2[s0:s1],
                        np.arange(s0, s1, dtype=np.int32))
        return np.arange(s0, s1, dtype=np.int32)

    def keep(self, ids: np.ndarray) -> None:
        """Keep only keys ``ids`` (sorted), renumbered 0.. in that order."""
        self.k1 = self.k1[ids]
        self.k2 = self.k2[ids]
        self.n = len(ids)
        self._table(1 << int(math.ceil(math.log2(max(4 * self.n, 1024)))))


def _grow(arr: np.ndarray, need: int) -> np.ndarray:
    """``arr`` with room for ``need`` rows (doubling)."""
    if len(arr) >= need:
        return arr
    new = np.empty((max(need, 2 * len(arr), 256),) + arr.shape[1:], arr.dtype)
    new[:len(arr)] = arr
    return new


class SampleStore:
    """Traced lines keyed by lattice point, with their ray trees (growth owned here)."""

    _SAMPLE = ("_rad", "_inst", "_cls", "_depth", "_nstart", "_ncount")
    _NODE = ("_npath", "_ninst", "_ncls", "_nocc", "_npoint")

    def __init__(self, n_lights: int) -> None:
        self.L = max(int(n_lights), 0)
        self.clear()

    def clear(self) -> None:
        self.keys = KeyMap()
        self.n_nodes = 0
        self._rad = np.empty((0, 3))
        self._inst = np.empty(0, np.int32)
        self._cls = np.empty(0, np.int32)
        self._depth = np.empty(0)
        self._nstart = np.empty(0, np.int64)
        self._ncount = np.empty(0, np.int32)
        self._npath = np.empty(0, np.int64)
        self._ninst = np.empty(0, np.int32)
        self._ncls = np.empty(0, np.int32)
        self._nocc = np.empty((0, self.L), np.int32)
        self._npoint = np.empty((0, 3))

    @property
    def n(self) -> int:
        return self.keys.n

    @property
    def memory_bytes(self) -> int:
        """Bytes of the samples, their ray-tree nodes and keys (not the hash table)."""
        per_sample = 24 + 4 + 4 + 8 + 8 + 4 + 16
        per_node = 8 + 4 + 4 + 4 * self.L + 24
        return self.n * per_sample + self.n_nodes * per_node

    def view(self) -> SampleArrays:
        n, m = self.n, self.n_nodes
        return SampleArrays(self._rad[:n], self._inst[:n], self._cls[:n], self._depth[:n],
                            self._nstart[:n], self._ncount[:n], self._npath[:m],
                            self._ninst[:m], self._ncls[:m], self._nocc[:m], self._npoint[:m])

    def radiance(self) -> np.ndarray:
        return self._rad[:self.n]

    def lookup(self, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        return self.keys.lookup(k1, k2)

    def add(self, k1, k2, rad, inst, cls, depth, tree, node_cls) -> np.ndarray:
        """Append samples (keys unique and absent) and their ray-tree nodes; returns ids."""
        n = len(k1)
        s0, s1 = self.n, self.n + n
        for name in self._SAMPLE:
            setattr(self, name, _grow(getattr(self, name), s1))
        order = np.argsort(tree.node_ray, kind="stable")
        count = np.bincount(tree.node_ray, minlength=n).astype(np.int32)
        m0, m1 = self.n_nodes, self.n_nodes + len(order)
        for name in self._NODE:
            setattr(self, name, _grow(getattr(self, name), m1))
        self._rad[s0:s1] = rad
        self._inst[s0:s1] = inst
        self._cls[s0:s1] = cls
        self._depth[s0:s1] = depth
        self._ncount[s0:s1] = count
        self._nstart[s0:s1] = m0 + np.concatenate([[0], np.cumsum(count)[:-1]])
        self._npath[m0:m1] = tree.node_path[order]
        self._ninst[m0:m1] = tree.node_inst[order]
        self._ncls[m0:m1] = node_cls[order]
        self._nocc[m0:m1] = tree.node_occluder[order].reshape(len(order), self.L)
        self._npoint[m0:m1] = tree.node_point[order]
        self.n_nodes = m1
        return self.keys.add(k1, k2)

    def compact(self, keep: np.ndarray) -> np.ndarray:
        """Keep samples where ``keep`` (n,) bool; returns the old -> new id map (-1: gone)."""
        remap = np.full(self.n, -1, np.int32)
        ids = np.flatnonzero(keep)
        remap[ids] = np.arange(len(ids), dtype=np.int32)
        cnt = self._ncount[ids]
        start = np.concatenate([[0], np.cumsum(cnt)[:-1]]).astype(np.int64)
        rows = np.repeat(self._nstart[ids] - start, cnt) + np.arange(int(cnt.sum()))
        for name in self._SAMPLE:
            setattr(self, name, getattr(self, name)[ids])
        self._ncount, self._nstart = cnt, start
        for name in self._NODE:
            setattr(self, name, getattr(self, name)[rows])
        self.n_nodes = len(rows)
        self.keys.keep(ids)
        return remap


class LineCrossings:
    """Slab crossings of lines computed during one build (before any is shaded)."""

    def __init__(self) -> None:
        self.keys = KeyMap()
        self.o = np.empty((0, 3))
        self.d = np.empty((0, 3))
        self.t = np.empty(0)
        self.inst = np.empty(0, np.int32)
        self.prim = np.empty(0, np.int32)
        self.u = np.empty(0)
        self.v = np.empty(0)
        self.cls = np.empty(0, np.int32)

    def add(self, k1, k2, o, d, hits: Hits, cls) -> None:
        s0 = self.keys.n
        s1 = s0 + len(k1)
        for name, val in (("o", o), ("d", d), ("t", hits.t), ("inst", hits.inst),
                          ("prim", hits.prim), ("u", hits.u), ("v", hits.v), ("cls", cls)):
            arr = _grow(getattr(self, name), s1)
            arr[s0:s1] = val
            setattr(self, name, arr)
        self.keys.add(k1, k2)

    def hits(self, ids) -> Hits:
        return Hits(self.t[ids], self.inst[ids], self.prim[ids], self.u[ids], self.v[ids])


# ----------------------------------------------------------------------------- line crossings


@njit(cache=True, nogil=True)
def facing(sa, inst, prim, d, front):
    """front[r]: hit r is on the side its geometric normal points to (against d)."""
    for r in range(inst.shape[0]):
        if inst[r] < 0:
            front[r] = True
            continue
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, sa.inst_nmat[inst[r]], prim[r])
        front[r] = dot3(gx, gy, gz, d[r, 0], d[r, 1], d[r, 2]) < 0.0


@njit(cache=True, nogil=True)
def skip_tmin(o, d, t, ext, out):
    """Parameter just past hit t (the tracer's spawn offset along the line)."""
    for r in range(t.shape[0]):
        px = o[r, 0] + d[r, 0] * t[r]
        py = o[r, 1] + d[r, 1] * t[r]
        pz = o[r, 2] + d[r, 2] * t[r]
        dl = math.sqrt(d[r, 0] ** 2 + d[r, 1] ** 2 + d[r, 2] ** 2)
        out[r] = t[r] + spawn_offset(px, py, pz, ext) / dl
