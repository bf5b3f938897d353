"""The RI-tree cache of one scene packing: lazy demand-driven subdivision and queries.

:meth:`RITreeCache.query` takes a batch of rays that enter objects with an RI-tree (their
origins outside the object's expanded box) and returns their interpolated attributes or why
they must be traced (:mod:`.patches` status codes). Subdivision follows the queries (seed
004, 2.3-2.4): each ray descends to its leaf; an ``OPEN`` leaf is evaluated, all of a
level's at once: below the depth constraint its midpoint line is traced and compared with
the interpolation from its corners (:func:`.patches.midpoint_distances`); over the distance
threshold it splits (8 new shared samples traced in one batch) and its rays go on down,
otherwise (or at the depth constraint) it becomes ``FINAL``. Leaves no query reaches stay
``OPEN``. After each query batch the cache is pruned to :data:`PRUNE_KEEP` of the cache size
when it is over it (LRU by the stamps of :mod:`.kdtree`).
"""

from __future__ import annotations

import logging
import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..geometry.mesh_topology import mesh_topology
from ..interpolants.linetree import expanded_boxes, parameterize
from ..tracing.shading import geometric_normal, shading_normal
from .kdtree import NODE_BYTES, OPEN, KdForest, descend, split_leaves
from .patches import (
    MIN_USABLE,
    ST_FAIL_ANGLE,
    ST_FAIL_CLASS,
    ST_HIT,
    ST_MISS,
    ST_TEST,
    finalize,
    interpolate,
    midpoint_distances,
    patch_of,
)
from .sampling import MISS, SAMPLE_BYTES, alloc_samples, grow_samples, store, trace_samples

log = logging.getLogger(__name__)

#: pruning keeps this fraction of the cache size (the paper prunes 70%)
PRUNE_KEEP = 0.3


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


@njit(cache=True, nogil=True, parallel=True)
def _resolve(nd, S, leaf, abcd, status, P, NS, NG, OP, OD, gain, thick, nint, mat):
    for r in prange(leaf.shape[0]):
        x = leaf[r]
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
        else:
            status[r] = ST_FAIL_CLASS


@njit(cache=True, nogil=True, parallel=True)
def _resolve_tested(sa, nd, S, tri_class, inst, leaf, abcd, rows, o, d, t, prim, u, v,
                    status, P, NS, NG, OP, OD, gain, thick, nint, mat):
    """Rays ``rows`` of two-class leaves, with their exact first hits ``t, prim, u, v``."""
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
        # the entry is known exactly: use it
        k = inst[r]
        nm = sa.inst_nmat[k]
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, nm, prim[q])
        sx, sy, sz = shading_normal(sa.tri_normals, nm, prim[q], u[q], v[q], gx, gy, gz)
        for c in range(3):
            P[r, c] = o[r, c] + d[r, c] * t[q]
        NG[r, 0], NG[r, 1], NG[r, 2] = gx, gy, gz
        NS[r, 0], NS[r, 1], NS[r, 2] = sx, sy, sz


@njit(cache=True, nogil=True, parallel=True)
def _ray_param(o, d, status, P, t):
    """Hits move onto their rays: ``t`` = projection of P, P = o + t d."""
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


