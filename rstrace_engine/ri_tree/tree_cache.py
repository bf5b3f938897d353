"""The RI-tree cache of one scene packing: lazy demand-driven subdivision and queries.

:meth:`RITreeCache.query` takes a batch of rays that enter objects with an RI-tree (their
origins outside the object's expanded box) and returns their interpolated attributes or why
they must be traced (:mod:`.patches` status codes). Subdivision follows the queries (seed
004, 2.3-2.4): each ray descends to its leaf; an ``OPEN`` leaf is evaluated, all of a
level's at once: below the depth constraint its midpoint line is traced and compared with
the interpolation from its corners (:func:`.patches.midpoint_distances`); over the distance
threshold it splits (8 new shared samples traced in one batch) and its rays go on down,
otherwise (or at the depth constraint) it becomes ``FINAL``. Leaves no query reaches stay
``OPEN``.

After each query batch the cache is pruned to :data:`PRUNE_KEEP` of the cache size when it
is over it (LRU by the stamps of :mod:`.kdtree`).

The exit-ray test (an addition to seed 004's distance and angular tests, ``probe_deg``; 0
turns it off): the distance in 4D line space admits an exit ray several degrees off, and the
corners' 30 degree angular threshold does not see it, while through a glass ball such an
error moves the horizon seen through it by many pixels. So a cell also splits while, at its
midpoint and at one more probe line (:func:`.patches.class_probes`: the other class of a
two-class cell, else toward the corner whose output ray turns farthest), the traced output
ray and its interpolation differ by more than ``probe_deg`` (:func:`.patches.probe_error`:
the angle between the rays or normals plus the origin's displacement as seen from a box
diagonal away; a probe of another class fails). A cell that still fails at the depth
constraint is final with its classes failing the angular test: its rays are traced, never
interpolated from corners known to be wrong there.
"""

from __future__ import annotations

import logging
import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..geometry.mesh_topology import mesh_topology_cached
from ..geometry.scene import SceneArrays
from ..interpolants.linetree import expanded_boxes, parameterize
from ..tracing.shading import geometric_normal, shading_normal
from ..views import fields, view_type
from .kdtree import FINAL, NODE_BYTES, OPEN, KdForest, descend, split_leaves
from .patches import (
    K_ONE,
    K_TWO,
    MIN_USABLE,
    ST_FAIL_ANGLE,
    ST_FAIL_CLASS,
    ST_HIT,
    ST_MISS,
    ST_SPARSE,
    ST_TEST,
    blind_at_cap,
    class_probes,
    corner_kinds,
    finalize,
    interpolate,
    interpolate_reflection,
    midpoint_distances,
    patch_of,
    probe_errors,
)
from .sampling import MISS, SAMPLE_BYTES, alloc_samples, grow_samples, store, trace_samples

log = logging.getLogger(__name__)

#: pruning keeps this fraction of the cache size (the paper prunes 70%)
PRUNE_KEEP = 0.3
#: within a query batch, pruning starts when less than this fraction of the cache is free
PRUNE_MIN_ROOM = 0.05
#: the cost rule: a leaf is evaluated (and split when its midpoint fails) once this many
#: queries have reached it; its 9 new samples then pay for themselves
SPLIT_QUERIES = 32
#: ... this many when its corners do not allow interpolation (all miss, three or more
#: classes): splitting only pays where it separates large interpolable regions
SPLIT_QUERIES_MIXED = 128


