"""Radiance interpolants: building them in batches, keeping them under an LRU memory cap.

An :class:`InterpolantCache` holds everything that outlives a frame for one packing of a scene:
the linetrees (:mod:`.linetree`), the traced *samples* (corner and test lines, keyed by their
lattice point so that neighbouring cells share them; a numba hash map from ``(instance, face
pair, a, b, c, d)`` to the sample) and the interpolant pool (16 RGB radiance samples, the slab
and surface class the predicate certified, the 16 sample ids whose ray trees name what the
interpolant depends on, and an LRU stamp). Camera moves invalidate nothing.

:meth:`InterpolantCache.resolve` takes the visible hits of a frame's rays on their objects and
walks them down the linetrees level by level. Per level: leaves holding an interpolant
interpolate (when the pixel's hit is the slab crossing the interpolant certifies); every empty
leaf with enough pixels is built (all of them in one batch: their missing samples are traced
together, against the object alone with :meth:`intersect_object`, then shaded through the
whole scene with :func:`~.whitted.trace` and ray trees recorded; then the error predicate of
:mod:`.predicate` and the radiance test run on the batch); failed leaves above
the depth cap split. Whatever is left is returned to be traced, with its pixel class.

The radiance test: at the cell's test lines (its centre, the 8 centres of its boundary
facets, 4 interior lines on the diagonals ``a = c, b = d``, and for non-convex meshes 4 more)
the quadrilinear interpolation of the corner radiance must match the traced radiance within
``TEST_EPS_FRAC * epsilon`` in display space (clamp to [0, 1], sRGB, per channel; above 1 the
transform is continued linearly, so saturated samples cannot hide a dip below 1 between
them): the margin stands in for the error between test lines, which samples cannot bound.
Test lines lie on the lattice of the children and grandchildren, so a split reuses them as
corners. With epsilon = 0 nothing is interpolated: no finite set of test lines proves an
interpolant exact.

Kernels over a frame's rays (``_pixel_lines``; the walk that descends and interpolates is
in :mod:`.walk`) and the
predicate run in parallel; the small per-batch kernels are serial on purpose: on a busy
machine every parallel region can cost a scheduler time slice, far more than their work.
"""

from __future__ import annotations

import logging
import math
import time
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..accel.accelerators import Hits
from ..cancel import kernel_flag
from ..frame import (
    CLASS_BACKGROUND,
    CLASS_FAIL_NONLINEAR,
    CLASS_FAIL_SHADOW,
    CLASS_FAIL_SILHOUETTE,
    CLASS_TRACED,
)
from ..geometry.mesh_topology import mesh_topology_cached, topology_kept
from . import fallback as fb_mod
from .fallback import Fallback, count_cells
from .invalidation import Dependencies, Invalidation, invalidate, take_edits
from .line_samples import line_geometry, shade_lines
from .linetree import (
    EMPTY,
    LATTICE_DEPTH,
    MAX_DEPTH,
    Linetrees,
    expanded_boxes,
    fail_class,
    fail_code,
    line_points,
    point_depth,
    ray_line,
)
from .pool import INTERP_BYTES, InterpolantPool
from .predicate import (
    N_TEST_ALL,
    N_TEST_BASE,
    R_CLASS,
    R_GLOSSY,
    R_TUNNEL_LIGHT,
    R_VALID,
    REASONS,
    TEST_POINTS,
    VALID,
    check_cells,
    corner_trees,
    radiance_ok,
)
from .sampled_term import per_pixel_query
from .samples import (
    GLOSSY,
    SEES_LIGHT,
    LineCrossings,
    SampleStore,
    TextureApplier,
)
from .shafts import light_fields, lights_only, query_scene
from .walk import group_active, settle, walk_level

log = logging.getLogger(__name__)

