"""The per-pixel records' compact codes (:mod:`.pixel_records`): hit points quantised to 32
bits in the scene box, miss directions in 32-bit octahedral coordinates."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: bits of the quantised point on the longest, middle and shortest axis of the box
POINT_BITS = (11, 11, 10)


@njit(cache=True, nogil=True)
def _oct_encode(x, y, z):
    s = abs(x) + abs(y) + abs(z)
    if s == 0.0:
        return np.uint32(0)
    u = x / s
    v = y / s
    if z < 0.0:
        uu = (1.0 - abs(v)) * (1.0 if u >= 0.0 else -1.0)
        vv = (1.0 - abs(u)) * (1.0 if v >= 0.0 else -1.0)
        u, v = uu, vv
    a = int(round((u * 0.5 + 0.5) * 65535.0))
    b = int(round((v * 0.5 + 0.5) * 65535.0))
    return np.uint32((a << 16) | b)


@njit(cache=True, nogil=True)
def _oct_decode(code):
    a = (code >> 16) & 0xFFFF
    b = code & 0xFFFF
    u = a / 65535.0 * 2.0 - 1.0
    v = b / 65535.0 * 2.0 - 1.0
    z = 1.0 - abs(u) - abs(v)
    if z < 0.0:
        uu = (1.0 - abs(v)) * (1.0 if u >= 0.0 else -1.0)
        vv = (1.0 - abs(u)) * (1.0 if v >= 0.0 else -1.0)
        u, v = uu, vv
    n = math.sqrt(u * u + v * v + z * z)
    return u / n, v / n, z / n


@njit(cache=True, nogil=True, parallel=True)
def _encode_nodes(inst, point, dirn, lo, step, levels, shift, codes, outside):
    """Quantised points (hits) or octahedral directions (misses) of n nodes."""
    for i in prange(inst.shape[0]):
        outside[i] = False
        if inst[i] < 0:
            codes[i] = _oct_encode(dirn[i, 0], dirn[i, 1], dirn[i, 2])
            continue
        c = np.uint32(0)
        for k in range(3):
            q = (point[i, k] - lo[k]) / step[k]
            r = int(round(q)) if q == q else 0
            if r < 0 or r > levels[k]:
                outside[i] = True
                r = 0 if r < 0 else levels[k]
            c |= np.uint32(r) << np.uint32(shift[k])
        codes[i] = c


@njit(cache=True, nogil=True, inline="always")
def _decode_point(code, lo, step, levels, shift):
    x = lo[0] + ((code >> shift[0]) & levels[0]) * step[0]
    y = lo[1] + ((code >> shift[1]) & levels[1]) * step[1]
    z = lo[2] + ((code >> shift[2]) & levels[2]) * step[2]
    return x, y, z
