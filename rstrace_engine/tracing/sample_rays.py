"""Sampled shadow rays in the per-pixel records (:mod:`.pixel_records`, issue 20).

A point under a light with an extent or a world that lights shoots ``n`` shadow rays per
such light, drawn from its *node seed* (:mod:`.soft_lights`: a Fibonacci lattice rotated by
a hash of the seed and the light). The records keep, per hit of a frame with soft light
(primary and secondary nodes), the shading normal (float32) and the node seed (20 bytes per
node), from which the
rays are regenerated exactly as the tracer drew them; an edit then dirties a sample only
where one of its own rays may meet an edited box:

* **world** (while it lights): ``n`` cosine-weighted directions about the shading normal,
  rays to infinity, against each box's bounding sphere within
  :data:`~.tolerances.RECORD_DIR_ERROR` radians (the normal is stored in float32);
* **area lights**: the ``n`` points sampled on the light do not depend on the shading point,
  so each shadow ray is the segment from the recorded point to its light point; the point's
  quantisation and spawn offset are inside the margin the edited boxes are grown by (a
  segment from anywhere within the margin to the same end stays within it);
* **suns with an angle**: the ``n`` directions do not depend on the point either: rays to
  infinity against the grown box.

Sphere lights' samples depend on the point (a cone about the direction to the centre): they
keep the shaft test of :func:`~.record_codes._light_hit`, as do nodes without a recorded
seed (interpolated samples).

The hits' lights are found *per light* (:func:`query_light_bits`) and the world's rays apart
(:func:`query_world`), at the primary and at the secondary nodes: a sample whose only dirty
rays are these shadow rays keeps its rays and its other terms, and the incremental frame
shades just those lights (or the world) again at those nodes (:mod:`.shadow_reshade`),
testing again only the samples the queries found (:class:`SampleCandidates`), exactly
(:func:`crossing_rows`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.edits import PART_NEW, PART_OLD
from ..geometry.scene import LIGHT_AREA, LIGHT_SUN, SceneArrays
from ..views import fields, view_type
from .record_codes import _cone_sphere, _decode_point, _light_hit, _segment_box
from .shading import dot3, far_origin, onb, rough_interface
from .soft_lights import (
    _cosine_dir,
    _sample_one,
    _sphere_exit,
    _sphere_sin2,
    row_hash,
    row_uv,
    sample_weight,
    world_row_hash,
)


@njit(cache=True, nogil=True, parallel=True)
def query_world(p_combo, p_code, combo_inst, wnorm, seed, n, lo, step, levels, shift,
                reg_c, reg_r, reg_tag, old, skip, out):
    """The world's rays of every primary hit against the edited regions (their bounding
    spheres ``reg_c, reg_r``, grown like every region by the quantisation and the spawn
    offset): each of the point's ``n`` cosine-weighted directions, regenerated from its
    shading normal and node seed as the tracer drew them (:func:`~.soft_lights.
    world_row_hash`), is a ray to infinity; a region it may meet
    dirties the sample. ``out`` (n_rays,) uint64: the bits of those samples (assigned; 0
    where ``skip``), every bit (:data:`ALL`) where the hit has no recorded normal (NaN) or
    lies in a region's sphere. Regions wholly
    below the tangent plane of the shading normal are skipped (every world ray leaves above
    it); a sample whose ``(u, v)`` puts its direction outside every region's cone is not
    drawn (:func:`_windows`). As :func:`crossing_rows`, a sample visible in the records'
    frame (its bit in ``old`` (n_rays,) uint64: :attr:`~.pixel_records.PixelRecords.p_vis`'
    world column) is tested against the regions tagged :data:`~.edits.PART_NEW` only, one
    blocked against those tagged :data:`~.edits.PART_OLD`."""
    m = p_combo.shape[0]
    k_reg = reg_c.shape[0]
    for ch in prange((m + _CROSSING_CHUNK - 1) // _CROSSING_CHUNK):
        cv = np.empty((k_reg, 4))
        win = np.empty((k_reg, 4))
        for g in range(ch * _CROSSING_CHUNK, min(m, (ch + 1) * _CROSSING_CHUNK)):
            out[g] = np.uint64(0)
            if not skip[g] and combo_inst[p_combo[g]] >= 0:
                out[g] = _world_crosses(p_code[g], wnorm, seed[g], g, n, lo, step, levels,
                                        shift, reg_c, reg_r, reg_tag, old[g], cv, win)


#: a row's candidate samples when any may cross (no per-sample answer: every bit)
ALL = ~np.uint64(0)


@njit(cache=True, nogil=True, inline="always")
def _world_crosses(code, wnorm, seed, g, n, lo, step, levels, shift, reg_c, reg_r, reg_tag,
                   old, cv, win):
    """:func:`query_world` of primary hit ``g`` (its samples' bits); ``cv``, ``win`` (k_reg,
    4) scratch."""
    k_reg = reg_c.shape[0]
    err = tol.RECORD_DIR_ERROR
    sx = float(wnorm[g, 0])
    sy = float(wnorm[g, 1])
    sz = float(wnorm[g, 2])
    if not (sx == sx and sy == sy and sz == sz) or (sz == 0.0 and math.copysign(1.0, sz) < 0):
        # unknown; or -0.0: the tracer's z may have been a negative too small for float32,
        # and the basis about the normal (shading.onb) follows z's sign (a stored +0.0 or
        # non-zero z has the sign of the tracer's own)
        return ALL
    nl = math.sqrt(sx * sx + sy * sy + sz * sz)
    sx /= nl
    sy /= nl
    sz /= nl
    px, py, pz = _decode_point(code, lo, step, levels, shift)
    full = (np.uint64(1) << np.uint64(n)) - np.uint64(1) if n < 64 else ~np.uint64(0)
    need = (PART_NEW if old != np.uint64(0) else 0) | (PART_OLD if old & full != full else 0)
    some = False
    for q in range(k_reg):
        if not reg_tag[q] & need:
            cv[q, 3] = np.inf  # (no sample tests it)
            continue
        vx = reg_c[q, 0] - px
        vy = reg_c[q, 1] - py
        vz = reg_c[q, 2] - pz
        dist = math.sqrt(vx * vx + vy * vy + vz * vz)
        r = reg_r[q]
        if dist <= r:
            return ALL
        cv[q, 0] = vx
        cv[q, 1] = vy
        cv[q, 2] = vz
        if vx * sx + vy * sy + vz * sz < -r - err * dist:
            cv[q, 3] = np.inf  # below the horizon
            continue
        half = math.asin(r / dist) + err
        cv[q, 3] = (math.cos(half) if half < math.pi else -1.0) * dist
        some = True
    if not some:
        return np.uint64(0)
    _windows(1, sx, sy, sz, 0.0, cv, win, reg_tag, need)
    for q in range(k_reg):
        if cv[q, 3] == np.inf:
            win[q, 0] = 2.0  # (no sample)
    h = world_row_hash(seed)
    b = np.uint64(0)
    for s in range(n):
        u, v = row_uv(h, n, s)
        if not _in_window(win, u, v):
            continue
        dx, dy, dz = _cosine_dir(sx, sy, sz, u, v)  # (world_sample_dir)
        need = PART_NEW if (old >> np.uint64(s)) & np.uint64(1) else PART_OLD
        for q in range(k_reg):
            if reg_tag[q] & need and cv[q, 3] < np.inf and \
                    dx * cv[q, 0] + dy * cv[q, 1] + dz * cv[q, 2] >= cv[q, 3]:
                b |= np.uint64(1) << np.uint64(s)
                break
    return b


@njit(cache=True, nogil=True, inline="always")
def _shaft_sphere(px, py, pz, j, cx, cy, cz, r, light_kind, lgeo, light_dir):
    """Can a shadow ray from p to light j come within ``r`` of c (a region's sphere)? As
    :func:`~.record_codes._light_hit`: every segment from p to a point within the light's
    bounding radius g of its centre stays within g of the segment to the centre, and its
    direction within ``asin(g / e)`` of the centre's (``e`` its distance; the sphere's
    directions within ``asin(r / |c - p|)`` of c's, both widened by
    :data:`~.tolerances.RECORD_DIR_ERROR` for rounding); a sun's rays are a cone of
    directions (or one ray)."""
    if light_kind[j] == LIGHT_SUN:
        if lgeo[j, 4] > 0.0:
            return _cone_sphere(px, py, pz, -light_dir[j, 0], -light_dir[j, 1],
                                -light_dir[j, 2], cx, cy, cz, r, lgeo[j, 4])
        return _segment_sphere(px, py, pz, -light_dir[j, 0], -light_dir[j, 1],
                               -light_dir[j, 2], np.inf, cx, cy, cz, r)
    dx = lgeo[j, 0] - px
    dy = lgeo[j, 1] - py
    dz = lgeo[j, 2] - pz
    e = math.sqrt(dx * dx + dy * dy + dz * dz)
    if e == 0.0:
        return True
    g = lgeo[j, 3] + tol.RECORD_SLACK_REL * e
    if not _segment_sphere(px, py, pz, dx / e, dy / e, dz / e, e, cx, cy, cz, r + g):
        return False
    vx, vy, vz = cx - px, cy - py, cz - pz
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    if dist <= r or e <= g:
        return True
    c = min(1.0, max(-1.0, (vx * dx + vy * dy + vz * dz) / (dist * e)))
    return math.acos(c) <= math.asin(r / dist) + math.asin(g / e) + tol.RECORD_DIR_ERROR


_BitsScene = view_type("_BitsScene", SceneArrays, (
    "light_cos_inner", "light_cos_outer", "light_dir", "light_ellipse", "light_half",
    "light_kind", "light_pos", "light_radius", "light_size", "light_soft",
    "light_spot_frame", "light_spot_scaled", "light_spread", "light_u", "light_v"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def query_light_bits(sa, p_combo, p_code, combo_inst, combo_traced, wnorm, seed, n, mask,
                     lo, step, levels, shift, reg_lo, reg_hi, reg_c, reg_r, reg_tag, lgeo,
                     vis, skip, bits, cols, masks):
    """Per primary hit not in ``skip``: the lights of ``mask`` ((W,) uint64: the set of
    the lights with an extent, :mod:`.light_bits`) whose shadow rays there may cross a grown
    region -- its box ``reg_lo, reg_hi`` and its sphere ``reg_c, reg_r`` both (the edited
    objects, old and new apart: :attr:`~.edits.EditEffects.parts`) -- as sets ``bits``
    (n_rays, W) uint64 (assigned).
    Area lights and suns with an angle regenerate the point's own samples from its node
    seed (module doc), where the light's shaft from the point comes near a region's
    sphere (:func:`_shaft_sphere`), and give their bits in ``masks[g, cols[j]]`` (left
    as they are elsewhere); with the samples' visibility ``vis`` (n_rays, L + 1) uint64
    (empty: unknown), a visible sample is tested against the regions whose ``reg_tag`` is
    :data:`~.edits.PART_NEW`, a blocked one against :data:`~.edits.PART_OLD` (as
    :func:`crossing_rows`). Sphere lights, and every light of a sample without a recorded
    seed (NaN normal), get the shaft test of :func:`~.record_codes._light_hit` and
    :func:`_shaft_sphere` (``lgeo``: :func:`~.record_codes.light_geometry`). ``sa``: the
    packing the records describe."""
    sa = _BitsScene(*fields(sa, _BitsScene))  # the fields its loop reads
    k_reg = reg_lo.shape[0]
    L = sa.light_kind.shape[0]
    known_vis = vis.shape[0] > 0
    W = mask.shape[0]
    for g in prange(p_combo.shape[0]):
        any_todo = False
        for w in range(W):
            bits[g, w] = np.uint64(0)
            any_todo |= (combo_traced[p_combo[g], w] & mask[w]) != 0
        c = p_combo[g]
        if skip[g] or combo_inst[c] < 0 or not any_todo:
            continue
        px, py, pz = _decode_point(p_code[g], lo, step, levels, shift)
        known = wnorm[g, 0] == wnorm[g, 0]
        for j in range(L):
            bit = np.uint64(1) << np.uint64(j & 63)
            if not combo_traced[c, j >> 6] & mask[j >> 6] & bit:
                continue
            kind = sa.light_kind[j]
            sun = kind == LIGHT_SUN
            near = False
            for q in range(k_reg):
                if _shaft_sphere(px, py, pz, j, reg_c[q, 0], reg_c[q, 1], reg_c[q, 2],
                                 reg_r[q], sa.light_kind, lgeo, sa.light_dir) and (
                        (known and (sun or kind == LIGHT_AREA)) or _light_hit(
                            px, py, pz, j, reg_lo[q], reg_hi[q], sa.light_kind, lgeo,
                            sa.light_dir)):
                    near = True
                    break
            if not near:
                continue
            if not known or not (sun or kind == LIGHT_AREA):
                bits[g, j >> 6] |= bit
                continue
            h = row_hash(seed[g], j, L)
            old = vis[g, j] if known_vis else np.uint64(0)
            b = np.uint64(0)
            for s in range(n):
                need = PART_OLD | PART_NEW
                if known_vis:
                    need = PART_NEW if (old >> np.uint64(s)) & np.uint64(1) else PART_OLD
                u, v = row_uv(h, n, s)
                dx, dy, dz, t, _ = _sample_one(sa, j, px, py, pz, u, v)
                if not sun:
                    t = t / (1.0 - tol.SHADOW_END_REL)  # to the light point itself
                ex = px + dx * (1.0 if sun else t)
                ey = py + dy * (1.0 if sun else t)
                ez = pz + dz * (1.0 if sun else t)
                for q in range(k_reg):
                    if reg_tag[q] & need and _segment_sphere(
                            px, py, pz, dx, dy, dz, np.inf if sun else t, reg_c[q, 0],
                            reg_c[q, 1], reg_c[q, 2], reg_r[q]) and _segment_box(
                                px, py, pz, ex, ey, ez, reg_lo[q], reg_hi[q], sun):
                        b |= np.uint64(1) << np.uint64(s)
                        break
            if b != np.uint64(0):
                bits[g, j >> 6] |= bit
                if cols[j] >= 0:
                    masks[g, cols[j]] = b


class SampleCandidates(NamedTuple):
    """Per row of the records' nodes -- a node and a column, a light slot or ``L`` the
    world -- the soft samples whose rays an edit batch may cross, as the records' queries
    found them (:func:`query_light_bits`' masks, :func:`query_world`): sorted keys ``node
    * width + column`` (``width``: ``L + 1``) and their sample bits. A row with none has
    no per-sample answer (a sphere light's shaft test): :data:`ALL`. The re-shade tests
    just those samples again, exactly (:func:`crossing_rows`' ``cand``)."""

    key: np.ndarray  # (m,) int64, sorted
    bits: np.ndarray  # (m,) uint64
    width: int

    @classmethod
    def of(cls, width: int, columns: list) -> SampleCandidates:
        """From ``(column, bits (k,) uint64)`` pairs over the nodes (0: none)."""
        keys, bits = [np.zeros(0, np.int64)], [np.zeros(0, np.uint64)]
        for c, m in columns:
            idx = np.flatnonzero(m)
            keys.append(idx * width + c)
            bits.append(np.asarray(m[idx], np.uint64))
        key, bit = np.concatenate(keys), np.concatenate(bits)
        order = np.argsort(key, kind="stable")
        return cls(key[order], bit[order], int(width))

    def merged(self, other: SampleCandidates) -> SampleCandidates:
        """Both batches' candidates (a row's bits or-ed)."""
        key = np.concatenate([self.key, other.key])
        bit = np.concatenate([self.bits, other.bits])
        order = np.argsort(key, kind="stable")
        key, bit = key[order], bit[order]
        first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
        if len(key) == 0:
            return self
        return SampleCandidates(key[first], np.bitwise_or.reduceat(bit, first), self.width)

    def of_rows(self, nodes: np.ndarray, column: int) -> np.ndarray:
        """(len nodes,) uint64: the candidate bits of the nodes' rows of ``column``."""
        if len(self.key) == 0:
            return np.full(len(nodes), ALL, np.uint64)
        q = np.asarray(nodes, np.int64) * self.width + int(column)
        k = np.minimum(np.searchsorted(self.key, q), len(self.key) - 1)
        return np.where(self.key[k] == q, self.bits[k], ALL)


#: the most samples per (point, light) row whose visibility the records keep as bits
VIS_BITS_MAX = 64


@njit(cache=True, nogil=True)
def soft_bits(start, light, vis, n, out):
    """The visibility of every soft sample of ``nb`` points (:class:`~.soft_lights.
    SoftSamples`' ``start``, ``light``, ``vis``, ``n`` samples per row) as bits: ``out``
    (nb, L + 1) uint64, bit ``s`` of column ``j`` (``L``: the world) sample ``s`` of the
    point's row of light ``j`` (zero where it has none)."""
    for i in range(out.shape[0]):
        for c in range(out.shape[1]):
            out[i, c] = np.uint64(0)
        k0 = start[i]
        while k0 < start[i + 1]:
            b = np.uint64(0)
            for s in range(n):
                if vis[k0 + s]:
                    b |= np.uint64(1) << np.uint64(s)
            out[i, light[k0]] = b
            k0 += n


@njit(cache=True, nogil=True)
def unpack_bits(bits, n, vis):
    """``vis`` (m n,) bool from ``bits`` (m,) (:func:`soft_bits`' columns)."""
    for r in range(bits.shape[0]):
        b = np.uint64(bits[r])
        for s in range(n):
            vis[r * n + s] = (b >> np.uint64(s)) & np.uint64(1) != 0


@njit(cache=True, nogil=True, inline="always")
def _row_inside(sa, j, L, qx, qy, qz):
    """A point inside sphere light ``j`` (no soft falloff) samples it cosine-weighted
    (:func:`~.soft_lights._soft_kernel`'s ``inside``)."""
    if j >= L or sa.light_kind[j] == LIGHT_SUN or sa.light_kind[j] == LIGHT_AREA:
        return False
    rr = sa.light_radius[j]
    vx = sa.light_pos[j, 0] - qx
    vy = sa.light_pos[j, 1] - qy
    vz = sa.light_pos[j, 2] - qz
    return (not sa.light_soft[j]) and vx * vx + vy * vy + vz * vz <= rr * rr


@njit(cache=True, nogil=True, inline="always")
def _far_side(sa, P, NG, MAT, i, qx, qy, qz):
    """``(far, fx, fy, fz)``: whether point ``i`` is on a rough interface (its lights'
    samples below the surface traced too) and their origin there (the far side of its hit
    ``P``, :func:`~.shading.far_origin`; else its spawn point ``q``)."""
    if rough_interface(sa, MAT[i]):
        fx, fy, fz = far_origin(sa, P[i, 0], P[i, 1], P[i, 2], NG[i, 0], NG[i, 1], NG[i, 2])
        return True, fx, fy, fz
    return False, qx, qy, qz


@njit(cache=True, nogil=True, inline="always")
def _sample_ray(sa, j, L, inside, far, qx, qy, qz, gx, gy, gz, sx, sy, sz, n, u, v):
    """One sample of a (point, light) row as :func:`~.soft_lights._soft_kernel` draws it:
    ``(dx, dy, dz, tmax, traced, below)`` (``traced``: its weight is not zero; ``below``: a
    light's sample below a rough interface, ``far``, which the tracer traces from the far
    side, :func:`~.shading.far_origin`)."""
    if j >= L or inside:
        dx, dy, dz = _cosine_dir(sx, sy, sz, u, v)
        if j >= L:
            t = np.inf
        else:
            t = _sphere_exit(qx, qy, qz, dx, dy, dz, sa.light_pos[j, 0], sa.light_pos[j, 1],
                             sa.light_pos[j, 2], sa.light_radius[j]) * (
                                 1.0 - tol.SHADOW_END_REL)
        wgt = math.pi
        cs = 1.0
    else:
        dx, dy, dz, t, wgt = _sample_one(sa, j, qx, qy, qz, u, v)
        cs = dot3(sx, sy, sz, dx, dy, dz)
    # (the weight the tracer keeps; a sample is traced where it is not zero)
    w, below = sample_weight(far and j < L, wgt, cs, dot3(gx, gy, gz, dx, dy, dz),
                             dot3(sx, sy, sz, dx, dy, dz), t, 1.0 / n)
    return dx, dy, dz, t, w > 0.0, below


@njit(cache=True, nogil=True, inline="always")
def _segment_sphere(ox, oy, oz, dx, dy, dz, e, cx, cy, cz, r):
    """Does the segment from o along unit d to length ``e`` (inf: a ray) come within ``r``
    of c?"""
    wx, wy, wz = cx - ox, cy - oy, cz - oz
    s = min(max(wx * dx + wy * dy + wz * dz, 0.0), e)
    px, py, pz = wx - s * dx, wy - s * dy, wz - s * dz
    return px * px + py * py + pz * pz <= r * r


@njit(cache=True, nogil=True, inline="always")
def _row_axis(sa, j, L, inside, qx, qy, qz, sx, sy, sz):
    """How the row of light ``j`` (``L``: the world) at spawn point q draws its samples'
    directions from ``(u, v)``, for :func:`_windows`: ``(form, ax, ay, az, omc)`` -- form
    1 cosine-weighted about unit a (``sin^2`` of the polar angle is u), 2 uniform in the
    cone about unit a with ``1 - cos`` of its half angle ``omc`` (``1 - cos`` of the polar
    angle is ``u omc``), the azimuth ``2 pi v`` about :func:`~.shading.onb` (a) in both
    (:func:`~.soft_lights._cosine_dir`, :func:`~.soft_lights._cone_dir`); 0: neither (an
    area light's points)."""
    if j >= L or inside:
        return 1, sx, sy, sz, 0.0
    kind = sa.light_kind[j]
    if kind == LIGHT_AREA:
        return 0, 0.0, 0.0, 1.0, 0.0
    if kind == LIGHT_SUN:
        omc = 2.0 * math.sin(0.5 * sa.light_half[j]) ** 2
        return 2, -sa.light_dir[j, 0], -sa.light_dir[j, 1], -sa.light_dir[j, 2], omc
    vx = sa.light_pos[j, 0] - qx
    vy = sa.light_pos[j, 1] - qy
    vz = sa.light_pos[j, 2] - qz
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    if not dist > 0.0:
        return 0, 0.0, 0.0, 1.0, 0.0
    s2 = _sphere_sin2(sa.light_radius[j], dist, sa.light_soft[j])
    if s2 < 0.0:
        s2 = 1.0
    omc = s2 / (1.0 + math.sqrt(max(0.0, 1.0 - s2)))
    return 2, vx / dist, vy / dist, vz / dist, omc


@njit(cache=True, nogil=True, inline="always")
def _windows(form, ax, ay, az, omc, cv, win, reg_tag, need):
    """Per region (its sphere's cone from the point: :func:`crossing_rows`' ``cv``) the
    samples of a row (:func:`_row_axis`) whose direction may lie in that cone, as a window
    of the unit square: ``win[q] = (u_lo, u_hi, phi_c, dphi)`` -- u within [u_lo, u_hi] and
    the azimuth ``2 pi v`` within ``dphi`` of ``phi_c`` (``dphi`` < 0: any azimuth). The
    cone of half angle h about a direction at polar angle alpha from a holds polar angles
    within h of alpha and (alpha > h) azimuths within ``asin(sin h / sin alpha)`` of its
    own; both widened by :data:`~.tolerances.RECORD_DIR_ERROR` (the rounding of the
    sample's direction is far below it). A region whose ``reg_tag`` is not in ``need`` has
    no window (no sample tests it)."""
    err = tol.RECORD_DIR_ERROR
    tx, ty, tz, bx, by, bz = onb(ax, ay, az)
    for q in range(cv.shape[0]):
        win[q, 0] = -1.0
        win[q, 1] = 2.0
        win[q, 3] = -1.0
        if not reg_tag[q] & need:
            win[q, 0] = 2.0
            continue
        if form == 0 or cv[q, 3] == -2.0:
            continue
        vx, vy, vz = cv[q, 0], cv[q, 1], cv[q, 2]
        dist = math.sqrt(vx * vx + vy * vy + vz * vz)
        h = math.acos(min(max(cv[q, 3] / dist, -1.0), 1.0)) + err  # (cv[q, 3]: cos h dist)
        ca = (vx * ax + vy * ay + vz * az) / dist
        alpha = math.acos(min(max(ca, -1.0), 1.0))
        lo_a = alpha - h
        hi_a = alpha + h
        if form == 1:
            if lo_a >= 0.5 * math.pi:
                win[q, 0] = 2.0  # wholly below the horizon: no sample
                continue
            if lo_a > 0.0:
                win[q, 0] = math.sin(lo_a) ** 2 * (1.0 - 1e-9)
            if hi_a < 0.5 * math.pi:
                win[q, 1] = math.sin(hi_a) ** 2 * (1.0 + 1e-9) + 1e-15
        elif omc > 0.0:
            if lo_a > 0.0:
                win[q, 0] = 2.0 * math.sin(0.5 * lo_a) ** 2 / omc * (1.0 - 1e-9)
            if hi_a < math.pi:
                win[q, 1] = 2.0 * math.sin(0.5 * hi_a) ** 2 / omc * (1.0 + 1e-9) + 1e-15
        if lo_a > 0.0 and hi_a < math.pi:
            sa_ = math.sin(alpha)
            win[q, 2] = math.atan2(vx * bx + vy * by + vz * bz, vx * tx + vy * ty + vz * tz)
            win[q, 3] = math.asin(min(math.sin(h) / sa_, 1.0)) + err


@njit(cache=True, nogil=True, inline="always")
def _in_window(win, u, v):
    """Can a sample at ``(u, v)`` lie in one of the regions' cones (:func:`_windows`)?"""
    for q in range(win.shape[0]):
        if u < win[q, 0] or u > win[q, 1]:
            continue
        if win[q, 3] < 0.0:
            return True
        dp = abs(2.0 * math.pi * v - win[q, 2])  # (in [0, 3 pi): v in [0, 1), phi_c in [-pi, pi])
        if dp > 2.0 * math.pi:
            dp -= 2.0 * math.pi
        if min(dp, 2.0 * math.pi - dp) <= win[q, 3]:
            return True
    return False


#: rows per task of :func:`crossing_rows` (its scratch arrays are allocated per task)
_CROSSING_CHUNK = 256


_CrossingScene = view_type("_CrossingScene", SceneArrays, (
    "light_cos_inner", "light_cos_outer", "light_dir", "light_ellipse", "light_half",
    "light_kind", "light_pos", "light_radius", "light_size", "light_soft",
    "light_spot_frame", "light_spot_scaled", "light_spread", "light_u", "light_v",
    "mat_ior", "mat_model", "mat_roughness", "mat_transmission", "scene_extent"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def crossing_rows(sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, reg_lo, reg_hi, reg_c, reg_r,
                  reg_tag, old, cand, windows, mask, count):
    """Per (point, light) row (point ``pt``, light ``lj``, ``L`` for the world): the bits of
    its ``n`` samples (drawn as the tracer draws them from the point's seed, from its spawn
    point ``Q`` or, below a rough interface of material ``MAT``, from the far side of its
    hit ``P``) that carry light and whose visibility an edit may change (``mask`` (m,)
    uint64), and how many (``count``): a sample visible before (its bit in ``old`` (m,)
    uint64 set) only where it may cross a region an object is in now (``reg_tag`` with
    :data:`~.edits.PART_NEW`), one blocked before only where it may cross one an object
    left (:data:`~.edits.PART_OLD`) -- a ray that met nothing meets something only where
    geometry came, one that met something meets nothing only where geometry went -- by
    the region's box ``reg_lo, reg_hi`` and its sphere ``reg_c, reg_r`` both.
    ``cand`` (m,) uint64: the samples to test (the records' queries' answer,
    :class:`SampleCandidates`; :data:`ALL`: every one). ``windows``: skip the samples
    whose ``(u, v)`` alone puts them outside every region's cone (:func:`_windows`; False
    only to test that it drops none; not drawn for a row with candidates)."""
    sa = _CrossingScene(*fields(sa, _CrossingScene))  # the fields its loop reads
    k_reg = reg_lo.shape[0]
    m = pt.shape[0]
    for ch in prange((m + _CROSSING_CHUNK - 1) // _CROSSING_CHUNK):
        cv = np.empty((k_reg, 4))
        win = np.empty((k_reg, 4))
        for r in range(ch * _CROSSING_CHUNK, min(m, (ch + 1) * _CROSSING_CHUNK)):
            mask[r], count[r] = _crossing_row(sa, P, Q, NG, NS, MAT, seeds, pt[r], lj[r], n,
                                              reg_lo, reg_hi, reg_c, reg_r, reg_tag, old[r],
                                              cand[r], windows, cv, win)


@njit(cache=True, nogil=True, inline="always")
def _crossing_row(sa, P, Q, NG, NS, MAT, seeds, i, j, n, reg_lo, reg_hi, reg_c, reg_r,
                  reg_tag, old, cand, windows, cv, win):
    """:func:`crossing_rows` of one row (point ``i``, light ``j``): ``(mask, count)``;
    ``cv``, ``win`` (k_reg, 4) scratch."""
    L = sa.light_kind.shape[0]
    k_reg = reg_lo.shape[0]
    err = tol.RECORD_DIR_ERROR
    qx, qy, qz = Q[i, 0], Q[i, 1], Q[i, 2]
    # the regions some sample may need: where objects came if one was visible, where they
    # went if one was blocked (the others are skipped, their windows empty)
    full = (np.uint64(1) << np.uint64(n)) - np.uint64(1) if n < 64 else ~np.uint64(0)
    need = (PART_NEW if old != np.uint64(0) else 0) | (PART_OLD if old & full != full else 0)
    # each region's sphere seen from the point: a cone of directions (a cheap rejection
    # before the sphere and box tests; -2: the point is inside the sphere)
    for q in range(k_reg):
        if not reg_tag[q] & need:
            continue
        vx = reg_c[q, 0] - qx
        vy = reg_c[q, 1] - qy
        vz = reg_c[q, 2] - qz
        rad = reg_r[q]
        dist = math.sqrt(vx * vx + vy * vy + vz * vz)
        cv[q, 0] = vx
        cv[q, 1] = vy
        cv[q, 2] = vz
        if dist <= rad * (1.0 + err):
            cv[q, 3] = -2.0
        else:
            half = math.asin(min(rad / dist, 1.0)) + err
            cv[q, 3] = (math.cos(half) if half < math.pi else -1.0) * dist
    inside = _row_inside(sa, j, L, qx, qy, qz)
    far, fx, fy, fz = _far_side(sa, P, NG, MAT, i, qx, qy, qz)
    # the samples' (u, v) whose directions may meet a region's cone, tested before the
    # direction is drawn (not for rows traced from the far side of a rough interface:
    # their cones are seen from Q)
    form, ax, ay, az, omc = _row_axis(sa, j, L, inside, qx, qy, qz, NS[i, 0], NS[i, 1],
                                      NS[i, 2])
    _windows(0 if far or not windows or cand != ALL else form, ax, ay, az, omc, cv, win,
             reg_tag, need)
    h = row_hash(seeds[i], j, L)
    b = np.uint64(0)
    c = 0
    for s in range(n):
        if not (cand >> np.uint64(s)) & np.uint64(1):
            continue
        u, v = row_uv(h, n, s)
        if not _in_window(win, u, v):
            continue
        dx, dy, dz, t, ok, below = _sample_ray(sa, j, L, inside, far, qx, qy, qz, NG[i, 0],
                                               NG[i, 1], NG[i, 2], NS[i, 0], NS[i, 1],
                                               NS[i, 2], n, u, v)
        if not ok:
            continue
        ray = not t < np.inf
        e = 1.0 if ray else t
        ox, oy, oz = (fx, fy, fz) if below else (qx, qy, qz)
        need = PART_NEW if (old >> np.uint64(s)) & np.uint64(1) else PART_OLD
        for q in range(k_reg):
            if not reg_tag[q] & need:
                continue  # (visible: only what came may block it; blocked: only what went)
            if not below and cv[q, 3] != -2.0 and \
                    dx * cv[q, 0] + dy * cv[q, 1] + dz * cv[q, 2] < cv[q, 3]:
                continue  # outside the cone of the region's sphere (seen from Q)
            if not _segment_sphere(ox, oy, oz, dx, dy, dz, t, reg_c[q, 0], reg_c[q, 1],
                                   reg_c[q, 2], reg_r[q]):
                continue
            if _segment_box(ox, oy, oz, ox + dx * e, oy + dy * e, oz + dz * e, reg_lo[q],
                            reg_hi[q], ray):
                b |= np.uint64(1) << np.uint64(s)
                c += 1
                break
    return b, c


@njit(cache=True, nogil=True, parallel=True)
def crossing_rays(sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, mask, start, o, d, tmax, row,
                  bit):
    """The rays of :func:`crossing_rows`' samples (``mask``): row ``r``'s from
    ``start[r]`` on, in sample order, into ``o, d, tmax``, their row ``row`` and their
    sample's bit ``bit``."""
    sa = _CrossingScene(*fields(sa, _CrossingScene))  # the fields its loop reads
    L = sa.light_kind.shape[0]
    for r in prange(pt.shape[0]):
        if mask[r] == 0:
            continue
        i = pt[r]
        j = lj[r]
        qx, qy, qz = Q[i, 0], Q[i, 1], Q[i, 2]
        inside = _row_inside(sa, j, L, qx, qy, qz)
        far, fx, fy, fz = _far_side(sa, P, NG, MAT, i, qx, qy, qz)
        h = row_hash(seeds[i], j, L)
        k = start[r]
        for s in range(n):
            if not (mask[r] >> np.uint64(s)) & np.uint64(1):
                continue
            u, v = row_uv(h, n, s)
            dx, dy, dz, t, _, below = _sample_ray(sa, j, L, inside, far, qx, qy, qz,
                                                  NG[i, 0], NG[i, 1], NG[i, 2], NS[i, 0],
                                                  NS[i, 1], NS[i, 2], n, u, v)
            o[k, 0] = fx if below else qx
            o[k, 1] = fy if below else qy
            o[k, 2] = fz if below else qz
            d[k, 0] = dx
            d[k, 1] = dy
            d[k, 2] = dz
            tmax[k] = t
            row[k] = r
            bit[k] = np.uint64(1) << np.uint64(s)
            k += 1