#: Cells shallower than this are split without being built (their lines span so much of
#: the face pair that they essentially never pass).
MIN_BUILD_DEPTH = 2
#: A leaf is built (or a failed leaf split) only when at least this many of the rays of a
#: resolve (a frame's pass: one sample of every pixel) fall in it; fewer are cheaper to
#: trace. A build costs about 60-100 traced pixels and about
#: a third of the cells built pass, so a cell of 48 rays pays back in a few frames of reuse.
MIN_PIXELS = 48
#: Cells built per batch when ``resolve`` is given a :class:`~rstrace_engine.cancel.
#: CancelFlag` (the viewport), polled between batches: a few tens of milliseconds of
#: building (otherwise one batch per level). A cell is never interrupted half built.
BUILD_STEP_CANCELLABLE = 32
#: Why a built cell ended as it did (``InterpolantCache.outcome_log``): the predicate's
#: :data:`~.predicate.REASONS`, then the radiance test and the corners' box pre-test.
OUTCOMES = (*REASONS, "radiance", "box_miss")
O_RADIANCE = len(REASONS)
O_BOX_MISS = len(REASONS) + 1
#: Shade a cell's 16 corners before its test lines and fail the cell at once when their
#: ray trees differ (``predicate.corner_trees``: the outcome ``check_cells`` would give).
#: Off only to compare (the frames are the same; more samples are shaded).
CORNERS_FIRST = True


#: (packing, :func:`.shafts.query_scene` of it) of the last packing asked for
_QS_LAST: list = [None]

# ----------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True)
def _cell_keys(box, inst, face, depth, coord, tests, ntest, aabb, k2, ok):
    """Lattice keys of each cell's 16 corners and test lines, and the cheap pre-test that
    all 16 corner lines meet the object's world box (else the cell cannot pass)."""
    for c in range(inst.shape[0]):
        sh = LATTICE_DEPTH - depth[c]
        unit = 1 << sh
        ok[c] = True
        F = np.empty(3)
        B = np.empty(3)
        sc = 1.0 / (1 << depth[c])
        o = inst[c]
        for q in range(16 + ntest[c]):
            key = 0
            for m in range(4):
                if q < 16:
                    x = (coord[c, m] + ((q >> m) & 1)) * unit
                else:
                    x = coord[c, m] * unit + int(tests[q - 16, m] * unit)
                key = (key << 15) | x
            k2[c, q] = key
        for q in range(16):
            line_points(box, o, face[c], (coord[c, 0] + (q & 1)) * sc,
                        (coord[c, 1] + ((q >> 1) & 1)) * sc, (coord[c, 2] + ((q >> 2) & 1)) * sc,
                        (coord[c, 3] + ((q >> 3) & 1)) * sc, F, B)
            t0 = 0.0
            t1 = 1.0
            for m in range(3):
                dm = B[m] - F[m]
                lo = aabb[o, 0, m]
                hi = aabb[o, 1, m]
                if dm == 0.0:
                    if F[m] < lo or F[m] > hi:
                        t0 = 2.0
                    continue
                ta = (lo - F[m]) / dm
                tb = (hi - F[m]) / dm
                t0 = max(t0, min(ta, tb))
                t1 = min(t1, max(ta, tb))
            if t0 > t1 * (1.0 + 1e-9) + 1e-12:
                ok[c] = False
                break


@njit(cache=True, nogil=True, parallel=True)
def _pixel_lines(box, cls_of_tri, inst, prim, t, o, d, face, abcd, zp, clsp):
    """Line coordinates, slab depth and surface class of the visible hits of a frame's rays
    (rays that miss, ``inst < 0``, are skipped)."""
    for r in prange(inst.shape[0]):
        k = inst[r]
        if k < 0:
            continue
        f = ray_line(box, k, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2], abcd[r])
        face[r] = f
        zp[r] = point_depth(box, k, f, o[r, 0] + d[r, 0] * t[r], o[r, 1] + d[r, 1] * t[r],
                            o[r, 2] + d[r, 2] * t[r])
        clsp[r] = cls_of_tri[prim[r]]


# ----------------------------------------------------------------------------- pool


class ResolveResult(NamedTuple):
    """Outcome of :meth:`InterpolantCache.resolve` for ``n`` rays."""

    radiance: np.ndarray  # (n, 3) float64, valid where interpolated
    interpolated: np.ndarray  # (n,) bool
    pixel_class: np.ndarray  # (n,) uint8 class of each ray (traced ones: why; misses:
    # background)
    interpolant: np.ndarray  # (n,) int32 interpolant an interpolated ray used, else -1


# ----------------------------------------------------------------------------- the cache


