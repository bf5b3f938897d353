"""Sets of lights as bits: ``W = words(L)`` uint64 words per set, light ``j`` bit ``j % 64``
of word ``j // 64`` -- the per-pixel records' traced and visible lights
(:mod:`.pixel_records`), the lights a node's soft samples re-shade (:mod:`.sample_rays`,
:mod:`.shadow_reshade`). A scene of up to 64 lights has one word per set, as when the sets
were a single uint64; more lights take more words (the scene's limit is
:data:`~..geometry.elements.MAX_LIGHTS`)."""

from __future__ import annotations

import numpy as np
from numba import njit

_ONE = np.uint64(1)


def words(n_lights: int) -> int:
    """The uint64 words of a set of ``n_lights`` light slots (at least one)."""
    return max(1, (int(n_lights) + 63) // 64)


def mask_of(slots, width: int) -> np.ndarray:
    """(width,) uint64: the set of the light slots ``slots``."""
    out = np.zeros(width, np.uint64)
    for j in slots:
        out[int(j) >> 6] |= _ONE << np.uint64(int(j) & 63)
    return out


def column(masks: np.ndarray, j: int) -> np.ndarray:
    """(n,) bool: whether light ``j`` is in each of the sets ``masks`` (n, W)."""
    return (masks[:, int(j) >> 6] >> np.uint64(int(j) & 63)) & _ONE != 0


def set_column(masks: np.ndarray, j: int, on: np.ndarray) -> np.ndarray:
    """``masks`` (n, W) uint64 with light ``j`` put in the sets where ``on`` (n,) bool and
    taken out elsewhere (a new array)."""
    out = np.array(masks, np.uint64)
    bit = _ONE << np.uint64(int(j) & 63)
    w = int(j) >> 6
    out[:, w] = np.where(on, out[:, w] | bit, out[:, w] & ~bit)
    return out


@njit(cache=True, nogil=True, inline="always")
def has(row, j):
    """Whether light ``j`` is in the set ``row`` (W,) uint64."""
    return (row[j >> 6] >> np.uint64(j & 63)) & np.uint64(1) != np.uint64(0)