class QueryResult(NamedTuple):
    """Outcome of :meth:`RITreeCache.query` for ``n`` rays."""

    status: np.ndarray  # (n,) int8 ST_* of .patches
    t: np.ndarray  # (n,) float64 ray parameter of the hit (ST_HIT), inf otherwise
    P: np.ndarray  # (n, 3) float64 hit point (on the ray)
    NS: np.ndarray  # (n, 3) shading normal (winding side)
    NG: np.ndarray  # (n, 3) geometric normal (winding side)
    OP: np.ndarray  # (n, 3) exit ray origin (glass)
    OD: np.ndarray  # (n, 3) exit ray direction
    gain: np.ndarray  # (n, 3) exit path weight
    nint: np.ndarray  # (n,) int16 interfaces inside, -1: no exit ray
    mat: np.ndarray  # (n,) int32 material
    thick: np.ndarray  # (n,) float64 length inside the object
    test_t: np.ndarray  # (n,) float64 exact first hit of the cheap test (inf: none / miss)
    test_prim: np.ndarray  # (n,) int32 its triangle (-1: not tested or a miss)
    test_u: np.ndarray  # (n,) float64
    test_v: np.ndarray  # (n,) float64
    RP: np.ndarray  # (n, 3) internal reflection at the exit: origin (inside the object)
    RD: np.ndarray  # (n, 3) its direction
    rgain: np.ndarray  # (n, 3) its weight past the entry (0: none)