class InterpolantCache:
    """Interpolants of one scene packing (see the module doc).

    sa : the :class:`~.scene.SceneArrays`; accel : an accelerator over it; epsilon : display
    error bound; depth_cap : deepest linetree level (at most :data:`~.linetree.MAX_DEPTH`);
    memory_cap_mb : LRU cap on interpolants plus their samples (linetree nodes are counted
    apart); max_depth : the tracer's reflection/refraction depth.
    """

    def __init__(self, sa, accel, epsilon: float, depth_cap: int, memory_cap_mb: float,
                 max_depth: int) -> None:
        t0 = time.perf_counter()
        # (a cache started over by an edit batch that changed the number of lights had kept
        # the old scene's topology and query structures: an IndexError, or a predicate
        # tested against the old geometry -- 0.81 display error at epsilon 0.1)
        self.drop_scene_structures()
        self.sa = sa
        self.accel = accel
        self.epsilon = float(epsilon)
        self.depth_cap = min(int(depth_cap), MAX_DEPTH)
        if int(depth_cap) > MAX_DEPTH:
            log.info("interpolants: depth cap %d lowered to %d", depth_cap, MAX_DEPTH)
        self.memory_cap_bytes = float(memory_cap_mb) * 1e6
        self.max_depth = int(max_depth)
        #: the scene extent the objects' boxes are padded with, frozen: an object's box (its
        #: lines' parameterisation) depends on that object alone
        self.box_extent = float(sa.scene_extent)
        self.box = expanded_boxes(sa, self.box_extent)
        self.trees = Linetrees(len(sa.inst_mesh))
        self.deps = Dependencies(sa)
        self.samples = SampleStore(len(sa.light_kind))
        self.pool = InterpolantPool()
        self.clock = 0
        self.samples_stale = False  # an edit may have made unreferenced samples stale
        self.totals = dict(cells_built=0, cells_valid=0, samples_traced=0, evicted=0,
                           invalidated=0)
        self.frame_stats: dict = {}
        #: cells built per instance slot since the frame reset it (:mod:`.fallback`)
        self.cells_by_inst = np.zeros(len(sa.inst_mesh), np.int64)
        #: what the mode learned of where cells do not pay (:mod:`.fallback`)
        self.fallback = Fallback(len(sa.inst_mesh))
        #: a list to receive, per batch of built cells, ``(tree (m,) int32 (inst * 6 +
        #: face), depth (m,), coord (m, 4), outcome (m,) int8 index into OUTCOMES)``
        #: (diagnostics: ``scripts/interpolant_outcomes.py``); None records nothing
        self.outcome_log: list | None = None
        #: what the last full frame leaves for reprojected visibility (:mod:`.reproject`);
        #: dropped by edits
        self.view = None
        #: samples keep their per-light shares, so a light's power or colour change
        #: rescales interpolants (:mod:`.relight`; :meth:`keep_light_terms`)
        self.light_terms = False
        #: the cap (bytes) on the shares; over it new samples keep none (their cells are
        #: invalidated by light edits), and ``shares_overflow`` says so
        self.shares_cap_bytes = math.inf
        self.shares_overflow: str | None = None
        self._shares_need = 0.0
        self.setup_s = time.perf_counter() - t0

    # -- scene structures (built on first use: a frame at epsilon 0 needs none) ---------

    def drop_scene_structures(self) -> None:
        """Forget the structures built from ``self.sa`` (rebuilt for the next scene)."""
        for name in ("topo", "qs", "n_test"):
            self.__dict__.pop(name, None)

    @cached_property
    def topo(self):
        """Surface classes, boundary edges, convexity (:func:`.mesh_topology.mesh_topology`;
        kept for the last packing: a new cache of the same scene does not compute it again)."""
        if topology_kept(self.sa):
            return mesh_topology_cached(self.sa)
        return fb_mod.timed_structure("topo", len(self.sa.tris),
                                      lambda: mesh_topology_cached(self.sa))

    @cached_property
    def qs(self):
        """The predicate's query structures (:func:`.shafts.query_scene`). While the
        sampled terms of lights with an extent are traced per pixel
        (:mod:`.sampled_term`), a fully visible light needs no closed form and no
        Lambertian surface over a cell: only the horizon conditions of
        :func:`.soft_slab.soft_slab` (its closed form's, when it has one). Kept for the last
        packing (as its topology): a new cache of the same scene does not build them again;
        a packing that differs from it in its lights and world alone takes its geometry's
        (:func:`.shafts.lights_only`: a light edit does not build them again either)."""
        memo = _QS_LAST[0]
        if memo is None or memo[0] is not self.sa:
            if memo is not None and lights_only(memo[0], self.sa):
                memo = (self.sa, memo[1]._replace(**light_fields(self.sa)))
            else:
                topo = self.topo
                memo = (self.sa, fb_mod.timed_structure(
                    "qs", len(self.sa.tris), lambda: query_scene(self.sa, topo)))
            _QS_LAST[0] = memo
        return per_pixel_query(memo[1], self.sa)

    def structures_missing(self) -> list[str]:
        """The structures (:data:`.fallback.STRUCTURE_RATE`) not built for this packing."""
        m = _QS_LAST[0]
        qs = "qs" in self.__dict__ or (m is not None and lights_only(m[0], self.sa))
        return [k for k, kept in (("topo", "topo" in self.__dict__ or topology_kept(self.sa)),
                                  ("qs", qs)) if not kept]

    @property
    def tex_max(self) -> np.ndarray:
        """(3,) the largest texel of any texture (the radiance test's texel range)."""
        memo = getattr(self, "_tex_max", None)
        if memo is None or memo[0] is not self.sa.tex_data:
            memo = (self.sa.tex_data, np.maximum(np.asarray(self.sa.tex_data).max(axis=0), 0.0))
            self._tex_max = memo
        return memo[1]

    @cached_property
    def n_test(self) -> np.ndarray:
        """Test lines per instance: more for non-convex meshes."""
        return np.where(self.topo.mesh_convex[self.sa.inst_mesh], N_TEST_BASE,
                        N_TEST_ALL).astype(np.int32)

    # -- configuration ----------------------------------------------------------------

    def compatible(self, sa, epsilon: float, depth_cap: int, max_depth: int) -> bool:
        """Whether this cache's interpolants hold for these inputs."""
        return sa is self.sa and self.compatible_settings(epsilon, depth_cap, max_depth)

    def compatible_settings(self, epsilon: float, depth_cap: int, max_depth: int) -> bool:
        """Whether this cache's interpolants hold for these settings (any scene:
        :meth:`take_edits` moves them to another)."""
        return (float(epsilon) == self.epsilon
                and min(int(depth_cap), MAX_DEPTH) == self.depth_cap
                and int(max_depth) == self.max_depth)

    def keep_light_terms(self, on: bool, cap_mb: float) -> None:
        """Whether cells built from now on keep per-light shares in their samples and
        their test lines' samples (:mod:`.relight`), under a cap of ``cap_mb`` MB on the
        shares (``RenderSettings.relight_memory_mb``). Once over it the shares are dropped
        (light power and colour edits invalidate, as without them) until the cap is raised
        above what they needed. Turning it off keeps what is kept."""
        self.shares_cap_bytes = float(cap_mb) * 1e6
        if self.shares_overflow is not None and self.shares_cap_bytes > self._shares_need:
            self.shares_overflow = None  # the cap was raised: try again
        self.light_terms = (bool(on) and cap_mb > 0.0 and len(self.sa.light_kind) > 0
                            and self.shares_overflow is None)
        if self.light_terms:
            self.samples.keep_shares()

    def _keeps_shares(self, n_new: int) -> bool:
        """Whether ``n_new`` samples about to be shaded keep their shares: over the cap,
        every share is dropped (the test lines' samples no longer kept) and it is said."""
        if not self.light_terms:
            return False
        need = self.samples.share_bytes + 24 * len(self.sa.light_kind) * int(n_new)
        if need <= self.shares_cap_bytes:
            return True
        self._shares_need = need
        self.shares_overflow = (
            f"per-light shares of the interpolants' samples need {need / 1e6:.1f} MB, over "
            f"the cap of {self.shares_cap_bytes / 1e6:.1f} MB (setting 'relight_memory_mb'): "
            f"dropped, light power or colour edits invalidate the interpolants they shade")
        self.light_terms = False
        self.samples.drop_shares()
        self.pool.tests[:] = -1
        return False

    def set_memory_cap(self, memory_cap_mb: float) -> None:
        self.memory_cap_bytes = float(memory_cap_mb) * 1e6
        self.enforce_cap()

    # -- memory -----------------------------------------------------------------------

    @property
    def interpolant_bytes(self) -> int:
        """Memory under the cap: interpolant records plus the samples they keep."""
        return self.pool.n_live * INTERP_BYTES + self.samples.memory_bytes

    @property
    def memory_bytes(self) -> int:
        """Everything: interpolants, samples, the samples' hash table, linetree nodes, the
        ray segment trees and membership index."""
        return (self.interpolant_bytes + self.samples.keys.table_bytes
                + self.trees.memory_bytes + self.deps.memory_bytes)

    def compact_samples(self) -> None:
        """Drop the samples no interpolant refers to (test lines, failed cells)."""
        self.samples_stale = False
        live = np.flatnonzero(self.pool.live)
        keep = np.zeros(self.samples.n, bool)
        keep[self.pool.samples[live].reshape(-1)] = True
        tests = self.pool.tests[live]
        keep[tests[tests >= 0]] = True
        remap = self.samples.compact(keep)
        self.pool.samples[live] = remap[self.pool.samples[live]]
        self.pool.tests[live] = np.where(tests >= 0, remap[np.maximum(tests, 0)], -1)

    def evict(self, ids: np.ndarray, invalidated: bool = False) -> None:
        """Drop interpolants ``ids``: their leaves become empty (rebuilt on demand). Their
        tunnels and membership entries die with them (the pool's serials)."""
        ids = np.asarray(ids, np.int32)
        if len(ids) == 0:
            return
        self.trees.arrays.leaf[self.pool.node[ids]] = EMPTY
        self.pool.release(ids)
        self.totals["invalidated" if invalidated else "evicted"] += len(ids)

    def enforce_cap(self) -> None:
        """Evict least recently used interpolants until the cap holds."""
        cap = self.memory_cap_bytes
        if self.interpolant_bytes <= cap:
            return
        self.compact_samples()
        while self.interpolant_bytes > cap and self.pool.n_live > 0:
            live = np.flatnonzero(self.pool.live)
            per = self.interpolant_bytes / len(live)
            k = min(len(live), max(1, int(math.ceil((self.interpolant_bytes - cap) / per))))
            order = np.argsort(self.pool.stamp[live], kind="stable")
            self.evict(live[order[:k]])
            self.compact_samples()

    # -- edits ------------------------------------------------------------------------

    def invalidate(self, regions, objects=(), lights=(), materials=(), world: bool = False,
                   light_shading=()) -> Invalidation:
        """Invalidate what an edit may change (:func:`.invalidation.invalidate`)."""
        self.view = None
        return invalidate(self, regions, objects, lights, materials, world, light_shading)

    def take_edits(self, fx, sa, accel) -> Invalidation:
        """An edit batch's effects ``fx``: invalidate what they may change and go on with
        the edited scene ``sa``, keeping every valid interpolant
        (:func:`.invalidation.take_edits`)."""
        self.view = None
        out = take_edits(self, fx, sa, accel)
        self.fallback.forget(fx.objects, len(self.sa.inst_mesh))  # edited: a new chance
        return out

    def rst_memory_bytes(self) -> int:
        """Bytes of the ray segment trees and the membership index."""
        return self.deps.memory_bytes

    # -- rays -------------------------------------------------------------------------

    def pixel_lines(self, hits: Hits, origins: np.ndarray, directions: np.ndarray):
        """Line coordinates of a frame's rays: ``face (n,) int8, abcd (n, 4), depth (n,),
        surface class (n,)`` of their visible hits ``hits`` (undefined where they miss)."""
        n = len(hits.t)
        face = np.zeros(n, np.int8)
        abcd = np.zeros((n, 4))
        zp = np.zeros(n)
        clsp = np.zeros(n, np.int32)
        _pixel_lines(self.box, self.topo.tri_class, hits.inst, hits.prim, hits.t, origins,
                     directions, face, abcd, zp, clsp)
        return face, abcd, zp, clsp

    def resolve(self, inst, face, abcd, zp, clsp, cancel=None, hits=None,
                pre=None, budget=None, finish: bool = True) -> ResolveResult:
        """Interpolate what the linetrees cover, building cells as needed (module doc).

        inst (n,) int32 visible object of each ray (-1: a miss, left alone); face, abcd, zp,
        clsp from :meth:`pixel_lines`. hits: the rays' visible hits, needed when the scene
        has textures (applied per ray, :func:`.samples.apply_textures`). pre: the arrays
        ``(radiance, interpolated, pixel_class, interpolant)`` with rays interpolated
        already (reprojected: :mod:`.reproject`; their ``inst`` is -1), filled in place.
        budget: a :class:`.fallback.Budget`, cells are built while it allows (in batches).
        ``finish``: end with :meth:`finish_resolve` (a frame that resolves its pass in
        chunks calls it once, after the last).
        """
        texture = TextureApplier(self, hits) if np.any(self.sa.mat_tex >= 0) else None
        n = len(inst)
        if pre is None:
            rad = np.zeros((n, 3))
            done = np.zeros(n, bool)
            pinterp = np.full(n, -1, np.int32)
            pcls = np.where(inst >= 0, CLASS_TRACED, CLASS_BACKGROUND).astype(np.uint8)
        else:
            rad, done, pcls, pinterp = pre
            pcls[~done] = np.where(inst[~done] >= 0, CLASS_TRACED, CLASS_BACKGROUND)
        st = dict(cells_built=0, cells_valid=0, samples_traced=0, build_s=0.0, deps_s=0.0,
                  levels=0, reasons={})
        self.frame_stats = st
        active = inst >= 0
        if self.samples_stale:  # invalidate() was called alone (take_edits compacts)
            self.compact_samples()
        if not np.any(active) or self.epsilon <= 0.0:
            return ResolveResult(rad, done, pcls, pinterp)
        lt = self.trees
        nodes = np.zeros(n, np.int32)
        idx = np.flatnonzero(active)  # the rays still walking, in order
        nodes[idx] = lt.get_roots(inst[idx], face[idx])
        inherited = np.full(n, EMPTY, np.int32)
        first = min(MIN_BUILD_DEPTH, self.depth_cap)
        counts = np.zeros(0, np.int32)  # per node scratch, zero between levels
        node_cls = np.zeros(0, np.uint8)
        uniq_buf = np.empty(n, np.int32)
        for _ in range(self.depth_cap + MIN_BUILD_DEPTH + 2):
            if cancel is not None and cancel():
                break
            st["levels"] += 1
            self.clock += 1
            p = self.pool
            walk_level(lt.arrays, p.rad, p.zlo, p.zhi, p.cls, p.stamp, p.rebuilt, self.clock, nodes,
                  inherited, abcd, zp, clsp, active, idx, rad, done, pcls, pinterp)
            if texture is not None:  # before the cap may evict what was just used
                texture.apply(abcd, pinterp, rad)
            self.enforce_cap()
            if len(counts) < lt.n_nodes:
                counts = np.zeros(2 * lt.n_nodes, np.int32)
                node_cls = np.zeros(2 * lt.n_nodes, np.uint8)
            nu = group_active(nodes, active, idx, counts, uniq_buf)
            if nu == 0:
                break
            uniq = uniq_buf[:nu].copy()
            ucount = counts[uniq]
            counts[uniq] = 0
            ustate = lt.arrays.leaf[uniq]
            udepth = lt.arrays.depth[uniq].astype(np.int64)
            enough = ucount >= MIN_PIXELS
            empty = ustate == EMPTY
            split = enough & (udepth < self.depth_cap) & ((empty & (udepth < first)) | ~empty)
            build = enough & empty & (udepth >= first)
            if budget is not None and not budget.may_build(int(np.count_nonzero(done))):
                budget.defer(lt.arrays.tree[uniq[build]] // 6)  # their rays are traced
                build[:] = False
            node_cls[uniq[~empty]] = fail_class(ustate[~empty])
            node_cls[uniq[split | build]] = 255
            settle(node_cls, nodes, inherited, active, idx, pcls)
            idx = idx[active[idx]]
            node_cls[uniq] = 0
            lt.split(uniq[split])
            if np.any(build):
                tb = fb_mod.CLOCK()
                cells = uniq[build]
                step = BUILD_STEP_CANCELLABLE if kernel_flag(cancel) is not None else len(cells)
                lo = 0  # (cells left EMPTY: built by a later frame, or traced when spent)
                while lo < len(cells) and not (lo and cancel is not None and cancel()):
                    nb = step if budget is None else budget.batch(step, np.count_nonzero(done))
                    if nb == 0:
                        break
                    t1 = fb_mod.CLOCK()
                    self._build(cells[lo:lo + nb], st)
                    if budget is not None:
                        budget.charge(fb_mod.CLOCK() - t1, nb)
                    lo += nb
                # failed cells with room below go one level down right away
                again = (lt.arrays.leaf[cells] < EMPTY) & (udepth[build] < self.depth_cap)
                lt.split(cells[again])
                st["build_s"] += fb_mod.CLOCK() - tb
        for k in ("cells_built", "cells_valid", "samples_traced"):
            self.totals[k] += st[k]
        if finish:
            self.finish_resolve()
        return ResolveResult(rad, done, pcls, pinterp)

    def finish_resolve(self) -> None:
        """After a pass's walk: the memory cap, empty blocks of leaves collapsed, the ray
        segment trees compacted."""
        self.enforce_cap()
        self.trees.collapse()
        self.deps.compact(self.pool, self.trees)
        self.deps.warm(self)

    # -- building ---------------------------------------------------------------------

    def _build(self, cells: np.ndarray, st: dict) -> None:
        """Build the cells (unique EMPTY leaves) in one batch and store the outcome.

        Cheap tests first: the corner lines against the object's box, then the corners'
        and the test lines' slab crossings (geometry only); only cells that pass those are
        shaded and go through the predicate and the radiance test.
        """
        a = self.trees.arrays
        tree = a.tree[cells].astype(np.int64)
        inst = (tree // 6).astype(np.int32)
        face = (tree % 6).astype(np.int8)
        depth = a.depth[cells].astype(np.int64)
        coord = a.coord[cells].astype(np.int64)
        nc = len(cells)
        self.cells_by_inst = count_cells(self.cells_by_inst, inst, len(self.sa.inst_mesh))
        ntest = self.n_test[inst]
        ns = 16 + N_TEST_ALL
        k2 = np.full((nc, ns), -1, np.int64)
        pre = np.empty(nc, bool)
        _cell_keys(self.box, inst, face, depth, coord, TEST_POINTS, ntest, self.sa.inst_aabb,
                   k2, pre)
        kc = inst.astype(np.int64) * 8 + face
        status = np.full(nc, CLASS_FAIL_SILHOUETTE, np.int32)
        why = st["reasons"]
        st["cells_built"] += nc
        go = np.flatnonzero(pre)
        why["box_miss"] = why.get("box_miss", 0) + nc - len(go)
        outcome = np.full(nc, O_BOX_MISS, np.int8)
        geo = LineCrossings()
        cls0 = np.zeros(nc, np.int32)
        for lo, hi in ((0, 16), (16, ns)):
            if len(go) == 0:
                break
            used = np.arange(lo, hi)[None, :] < (16 + ntest[go])[:, None]
            k1 = np.broadcast_to(kc[go][:, None], used.shape)[used]
            g_inst, g_cls = line_geometry(self, k1, k2[go, lo:hi][used], geo)
            gi = np.full(used.shape, -1, np.int32)
            gc = np.full(used.shape, -1, np.int32)
            gi[used], gc[used] = g_inst, g_cls
            if lo == 0:
                cls0[go] = gc[:, 0]
            miss = np.any(used & (gi != inst[go][:, None]), axis=1)
            jump = ~miss & np.any(used & (gc != cls0[go][:, None]), axis=1)
            why["corner_miss"] = why.get("corner_miss", 0) + int(np.count_nonzero(miss))
            why["class_change"] = why.get("class_change", 0) + int(np.count_nonzero(jump))
            outcome[go[miss]] = REASONS.index("corner_miss")
            outcome[go[jump]] = REASONS.index("class_change")
            go = go[~miss & ~jump]
        if len(go) and CORNERS_FIRST:
            # the corners first: a cell whose corners' ray trees differ fails whatever its
            # test lines (check_cells compares the corners first), so their lines are not
            # shaded (they would be the children's corners: a split shades them if needed)
            k1 = np.repeat(kc[go], 16)
            corner_ids = shade_lines(self, k1, k2[go, :16].reshape(-1), geo).reshape(len(go), 16)
            early = np.empty(len(go), np.int8)
            corner_trees(self.samples.view(), corner_ids, early)
            # a rough surface in a corner's tree: the reason is that (glossy rays)
            cflag = self.samples.texture_terms()[2][corner_ids]
            # a light mirror or refraction rays may see: the lines between may see it
            early[((cflag & SEES_LIGHT) > 0).any(axis=1)] = R_TUNNEL_LIGHT
            early[((cflag & GLOSSY) > 0).any(axis=1)] = R_GLOSSY
            off = early != R_VALID
            if np.any(off):
                bad_go = go[off]
                outcome[bad_go] = early[off]
                status[bad_go] = np.where(early[off] == R_CLASS, CLASS_FAIL_SILHOUETTE,
                                          np.where(early[off] == R_GLOSSY,
                                                   CLASS_FAIL_NONLINEAR, CLASS_FAIL_SHADOW))
                for r, k in zip(*np.unique(early[off], return_counts=True), strict=True):
                    why[REASONS[r]] = why.get(REASONS[r], 0) + int(k)
                td = time.perf_counter()
                self.deps.add_failed(self, cells[bad_go], corner_ids[off],
                                     np.full(len(bad_go), 16, np.int32))
                st["deps_s"] += time.perf_counter() - td
                go = go[~off]
        if len(go):
            nsamp = (16 + ntest[go]).astype(np.int32)
            used = np.arange(ns)[None, :] < nsamp[:, None]
            k1 = np.broadcast_to(kc[go][:, None], used.shape)[used]
            cell_samples = np.full((len(go), ns), -1, np.int32)
            cell_samples[used] = shade_lines(self, k1, k2[go][used], geo)
            sub_status = np.empty(len(go), np.int32)
            detail = np.empty(len(go), np.int8)
            zlo = np.zeros(len(go))
            zhi = np.zeros(len(go))
            cls = np.zeros(len(go), np.int32)
            check_cells(self.qs, self.box, self.samples.view(), inst[go], face[go],
                        depth[go], coord[go], cell_samples, nsamp, sub_status, detail, zlo,
                        zhi, cls)
            # rough surfaces in the samples' trees: their radiance is sampled (glossy rays),
            # the cell is traced per pixel (docs/INTERPOLANTS.md, "Rough surfaces")
            sflag = self.samples.texture_terms()[2][np.maximum(cell_samples, 0)]
            rough = ((sflag & GLOSSY) > 0) & (cell_samples >= 0)
            rough = rough.any(axis=1)  # whatever else the predicate found
            sub_status[rough] = CLASS_FAIL_NONLINEAR
            detail[rough] = R_GLOSSY
            seen = (((sflag & SEES_LIGHT) > 0) & (cell_samples >= 0)).any(axis=1) & ~rough
            sub_status[seen] = CLASS_FAIL_SHADOW
            detail[seen] = R_TUNNEL_LIGHT
            ok = np.flatnonzero(sub_status == VALID)
            lin = radiance_ok(self.samples.radiance(), cell_samples[ok], nsamp[ok], self.epsilon,
                              self.samples.texture_terms(), self.tex_max)
            sub_status[ok[~lin]] = CLASS_FAIL_NONLINEAR
            detail[ok[~lin]] = O_RADIANCE
            outcome[go] = detail
            for r, k in zip(*np.unique(detail, return_counts=True), strict=True):
                name = REASONS[r] if r < len(REASONS) else "radiance"
                why[name] = why.get(name, 0) + int(k)
            status[go] = sub_status
            td = time.perf_counter()
            shaded_bad = np.flatnonzero(sub_status != VALID)
            self.deps.add_failed(self, cells[go[shaded_bad]], cell_samples[shaded_bad],
                                 nsamp[shaded_bad])
            st["deps_s"] += time.perf_counter() - td
            good = np.flatnonzero(sub_status == VALID)
            if len(good):
                pids = self.pool.alloc(len(good))
                p = self.pool
                p.rad[pids] = self.samples.radiance()[cell_samples[good, :16]]
                p.zlo[pids], p.zhi[pids], p.cls[pids] = zlo[good], zhi[good], cls[good]
                p.node[pids] = cells[go[good]]
                p.stamp[pids] = self.clock
                p.samples[pids] = cell_samples[good, :16]
                if self.samples.shares_on:  # what re-running its radiance test needs
                    p.tests[pids] = cell_samples[good, 16:]
                p.rebuilt[pids] = a.dirty[cells[go[good]]]
                a.leaf[cells[go[good]]] = pids
                g = go[good]
                td = time.perf_counter()
                self.deps.add(self, pids, inst[g], face[g], depth[g], coord[g], zlo[good],
                              zhi[good], cell_samples[good], nsamp[good])
                st["deps_s"] += time.perf_counter() - td
        bad = status != VALID
        a.leaf[cells[bad]] = fail_code(status[bad]).astype(np.int32)
        if self.outcome_log is not None:
            self.outcome_log.append((a.tree[cells].copy(), depth.copy(), coord.copy(), outcome))
        st["cells_valid"] += int(np.count_nonzero(~bad))
