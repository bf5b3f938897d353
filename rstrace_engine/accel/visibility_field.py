"""The visibility field (Khanna, Mortensen, Yu, Slater; seed 003): a ray accelerator built
from parallel beams, cheap to update for moving objects.

Structure (all flat arrays, built and queried by numba kernels)
    * ``l`` directions from a subdivided tetrahedron with a constant-time nearest-direction
      look-up (:mod:`.directions`).
    * For each direction ``w`` a *parallel subfield*: the field box (the scene box grown by
      :data:`BOX_MARGIN_REL`) projected along
      ``w`` onto the plane spanned by ``e1, e2`` (``e1, e2, w`` orthonormal) and cut into
      ``n x n`` tiles. Every triangle of every instance (a *reference*: instance + global
      triangle) is scan-converted, in world space, into the tiles its projection covers
      (row by row, the span of the triangle within each row; conservatively grown by
      :data:`~.tolerances.VF_PAD_REL`; the kernels are in :mod:`.tiles`). Tile
      ``t = (k * n + row) * n + col`` lists its references in ``ref[start[t]:start[t + 1]]``
      (one flat candidate array).
    * Within a tile the references are ordered along the beam by ``zmin`` (their smallest
      depth ``x . w``), with ``pmax`` the running maximum of their largest depth, and each
      entry carries an 8 x 8 bit mask of the sub-tiles its triangle covers. A ray walks a
      tile from the first entry whose ``pmax`` reaches the depth where the ray enters the
      tile (a binary search skips everything behind it), skips entries whose mask misses
      the sub-tiles the ray crosses there, and stops at the first entry whose ``zmin`` lies
      beyond the closest hit found so far or beyond where the ray leaves the tile: the
      paper's "type of BSP tree" replaced by an order along the beam with an early exit
      (the benchmark measures it against testing every candidate). Depths are float32,
      rounded outward.

Query
    nearest direction ``w`` of the ray -> the ray's segment inside the field box projected
    onto that subfield (usually one tile; every tile the projected segment crosses is
    visited, row by row along the ray) -> the candidates are tested with the watertight test
    of :mod:`.triangle` *in object space*. Tiles are visited in the ray's order and the walk
    ends at the first tile the ray enters beyond the closest hit. The ray is taken to
    object space exactly as the
    BVH does (:func:`.bvh.ray_to_object`), so hits and distances equal the BVH's bit for bit
    (up to ties between triangles at the same distance).

Dynamic objects (the paper's section 3)
    :meth:`VisibilityField.update` compares the new packing's instance transforms with the
    previous ones; an instance whose transform changed becomes *dynamic* (for the lifetime of
    the field). Its static entries are skipped from then on (per-instance state, see
    :func:`instance_states`), and all dynamic instances are scan-converted into per-tile
    dynamic lists stamped with a version ``V``: a global ``GV`` is incremented each time the
    dynamic set moves, a query reads a tile's dynamic list only when ``V == GV``, so stale
    lists die without being visited (no pass over the ``l n^2`` tiles); the flat dynamic
    array is allocated afresh each time (the old one is reclaimed). A query searches the
    static candidates, then the valid dynamic ones linearly. A dynamic object that leaves the
    field box, or any change of geometry or of the instance set, rebuilds the field.

Memory: ``l n^2`` tiles cost 28 bytes (offsets, version, dynamic offsets and count), each
entry 20 (reference, two depths, mask); beyond ``memory_cap_mb`` the build stops with a
:class:`~.scene.SceneError` that names the settings, before the big arrays are allocated.
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..frame import VF_MEMORY_CAP_MB, check_vf_settings
from ..geometry.scene import SceneArrays, SceneError
from .bvh import ray_to_object
from .directions import direction_table, level_for, nearest_direction
from .interface import Accelerator, empty_hits
from .tiles import (
    COUNT,
    DYN_COUNT,
    DYN_FILL,
    FILL,
    SUB,
    cell,
    order_tiles,
    raster,
    row_bits,
    world_triangles,
)
from .triangle import intersect_sheared, ray_shear

log = logging.getLogger(__name__)

#: Default number of directions ``l`` (subdivision level 2) and tiles per side ``n``: the
#: fastest queries per MB in the benchmark's sweep (README, *Measured*).
DEFAULT_DIRECTIONS = 34
DEFAULT_TILES = 64
#: The field box is the scene box grown by this fraction of its diagonal on every side, so
#: objects can move a little beyond the scene's first extent without a rebuild.
BOX_MARGIN_REL = 0.1
#: Bytes per tile (static offset int64, dynamic version int64, offset int64, count int32).
TILE_BYTES = 28
#: Bytes per entry (reference int32, zmin float32, pmax or zmax float32, sub-tile mask int64).
ENTRY_BYTES = 20
#: Rays per parallel work item and work items a thread takes at a time.
CHUNK = 64
PARALLEL_CHUNKSIZE = 16


#: Instance states (:func:`instance_states`).
STATIC, DYNAMIC, NEVER = 0, 1, 2



class Subfields(NamedTuple):
    """The parallel subfields' geometry: one row per direction ``k``."""

    frame: np.ndarray  # (l, 9) float64: e1, e2, w
    grid: np.ndarray  # (l, 4) float64: u0, v0, n / width_u, n / width_v
    box: np.ndarray  # (2, 3) float64 field box (padded scene box)
    pad: float  # world-space margin (VF_PAD_REL * coordinate magnitude)
    n: int  # tiles per side


