"""Embree backend through ``embreex`` (the yardstick the numba BVH is measured against).

The scene is flattened: one Embree triangle geometry per instance, its mesh's vertices taken
to world space in float32 (Embree's precision), so ``geomID`` is the instance id and
``primID`` the triangle within the instance's mesh (reported as the GLOBAL triangle index).
Closest hits use Embree's intersect query, ``any_hit`` its occlusion query, and
``intersect_object`` a per-instance Embree scene built lazily on first use. The scene is
built in robust mode (watertight). Embree has no per-ray ``tnear`` in ``embreex``: a ray with
``tmin > 0`` is started at ``o + tmin d`` and its distances shifted back.

Float32 and spawned rays: Embree's geometry and rays are float32, so a ray spawned a float64
offset (``tolerances.SPAWN_OFFSET_REL``, 1e-9 relative) off a surface starts *inside* that
surface's float32 rounding and hits it again (shadow acne: 29% of the pixels of a small scene
differed from the BVH's). Two things make an Embree frame the BVH's frame:

* every ray starts at least ``tolerances.FLOAT32_TNEAR_REL`` times the magnitude of the scene
  and of its origin along itself (Embree cannot tell hits closer than that from its own
  rounding), and
* the distance of every closest hit is recomputed in float64 against the float64 plane of the
  triangle Embree reports, so hit points (and every ray spawned from them) are where the
  BVH puts them, not float32-t away.

``embreex``'s ``run`` releases the GIL, so batches are split into chunks run from a small
thread pool (one chunk per numba thread, ``numba.get_num_threads()``).
"""

from __future__ import annotations

import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.scene import SceneArrays
from .accelerators import Accelerator, AcceleratorUnavailable, Hits, empty_hits
from .bvh import ray_to_object

log = logging.getLogger(__name__)

try:  # optional dependency
    from embreex import mesh_construction as _mc
    from embreex import rtcore_scene as _rs
except ImportError:  # pragma: no cover - depends on the machine
    _mc = _rs = None

#: Fewest rays per thread worth splitting a batch for.
MIN_RAYS_PER_THREAD = 4096


def available() -> bool:
    """True when ``embreex`` can be imported."""
    return _rs is not None


def _instance_geometry(sa: SceneArrays, i: int):
    """World-space float32 vertices (V, 3) and int32 triangles (m, 3) of instance ``i``."""
    m = sa.inst_mesh[i]
    tris = sa.tris[sa.mesh_tri_start[m]:sa.mesh_tri_start[m + 1]]
    v0, v1 = int(tris.min()), int(tris.max()) + 1
    x = sa.inst_xform[i]
    world = sa.verts[v0:v1] @ x[:3, :3].T + x[:3, 3]
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
        self._build(scene_arrays)

    def update(self, scene_arrays: SceneArrays) -> None:
        self._build(scene_arrays)

    def _build(self, sa: SceneArrays) -> None:
        t0 = time.perf_counter()
        scene = _rs.EmbreeScene(robust=True)
        self._keep = []  # embreex geometries must outlive the scene's use of them
        # geometry ids are given in order: geom_slot maps them back to instance slots
        self._geom_slot = np.ascontiguousarray(np.flatnonzero(sa.inst_alive), np.int32)
        for i in self._geom_slot:
            v, f = _instance_geometry(sa, int(i))
            self._keep.append(_mc.TriangleMesh(scene, v, f))
        self.scene = scene
        self.sa = sa
        self._prim_offset = np.ascontiguousarray(sa.mesh_tri_start[sa.inst_mesh], np.int32)
        self._magnitude = float(np.max(np.abs(sa.scene_aabb)))
        self._objects: dict[int, object] = {}
        self.stats["build_s"] = time.perf_counter() - t0

    def _object_scene(self, i: int):
        sc = self._objects.get(i)
        if sc is None:
            sc = _rs.EmbreeScene(robust=True)
            v, f = _instance_geometry(self.sa, i)
            self._objects[i] = sc
            self._keep.append(_mc.TriangleMesh(sc, v, f))
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

    def _fill(self, hits: Hits, scene, o, d, tmin, tmax, anyhit, inst):
        """Trace rays with ``scene`` into ``hits`` (pre-filled as misses), in chunks on the
        thread pool; conversion to and from Embree's float32 runs in the workers too."""
        n = len(o)
        threads = max(1, min(numba.get_num_threads(), n // MIN_RAYS_PER_THREAD))
        edges = np.linspace(0, n, threads + 1).astype(int)
        parts = [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
        offset = self._prim_offset
        sa = self.sa
        mag = self._magnitude

        def job(s):
            m = s.stop - s.start
            org = np.empty((m, 3), np.float32)
            dirs = np.empty((m, 3), np.float32)
            dist = np.empty(m, np.float32)
            t0 = np.empty(m, np.float64)
            _to_embree(o[s], d[s], tmin[s], tmax[s], mag, org, dirs, dist, t0)
            if anyhit:
                res = scene.run(org, dirs, dists=dist, query="OCCLUDED")
                _store_occluded(np.asarray(res, np.int32), tmin[s], tmax[s], max(inst, 0),
                                hits.inst[s])
            else:
                res = scene.run(org, dirs, dists=dist, output=1)
                _store_hits(res["geomID"], res["primID"], res["tfar"], res["u"], res["v"],
                            t0, tmin[s], tmax[s], inst, self._geom_slot, offset, hits.t[s],
                            hits.inst[s],
                            hits.prim[s], hits.u[s], hits.v[s])
                _refine_t(sa.verts, sa.tris, sa.inst_inv, o[s], d[s], tmin[s], tmax[s],
                          hits.inst[s], hits.prim[s], hits.t[s])

        if threads == 1:
            job(parts[0])
            return
        if self._pool is None or self._pool._max_workers < threads:
            self._pool = ThreadPoolExecutor(max_workers=threads)
        list(self._pool.map(job, parts))


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
def _refine_t(verts, tris, inst_inv, o, d, tmin, tmax, inst, prim, t):
    """Hit distances recomputed in float64 against the plane of the float64 triangle (in
    its instance's object space, where ``t`` is the world ``t``); kept as Embree gave them
    when the plane is (near) parallel to the ray or the result leaves ``[tmin, tmax]``."""
    for r in range(inst.shape[0]):
        i = inst[r]
        if i < 0:
            continue
        ox, oy, oz, dx, dy, dz = ray_to_object(inst_inv, i, o[r, 0], o[r, 1], o[r, 2],
                                               d[r, 0], d[r, 1], d[r, 2])
        p = prim[r]
        a, b, c = tris[p, 0], tris[p, 1], tris[p, 2]
        e1x = verts[b, 0] - verts[a, 0]
        e1y = verts[b, 1] - verts[a, 1]
        e1z = verts[b, 2] - verts[a, 2]
        e2x = verts[c, 0] - verts[a, 0]
        e2y = verts[c, 1] - verts[a, 1]
        e2z = verts[c, 2] - verts[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        dn = nx * dx + ny * dy + nz * dz
        if dn == 0.0:
            continue
        s = (nx * (verts[a, 0] - ox) + ny * (verts[a, 1] - oy) + nz * (verts[a, 2] - oz)) / dn
        if math.isfinite(s) and tmin[r] <= s <= tmax[r]:
            t[r] = s


@njit(cache=True, nogil=True)
def _store_occluded(res, tmin, tmax, inst, out_inst):
    for r in range(res.shape[0]):
        if res[r] != -1 and tmin[r] <= tmax[r]:
            out_inst[r] = inst
