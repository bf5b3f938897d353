"""Sampled shadow rays in the per-pixel records (:mod:`.pixel_records`, issue 20).

A point under a light with an extent or a world that lights shoots ``n`` shadow rays per
such light, drawn from its *node seed* (:mod:`.soft_lights`: a Fibonacci lattice rotated by
a hash of the seed and the light). The records keep, per primary hit of a frame with soft
light, the shading normal (float32) and the node seed (20 bytes per sample), from which the
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
seed (secondary nodes, interpolated samples).

The primary hits' lights are found *per light* (:func:`query_light_bits`) and the world's
rays apart (:func:`query_world`): a sample whose only dirty rays are these shadow rays keeps
its primary ray and its other terms, and the incremental frame shades just those lights (or
the world) again at its primary node (:mod:`.shadow_reshade`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.scene import LIGHT_AREA, LIGHT_SUN
from .record_codes import _decode_point, _light_hit, _segment_box
from .soft_lights import _sample_one, row_hash, row_uv, world_sample_dir


def sampled_lights(sa) -> np.ndarray:
    """(L,) bool: the lights whose samples the records regenerate (area lights, suns with
    an angle; see the module doc)."""
    kind = np.asarray(sa.light_kind)
    return np.asarray(sa.light_ext, bool) & ((kind == LIGHT_AREA) | (kind == LIGHT_SUN))


@njit(cache=True, nogil=True, parallel=True)
def query_world(p_combo, p_code, combo_inst, wnorm, seed, n, n_lights, lo, step, levels,
                shift, reg_c, reg_r, out):
    """The world's rays of every primary hit against the edited regions (their bounding
    spheres ``reg_c, reg_r``, grown like every region by the quantisation and the spawn
    offset): each of the point's ``n`` cosine-weighted directions, regenerated from its
    shading normal and node seed as the tracer drew them (``n_lights``: the light slots
    when recorded, the world's row is the last), is a ray to infinity; a region it may meet
    dirties the sample. Samples with no recorded normal (NaN) are dirty. Regions wholly
    below the tangent plane of the shading normal are skipped (every world ray leaves above
    it)."""
    k_reg = reg_c.shape[0]
    err = tol.RECORD_DIR_ERROR
    for g in prange(p_combo.shape[0]):
        if out[g] or combo_inst[p_combo[g]] < 0:
            continue
        sx = float(wnorm[g, 0])
        sy = float(wnorm[g, 1])
        sz = float(wnorm[g, 2])
        if not (abs(sz) >= 1e-30 and sx == sx and sy == sy):
            out[g] = True  # unknown, or a normal whose basis could flip side
            continue
        nl = math.sqrt(sx * sx + sy * sy + sz * sz)
        sx /= nl
        sy /= nl
        sz /= nl
        h = row_hash(seed[g], n_lights)
        px, py, pz = _decode_point(p_code[g], lo, step, levels, shift)
        for q in range(k_reg):
            vx = reg_c[q, 0] - px
            vy = reg_c[q, 1] - py
            vz = reg_c[q, 2] - pz
            dist = math.sqrt(vx * vx + vy * vy + vz * vz)
            r = reg_r[q]
            if dist <= r:
                out[g] = True
                break
            if vx * sx + vy * sy + vz * sz < -r - err * dist:
                continue  # below the horizon
            half = math.asin(r / dist) + err
            ca = math.cos(half) if half < math.pi else -1.0
            hit = False
            for s in range(n):
                dx, dy, dz = world_sample_dir(h, n, s, sx, sy, sz)
                if (dx * vx + dy * vy + dz * vz) >= ca * dist:
                    hit = True
                    break
            if hit:
                out[g] = True
                break


@njit(cache=True, nogil=True, parallel=True)
def query_light_bits(sa, p_combo, p_code, combo_inst, combo_traced, wnorm, seed, n, mask,
                     lo, step, levels, shift, reg_lo, reg_hi, lgeo, skip, bits):
    """Per primary hit not in ``skip``: the lights of ``mask`` (uint64 bits: the lights
    with an extent) whose shadow rays there may cross a grown region ``reg_lo, reg_hi``,
    as bits of ``bits`` (n_rays,) uint64 (assigned). Area lights and suns with an angle
    (:func:`sampled_lights`) regenerate the point's own samples from its node seed (module
    doc); sphere lights, and every light of a sample without a recorded seed (NaN normal),
    get the shaft test of :func:`~.record_codes._light_hit` (``lgeo``:
    :func:`~.record_codes.light_geometry`). ``sa``: the packing the records describe."""
    k_reg = reg_lo.shape[0]
    L = sa.light_kind.shape[0]
    for g in prange(p_combo.shape[0]):
        bits[g] = np.uint64(0)
        c = p_combo[g]
        if skip[g] or combo_inst[c] < 0:
            continue
        todo = combo_traced[c] & mask
        if todo == 0:
            continue
        px, py, pz = _decode_point(p_code[g], lo, step, levels, shift)
        known = wnorm[g, 0] == wnorm[g, 0]
        out = np.uint64(0)
        for j in range(L):
            bit = np.uint64(1) << np.uint64(j)
            if not todo & bit:
                continue
            kind = sa.light_kind[j]
            sun = kind == LIGHT_SUN
            if not known or not (sun or kind == LIGHT_AREA):
                for q in range(k_reg):
                    if _light_hit(px, py, pz, j, reg_lo[q], reg_hi[q], sa.light_kind, lgeo,
                                  sa.light_dir):
                        out |= bit
                        break
                continue
            h = row_hash(seed[g], j)
            hit = False
            for s in range(n):
                u, v = row_uv(h, n, s)
                dx, dy, dz, t, _ = _sample_one(sa, j, px, py, pz, u, v)
                if not sun:
                    t = t / (1.0 - tol.SHADOW_END_REL)  # to the light point itself
                ex = px + dx * (1.0 if sun else t)
                ey = py + dy * (1.0 if sun else t)
                ez = pz + dz * (1.0 if sun else t)
                for q in range(k_reg):
                    if _segment_box(px, py, pz, ex, ey, ez, reg_lo[q], reg_hi[q], sun):
                        hit = True
                        break
                if hit:
                    break
            if hit:
                out |= bit
        bits[g] = out