class StaticLists(NamedTuple):
    """Static candidates: tile ``t`` owns ``ref[start[t]:start[t + 1]]`` (ordered by zmin)."""

    start: np.ndarray  # (l n^2 + 1,) int64
    ref: np.ndarray  # (E,) int32 reference id
    zmin: np.ndarray  # (E,) float32 smallest depth along w (rounded down)
    pmax: np.ndarray  # (E,) float32 running max of the largest depth (rounded up)
    mask: np.ndarray  # (E,) int64 sub-tile cells (8 x 8, bit 8 row + col) it covers


class DynamicLists(NamedTuple):
    """Dynamic candidates: tile ``t`` is valid when ``stamp[t] == GV``; it owns
    ``ref[start[t]:start[t] + count[t]]``."""

    stamp: np.ndarray  # (l n^2,) int64 version V of the tile's list
    start: np.ndarray  # (l n^2,) int64
    count: np.ndarray  # (l n^2,) int32
    ref: np.ndarray  # (D,) int32
    zmin: np.ndarray  # (D,) float32
    zmax: np.ndarray  # (D,) float32
    mask: np.ndarray  # (D,) int64


class References(NamedTuple):
    """Every (instance, triangle) pair of the scene and the object-space triangles."""

    inst: np.ndarray  # (R,) int32
    prim: np.ndarray  # (R,) int32 global triangle
    first: np.ndarray  # (I + 1,) int64: instance i owns references first[i]:first[i + 1]
    tv: np.ndarray  # (T, 9) float64 object-space vertices of every global triangle


# ----------------------------------------------------------------------------- build helpers


def references(sa: SceneArrays) -> References:
    """The scene's references, instance by instance."""
    s = sa.mesh_tri_start.astype(np.int64)
    m = sa.inst_mesh.astype(np.int64)
    cnt = s[m + 1] - s[m]
    first = np.concatenate([[0], np.cumsum(cnt)]).astype(np.int64)
    inst = np.repeat(np.arange(len(m), dtype=np.int32), cnt)
    prim = (s[m][inst] + np.arange(first[-1]) - first[:-1][inst]).astype(np.int32)
    tv = np.ascontiguousarray(sa.verts[sa.tris].reshape(-1, 9))
    return References(inst, prim, first, tv)


