"""Embree backend through ``embreex`` (the yardstick the numba BVH is measured against).

The scene is flattened: one Embree triangle geometry per instance, its mesh's vertices taken
to world space in float32 (Embree's precision), so ``geomID`` is the instance id and
``primID`` the triangle within the instance's mesh (reported as the GLOBAL triangle index).
Closest hits use Embree's intersect query, ``any_hit`` its occlusion query, and
``intersect_object`` a per-instance Embree scene built lazily on first use. The scene is
built in robust mode (watertight). Embree has no per-ray ``tnear`` in ``embreex``: a ray with
``tmin > 0`` is started at ``o + tmin d`` and its distances shifted back.

``embreex``'s ``run`` releases the GIL, so batches are split into chunks run from a small
thread pool (one chunk per numba thread, ``numba.get_num_threads()``).
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from .accelerators import Accelerator, AcceleratorUnavailable, Hits, empty_hits
from .scene import SceneArrays

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
        for i in range(len(sa.inst_mesh)):
            v, f = _instance_geometry(sa, i)
            self._keep.append(_mc.TriangleMesh(scene, v, f))
        self.scene = scene
        self.sa = sa
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

    def _run(self, scene, o, d, tmin, tmax, query):
        """Run ``query`` on float32 rays, split across threads; returns a list of results
        per chunk and the chunk slices."""
        org = np.ascontiguousarray(o + tmin[:, None] * d, dtype=np.float32)
        dirs = np.ascontiguousarray(d, dtype=np.float32)
        dist = np.ascontiguousarray(tmax - tmin, dtype=np.float32)
        n = len(o)
        threads = max(1, min(numba.get_num_threads(), n // MIN_RAYS_PER_THREAD))
        bounds = np.linspace(0, n, threads + 1).astype(int)
        parts = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]

        def job(s):
            if query == "OCCLUDED":
                return scene.run(org[s], dirs[s], dists=dist[s], query="OCCLUDED")
            return scene.run(org[s], dirs[s], dists=dist[s], output=1)

        if threads == 1:
            return [job(parts[0])], parts
        if self._pool is None or self._pool._max_workers < threads:
            self._pool = ThreadPoolExecutor(max_workers=threads)
        return list(self._pool.map(job, parts)), parts

    def _trace(self, o, d, tmin, tmax, only, anyhit):
        n = len(o)
        hits = empty_hits(n)
        if n == 0:
            return hits
        t0 = time.perf_counter()
        valid = tmin <= tmax
        if not valid.all():
            idx = np.flatnonzero(valid)
            sub = self._trace(o[idx], d[idx], tmin[idx], tmax[idx],
                              None if only is None else only[idx], anyhit)
            for full, part in zip(hits, sub, strict=True):
                full[idx] = part
            return hits
        if only is not None:
            for i in np.unique(only):
                idx = np.flatnonzero(only == i)
                self._fill(hits, idx, self._object_scene(int(i)), o[idx], d[idx], tmin[idx],
                           tmax[idx], anyhit, int(i))
        else:
            self._fill(hits, slice(None), self.scene, o, d, tmin, tmax, anyhit, -1)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + n
        return hits

    def _fill(self, hits: Hits, where, scene, o, d, tmin, tmax, anyhit, inst):
        results, parts = self._run(scene, o, d, tmin, tmax, "OCCLUDED" if anyhit else None)
        sa = self.sa
        t = np.full(len(o), np.inf)
        ii = np.full(len(o), -1, np.int32)
        pp = np.full(len(o), -1, np.int32)
        uu = np.zeros(len(o))
        vv = np.zeros(len(o))
        for res, s in zip(results, parts, strict=True):
            if anyhit:
                ii[s] = np.where(np.asarray(res) != -1, max(inst, 0), -1)
                continue
            geom = res["geomID"]
            hit = geom >= 0
            ii[s] = np.where(hit, geom if inst < 0 else inst, -1)
            t[s] = np.where(hit, res["tfar"].astype(np.float64) + tmin[s], np.inf)
            pp[s] = np.where(hit, res["primID"], -1)
            uu[s] = np.where(hit, res["u"], 0.0)
            vv[s] = np.where(hit, res["v"], 0.0)
        if not anyhit:
            hit = ii >= 0
            pp[hit] += sa.mesh_tri_start[sa.inst_mesh[ii[hit]]]
        hits.t[where], hits.inst[where], hits.prim[where] = t, ii, pp
        hits.u[where], hits.v[where] = uu, vv