def tree_of(nd, nodes) -> tuple[np.ndarray, np.ndarray]:
    """The instance (int32) and face pair (int8) of the trees holding ``nodes``
    (``nd.tree`` keys are ``6 * instance + face``)."""
    keys = nd.tree[nodes].astype(np.int64)
    return (keys // 6).astype(np.int32), (keys % 6).astype(np.int8)


@njit(cache=True, nogil=True, parallel=True)
def _resolve(nd, S, leaf, abcd, status, P, NS, NG, OP, OD, gain, thick, nint, mat, RP, RD,
             rgain):
    for r in prange(leaf.shape[0]):
        x = leaf[r]
        if x < 0 or nd.state[x] != FINAL:
            status[r] = ST_SPARSE
            continue
        nc = nd.nclass[x]
        if nc >= 3:
            status[r] = ST_FAIL_CLASS
        elif nc == 2:
            status[r] = ST_TEST
        elif nd.cls[x, 0] == MISS:
            status[r] = ST_MISS
        elif not (nd.ang_ok[x] & 1):
            status[r] = ST_FAIL_ANGLE
        elif interpolate(nd, x, S, abcd[r], nd.cls[x, 0], r, P, NS, NG, OP, OD, gain, thick,
                         nint, mat) >= MIN_USABLE:
            status[r] = ST_HIT
            interpolate_reflection(nd, x, S, abcd[r], nd.cls[x, 0], r, RP, RD, rgain)
        else:
            status[r] = ST_FAIL_CLASS


_ResolveScene = view_type("_ResolveScene", SceneArrays, (
    "inst_nmat", "inst_mesh", "mesh_nrm", "normals", "tris", "verts"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def _resolve_tested(sa, nd, S, tri_class, inst, leaf, abcd, rows, o, d, t, prim, u, v,
                    status, P, NS, NG, OP, OD, gain, thick, nint, mat, RP, RD, rgain):
    """Rays ``rows`` of two-class leaves, with their exact first hits ``t, prim, u, v``."""
    sa = _ResolveScene(*fields(sa, _ResolveScene))  # the fields its loop reads
    for q in prange(rows.shape[0]):
        r = rows[q]
        x = leaf[r]
        if prim[q] < 0:
            status[r] = ST_MISS
            continue
        patch = tri_class[prim[q]]
        m0 = patch_of(nd.cls[x, 0]) == patch
        m1 = patch_of(nd.cls[x, 1]) == patch
        if m0 == m1:
            status[r] = ST_FAIL_CLASS
            continue
        key = nd.cls[x, 0] if m0 else nd.cls[x, 1]
        if not (nd.ang_ok[x] & (1 if m0 else 2)):
            status[r] = ST_FAIL_ANGLE
            continue
        if interpolate(nd, x, S, abcd[r], key, r, P, NS, NG, OP, OD, gain, thick, nint,
                       mat) < MIN_USABLE:
            status[r] = ST_FAIL_CLASS
            continue
        status[r] = ST_HIT
        interpolate_reflection(nd, x, S, abcd[r], key, r, RP, RD, rgain)
        # the entry is known exactly: use it
        k = inst[r]
        nm = sa.inst_nmat[k]
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, nm, prim[q])
        sx, sy, sz = shading_normal(sa, sa.inst_mesh[k], nm, prim[q], u[q], v[q], gx, gy, gz)
        for c in range(3):
            P[r, c] = o[r, c] + d[r, c] * t[q]
        NG[r, 0], NG[r, 1], NG[r, 2] = gx, gy, gz
        NS[r, 0], NS[r, 1], NS[r, 2] = sx, sy, sz


@njit(cache=True, nogil=True, parallel=True)
def _ray_param(o, d, inst, straight, status, P, t, nint, OP, OD):
    """Hits move onto their rays: ``t`` = projection of P, P = o + t d. Through an object
    that does not refract (``straight`` per instance: every material's IOR 1) the exit ray
    *is* the ray: its direction the ray's own and its origin on it (interpolating the
    corners' directions only adds their error, which a silhouette far behind the object
    turns into a flipped pixel)."""
    for r in prange(o.shape[0]):
        if status[r] != ST_HIT:
            t[r] = np.inf
            continue
        dd = d[r, 0] ** 2 + d[r, 1] ** 2 + d[r, 2] ** 2
        tt = ((P[r, 0] - o[r, 0]) * d[r, 0] + (P[r, 1] - o[r, 1]) * d[r, 1]
              + (P[r, 2] - o[r, 2]) * d[r, 2]) / dd
        t[r] = tt
        for c in range(3):
            P[r, c] = o[r, c] + d[r, c] * tt
        if straight[inst[r]] and nint[r] >= 0:
            to = ((OP[r, 0] - o[r, 0]) * d[r, 0] + (OP[r, 1] - o[r, 1]) * d[r, 1]
                  + (OP[r, 2] - o[r, 2]) * d[r, 2]) / dd
            inv = 1.0 / math.sqrt(dd)
            for c in range(3):
                OP[r, c] = o[r, c] + d[r, c] * to
                OD[r, c] = d[r, c] * inv


def straight_instances(sa) -> np.ndarray:
    """(I,) bool: instances whose every material has IOR 1 (no ray bends inside them: a
    wrap, a window pane modelled as a sheet), so an exit ray continues its entering ray."""
    out = np.zeros(len(sa.inst_mesh), np.bool_)
    bent = (np.asarray(sa.mat_ior) != 1.0)[sa.inst_mat].astype(np.int64)
    start = np.asarray(sa.inst_mat_start, np.int64)
    cum = np.concatenate([[0], np.cumsum(bent)])
    out[:] = (start[1:] > start[:-1]) & (cum[start[1:]] == cum[start[:-1]])
    return out


class RITreeCache:
    """The RI-trees of one scene packing (all instances), with their settings.

    sa, accel: the scene and an accelerator over all of it (``intersect_object`` samples one
    object). dist_thresh: distance threshold; ang_thresh_deg: angular threshold (degrees);
    depth: depth constraint; cache_mb: cache size (MB); probe_deg: the exit-ray test's
    threshold (degrees, module doc; 0: off, seed 004's tests alone); thickness: the trees
    hold lengths
    (thickness view) instead of exit rays; split_queries, split_queries_mixed: the cost
    rule's query counts (default :data:`SPLIT_QUERIES`, :data:`SPLIT_QUERIES_MIXED`; 1 and 1
    give the paper's plain lazy subdivision, every leaf a query reaches refined to FINAL).
    """

    def __init__(self, sa, accel, dist_thresh: float, ang_thresh_deg: float, depth: int,
                 cache_mb: float, thickness: bool = False, extent: float | None = None,
                 split_queries: int | None = None, split_queries_mixed: int | None = None,
                 probe_deg: float = 0.0) -> None:
        t0 = time.perf_counter()
        self.sa = sa
        self.accel = accel
        self.dist_thresh = float(dist_thresh)
        self.ang_thresh_deg = float(ang_thresh_deg)
        self.cosmin = math.cos(math.radians(self.ang_thresh_deg))
        self.depth = int(depth)
        self.probe_deg = float(probe_deg)
        self.probe_rad = math.radians(self.probe_deg) if self.probe_deg > 0.0 else np.inf
        self.cache_bytes = float(cache_mb) * 1e6
        self.thickness = bool(thickness)
        # the scene extent the boxes' padding scales with, frozen (default: sa's) so that a
        # tree's line parameterisation survives edits of other objects
        self.extent = float(sa.scene_extent if extent is None else extent)
        self.box = expanded_boxes(sa, self.extent)
        self.diag = np.linalg.norm(self.box[:, 1] - self.box[:, 0], axis=1)
        self.tri_class = np.ascontiguousarray(mesh_topology_cached(sa).tri_class, np.int32)
        self._straight = (None, None)
        self.forest = KdForest(len(sa.inst_mesh))
        self.samples = alloc_samples(1024)
        self.peak_bytes = 0
        self.split_queries = int(SPLIT_QUERIES if split_queries is None else split_queries)
        self.split_queries_mixed = int(SPLIT_QUERIES_MIXED if split_queries_mixed is None
                                       else split_queries_mixed)
        self._pruned_in = -1
        self.counters = dict(samples_traced=0, cells_split=0, leaves_final=0, prunes=0,
                             sample_s=0.0)
        #: samples traced per instance slot (the fallback's ledger), and CPU seconds
        self.inst_samples = np.zeros(len(sa.inst_mesh), np.int64)
        self.setup_s = time.perf_counter() - t0

    @property
    def straight(self) -> np.ndarray:
        """:func:`straight_instances` of the current scene (``sa`` follows edits)."""
        if self._straight[0] is not self.sa:
            self._straight = (self.sa, straight_instances(self.sa))
        return self._straight[1]

    # -- accounting ----------------------------------------------------------------------

    @property
    def memory_bytes(self) -> int:
        return self.forest.live_nodes * NODE_BYTES + self.forest.live_samples * SAMPLE_BYTES

    def compatible(self, dist_thresh, ang_thresh_deg, depth, thickness,
                   probe_deg: float = 0.0) -> bool:
        return (self.dist_thresh == float(dist_thresh)
                and self.ang_thresh_deg == float(ang_thresh_deg)
                and self.probe_deg == float(probe_deg)
                and self.depth == int(depth) and self.thickness == bool(thickness))

    def invalidate(self, instances) -> int:
        """Drop the trees of instance slots ``instances`` (moved or edited objects)."""
        return self.forest.invalidate(instances)

    # -- samples -------------------------------------------------------------------------

    def _frame(self, inst, face):
        """World length of one unit of each line coordinate: (k, 4)."""
        b = self.box[inst]
        k = (face >> 1).astype(np.int64)
        i = (k + 1) % 3
        j = (k + 2) % 3
        rows = np.arange(len(inst))
        L = b[rows, 1, k] - b[rows, 0, k]
        wi = b[rows, 1, i] - b[rows, 0, i] + 2 * L
        wj = b[rows, 1, j] - b[rows, 0, j] + 2 * L
        return np.ascontiguousarray(np.stack([wi, wj, wi, wj], axis=1))

    def _trace(self, inst, face, abcd) -> np.ndarray:
        """Trace sample lines into the pool; returns their ids."""
        t0 = time.process_time()
        ids = self.forest.alloc_samples(len(inst))
        self.samples = grow_samples(self.samples, self.forest.n_samples)
        batch = trace_samples(self.sa, self.accel, self.tri_class, self.box, inst, face,
                              abcd, self.thickness)
        store(self.samples, ids, batch)
        self.counters["samples_traced"] += len(inst)
        self.inst_samples += np.bincount(inst, minlength=len(self.inst_samples))
        self.counters["sample_s"] += time.process_time() - t0
        return ids

    def _room(self, held=None) -> float:
        """Bytes that may still be allocated in this query batch without passing the cache
        size. When there is too little, least recently used nodes of *earlier* batches are
        pruned first (nothing the current batch's rays stand on: their paths carry its
        stamp), once per batch. ``held``: sample ids in use that no node references."""
        free = self.cache_bytes - self.memory_bytes
        f = self.forest
        if free >= PRUNE_MIN_ROOM * self.cache_bytes or self._pruned_in == f.stamp:
            return free
        self._pruned_in = f.stamp
        live = max(f.live_nodes, 1)
        per_node = self.memory_bytes / live
        cut = min(f.cutoff_for(int(PRUNE_KEEP * self.cache_bytes / per_node)), f.stamp)
        f.prune(cut, held)
        self.counters["prunes"] += 1
        return self.cache_bytes - self.memory_bytes

    def _note_peak(self, extra: int = 0) -> None:
        self.peak_bytes = max(self.peak_bytes, self.memory_bytes + int(extra))

    def _roots(self, keys: np.ndarray) -> np.ndarray:
        """Root node of each tree ``keys`` (inst * 6 + face), created (16 samples each) when
        missing and when the cache has room; -1 where it has none."""
        flat = self.forest.roots.reshape(-1)
        missing = np.unique(keys[flat[keys] < 0])
        if len(missing):
            each = 16 * SAMPLE_BYTES + NODE_BYTES
            fit = int(max(self._room(), 0.0) // each)
            missing = missing[:fit]
        if len(missing):
            bits = (np.arange(16)[:, None] >> np.arange(4)[None, :]) & 1  # (16, 4)
            k = len(missing)
            inst = np.repeat(missing // 6, 16).astype(np.int32)
            face = np.repeat(missing % 6, 16).astype(np.int8)
            abcd = np.tile(bits.astype(np.float64), (k, 1))
            ids = self._trace(inst, face, abcd).reshape(k, 16)
            self.forest.new_roots(missing.astype(np.int32), ids)
            self._note_peak()
        return np.ascontiguousarray(flat[keys], np.int32)

    # -- queries -------------------------------------------------------------------------

    def _subdivide(self, leaf: np.ndarray, abcd: np.ndarray) -> None:
        """Demand-driven subdivision under the cost rule (module doc), in place: rays whose
        leaf is evaluated go down to FINAL leaves; the others stay in OPEN leaves (traced).

        One batch of samples per level: the 8 new corners of the cells split at a level are
        traced together with the midpoints of those of their children that enough of the
        batch's rays reach to be evaluated at the next level."""
        f = self.forest
        act = np.flatnonzero(leaf >= 0)
        act = act[f.nodes.state[leaf[act]] == OPEN]
        # the midpoint is freed after the test, the 8 corners and two children's midpoints
        # are held until the next level
        per_split = 2 * NODE_BYTES + 10 * SAMPLE_BYTES
        mid_node = np.empty(0, np.int32)  # cells whose midpoint was traced ahead ...
        mid_id = np.empty(0, np.int32)  # ... and its sample id
        try:
            while len(act):
                nd = f.nodes
                lv, cnt = np.unique(leaf[act], return_counts=True)
                nd.visits[lv] = np.minimum(nd.visits[lv].astype(np.int64) + cnt,
                                           2 ** 30).astype(np.int32)
                kind = np.empty(len(lv), np.int8)
                corner_kinds(nd, lv, self.samples, kind)
                capped = nd.depth[lv] >= self.depth
                need = np.where((kind == K_ONE) | (kind == K_TWO), self.split_queries,
                                self.split_queries_mixed)
                fin = lv[capped]
                if len(fin):  # blind cells stay OPEN at the cap: their rays are traced
                    blind = np.empty(len(fin), np.bool_)
                    blind_at_cap(nd, fin, self.samples, self.box, self.sa.inst_aabb,
                                 *tree_of(nd, fin), blind)
                    fin = fin[~blind]
                ev = lv[~capped & (nd.visits[lv] >= need)]
                if len(ev):
                    fit = int(max(self._room(mid_id), 0.0) // per_split)
                    if fit < len(ev):  # the most wanted first
                        ev = ev[np.argsort(-nd.visits[ev], kind="stable")[:fit]]
                # with the exit-ray test, cells at the cap are tested too (module doc)
                n_ev = len(ev)
                if np.isfinite(self.probe_rad) and len(fin):
                    ev = np.concatenate([ev, fin])
                    fin = fin[:0]
                # per cell of ``fin``: failed the exit-ray test at the cap (made *after* the
                # capped cells moved into ``ev``, so that it lines up with ``fin``)
                coarse = np.zeros(len(fin), np.bool_)
                split = ev[:0]
                if len(ev):
                    ri, rf = tree_of(nd, ev)
                    mids = np.full(len(ev), -1, np.int32)
                    have = np.zeros(len(ev), np.bool_)
                    if len(mid_node):  # sorted
                        pos = np.minimum(np.searchsorted(mid_node, ev), len(mid_node) - 1)
                        have = mid_node[pos] == ev
                        mids[have] = mid_id[pos[have]]
                    todo = np.flatnonzero(~have)
                    if len(todo):
                        mids[todo] = self._trace(ri[todo], rf[todo],
                                                 0.5 * (nd.lo[ev[todo]] + nd.hi[ev[todo]]))
                        self._note_peak()
                    dist = np.empty(len(ev))
                    probe = np.empty(len(ev))
                    midpoint_distances(nd, ev, self.samples, mids, self.box,
                                       self.sa.inst_aabb, ri, rf, self.thickness,
                                       self.diag[ri], self.cosmin, dist, probe)
                    # (midpoints are never kept: those traced here are freed now)
                    f._free_samples.extend(mids[todo].tolist())
                    if np.isfinite(self.probe_rad) and not self.thickness:
                        self._probe_classes(ev, mids, ri, rf, probe)
                    at_cap = np.arange(len(ev)) >= n_ev
                    fails = ~(probe <= self.probe_rad)  # inf fails (when the test is on)
                    over = ~at_cap & ((dist > self.dist_thresh) | fails)
                    split = ev[over]
                    fin = np.concatenate([fin, ev[~over]])
                    coarse = np.concatenate([coarse, (at_cap & fails)[~over]])
                    si, sf = ri[over], rf[over]
                # midpoints traced ahead and not used: freed (midpoints are never kept)
                f._free_samples.extend(mid_id.tolist())
                mid_node = mid_id = np.empty(0, np.int32)
                if len(fin):
                    finalize(nd, fin, self.samples, self.cosmin, coarse)
                    self.counters["leaves_final"] += len(fin)
                if len(split) == 0:
                    return
                k = len(split)
                first = f.alloc_pairs(k)
                new_ids = f.alloc_samples(8 * k).reshape(k, 8)
                nd = f.nodes  # may have grown
                lines = np.empty((k, 8, 4))
                split_leaves(nd, split, first, new_ids, self._frame(si, sf), lines)
                moved = act[np.isin(leaf[act], split)]
                out = np.empty(len(moved), np.int32)
                descend(nd, leaf[moved], abcd[moved], f.stamp, out)
                leaf[moved] = out
                act = moved
                # children reached by enough rays to be evaluated next: midpoints now
                ch, ccnt = np.unique(out, return_counts=True)
                ahead = ch[(nd.depth[ch] < self.depth)
                           & (nd.visits[ch] + ccnt >= self.split_queries)]
                ahead_i, ahead_f = tree_of(nd, ahead)
                ai = np.concatenate([np.repeat(si, 8), ahead_i])
                af = np.concatenate([np.repeat(sf, 8), ahead_f])
                al = np.concatenate([lines.reshape(-1, 4), 0.5 * (nd.lo[ahead] + nd.hi[ahead])])
                aid = f.alloc_samples(len(ahead))
                self.samples = grow_samples(self.samples, f.n_samples)
                batch = trace_samples(self.sa, self.accel, self.tri_class, self.box, ai, af,
                                      al, self.thickness)
                store(self.samples, np.concatenate([new_ids.reshape(-1), aid]), batch)
                mid_node, mid_id = ahead.astype(np.int32), aid
                self._note_peak()
                self.counters["samples_traced"] += 8 * k + len(ahead)
                self.counters["cells_split"] += k
        finally:
            if len(mid_id):
                f._free_samples.extend(mid_id.tolist())

    def _probe_classes(self, ev, mids, ri, rf, probe) -> None:
        """The exit-ray test's second probe of the cells ``ev`` that pass at their midpoints
        ``mids`` (:func:`.patches.class_probes`): one line each, traced, compared, freed;
        ``probe`` takes the larger error."""
        nd = self.forest.nodes
        live = np.flatnonzero(probe <= self.probe_rad)
        # (the kernels run on empty batches too: a warm-up reaches them whatever it probes)
        abcd = np.empty((len(live), 4))
        want = np.empty(len(live), np.int32)
        class_probes(nd, ev[live], self.samples, mids[live], abcd, want)
        on = np.flatnonzero(want != MISS)
        rows = live[on]
        pids = (self._trace(ri[rows], rf[rows], abcd[on]) if len(on)
                else np.empty(0, np.int32))
        err = np.empty(len(on))
        probe_errors(nd, ev[rows], self.samples, pids, abcd[on], want[on],
                     self.diag[ri[rows]], err)
        self.forest._free_samples.extend(pids.tolist())
        probe[rows] = np.maximum(probe[rows], err)

    def query(self, inst, origins, directions) -> QueryResult:
        """Attributes of ``n`` rays on instances ``inst`` (n,) int32 whose origins lie
        outside the instance's expanded box (their lines are what the trees index)."""
        inst = np.ascontiguousarray(inst, np.int32)
        o = np.ascontiguousarray(origins, np.float64)
        d = np.ascontiguousarray(directions, np.float64)
        n = len(inst)
        f = self.forest
        f.stamp += 1
        face = np.empty(n, np.int8)
        abcd = np.empty((n, 4))
        parameterize(self.box, inst, o, d, face, abcd)
        roots = self._roots(inst.astype(np.int64) * 6 + face)
        leaf = np.full(n, -1, np.int32)
        ok = np.flatnonzero(roots >= 0)
        if len(ok):
            out = np.empty(len(ok), np.int32)
            descend(f.nodes, roots[ok], abcd[ok], f.stamp, out)
            leaf[ok] = out
        self._subdivide(leaf, abcd)
        res = QueryResult(np.empty(n, np.int8), np.full(n, np.inf), *(np.zeros((n, 3))
                          for _ in range(6)), np.full(n, -1, np.int16), np.full(n, -1, np.int32),
                          np.zeros(n), np.full(n, np.inf), np.full(n, -1, np.int32),
                          np.zeros(n), np.zeros(n), *(np.zeros((n, 3)) for _ in range(3)))
        nd = f.nodes
        _resolve(nd, self.samples, leaf, abcd, res.status, res.P, res.NS, res.NG, res.OP,
                 res.OD, res.gain, res.thick, res.nint, res.mat, res.RP, res.RD, res.rgain)
        rows = np.flatnonzero(res.status == ST_TEST)
        if len(rows):
            h = self.accel.intersect_object(inst[rows], o[rows], d[rows], 0.0, np.inf)
            res.test_t[rows] = h.t
            res.test_prim[rows] = h.prim
            res.test_u[rows] = h.u
            res.test_v[rows] = h.v
            _resolve_tested(self.sa, nd, self.samples, self.tri_class, inst, leaf, abcd,
                            rows.astype(np.int64), o, d, np.ascontiguousarray(h.t),
                            np.ascontiguousarray(h.prim, np.int32), np.ascontiguousarray(h.u),
                            np.ascontiguousarray(h.v), res.status, res.P, res.NS, res.NG,
                            res.OP, res.OD, res.gain, res.thick, res.nint, res.mat,
                            res.RP, res.RD, res.rgain)
        _ray_param(o, d, inst, self.straight, res.status, res.P, res.t, res.nint, res.OP,
                   res.OD)
        self._note_peak()
        self._enforce_cap()
        return res

    def _enforce_cap(self) -> None:
        """Prune to PRUNE_KEEP of the cache size when over it (LRU)."""
        if self.memory_bytes <= self.cache_bytes:
            return
        f = self.forest
        target = PRUNE_KEEP * self.cache_bytes
        for _ in range(6):
            live = max(f.live_nodes, 1)
            per_node = self.memory_bytes / live
            f.prune(f.cutoff_for(int(target / per_node)))
            self.counters["prunes"] += 1
            if self.memory_bytes <= target:
                return
        f.prune(f.stamp + 1)  # everything goes