class RITreeCache:
    """The RI-trees of one scene packing (all instances), with their settings.

    sa, accel: the scene and an accelerator over all of it (``intersect_object`` samples one
    object). dist_thresh: distance threshold; ang_thresh_deg: angular threshold (degrees);
    depth: depth constraint; cache_mb: cache size (MB); thickness: the trees hold lengths
    (thickness view) instead of exit rays.
    """

    def __init__(self, sa, accel, dist_thresh: float, ang_thresh_deg: float, depth: int,
                 cache_mb: float, thickness: bool = False, extent: float | None = None
                 ) -> None:
        t0 = time.perf_counter()
        self.sa = sa
        self.accel = accel
        self.dist_thresh = float(dist_thresh)
        self.ang_thresh_deg = float(ang_thresh_deg)
        self.cosmin = math.cos(math.radians(self.ang_thresh_deg))
        self.depth = int(depth)
        self.cache_bytes = float(cache_mb) * 1e6
        self.thickness = bool(thickness)
        # the scene extent the boxes' padding scales with, frozen (default: sa's) so that a
        # tree's line parameterisation survives edits of other objects
        self.extent = float(sa.scene_extent if extent is None else extent)
        self.box = expanded_boxes(sa, self.extent)
        self.diag = np.linalg.norm(self.box[:, 1] - self.box[:, 0], axis=1)
        self.tri_class = np.ascontiguousarray(mesh_topology(sa).tri_class, np.int32)
        self.forest = KdForest(len(sa.inst_mesh))
        self.samples = alloc_samples(1024)
        self.peak_bytes = 0
        self.counters = dict(samples_traced=0, cells_split=0, leaves_final=0, prunes=0)
        self.setup_s = time.perf_counter() - t0

    # -- accounting ----------------------------------------------------------------------

    @property
    def memory_bytes(self) -> int:
        return self.forest.live_nodes * NODE_BYTES + self.forest.live_samples * SAMPLE_BYTES

    def compatible(self, dist_thresh, ang_thresh_deg, depth, thickness) -> bool:
        return (self.dist_thresh == float(dist_thresh)
                and self.ang_thresh_deg == float(ang_thresh_deg)
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
        ids = self.forest.alloc_samples(len(inst))
        self.samples = grow_samples(self.samples, self.forest.n_samples)
        batch = trace_samples(self.sa, self.accel, self.tri_class, self.box, inst, face,
                              abcd, self.thickness)
        store(self.samples, ids, batch)
        self.counters["samples_traced"] += len(inst)
        return ids

    def _roots(self, keys: np.ndarray) -> np.ndarray:
        flat = self.forest.roots.reshape(-1)
        missing = np.unique(keys[flat[keys] < 0])
        if len(missing):
            bits = (np.arange(16)[:, None] >> np.arange(4)[None, :]) & 1  # (16, 4)
            k = len(missing)
            inst = np.repeat(missing // 6, 16).astype(np.int32)
            face = np.repeat(missing % 6, 16).astype(np.int8)
            abcd = np.tile(bits.astype(np.float64), (k, 1))
            ids = self._trace(inst, face, abcd).reshape(k, 16)
            self.forest.new_roots(missing.astype(np.int32), ids)
        return np.ascontiguousarray(flat[keys], np.int32)

    # -- queries -------------------------------------------------------------------------

    def _subdivide(self, leaf: np.ndarray, abcd: np.ndarray) -> None:
        """Evaluate and split OPEN leaves until every ray's leaf is FINAL (in place)."""
        f = self.forest
        while True:
            nd = f.nodes
            open_ = np.unique(leaf[nd.state[leaf] == OPEN])
            if len(open_) == 0:
                return
            log.debug("ri-tree level: %d open leaves, depths %s..%s, %d samples", len(open_),
                      nd.depth[open_].min(), nd.depth[open_].max(), f.n_samples)
            keys = nd.tree[open_].astype(np.int64)
            inst = (keys // 6).astype(np.int32)
            face = (keys % 6).astype(np.int8)
            cap = nd.depth[open_] >= self.depth
            fin = [open_[cap]]
            rest = open_[~cap]
            split = rest[:0]
            if len(rest):
                ri, rf = inst[~cap], face[~cap]
                mid_abcd = 0.5 * (nd.lo[rest] + nd.hi[rest])
                mids = self._trace(ri, rf, mid_abcd)
                dist = np.empty(len(rest))
                midpoint_distances(nd, rest, self.samples, mids, self.box, self.sa.inst_aabb,
                                   ri, rf, self.thickness, self.diag[ri], self.cosmin, dist)
                f._free_samples.extend(int(s) for s in mids)  # midpoints are not kept
                over = dist > self.dist_thresh
                split = rest[over]
                fin.append(rest[~over])
                si, sf = ri[over], rf[over]
            fin = np.concatenate(fin)
            if len(fin):
                finalize(nd, fin, self.samples, self.cosmin)
                self.counters["leaves_final"] += len(fin)
            if len(split) == 0:
                continue
            k = len(split)
            first = f.alloc_pairs(k)
            new_ids = f.alloc_samples(8 * k).reshape(k, 8)
            nd = f.nodes  # may have grown
            lines = np.empty((k, 8, 4))
            split_leaves(nd, split, first, new_ids, self._frame(si, sf), lines)
            self.samples = grow_samples(self.samples, f.n_samples)
            batch = trace_samples(self.sa, self.accel, self.tri_class, self.box,
                                  np.repeat(si, 8), np.repeat(sf, 8), lines.reshape(-1, 4),
                                  self.thickness)
            store(self.samples, new_ids.reshape(-1), batch)
            self.counters["samples_traced"] += 8 * k
            self.counters["cells_split"] += k
            moved = np.flatnonzero(np.isin(leaf, split))
            out = np.empty(len(moved), np.int32)
            descend(nd, leaf[moved], abcd[moved], f.stamp, out)
            leaf[moved] = out

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
        leaf = np.empty(n, np.int32)
        descend(f.nodes, roots, abcd, f.stamp, leaf)
        self._subdivide(leaf, abcd)
        res = QueryResult(np.empty(n, np.int8), np.full(n, np.inf), *(np.zeros((n, 3))
                          for _ in range(6)), np.full(n, -1, np.int16), np.full(n, -1, np.int32),
                          np.zeros(n), np.full(n, np.inf), np.full(n, -1, np.int32),
                          np.zeros(n), np.zeros(n))
        nd = f.nodes
        _resolve(nd, self.samples, leaf, abcd, res.status, res.P, res.NS, res.NG, res.OP,
                 res.OD, res.gain, res.thick, res.nint, res.mat)
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
                            res.OP, res.OD, res.gain, res.thick, res.nint, res.mat)
        _ray_param(o, d, res.status, res.P, res.t)
        self.peak_bytes = max(self.peak_bytes, self.memory_bytes)
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
