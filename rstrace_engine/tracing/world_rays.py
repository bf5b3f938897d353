"""The world's rays in the per-pixel records (:mod:`.pixel_records`, issue 20).

While the world lights, the tracer shoots ``n`` cosine-weighted rays to infinity from every
surface point. The records keep, per primary hit, the shading normal (float32) and the
world row's sample hash (:func:`~.soft_lights.world_row_hash`), from which the rays are
regenerated exactly as the tracer drew them (:func:`~.soft_lights.world_sample_dir`); an
edit dirties a sample only where one of them may meet an edited region. 20 bytes per
sample, kept only while the world lights.
"""

from __future__ import annotations

import math

from numba import njit, prange

from .. import tolerances as tol
from .record_codes import _decode_point
from .soft_lights import world_row_hash, world_sample_dir


@njit(cache=True, nogil=True)
def row_hashes(seeds, L, out):
    for i in range(seeds.shape[0]):
        out[i] = world_row_hash(seeds[i], L)


@njit(cache=True, nogil=True, parallel=True)
def query_world(p_combo, p_code, combo_inst, wnorm, whash, n, lo, step, levels, shift,
                 reg_c, reg_r, out):
    """The world's rays of every primary hit against the edited regions (their bounding
    spheres, grown like every region by the quantisation and the spawn offset): each of
    the point's ``n`` cosine-weighted directions, regenerated from its shading normal and
    row hash exactly as the tracer drew them (up to :data:`~.tolerances.RECORD_DIR_ERROR`
    radians), is a ray to infinity; a region it may meet dirties the sample. Samples with
    no recorded normal (NaN) are dirty. Regions wholly below the tangent plane of the
    shading normal are skipped at once (every world ray leaves above it)."""
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
                dx, dy, dz = world_sample_dir(whash[g], n, s, sx, sy, sz)
                if (dx * vx + dy * vy + dz * vz) >= ca * dist:
                    hit = True
                    break
            if hit:
                out[g] = True
                break
