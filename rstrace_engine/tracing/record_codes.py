"""The per-pixel records' compact codes and segment tests (:mod:`.pixel_records`): hit points
quantised to 32 bits in the scene box, miss directions in 32-bit octahedral coordinates;
segments, cones and light shafts against the edited boxes."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.scene import LIGHT_SUN

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


# ----------------------------------------------------------------------------- tests


def light_geometry(sa) -> np.ndarray:
    """(L, 5) float64 per light: position, bounding radius of its emitting points about
    that position (sphere radius, half the area light's diagonal; 0 for a point) and a
    sun's cone half angle (0: parallel); see :func:`_light_hit`."""
    out = np.zeros((len(sa.light_kind), 5))
    out[:, :3] = np.asarray(sa.light_pos, np.float64).reshape(-1, 3)
    out[:, 3] = sa.light_bound
    out[:, 4] = np.where(sa.light_ext & (sa.light_kind == LIGHT_SUN), sa.light_half, 0.0)
    # a margin on both for the shadow rays' origins being off the recorded points
    out[:, 3] = np.where(out[:, 3] > 0.0, out[:, 3] * (1.0 + tol.RECORD_SLACK_REL), 0.0)
    out[:, 4] = np.where(out[:, 4] > 0.0, out[:, 4] + tol.RECORD_DIR_ERROR, 0.0)
    return out


@njit(cache=True, nogil=True, inline="always")
def _segment_box(ax, ay, az, bx, by, bz, lo, hi, ray):
    """Does the segment a -> b (the ray from a through b when ``ray``) meet the box?"""
    t0 = 0.0
    t1 = 1e300 if ray else 1.0
    a = (ax, ay, az)
    d = (bx - ax, by - ay, bz - az)
    for k in range(3):
        if d[k] == 0.0:
            if a[k] < lo[k] or a[k] > hi[k]:
                return False
            continue
        ta = (lo[k] - a[k]) / d[k]
        tb = (hi[k] - a[k]) / d[k]
        if ta > tb:
            ta, tb = tb, ta
        if ta > t0:
            t0 = ta
        if tb < t1:
            t1 = tb
        if t0 > t1:
            return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _cone_sphere(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, err):
    """Can the ray from o along unit d, give or take ``err`` radians, meet the sphere?"""
    vx, vy, vz = cx - ox, cy - oy, cz - oz
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    if dist <= r:
        return True
    c = (vx * dx + vy * dy + vz * dz) / dist
    c = min(1.0, max(-1.0, c))
    return math.acos(c) <= math.asin(r / dist) + err


@njit(cache=True, nogil=True, inline="always")
def _light_hit(px, py, pz, j, lo, hi, light_kind, lgeo, light_dir):
    """Can a shadow ray from p to light j cross the box (lo, hi)? ``lgeo`` (L, 5): the
    light's position, its bounding radius and (a sun) its cone's half angle. A point light
    is one segment; a light with an extent a shaft, tested conservatively: every segment
    from p to a point within radius r of the light's centre stays within r of the segment
    to the centre, so the box grown by r is tested against that one segment; a sun with an
    angle is a cone of directions, tested against the box's bounding sphere."""
    if light_kind[j] == LIGHT_SUN:
        if lgeo[j, 4] > 0.0:
            cx = 0.5 * (lo[0] + hi[0])
            cy = 0.5 * (lo[1] + hi[1])
            cz = 0.5 * (lo[2] + hi[2])
            r = 0.5 * math.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2
                                + (hi[2] - lo[2]) ** 2)
            return _cone_sphere(px, py, pz, -light_dir[j, 0], -light_dir[j, 1],
                                -light_dir[j, 2], cx, cy, cz, r, lgeo[j, 4])
        return _segment_box(px, py, pz, px - light_dir[j, 0], py - light_dir[j, 1],
                            pz - light_dir[j, 2], lo, hi, True)
    g = lgeo[j, 3]
    if g > 0.0:
        glo = (lo[0] - g, lo[1] - g, lo[2] - g)
        ghi = (hi[0] + g, hi[1] + g, hi[2] + g)
        return _segment_box(px, py, pz, lgeo[j, 0], lgeo[j, 1], lgeo[j, 2], glo, ghi, False)
    return _segment_box(px, py, pz, lgeo[j, 0], lgeo[j, 1], lgeo[j, 2], lo, hi, False)


def _secondary_samples(levels: list):
    """The secondary levels' sampled rays (:attr:`~.pixel_records.PixelRecords.s_wnorm`):
    ``(normal (k, 3) float32, NaN at misses, seed (k,) uint64, soft bits (k, L + 1) or
    None)``, or None where the tracer gave none."""
    if not levels or not all("normal" in lv for lv in levels):
        return None
    hit = np.concatenate([lv["inst"] for lv in levels]) >= 0
    wn = np.concatenate([lv["normal"] for lv in levels])
    wn = np.where(hit[:, None], wn, np.nan).astype(np.float32)  # (a miss's: undefined)
    seed = np.concatenate([lv["seed"] for lv in levels]).astype(np.uint64)
    bits = None
    if all("soft_bits" in lv for lv in levels):
        bits = np.concatenate([lv["soft_bits"] for lv in levels])
    return wn, seed, bits


@njit(cache=True, nogil=True)
def _secondary_depths(s_parent, n_rays, depth):
    """The ray depth of each secondary node (parents come before their children)."""
    for k in range(s_parent.shape[0]):
        p = s_parent[k]
        depth[k] = 1 if p < n_rays else depth[p - n_rays] + 1


@njit(cache=True, nogil=True)
def _secondary_rays(s_parent, n_rays, s_ray):
    """The sample each secondary node belongs to (parents come before their children)."""
    for k in range(s_parent.shape[0]):
        p = s_parent[k]
        s_ray[k] = p if p < n_rays else s_ray[p - n_rays]


@njit(cache=True, nogil=True)
def _mark_used(combo, used) -> int:
    """``used[combo] = True``; returns how many rows it newly marked (the table rows the
    nodes use: :meth:`~.pixel_records.PixelRecords._compact`, without numpy's scatter)."""
    n = 0
    for i in range(combo.shape[0]):
        c = combo[i]
        if not used[c]:
            used[c] = True
            n += 1
    return n