def instance_states(alive: np.ndarray, dynamic: np.ndarray) -> np.ndarray:
    """Per-instance state (I,) int8: :data:`STATIC`, :data:`DYNAMIC` or :data:`NEVER`.

    The one place that decides which instances a query may hit and through which lists;
    slots that hold no visible object (``SceneArrays.inst_alive`` False: deleted or hidden,
    kept as tombstones) get ``NEVER``.
    """
    state = np.full(len(alive), STATIC, np.int8)
    state[dynamic] = DYNAMIC
    state[~np.asarray(alive, bool)] = NEVER
    return state


def subfields(dirs: np.ndarray, scene_aabb: np.ndarray, n: int) -> Subfields:
    """Frames and tile grids of every direction over the padded scene box."""
    lo, hi = scene_aabb
    mag = float(np.abs(scene_aabb).max() + np.linalg.norm(hi - lo))
    pad = tol.VF_PAD_REL * max(mag, 1e-300)
    margin = BOX_MARGIN_REL * float(np.linalg.norm(hi - lo)) + 4.0 * pad
    box = np.array([lo - margin, hi + margin])
    helper = np.where(np.abs(dirs[:, :1]) < 0.6, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(dirs, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(dirs, e1)
    corners = np.array([[x, y, z] for x in box[:, 0] for y in box[:, 1] for z in box[:, 2]])
    pu, pv = corners @ e1.T, corners @ e2.T  # (8, l)
    u0, v0 = pu.min(axis=0) - pad, pv.min(axis=0) - pad
    wu, wv = pu.max(axis=0) + pad - u0, pv.max(axis=0) + pad - v0
    grid = np.stack([u0, v0, n / wu, n / wv], axis=1)
    return Subfields(np.ascontiguousarray(np.concatenate([e1, e2, dirs], axis=1)),
                     np.ascontiguousarray(grid), box, float(pad), int(n))


# ----------------------------------------------------------------------------- query


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _clip_box(box, ox, oy, oz, dx, dy, dz, t0, t1):
    """Ray interval ``[t0, t1]`` clipped to the field box (may come back empty)."""
    for a in range(3):
        o = ox if a == 0 else (oy if a == 1 else oz)
        d = dx if a == 0 else (dy if a == 1 else dz)
        if d == 0.0:
            if o < box[0, a] or o > box[1, a]:
                return 1.0, 0.0
            continue
        ta, tb = (box[0, a] - o) / d, (box[1, a] - o) / d
        if ta > tb:
            ta, tb = tb, ta
        t0, t1 = max(t0, ta), min(t1, tb)
    return t0, t1


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _clip_slab(xa, xb, lo, hi, s0, s1):
    """``[s0, s1]`` clipped to where ``xa + s (xb - xa)`` lies in ``[lo, hi]``."""
    if xb == xa:
        if xa < lo or xa > hi:
            return 1.0, 0.0
        return s0, s1
    sa_, sb_ = (lo - xa) / (xb - xa), (hi - xa) / (xb - xa)
    return max(s0, min(sa_, sb_)), min(s1, max(sa_, sb_))


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _trace_ray(sf_frame, sf_grid, box, pad, n, tab, st, dyn, refs_inst, refs_prim, tv,
               inst_inv, state, gv, ox, oy, oz, dx, dy, dz, tmin, tmax, anyhit, only,
               ordered):
    """One ray through the field. Returns ``(inst, t, prim, u, v)`` (inst -1 on a miss).

    ``ordered`` False ignores the order along the beam (every static candidate of a tile is
    tested; for the benchmark's measurement of what the order buys)."""
    bi, bp, bu, bv = -1, -1, 0.0, 0.0
    best = tmax
    t0, t1 = _clip_box(box, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if not t0 <= t1:
        return bi, best, bp, bu, bv
    k = nearest_direction(tab.dirs, tab.corners, tab.face_inv, tab.res, tab.cell_start,
                          tab.cell_dirs, dx, dy, dz)
    ou = ox * sf_frame[k, 0] + oy * sf_frame[k, 1] + oz * sf_frame[k, 2]
    du = dx * sf_frame[k, 0] + dy * sf_frame[k, 1] + dz * sf_frame[k, 2]
    ov = ox * sf_frame[k, 3] + oy * sf_frame[k, 4] + oz * sf_frame[k, 5]
    dv = dx * sf_frame[k, 3] + dy * sf_frame[k, 4] + dz * sf_frame[k, 5]
    ow = ox * sf_frame[k, 6] + oy * sf_frame[k, 7] + oz * sf_frame[k, 8]
    dw = dx * sf_frame[k, 6] + dy * sf_frame[k, 7] + dz * sf_frame[k, 8]  # > 0: nearest w
    ua, ub, va, vb = ou + t0 * du, ou + t1 * du, ov + t0 * dv, ov + t1 * dv
    gu, gv0, iu, iv = sf_grid[k, 0], sf_grid[k, 1], sf_grid[k, 2], sf_grid[k, 3]
    ra = cell(va - pad if vb >= va else va + pad, gv0, iv, n)
    rb = cell(vb + pad if vb >= va else vb - pad, gv0, iv, n)
    rstep = 1 if rb >= ra else -1
    li = -1
    lx, ly, lz, kx, ky, kz, sx, sy, sz = 0.0, 0.0, 0.0, 0, 1, 2, 0.0, 0.0, 0.0
    # rows in the ray's order, then columns in the ray's order: the part of the segment in
    # each tile (s in [0, 1] from t0 to t1), grown by pad, gives the tile's depth window
    for r in range(ra, rb + rstep, rstep):
        s0, s1 = _clip_slab(va, vb, gv0 + r / iv - pad, gv0 + (r + 1) / iv + pad, 0.0, 1.0)
        if s0 > s1:
            continue
        if t0 + s0 * (t1 - t0) > best:
            break  # this row and every later one lie beyond the closest hit
        xa, xb = ua + s0 * (ub - ua), ua + s1 * (ub - ua)
        ca = cell(xa - pad if xb >= xa else xa + pad, gu, iu, n)
        cb = cell(xb + pad if xb >= xa else xb - pad, gu, iu, n)
        cstep = 1 if cb >= ca else -1
        for c in range(ca, cb + cstep, cstep):
            c0, c1 = _clip_slab(ua, ub, gu + c / iu - pad, gu + (c + 1) / iu + pad, s0, s1)
            if c0 > c1:
                continue
            t_in, t_out = t0 + c0 * (t1 - t0), t0 + c1 * (t1 - t0)
            if t_in > best:
                break
            d_in = ow + t_in * dw - pad
            t = (k * n + r) * n + c
            rmask = 0
            have_mask = False  # the ray's sub-tile mask, computed at the first candidate
            for phase in range(2):
                if phase == 0:
                    a, b = st.start[t], st.start[t + 1]
                    while ordered and a < b:  # first entry that reaches the window
                        mid = (a + b) >> 1
                        if st.pmax[mid] < d_in:
                            a = mid + 1
                        else:
                            b = mid
                    b = st.start[t + 1]
                else:
                    if dyn.stamp[t] != gv:
                        break
                    a = dyn.start[t]
                    b = a + dyn.count[t]
                for x in range(a, b):
                    d_out = ow + min(best, t_out) * dw + pad
                    if not have_mask:  # the sub-tiles the ray's part in this tile crosses
                        have_mask = True
                        tu0, tv0 = gu + c / iu, gv0 + r / iv
                        su, sv = SUB * iu, SUB * iv
                        for sr in range(SUB):
                            e0, e1 = _clip_slab(va, vb, tv0 + sr / sv - pad,
                                                tv0 + (sr + 1) / sv + pad, c0, c1)
                            if e0 <= e1:
                                xa2, xb2 = ua + e0 * (ub - ua), ua + e1 * (ub - ua)
                                rmask |= row_bits(min(xa2, xb2) - pad, max(xa2, xb2) + pad,
                                                   tu0, su, sr)
                    if phase == 0:
                        if st.zmin[x] > d_out and ordered:
                            break  # ordered along the beam: nothing nearer follows
                        if st.mask[x] & rmask == 0:
                            continue
                        q = st.ref[x]
                    else:
                        if (dyn.zmin[x] > d_out or dyn.zmax[x] < d_in
                                or dyn.mask[x] & rmask == 0):
                            continue
                        q = dyn.ref[x]
                    i = refs_inst[q]
                    if state[i] != phase or (only >= 0 and i != only):
                        continue
                    if i != li:
                        li = i
                        lx, ly, lz, ex, ey, ez = ray_to_object(inst_inv, i, ox, oy, oz,
                                                               dx, dy, dz)
                        kx, ky, kz, sx, sy, sz = ray_shear(ex, ey, ez)
                        lx, ly, lz = (lx if kx == 0 else (ly if kx == 1 else lz),
                                      lx if ky == 0 else (ly if ky == 1 else lz),
                                      lx if kz == 0 else (ly if kz == 1 else lz))
                    p = refs_prim[q]
                    hit, th, uh, vh = intersect_sheared(
                        tv[p, kx], tv[p, ky], tv[p, kz], tv[p, 3 + kx], tv[p, 3 + ky],
                        tv[p, 3 + kz], tv[p, 6 + kx], tv[p, 6 + ky], tv[p, 6 + kz],
                        lx, ly, lz, sx, sy, sz, tmin, best)
                    if hit:
                        bi, best, bp, bu, bv = i, th, p, uh, vh
                        if anyhit:
                            return bi, best, bp, bu, bv
    return bi, best, bp, bu, bv


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def trace_kernel(sf_frame, sf_grid, box, pad, n, tab, st, dyn, refs_inst, refs_prim, tv,
                 inst_inv, state, gv, o, d, tmin, tmax, only, anyhit, ordered, out_t,
                 out_inst, out_prim, out_u, out_v):
    """Closest (or any) hit of each ray; outputs as :func:`.bvh.trace_kernel` (rows that miss
    are left untouched)."""
    n_rays = o.shape[0]
    for ch in prange((n_rays + CHUNK - 1) // CHUNK):
        for r in range(ch * CHUNK, min(n_rays, (ch + 1) * CHUNK)):
            if not tmin[r] <= tmax[r]:
                continue
            bi, t, p, u, v = _trace_ray(sf_frame, sf_grid, box, pad, n, tab, st, dyn,
                                        refs_inst, refs_prim, tv, inst_inv, state, gv,
                                        o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2],
                                        tmin[r], tmax[r], anyhit, only[r], ordered)
            if bi >= 0:
                out_t[r], out_inst[r], out_prim[r], out_u[r], out_v[r] = t, bi, p, u, v


# ----------------------------------------------------------------------------- accelerator


class VisibilityField(Accelerator):
    """The visibility field behind the common batch interface (see the module docstring).

    ``directions`` is rounded up to the next count the tetrahedron gives (4, 10, 34, 130,
    514, 2050); ``tiles`` is ``n`` (``n x n`` tiles per direction).
    """

    name = "VISIBILITY_FIELD"
    #: Walk each tile in its order along the beam (binary search to the ray's start, stop
    #: past the closest hit); False tests every candidate (for measurements only).
    ordered = True

    def __init__(self, scene_arrays: SceneArrays, directions: int = DEFAULT_DIRECTIONS,
                 tiles: int = DEFAULT_TILES, memory_cap_mb: float = VF_MEMORY_CAP_MB) -> None:
        super().__init__(scene_arrays)
        check_vf_settings(directions, tiles, memory_cap_mb)
        self.level = level_for(int(directions))
        self.n = int(tiles)
        self.cap_mb = float(memory_cap_mb)
        self.table = direction_table(self.level)
        self.stats.update(rebuilds=0, updates=0, update_s=0.0)
        self._build(scene_arrays)

    # -- build -------------------------------------------------------------------------

    def _check_memory(self, n_entries: int) -> float:
        l_, nn = len(self.table.dirs), self.n * self.n
        mb = (l_ * nn * TILE_BYTES + n_entries * ENTRY_BYTES) / 2**20
        if mb > self.cap_mb:
            raise SceneError(
                f"visibility field: {l_} directions x {self.n}^2 tiles and {n_entries} "
                f"entries need {mb:.0f} MB, over the cap of {self.cap_mb:.0f} MB; lower "
                "'vf_directions' or 'vf_tiles'")
        return mb

    def _build(self, sa: SceneArrays) -> None:
        t0 = time.perf_counter()
        self._check_memory(0)  # before anything of size l n^2 is allocated
        refs = references(sa)
        sf = subfields(self.table.dirs, sa.scene_aabb, self.n)
        tiles = len(self.table.dirs) * self.n * self.n
        counts = np.zeros(tiles, np.int64)
        wv = world_triangles(refs.tv, refs.inst, refs.prim, sa.inst_xform,
                              np.arange(len(refs.inst), dtype=np.int64))
        sel = np.arange(len(refs.inst), dtype=np.int32)
        args = (sf.frame, sf.grid, sf.n, sf.pad, wv, sel)
        dummy_i, dummy_f = np.zeros(0, np.int32), np.zeros(0, np.float32)
        stamp0, tot0 = np.zeros(0, np.int64), np.zeros(0, np.int64)
        raster(*args, COUNT, counts, counts, dummy_i, dummy_f, dummy_f, stamp0, stamp0, 0,
                tot0)
        n_entries = int(counts.sum())
        mb = self._check_memory(n_entries)
        start = np.zeros(tiles + 1, np.int64)
        np.cumsum(counts, out=start[1:])
        cursor = start[:-1].copy()
        ref = np.empty(n_entries, np.int32)
        zmin = np.empty(n_entries, np.float32)
        zmax = np.empty(n_entries, np.float32)
        mask = np.empty(n_entries, np.int64)
        raster(*args, FILL, counts, cursor, ref, zmin, zmax, mask, stamp0, 0, tot0)
        order_tiles(start, ref, zmin, zmax, mask)
        self.sf, self.refs, self.sa = sf, refs, sa
        self.static = StaticLists(start, ref, zmin, zmax, mask)
        self.gv = 0
        self.dynamic = DynamicLists(np.zeros(tiles, np.int64), np.zeros(tiles, np.int64),
                                    np.zeros(tiles, np.int32), dummy_i, dummy_f, dummy_f,
                                    stamp0)
        self._dynamic = np.zeros(len(sa.inst_mesh), bool)
        self._state = instance_states(sa.inst_alive, self._dynamic)
        self._geometry = (sa.verts, sa.tris, sa.mesh_tri_start.copy(), sa.inst_mesh.copy())
        build_s = time.perf_counter() - t0
        self.stats.update(directions=len(self.table.dirs), level=self.level, tiles=self.n,
                          static_entries=n_entries, dynamic_entries=0, dynamic_instances=0,
                          gv=0, memory_mb=round(mb, 3), build_s=build_s,
                          entries_per_tile=n_entries / tiles)
        log.debug("visibility field: %d directions x %d^2 tiles, %d entries, %.1f MB, "
                  "%.3f s", len(self.table.dirs), self.n, n_entries, mb, build_s)

    def _same_geometry(self, sa: SceneArrays) -> bool:
        verts, tris, mts, im = self._geometry
        if len(sa.inst_mesh) != len(im) or not np.array_equal(sa.inst_mesh, im):
            return False
        if not np.array_equal(sa.inst_alive, self.sa.inst_alive):
            return False  # an object deleted, hidden, shown or added in a reused slot
        if not np.array_equal(sa.mesh_tri_start, mts):
            return False
        return ((sa.verts is verts or np.array_equal(sa.verts, verts))
                and (sa.tris is tris or np.array_equal(sa.tris, tris)))

    # -- dynamic objects ---------------------------------------------------------------

    def update(self, scene_arrays: SceneArrays) -> None:
        """Take a new packing: instances whose transform changed become dynamic and the
        dynamic lists are rewritten under a new ``GV``; other changes rebuild the field."""
        t0 = time.perf_counter()
        sa = scene_arrays
        self.stats["updates"] += 1
        if not self._same_geometry(sa):
            self.stats["rebuilds"] += 1
            self._build(sa)
            self.stats["update_s"] = time.perf_counter() - t0
            return
        moved = np.any(sa.inst_xform != self.sa.inst_xform, axis=(1, 2))
        self.sa = sa
        if moved.any():
            self._dynamic |= moved
            box = self.sf.box
            dyn_box = sa.inst_aabb[self._dynamic]
            if np.any(dyn_box[:, 0] < box[0]) or np.any(dyn_box[:, 1] > box[1]):
                self.stats["rebuilds"] += 1  # a moving object left the field box
                self._build(sa)
            else:
                self._state = instance_states(sa.inst_alive, self._dynamic)
                self._rasterize_dynamic()
        self.stats["update_s"] = time.perf_counter() - t0

    def _rasterize_dynamic(self) -> None:
        """Write every dynamic instance into the tiles under a new version ``GV``."""
        self.gv += 1
        refs, sf, dyn = self.refs, self.sf, self.dynamic
        inst = np.flatnonzero(self._state == DYNAMIC)
        sel = (np.concatenate([np.arange(refs.first[i], refs.first[i + 1]) for i in inst])
               if len(inst) else np.zeros(0, np.int64)).astype(np.int64)
        wv = world_triangles(refs.tv, refs.inst, refs.prim, self.sa.inst_xform, sel)
        sel32 = sel.astype(np.int32)
        l_ = len(self.table.dirs)
        total = np.zeros(l_, np.int64)
        dummy_i, dummy_f = np.zeros(0, np.int32), np.zeros(0, np.float32)
        args = (sf.frame, sf.grid, sf.n, sf.pad, wv, sel32)
        raster(*args, DYN_COUNT, dyn.count, dyn.start, dummy_i, dummy_f, dummy_f,
                np.zeros(0, np.int64), dyn.stamp, self.gv, total)
        n_dyn = int(total.sum())
        self._check_memory(self.stats["static_entries"] + n_dyn)
        base = np.zeros(l_, np.int64)
        np.cumsum(total[:-1], out=base[1:])
        ref = np.empty(n_dyn, np.int32)  # the previous version's array is dropped here
        zmin = np.empty(n_dyn, np.float32)
        zmax = np.empty(n_dyn, np.float32)
        mask = np.empty(n_dyn, np.int64)
        raster(*args, DYN_FILL, dyn.count, dyn.start, ref, zmin, zmax, mask, dyn.stamp,
                self.gv, base)
        self.dynamic = DynamicLists(dyn.stamp, dyn.start, dyn.count, ref, zmin, zmax, mask)
        mb = self._check_memory(self.stats["static_entries"] + n_dyn)
        self.stats.update(dynamic_entries=n_dyn, dynamic_instances=len(inst), gv=self.gv,
                          memory_mb=round(mb, 3))

    def set_dynamic(self, instances) -> None:
        """Mark ``instances`` (ids) dynamic now, e.g. ahead of an animation."""
        self._dynamic[np.asarray(instances, dtype=np.int64)] = True
        self._state = instance_states(self.sa.inst_alive, self._dynamic)
        self._rasterize_dynamic()

    # -- query -------------------------------------------------------------------------

    def _trace(self, o, d, tmin, tmax, only, anyhit):
        n = len(o)
        hits = empty_hits(n)
        if only is None:
            only = np.full(n, -1, np.int32)
        sf, refs = self.sf, self.refs
        t0 = time.perf_counter()
        with numba.parallel_chunksize(PARALLEL_CHUNKSIZE):
            trace_kernel(sf.frame, sf.grid, sf.box, sf.pad, sf.n, self.table, self.static,
                         self.dynamic, refs.inst, refs.prim, refs.tv,
                         np.ascontiguousarray(self.sa.inst_inv, dtype=np.float64),
                         self._state, self.gv, o, d, tmin, tmax, only, anyhit,
                         self.ordered, *hits)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + n
        return hits
