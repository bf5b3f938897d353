"""Embree backend through ``embreex`` (the yardstick the numba BVH is measured against).

The scene is flattened: one Embree triangle geometry per instance, its mesh's vertices taken
to world space less the centre of the scene's box, in float32 (Embree's precision; rays are
re-centred alike, so a scene far from the origin keeps its float32 resolution: at 1e6 world
float32 is good to 6 cm), so ``geomID`` is the instance id and
``primID`` the triangle within the instance's mesh (reported as the GLOBAL triangle index).
Closest hits use Embree's intersect query, ``any_hit`` its occlusion query, and
``intersect_object`` a per-instance Embree scene built lazily on first use. The scene is
built in robust mode (watertight). Embree has no per-ray ``tnear`` in ``embreex``: a ray with
``tmin > 0`` is started at ``o + tmin d`` and its distances shifted back.

Float32 and spawned rays: Embree's geometry and rays are float32, so a ray spawned a float64
offset (``tolerances.SPAWN_OFFSET_REL``, far below a float32 ulp) off a surface starts
*inside* that surface's float32 rounding and hits it again (shadow acne: 29% of the pixels
of a small scene differed from the BVH's). Two things make an Embree frame the BVH's frame:

* every ray starts at least ``tolerances.FLOAT32_TNEAR_REL`` times the magnitude of the scene
  and of its origin along itself (Embree cannot tell hits closer than that from its own
  rounding), and
* the distance and barycentrics of every closest hit are recomputed in float64 on the float64
  triangle Embree reports, with the BVH's own arithmetic (:func:`.triangle.solve_sheared`),
  so hit points (and every ray spawned from them) are where the BVH puts them, not
  float32-t away; a hit whose float64 plane lies before the ray's start (its own surface
  found again) is queried again past it, and an any-hit ray Embree calls occluded is
  checked by such a closest-hit query (shadow acne on small, finely tessellated objects
  otherwise; it costs Embree frames 10-25%).

Every scene is made on one Embree device (:func:`_new_scene`): a device per scene crashed
the process at about the 1,017th per-object scene.

Hits that Embree cannot order (``tolerances.FLOAT32_TIE_REL``): two objects whose faces are
within float32 rounding of each other along a ray (a box resting on a floor, coplanar
panels) give equal float32 distances, and which one Embree reports depends on its BVH, so
on every *other* object of the scene: hiding, moving or adding an object elsewhere changed
pixels its rays never came near (an incremental frame then differed from a fresh one in
pixels nobody marked dirty). Every object other than the reported one whose box holds the
hit point (:mod:`.embree_ties`: few box tests for most hits) is re-tested alone
(its own Embree scene, as ``intersect_object``) in a window of that half-width around the
hit, refined in float64 the same way, and the closest float64 hit wins, equal distances
going to the highest instance id (the brute-force oracle's rule). The result depends only on
the objects near the hit, never on the BVH.

``embreex``'s ``run`` releases the GIL, so batches are split into chunks run from a small
thread pool (one chunk per numba thread, ``numba.get_num_threads()``).
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.scene import SceneArrays
from .bvh import ray_to_object
from .embree_ties import build_tie_index, merge_closer, tie_candidates, tie_window
from .interface import Accelerator, AcceleratorUnavailable, Hits, empty_hits
from .triangle import ray_shear, solve_sheared

log = logging.getLogger(__name__)

try:  # optional dependency
    from embreex import mesh_construction as _mc
    from embreex import rtcore as _rc
    from embreex import rtcore_scene as _rs
except ImportError:  # pragma: no cover - depends on the machine
    _mc = _rc = _rs = None

_device = None
_device_lock = threading.Lock()


def _new_scene():
    """A robust (watertight) Embree scene on the process's one Embree device. A scene made
    without a device gets a device of its own, and the process crashed at about the
    1,017th (a museum's per-object scenes reach that)."""
    global _device
    with _device_lock:
        if _device is None:
            _device = _rc.EmbreeDevice()
        return _rs.EmbreeScene(_device, robust=True)

#: Fewest rays per thread worth splitting a batch for.
MIN_RAYS_PER_THREAD = 4096
#: How often a ray whose float32 hit the float64 scene does not have is queried again past it.
REQUERY_ROUNDS = 4


def available() -> bool:
    """True when ``embreex`` can be imported."""
    return _rs is not None


def _instance_geometry(sa: SceneArrays, i: int, centre: np.ndarray):
    """Float32 vertices (V, 3) of instance ``i`` in world space less ``centre`` (re-centred
    before the rounding to float32), and its int32 triangles (m, 3)."""
    m = sa.inst_mesh[i]
    tris = sa.tris[sa.mesh_tri_start[m]:sa.mesh_tri_start[m + 1]]
    v0, v1 = int(tris.min()), int(tris.max()) + 1
    x = sa.inst_xform[i]
    world = sa.verts[v0:v1] @ x[:3, :3].T + (x[:3, 3] - centre)
    return (np.ascontiguousarray(world, dtype=np.float32),
            np.ascontiguousarray(tris - v0, dtype=np.int32))


class EmbreeAccelerator(Accelerator):
    """All instances in one Embree scene (world space, float32)."""

    name = "EMBREE"

    def __init__(self, scene_arrays: SceneArrays) -> None:
        if not available():
            raise AcceleratorUnavailable("accelerator 'EMBREE' needs the 'embreex' package "
                                         "(pip install embreex); use 'BVH'")
        super().__init__(scene_arrays)
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()  # per-object scenes are built lazily from the workers
        self._build(scene_arrays)

    def update(self, scene_arrays: SceneArrays) -> None:
        self._build(scene_arrays)

    def _build(self, sa: SceneArrays) -> None:
        t0 = time.perf_counter()
        scene = _new_scene()
        self._keep = []  # embreex geometries must outlive the scene's use of them
        # Embree works in float32 around the centre of the scene's box: translated by 1e6
        # a float32 world coordinate is only good to 6 cm (at 1e7 every primary ray missed)
        box = np.asarray(sa.scene_aabb, np.float64)
        centre = 0.5 * (box[0] + box[1])
        self._centre = centre if np.all(np.isfinite(centre)) else np.zeros(3)
        # geometry ids are given in order: geom_slot maps them back to instance slots
        self._geom_slot = np.ascontiguousarray(np.flatnonzero(sa.inst_alive), np.int32)
        for i in self._geom_slot:
            v, f = _instance_geometry(sa, int(i), self._centre)
            self._keep.append(_mc.TriangleMesh(scene, v, f))
        self.scene = scene
        self.sa = sa
        self._prim_offset = np.ascontiguousarray(sa.mesh_tri_start[sa.inst_mesh], np.int32)
        # the largest re-centred coordinate: the scale of Embree's float32 rounding
        self._magnitude = float(np.max(np.abs(box - self._centre))) if len(
            self._geom_slot) else 0.0
        self._objects: dict[int, object] = {}
        # the objects a hit may tie with (None: fewer than two objects), re-centred too
        self._ties = build_tie_index(sa.inst_aabb - self._centre, self._geom_slot,
                                     self._magnitude)
        self.stats["build_s"] = time.perf_counter() - t0

    def _object_scene(self, i: int):
        with self._lock:
            sc = self._objects.get(i)
            if sc is None:
                sc = _new_scene()
                v, f = _instance_geometry(self.sa, i, self._centre)
                self._keep.append(_mc.TriangleMesh(sc, v, f))
                self._objects[i] = sc
            return sc

    # -- running -----------------------------------------------------------------------

    def _trace(self, o, d, tmin, tmax, only, anyhit):
        n = len(o)
        hits = empty_hits(n)
        if n == 0:
            return hits
        t0 = time.perf_counter()
        if only is not None:
            for i in np.unique(only):
                idx = np.flatnonzero(only == i)
                sub = empty_hits(len(idx))
                self._fill(sub, self._object_scene(int(i)), o[idx], d[idx], tmin[idx],
                           tmax[idx], anyhit, int(i))
                for full, part in zip(hits, sub, strict=True):
                    full[idx] = part
        else:
            self._fill(hits, self.scene, o, d, tmin, tmax, anyhit, -1)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + n
        return hits

    def _fill(self, hits: Hits, scene, o, d, tmin, tmax, anyhit, inst, rounds=0,
              ties=True, valid_tmin=None):
        """Trace rays with ``scene`` into ``hits`` (pre-filled as misses), in chunks on the
        thread pool; conversion to and from Embree's float32 runs in the workers too.

        Float32 hits the float64 scene does not have (:func:`_refine`'s ``behind``: the
        surface a ray was spawned from, found again) are queried again past that hit, and
        any-hit queries Embree answers "occluded" are checked so, by a closest-hit query of
        those rays: a ray spawned off a small, finely tessellated object otherwise found that
        object as its own occluder (shadow acne on ``museum``). ``ties``: resolve hits
        Embree cannot order (:meth:`_resolve_ties`; not needed to learn *whether* a ray is
        occluded). ``valid_tmin``: where hits count from when the query starts later
        (``tmin``: past a rejected hit), so a float64 hit just before that start still
        counts."""
        n = len(o)
        if anyhit:
            self._fill_occluded(hits, scene, o, d, tmin, tmax, inst)
            return
        vmin = tmin if valid_tmin is None else valid_tmin
        behind = np.zeros(n, np.bool_)
        offset = self._prim_offset
        sa = self.sa
        mag = self._magnitude
        centre = self._centre

        def job(s):
            oc, org, dirs, dist, t0 = self._rays(o[s], d[s], tmin[s], tmax[s])
            res = scene.run(org, dirs, dists=dist, output=1)
            _store_hits(res["geomID"], res["primID"], res["tfar"], res["u"], res["v"],
                        t0, vmin[s], tmax[s], inst, self._geom_slot, offset, hits.t[s],
                        hits.inst[s], hits.prim[s], hits.u[s], hits.v[s])
            _refine(sa.verts, sa.tris, sa.inst_inv, o[s], d[s], vmin[s], tmax[s],
                    hits.inst[s], hits.prim[s], hits.t[s], hits.u[s], hits.v[s], behind[s])
            if ties and inst < 0 and self._ties is not None:
                was_inst, was_prim = hits.inst[s].copy(), hits.prim[s].copy()
                self._resolve_ties(o[s], oc, d[s], t0, tmax[s], hits.t[s], hits.inst[s],
                                   hits.prim[s], hits.u[s], hits.v[s])
                # a closer hit of another object replaced the one to query past
                behind[s] &= (hits.inst[s] == was_inst) & (hits.prim[s] == was_prim)

        self._run(job, n)
        again = np.flatnonzero(behind)
        if len(again) == 0:
            return
        if rounds >= REQUERY_ROUNDS:  # (not seen) the rounds are spent: leave the hits
            log.debug("embree: %d rays still behind after %d rounds", len(again), rounds)
            return
        start = np.empty(len(again))
        _past(o[again] - centre, d[again], hits.t[again], mag, start)
        sub = empty_hits(len(again))
        self._fill(sub, scene, o[again], d[again], start, tmax[again], False, inst, rounds + 1,
                   ties, vmin[again])
        for full, part in zip(hits, sub, strict=True):
            full[again] = part

    def _fill_occluded(self, hits: Hits, scene, o, d, tmin, tmax, inst):
        """Any-hit queries: Embree's occlusion query, then a closest-hit query (with its
        float64 checks) of the rays it says are occluded; occluded where that finds a hit."""
        n = len(o)
        occluded = np.zeros(n, np.int32)

        def job(s):
            _, org, dirs, dist, _ = self._rays(o[s], d[s], tmin[s], tmax[s])
            res = scene.run(org, dirs, dists=dist, query="OCCLUDED")
            _store_occluded(np.asarray(res, np.int32), tmin[s], tmax[s], 1, occluded[s])

        self._run(job, n)
        check = np.flatnonzero(occluded)
        if len(check) == 0:
            return
        sub = empty_hits(len(check))
        self._fill(sub, scene, o[check], d[check], tmin[check], tmax[check], False, inst,
                   ties=False)
        hits.inst[check[sub.inst >= 0]] = max(inst, 0)

    def _rays(self, o, d, tmin, tmax):
        """Rays in Embree's terms: the re-centred float64 origins, then float32 origins,
        directions and ranges, and where each query starts (see :func:`_to_embree`)."""
        m = len(o)
        oc = o - self._centre  # float64, re-centred as Embree's geometry
        org = np.empty((m, 3), np.float32)
        dirs = np.empty((m, 3), np.float32)
        dist = np.empty(m, np.float32)
        t0 = np.empty(m, np.float64)
        _to_embree(oc, d, tmin, tmax, self._magnitude, org, dirs, dist, t0)
        return oc, org, dirs, dist, t0

    def _run(self, job, n: int) -> None:
        """``job(slice)`` over ``n`` rays in chunks, one per numba thread, on the pool."""
        threads = max(1, min(numba.get_num_threads(), n // MIN_RAYS_PER_THREAD))
        edges = np.linspace(0, n, threads + 1).astype(int)
        parts = [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
        if len(parts) == 1:
            job(parts[0])
            return
        if self._pool is None or self._pool._max_workers < len(parts):
            self._pool = ThreadPoolExecutor(max_workers=len(parts))
        list(self._pool.map(job, parts))

    def _resolve_ties(self, o, oc, d, t0, tmax, t, inst, prim, u, v):
        """Closest hits (refined, rows of one chunk, updated in place) made independent of
        Embree's BVH: every other live object whose box holds a hit point is re-tested alone
        in the window where float32 cannot order it against that hit (module docstring).
        ``o`` world origins, ``oc`` the same re-centred; ``t0``: where each ray's Embree
        query started (its effective ``tmin``)."""
        mag = self._magnitude
        rows = np.empty(len(t), np.int32)
        objs = np.empty(len(t), np.int32)
        k = tie_candidates(self._ties, oc, d, t, inst, mag, rows, objs)
        if k > len(rows):  # more candidates than rays: count known, run again
            rows = np.empty(k, np.int32)
            objs = np.empty(k, np.int32)
            k = tie_candidates(self._ties, oc, d, t, inst, mag, rows, objs)
        if k == 0:
            return
        order = np.argsort(objs[:k], kind="stable")
        rows, objs = rows[:k][order], objs[:k][order]
        ow, occ, dc, tmax_c, t0_c = o[rows], oc[rows], d[rows], tmax[rows], t0[rows]
        lo = np.empty(k)
        hi = np.empty(k)
        tie_window(occ, dc, t[rows], t0_c, tmax_c, mag, lo, hi)
        _, org, dirs, dist, s0 = self._rays(ow, dc, lo, hi)
        c = empty_hits(k)
        edges = np.flatnonzero(np.diff(objs)) + 1
        for a, b in zip(np.r_[0, edges], np.r_[edges, k], strict=True):
            j = int(objs[a])
            res = self._object_scene(j).run(org[a:b], dirs[a:b], dists=dist[a:b], output=1)
            _store_hits(res["geomID"], res["primID"], res["tfar"], res["u"], res["v"],
                        s0[a:b], lo[a:b], hi[a:b], j, self._geom_slot, self._prim_offset,
                        *(x[a:b] for x in c))
        sa = self.sa
        behind = np.zeros(k, np.bool_)
        _refine(sa.verts, sa.tris, sa.inst_inv, ow, dc, t0_c, tmax_c, c.inst, c.prim, c.t,
                c.u, c.v, behind)
        # a candidate's own surface found again (float64 plane before the start) is no hit
        c.inst[behind], c.prim[behind], c.t[behind] = -1, -1, np.inf
        merge_closer(rows, c.t, c.inst, c.prim, c.u, c.v, t, inst, prim, u, v)


@njit(cache=True, nogil=True)
def _to_embree(o, d, tmin, tmax, magnitude, org, dirs, dist, t0):
    """float64 rays -> Embree's float32: the origin moved to ``o + t0 d`` and the range
    ``tmax - t0``, where ``t0`` (written out) is ``tmin`` raised to the float32 resolution
    ``FLOAT32_TNEAR_REL * (magnitude + |o|_inf) / |d|`` (hits closer than that are Embree's
    own rounding: a ray spawned off a surface would hit that surface again)."""
    for r in range(o.shape[0]):
        dl = max(abs(d[r, 0]), abs(d[r, 1]), abs(d[r, 2]))
        om = max(abs(o[r, 0]), abs(o[r, 1]), abs(o[r, 2]))
        near = tol.FLOAT32_TNEAR_REL * (magnitude + om) / dl if dl > 0.0 else 0.0
        s = max(tmin[r], near, 0.0)
        t0[r] = s
        for k in range(3):
            org[r, k] = o[r, k] + s * d[r, k]
            dirs[r, k] = d[r, k]
        dist[r] = tmax[r] - s if tmax[r] >= s else -1.0


@njit(cache=True, nogil=True)
def _store_hits(geom, prim, tfar, u, v, t0, tmin, tmax, inst, geom_slot, prim_offset, out_t,
                out_inst, out_prim, out_u, out_v):
    """Embree results -> :class:`Hits` rows (global triangle ids, float64 distances)."""
    for r in range(geom.shape[0]):
        if geom[r] < 0 or not tmin[r] <= tmax[r]:
            continue
        i = geom_slot[geom[r]] if inst < 0 else inst
        out_inst[r] = i
        out_prim[r] = prim[r] + prim_offset[i]
        out_t[r] = np.float64(tfar[r]) + t0[r]
        out_u[r] = u[r]
        out_v[r] = v[r]


@njit(cache=True, nogil=True)
def _refine(verts, tris, inst_inv, o, d, tmin, tmax, inst, prim, t, u, v, behind):
    """Hit distances and barycentrics recomputed in float64 on the float64 triangle (in its
    instance's object space, where ``t`` is the world ``t``) with the BVH's arithmetic
    (:func:`.triangle.solve_sheared`); kept as Embree gave them when the plane is parallel
    to the ray, and a miss where the plane lies past ``tmax``. ``behind[r]`` is set where the
    float64 plane lies before ``tmin``: Embree's float32 rounding put the surface a ray was
    spawned from (or one it grazes) in front of it -- not a hit of the float64 scene."""
    for r in range(inst.shape[0]):
        i = inst[r]
        if i < 0:
            continue
        ox, oy, oz, dx, dy, dz = ray_to_object(inst_inv, i, o[r, 0], o[r, 1], o[r, 2],
                                               d[r, 0], d[r, 1], d[r, 2])
        kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
        p = prim[r]
        a, b, c = tris[p, 0], tris[p, 1], tris[p, 2]
        ok, s, su, sv = solve_sheared(verts[a, kx], verts[a, ky], verts[a, kz],
                                      verts[b, kx], verts[b, ky], verts[b, kz],
                                      verts[c, kx], verts[c, ky], verts[c, kz],
                                      ox if kx == 0 else (oy if kx == 1 else oz),
                                      ox if ky == 0 else (oy if ky == 1 else oz),
                                      ox if kz == 0 else (oy if kz == 1 else oz), sx, sy, sz)
        if ok and tmin[r] <= s <= tmax[r]:
            t[r], u[r], v[r] = s, su, sv
        elif ok and s < tmin[r]:
            behind[r] = True
        elif ok and s > tmax[r]:
            # past the ray's end (float32 cannot resolve a shadow ray's end
            # ``tolerances.SHADOW_END_REL`` short of a light on a surface: that surface
            # darkened the light): no hit in range
            t[r], inst[r], prim[r], u[r], v[r] = np.inf, -1, -1, 0.0, 0.0


@njit(cache=True, nogil=True)
def _past(oc, d, t, magnitude, out):
    """Where a ray queried again after a rejected float32 hit at ``t`` starts: one float32
    resolution (``FLOAT32_TNEAR_REL``, as :func:`_to_embree`) beyond it."""
    for r in range(oc.shape[0]):
        dl = max(abs(d[r, 0]), abs(d[r, 1]), abs(d[r, 2]))
        p = max(abs(oc[r, 0] + t[r] * d[r, 0]), abs(oc[r, 1] + t[r] * d[r, 1]),
                abs(oc[r, 2] + t[r] * d[r, 2]))
        out[r] = t[r] + (tol.FLOAT32_TNEAR_REL * (magnitude + p) / dl if dl > 0.0 else 0.0)


@njit(cache=True, nogil=True)
def _store_occluded(res, tmin, tmax, inst, out_inst):
    for r in range(res.shape[0]):
        if res[r] != -1 and tmin[r] <= tmax[r]:
            out_inst[r] = inst
