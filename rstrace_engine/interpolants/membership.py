"""The membership index: which interpolants' ray trees name an object, a light (seed 000, 5.1).

Keys are small integers (:mod:`.tunnels`: ``2 * instance + OBJ_HIT / OBJ_OCCLUDES`` for
objects, ``2 * light + LIGHT_SHADES / LIGHT_OCCLUDED`` for lights); each key has a list of
entries ``(interpolant id, serial)``, linked newest first in flat arrays. Interpolant ids are
reused by the pool, so an entry only counts while the pool slot still holds the interpolant it
was made for (``pool.serial[q] == serial`` and ``pool.live[q]``): freeing an interpolant (LRU
eviction, invalidation) needs no work here, and :meth:`Membership.compact` drops the dead
entries once they outnumber the live ones, so memory stays proportional to the live
interpolants.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

#: Dead entries tolerated beyond the live ones before a compaction.
COMPACT_SLACK = 4096


class MembershipArrays(NamedTuple):
    head: np.ndarray  # (K,) int32 newest entry of each key, -1 none
    nxt: np.ndarray  # (E,) int32 next (older) entry of the same key, -1 none
    q: np.ndarray  # (E,) int32 interpolant id
    serial: np.ndarray  # (E,) int64 the interpolant's serial when the entry was made


@njit(cache=True, nogil=True)
def _insert(ma, n, keys, q, serial):
    for r in range(keys.shape[0]):
        k = keys[r]
        e = n + r
        ma.nxt[e] = ma.head[k]
        ma.q[e] = q[r]
        ma.serial[e] = serial[r]
        ma.head[k] = e


@njit(cache=True, nogil=True)
def _query(ma, keys, pool_serial, pool_live, flag):
    """flag[q] = True for every live interpolant listed under one of ``keys``; returns how
    many entries were visited."""
    seen = 0
    for r in range(keys.shape[0]):
        k = keys[r]
        if k < 0 or k >= ma.head.shape[0]:
            continue
        e = ma.head[k]
        while e >= 0:
            q = ma.q[e]
            if pool_live[q] and pool_serial[q] == ma.serial[e]:
                flag[q] = True
            e = ma.nxt[e]
            seen += 1
    return seen


@njit(cache=True, nogil=True)
def _valid(ma, n, pool_serial, pool_live, keep):
    cnt = 0
    for e in range(n):
        q = ma.q[e]
        keep[e] = pool_live[q] and pool_serial[q] == ma.serial[e]
        if keep[e]:
            cnt += 1
    return cnt


@njit(cache=True, nogil=True)
def _entry_keys(ma, out):
    """The key of every entry (walking each key's list)."""
    for k in range(ma.head.shape[0]):
        e = ma.head[k]
        while e >= 0:
            out[e] = k
            e = ma.nxt[e]


class Membership:
    """Owner of one membership index (growth and compaction; see the module doc)."""

    #: bytes per entry (nxt, q, serial)
    ENTRY_BYTES = 4 + 4 + 8

    def __init__(self) -> None:
        self.n = 0
        self.arrays = MembershipArrays(np.full(64, -1, np.int32), np.empty(1024, np.int32),
                                       np.empty(1024, np.int32), np.empty(1024, np.int64))

    @property
    def memory_bytes(self) -> int:
        return 4 * len(self.arrays.head) + self.ENTRY_BYTES * self.n

    def _reserve(self, n_keys: int, extra: int) -> None:
        a = self.arrays
        head = a.head
        if n_keys > len(head):
            head = np.full(max(n_keys, 2 * len(head)), -1, np.int32)
            head[:len(a.head)] = a.head
        need = self.n + extra
        nxt, q, serial = a.nxt, a.q, a.serial
        if need > len(nxt):
            cap = max(need, 2 * len(nxt))
            nxt, q, serial = (np.concatenate([x[:self.n], np.empty(cap - self.n, x.dtype)])
                              for x in (a.nxt, a.q, a.serial))
        self.arrays = MembershipArrays(head, nxt, q, serial)

    def add(self, keys: np.ndarray, q: np.ndarray, serial: np.ndarray) -> None:
        """Entries ``keys[r] -> (q[r], serial[r])`` (keys >= 0)."""
        keys = np.ascontiguousarray(keys, np.int64)
        if len(keys) == 0:
            return
        self._reserve(int(keys.max()) + 1, len(keys))
        _insert(self.arrays, self.n, keys, np.ascontiguousarray(q, np.int32),
                np.ascontiguousarray(serial, np.int64))
        self.n += len(keys)

    def query(self, keys, pool_serial: np.ndarray, pool_live: np.ndarray,
              flag: np.ndarray) -> int:
        """Set ``flag[q]`` for the live interpolants under ``keys``; returns entries seen."""
        keys = np.ascontiguousarray(np.asarray(keys, np.int64).reshape(-1))
        if len(keys) == 0 or self.n == 0:
            return 0
        return int(_query(self.arrays, keys, pool_serial, pool_live, flag))

    def compact(self, pool_serial: np.ndarray, pool_live: np.ndarray,
                force: bool = False) -> bool:
        """Drop the entries of freed interpolants once they outnumber the live ones (or
        always with ``force``). Returns whether it compacted."""
        a = self.arrays
        keep = np.empty(self.n, np.bool_)
        live = int(_valid(a, self.n, pool_serial, pool_live, keep))
        if not force and self.n - live <= live + COMPACT_SLACK:
            return False
        keys = np.empty(len(a.nxt), np.int64)
        _entry_keys(a, keys)
        keys = keys[:self.n][keep]
        q = a.q[:self.n][keep]
        serial = a.serial[:self.n][keep]
        # oldest first, so that the lists keep their newest-first order
        order = np.arange(len(keys))
        self.n = 0
        self.arrays = MembershipArrays(np.full(len(a.head), -1, np.int32),
                                       np.empty(max(1024, 2 * len(keys)), np.int32),
                                       np.empty(max(1024, 2 * len(keys)), np.int32),
                                       np.empty(max(1024, 2 * len(keys)), np.int64))
        self.add(keys[order], q[order], serial[order])
        return True
