"""The interpolant pool: records of valid interpolants, a free list, LRU stamps, serials."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .predicate import N_TEST_ALL

#: bytes of one interpolant record (16 RGB float64, slab, class, node, stamp, 16 sample ids,
#: serial, rebuilt and world flags)
INTERP_BYTES = 16 * 3 * 8 + 8 + 8 + 4 + 4 + 8 + 16 * 4 + 8 + 1 + 1


class PoolArrays(NamedTuple):
    """The pool's record arrays, as kernels take them (valid until the pool grows)."""

    rad: np.ndarray  # (cap, 16, 3) float64 corner radiance
    zlo: np.ndarray  # (cap,) float64 certified slab depths
    zhi: np.ndarray  # (cap,) float64
    cls: np.ndarray  # (cap,) int32
    node: np.ndarray  # (cap,) int32 linetree leaf
    stamp: np.ndarray  # (cap,) int64 LRU stamp
    samples: np.ndarray  # (cap, 16) int32 corner sample ids
    live: np.ndarray  # (cap,) bool
    serial: np.ndarray  # (cap,) int64
    rebuilt: np.ndarray  # (cap,) bool
    world: np.ndarray  # (cap,) bool


class InterpolantPool:
    """Interpolant records with a free list and LRU stamps.

    ``serial[q]`` numbers every interpolant ever made (ids are reused, serials never), so the
    ray segment trees and the membership index can tell a freed interpolant's entries from
    its successor's without being told of every eviction. ``rebuilt[q]``: built in a cell an
    edit invalidated (shown as ``CLASS_REBUILT``); ``world[q]``: some ray-tree node misses
    (the world colour shows in its radiance).
    """

    _FIELDS = ("rad", "zlo", "zhi", "cls", "node", "stamp", "samples", "live", "serial",
               "rebuilt", "world")

    def __init__(self, capacity: int = 1024) -> None:
        self.cap = 0
        self.rad = np.empty((0, 16, 3))
        self.zlo = np.empty(0)
        self.zhi = np.empty(0)
        self.cls = np.empty(0, np.int32)
        self.node = np.empty(0, np.int32)
        self.stamp = np.empty(0, np.int64)
        self.samples = np.empty((0, 16), np.int32)
        self.live = np.empty(0, bool)
        self.serial = np.empty(0, np.int64)
        self.rebuilt = np.empty(0, bool)
        self.world = np.empty(0, bool)
        #: (cap, N_TEST_ALL) int32 the test lines' sample ids of an interpolant whose
        #: samples keep per-light shares (-1: none kept): what re-running its radiance test
        #: after a light's power or colour change needs (:mod:`.relight`); not a kernel input
        self.tests = np.empty((0, N_TEST_ALL), np.int32)
        self.next_serial = 1
        self._free = np.empty(0, np.int32)
        self._grow(capacity)

    def _grow(self, cap: int) -> None:
        old = self.cap
        for name in self._FIELDS:
            a = getattr(self, name)
            new = np.zeros((cap,) + a.shape[1:], a.dtype)
            new[:old] = a
            setattr(self, name, new)
        tests = np.full((cap, N_TEST_ALL), -1, np.int32)
        tests[:old] = self.tests
        self.tests = tests
        self._free = np.concatenate([np.arange(cap - 1, old - 1, -1, dtype=np.int32),
                                     self._free])
        self.cap = cap

    def arrays(self) -> PoolArrays:
        """The record arrays (a view: valid until the pool grows)."""
        return PoolArrays(*(getattr(self, name) for name in self._FIELDS))

    @property
    def n_live(self) -> int:
        return self.cap - len(self._free)

    def alloc(self, n: int) -> np.ndarray:
        """``n`` fresh ids (live, new serials, flags cleared)."""
        if n > len(self._free):
            self._grow(max(2 * self.cap, self.cap + n))
        ids = self._free[len(self._free) - n:][::-1].copy()
        self._free = self._free[:len(self._free) - n]
        self.live[ids] = True
        self.serial[ids] = np.arange(self.next_serial, self.next_serial + n)
        self.next_serial += n
        self.rebuilt[ids] = False
        self.world[ids] = False
        self.tests[ids] = -1
        return ids

    def release(self, ids: np.ndarray) -> None:
        self.live[ids] = False
        self._free = np.concatenate([self._free, np.asarray(ids, np.int32)])
