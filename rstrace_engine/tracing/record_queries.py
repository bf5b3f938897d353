"""The per-pixel records' segment queries (:mod:`.pixel_records`): every recorded node's
segment -- the view ray, a reflection or refraction ray, the shadow rays to the lights it
traced -- against the edited regions, primary nodes culled by screen tiles.

A node's own segment (the ray to its hit, or a miss's direction) is tested against the
places edited objects *came to* only (``seg_*``: :data:`~.edits.PART_NEW` parts, each by its
box and its sphere, grown): a ray that did not hit an edited object (a node that did is
dirty by its table row) meets what it met unless geometry came into its way -- taking an
object away changes only the rays that hit it. The shadow segments to hard lights are
tested against the regions (``reg_*``: old box union new box), as a shadow ray may pass
where its blocker went."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import stripes
from .. import tolerances as tol
from .light_bits import has
from .record_codes import _cone_sphere, _decode_point, _light_hit, _oct_decode, _segment_box
from .sample_rays import _segment_sphere


@njit(cache=True, nogil=True)
def _node_dirty(code, origin_x, origin_y, origin_z, inst, traced, lo, step, levels, shift,
                reg_lo, reg_hi, seg_lo, seg_hi, seg_c, seg_r, light_kind, light_pos,
                light_dir):
    """Geometric test of one node: its segment against the places objects came to
    (``seg_*``: box and sphere both) and its shadow segments against the regions
    (``reg_*``)."""
    if inst < 0:
        dx, dy, dz = _oct_decode(code)
        for q in range(seg_lo.shape[0]):
            if _cone_sphere(origin_x, origin_y, origin_z, dx, dy, dz, seg_c[q, 0],
                            seg_c[q, 1], seg_c[q, 2], seg_r[q], tol.RECORD_DIR_ERROR):
                return True
        return False
    k_reg = reg_lo.shape[0]
    px, py, pz = _decode_point(code, lo, step, levels, shift)
    if seg_lo.shape[0]:
        ex, ey, ez = px - origin_x, py - origin_y, pz - origin_z
        e = math.sqrt(ex * ex + ey * ey + ez * ez)
        if e > 0.0:
            ex, ey, ez = ex / e, ey / e, ez / e
        for q in range(seg_lo.shape[0]):
            if _segment_box(origin_x, origin_y, origin_z, px, py, pz, seg_lo[q], seg_hi[q],
                            False) and _segment_sphere(origin_x, origin_y, origin_z, ex, ey,
                                                       ez, e, seg_c[q, 0], seg_c[q, 1],
                                                       seg_c[q, 2], seg_r[q]):
                return True
    L = light_kind.shape[0]
    for j in range(L):
        if not has(traced, j):
            continue
        for q in range(k_reg):
            if _light_hit(px, py, pz, j, reg_lo[q], reg_hi[q], light_kind, light_pos,
                          light_dir):
                return True
    return False


@njit(cache=True, nogil=True, parallel=True)
def _query_primary(p_combo, p_code, combo_dirty, combo_inst, combo_traced, cam_origin,
                   ortho_origins, lo, step, levels, shift, reg_lo, reg_hi, seg_lo, seg_hi,
                   seg_c, seg_r, light_kind, light_pos, light_dir, out):
    n = p_combo.shape[0]
    for g in prange(n):
        c = p_combo[g]
        if combo_dirty[c]:
            out[g] = True
            continue
        if ortho_origins.shape[0] > 0:
            ox = ortho_origins[g, 0]
            oy = ortho_origins[g, 1]
            oz = ortho_origins[g, 2]
        else:
            ox, oy, oz = cam_origin[0], cam_origin[1], cam_origin[2]
        out[g] = _node_dirty(p_code[g], ox, oy, oz, combo_inst[c], combo_traced[c], lo, step,
                             levels, shift, reg_lo, reg_hi, seg_lo, seg_hi, seg_c, seg_r,
                             light_kind, light_pos, light_dir)


TILE = 8  # pixels per side of the screen tiles the primary query culls with


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _query_tiles(p_combo, p_code, combo_dirty, combo_inst, combo_traced, cam_origin, width,
                 height, n_pixels, lo, step, levels, shift, reg_lo, reg_hi, seg_lo, seg_hi,
                 seg_c, seg_r, light_kind, light_pos, light_dir, out, box_scratch,
                 traced_scratch, first, n_stripes):
    """The primary query, culled by screen tiles (perspective cameras).

    Per tile of TILE x TILE pixels of one sample: the box of its decoded hit points and the
    union of its traced lights. A segment from the camera to any point of the box lies
    within the box's half-size of the segment to its centre (and likewise towards a
    light), so growing the regions by that half-size makes one test per tile and light
    conservative; only tiles that fail it (or hold a miss) test their rays one by one
    (the view segments against the places objects came to, ``seg_*``; the shadow
    segments against the regions, ``reg_*``: :func:`_node_dirty`).

    Serial over the tiles of stripe ``first`` of ``n_stripes`` (:func:`query_tiles` runs
    them with :func:`~rstrace_engine.stripes.run`), without numba's reference counting
    (``_nrt=False``; a ``prange`` over 23 arrays was the costliest compile of the records'
    kernels, docs/first-render.md). It allocates nothing: box_scratch (n_stripes, 4, 3)
    float64 (the tile's box and a grown region) and traced_scratch (n_stripes, W) uint64
    (the tile's lights), row ``first`` each.
    """
    tw = (width + TILE - 1) // TILE
    th = (height + TILE - 1) // TILE
    n_tiles = tw * th * (p_combo.shape[0] // n_pixels)
    k_reg = reg_lo.shape[0]
    k_seg = seg_lo.shape[0]
    blo, bhi = box_scratch[first, 0], box_scratch[first, 1]
    glo, ghi = box_scratch[first, 2], box_scratch[first, 3]
    traced = traced_scratch[first]
    for stripe_q in range(stripes.stripe_len(n_tiles, first, n_stripes)):  # stripes.run
        t = stripes.stripe_item(stripe_q, first, n_stripes)
        if t >= n_tiles:
            break
        s = t // (tw * th)
        r = t - s * tw * th
        ty = r // tw
        tx = r - ty * tw
        x0, y0 = tx * TILE, ty * TILE
        x1, y1 = min(x0 + TILE, width), min(y0 + TILE, height)
        blo[:] = np.inf
        bhi[:] = -np.inf
        traced[:] = 0
        check = False
        for y in range(y0, y1):
            for x in range(x0, x1):
                g = s * n_pixels + y * width + x
                c = p_combo[g]
                if combo_inst[c] < 0:
                    check = True  # misses are tested ray by ray
                    continue
                for w in range(traced.shape[0]):
                    traced[w] |= combo_traced[c, w]
                px, py, pz = _decode_point(p_code[g], lo, step, levels, shift)
                blo[0] = min(blo[0], px)
                blo[1] = min(blo[1], py)
                blo[2] = min(blo[2], pz)
                bhi[0] = max(bhi[0], px)
                bhi[1] = max(bhi[1], py)
                bhi[2] = max(bhi[2], pz)
        if not check and blo[0] <= bhi[0] and k_reg + k_seg > 0:
            cx = 0.5 * (blo[0] + bhi[0])
            cy = 0.5 * (blo[1] + bhi[1])
            cz = 0.5 * (blo[2] + bhi[2])
            for q in range(k_seg):
                for k in range(3):
                    half = 0.5 * (bhi[k] - blo[k])
                    glo[k] = seg_lo[q, k] - half
                    ghi[k] = seg_hi[q, k] + half
                if _segment_box(cam_origin[0], cam_origin[1], cam_origin[2], cx, cy, cz,
                                glo, ghi, False):
                    check = True
                    break
            for q in range(k_reg):
                if check:
                    break
                for k in range(3):
                    half = 0.5 * (bhi[k] - blo[k])
                    glo[k] = reg_lo[q, k] - half
                    ghi[k] = reg_hi[q, k] + half
                for j in range(light_kind.shape[0]):
                    if not has(traced, j):
                        continue
                    if _light_hit(cx, cy, cz, j, glo, ghi, light_kind, light_pos, light_dir):
                        check = True
                        break
                if check:
                    break
        for y in range(y0, y1):
            for x in range(x0, x1):
                g = s * n_pixels + y * width + x
                c = p_combo[g]
                if combo_dirty[c]:
                    out[g] = True
                elif check:
                    out[g] = _node_dirty(p_code[g], cam_origin[0], cam_origin[1],
                                         cam_origin[2], combo_inst[c], combo_traced[c], lo,
                                         step, levels, shift, reg_lo, reg_hi, seg_lo, seg_hi,
                                         seg_c, seg_r, light_kind, light_pos, light_dir)


def query_tiles(p_combo, p_code, combo_dirty, combo_inst, combo_traced, cam_origin, width,
                height, n_pixels, lo, step, levels, shift, reg_lo, reg_hi, seg_lo, seg_hi,
                seg_c, seg_r, light_kind, light_pos, light_dir, out) -> None:
    """:func:`_query_tiles` over its tiles on the calling thread's numba thread count
    (:func:`~rstrace_engine.stripes.run`, blocks of tiles dealt in turn)."""
    n_tiles = (((width + TILE - 1) // TILE) * ((height + TILE - 1) // TILE)
               * (p_combo.shape[0] // max(n_pixels, 1)))
    blocks = stripes.blocks_of(n_tiles)
    k = stripes.threads_for(blocks)
    box_scratch = np.empty((k, 4, 3))
    traced_scratch = np.empty((k, combo_traced.shape[1]), np.uint64)
    stripes.run(_query_tiles, blocks, p_combo, p_code, combo_dirty, combo_inst, combo_traced,
                cam_origin, width, height, n_pixels, lo, step, levels, shift, reg_lo, reg_hi,
                seg_lo, seg_hi, seg_c, seg_r, light_kind, light_pos, light_dir, out,
                box_scratch, traced_scratch)


@njit(cache=True, nogil=True, parallel=True)
def _query_secondary(s_parent, s_combo, s_code, p_combo, p_code, n_rays, combo_dirty,
                     combo_inst, combo_traced, lo, step, levels, shift, reg_lo, reg_hi,
                     seg_lo, seg_hi, seg_c, seg_r, light_kind, light_pos, light_dir, out):
    m = s_parent.shape[0]
    for k in prange(m):
        c = s_combo[k]
        if combo_dirty[c]:
            out[k] = True
            continue
        p = s_parent[k]
        pcode = p_code[p] if p < n_rays else s_code[p - n_rays]
        ox, oy, oz = _decode_point(pcode, lo, step, levels, shift)
        out[k] = _node_dirty(s_code[k], ox, oy, oz, combo_inst[c], combo_traced[c], lo, step,
                             levels, shift, reg_lo, reg_hi, seg_lo, seg_hi, seg_c, seg_r,
                             light_kind, light_pos, light_dir)


@njit(cache=True, nogil=True)
def _mark_rays(s_ray, s_dirty, ray_dirty):
    for k in range(s_ray.shape[0]):
        if s_dirty[k]:
            ray_dirty[s_ray[k]] = True
