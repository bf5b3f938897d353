"""Ray accelerators behind one batch interface, created by name.

``create_accelerator(name, scene_arrays)`` returns an object with

* ``closest_hit(origins, directions, tmin, tmax) -> Hits``
* ``any_hit(origins, directions, tmin, tmax) -> (n,) bool``
* ``intersect_object(inst, origins, directions, tmin, tmax) -> Hits`` (that object alone)
* ``update(scene_arrays)``: take a new packing of the scene, reusing per-mesh structures whose
  mesh content is unchanged
* ``name`` and ``stats`` (a dict)

Rays: ``origins``, ``directions`` (n, 3) float64 (directions need not be unit length),
``tmin``, ``tmax`` (n,) float64; hits with ``tmin <= t <= tmax`` count. Distances are along
the given direction. Names: ``"BVH"`` (the default, :mod:`.bvh`), ``"EMBREE"`` (:mod:`.embree`,
needs ``embreex``), ``"BRUTE_FORCE"`` (every triangle of every instance: the test oracle),
``"VISIBILITY_FIELD"`` (:mod:`.visibility_field`; options ``directions``, ``tiles``,
``memory_cap_mb``).
"""

from __future__ import annotations

import contextlib
import logging
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..cancel import kernel_flag
from ..frame import ACCELERATORS
from ..geometry.scene import SceneArrays, SceneError
from . import bvh
from .bvh import ray_to_object
from .triangle import intersect, ray_shear

log = logging.getLogger(__name__)

NAMES = ACCELERATORS  # the one list lives in frame.py


class AcceleratorUnavailable(SceneError):
    """The requested accelerator does not exist or cannot run here (message says why)."""


class Hits(NamedTuple):
    """Closest hits of a batch of ``n`` rays."""

    t: np.ndarray  # (n,) float64, inf on miss
    inst: np.ndarray  # (n,) int32 instance id, -1 on miss
    prim: np.ndarray  # (n,) int32 triangle index, global into SceneArrays.tris, -1 on miss
    u: np.ndarray  # (n,) float64 barycentric of vertex 1
    v: np.ndarray  # (n,) float64 barycentric of vertex 2


def empty_hits(n: int) -> Hits:
    """Hits of ``n`` rays that all miss."""
    return Hits(np.full(n, np.inf), np.full(n, -1, np.int32), np.full(n, -1, np.int32),
                np.zeros(n), np.zeros(n))


def per_ray(x, n: int, dtype) -> np.ndarray:
    """A scalar or (n,) array as a contiguous, *writeable* (n,) array of ``dtype``.

    ``np.broadcast_to`` gives read-only views, and a read-only array is another numba type:
    every kernel it reaches would be compiled once more (the BVH traversal had four
    signatures, 20 s of cold compile each on two cores, from read-only ``tmin``, ``tmax``
    and ``only`` arrays)."""
    a = np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=dtype), (n,)))
    return a if a.flags.writeable else a.copy()


def check_rays(origins, directions, tmin, tmax):
    """Validate and convert a ray batch to contiguous float64 arrays.

    Returns ``origins (n, 3), directions (n, 3), tmin (n,), tmax (n,)``; raises
    :class:`ValueError` naming the problem (wrong shapes, NaN or infinite origins or
    directions, NaN bounds).
    """
    o = np.ascontiguousarray(origins, dtype=np.float64)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"rays: origins {o.shape} and directions {d.shape} must both be (n, 3)")
    n = o.shape[0]
    lo = per_ray(tmin, n, np.float64)
    hi = per_ray(tmax, n, np.float64)
    if not (np.isfinite(o).all() and np.isfinite(d).all()):
        raise ValueError("rays: NaN or infinite origin or direction")
    if np.isnan(lo).any() or np.isnan(hi).any():
        raise ValueError("rays: NaN tmin or tmax")
    return o, d, lo, hi


def instance_array(inst, n: int, n_instances: int) -> np.ndarray:
    """``inst`` (an int or (n,) ints) as a contiguous (n,) int32 array, range-checked."""
    a = per_ray(inst, n, np.int32)
    if n and (a.min() < 0 or a.max() >= n_instances):
        raise ValueError(f"intersect_object: instance id out of range [0, {n_instances})")
    return a


class Accelerator:
    """Common batch interface; subclasses implement ``_trace`` and ``update``."""

    name = "?"

    #: The stop flag the kernels poll (:mod:`rstrace_engine.cancel`); bound by
    #: :meth:`cancellable`, never set otherwise.
    _stop = bvh.NEVER_STOP

    def __init__(self, scene_arrays: SceneArrays) -> None:
        self.sa = scene_arrays
        self.stats: dict = {}

    def update(self, scene_arrays: SceneArrays) -> None:
        self.sa = scene_arrays

    @contextlib.contextmanager
    def cancellable(self, cancel):
        """Within the block, this accelerator's kernels stop early once ``cancel`` (a
        :class:`~rstrace_engine.cancel.CancelFlag`) is set: their results are then
        incomplete, and the caller must poll ``cancel()`` after each query and discard
        what it returned. Other callables (or None) bind nothing. Kernels that poll: the
        BVH's; the others finish their query."""
        flag = kernel_flag(cancel)
        if flag is None:
            yield self
            return
        previous = self._stop
        self._stop = flag
        try:
            yield self
        finally:
            self._stop = previous

    def _trace(self, o, d, tmin, tmax, only, anyhit: bool) -> Hits:
        raise NotImplementedError

    def closest_hit(self, origins, directions, tmin, tmax) -> Hits:
        o, d, lo, hi = check_rays(origins, directions, tmin, tmax)
        return self._trace(o, d, lo, hi, None, False)

    def any_hit(self, origins, directions, tmin, tmax) -> np.ndarray:
        o, d, lo, hi = check_rays(origins, directions, tmin, tmax)
        return self._trace(o, d, lo, hi, None, True).inst >= 0

    def intersect_object(self, inst, origins, directions, tmin, tmax) -> Hits:
        return self._object(inst, origins, directions, tmin, tmax, False)

    def occludes_object(self, inst, origins, directions, tmin, tmax) -> np.ndarray:
        """(n,) bool: ray ``r`` hits object ``inst[r]`` between its bounds (any hit, as
        :meth:`any_hit` restricted to one object per ray)."""
        return self._object(inst, origins, directions, tmin, tmax, True).inst >= 0

    def _object(self, inst, origins, directions, tmin, tmax, anyhit: bool) -> Hits:
        o, d, lo, hi = check_rays(origins, directions, tmin, tmax)
        only = instance_array(inst, len(o), len(self.sa.inst_mesh))
        dead = ~self.sa.inst_alive[only]
        if dead.any():  # a tombstoned or hidden slot is never hit
            keep = np.flatnonzero(~dead)
            hits = empty_hits(len(o))
            if len(keep):
                part = self._trace(o[keep], d[keep], lo[keep], hi[keep], only[keep], anyhit)
                for full, p in zip(hits, part, strict=True):
                    full[keep] = p
            return hits
        return self._trace(o, d, lo, hi, only, anyhit)


# ----------------------------------------------------------------------------- brute force


@njit(cache=True, nogil=True, parallel=True)
def _brute_kernel(verts, tris, mesh_tri_start, inst_mesh, inst_inv, alive, o, d, tmin, tmax,
                  only, anyhit, out_t, out_inst, out_prim, out_u, out_v):
    """Every triangle of every live instance (or of ``only[r]`` when ``only[r] >= 0``)."""
    n = o.shape[0]
    ni = inst_mesh.shape[0]
    for r in prange(n):
        best = tmax[r]
        bi, bp, bu, bv = -1, -1, 0.0, 0.0
        i0, i1 = 0, ni
        if only[r] >= 0:
            i0, i1 = only[r], only[r] + 1
        for i in range(i0, i1):
            if not alive[i]:
                continue
            ox, oy, oz, dx, dy, dz = ray_to_object(inst_inv, i, o[r, 0], o[r, 1], o[r, 2],
                                                   d[r, 0], d[r, 1], d[r, 2])
            kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
            m = inst_mesh[i]
            for p in range(mesh_tri_start[m], mesh_tri_start[m + 1]):
                a, b, c = tris[p, 0], tris[p, 1], tris[p, 2]
                hit, t, u, v = intersect(ox, oy, oz, kx, ky, kz, sx, sy, sz,
                                         verts[a, 0], verts[a, 1], verts[a, 2],
                                         verts[b, 0], verts[b, 1], verts[b, 2],
                                         verts[c, 0], verts[c, 1], verts[c, 2], tmin[r], best)
                if hit:
                    best, bi, bp, bu, bv = t, i, p, u, v
                    if anyhit:
                        break
            if anyhit and bi >= 0:
                break
        if bi >= 0:
            out_t[r], out_inst[r], out_prim[r], out_u[r], out_v[r] = best, bi, bp, bu, bv


class BruteForce(Accelerator):
    """Every triangle of every instance, in numba: slow, simple, the test oracle."""

    name = "BRUTE_FORCE"

    def _trace(self, o, d, tmin, tmax, only, anyhit):
        n = len(o)
        hits = empty_hits(n)
        if only is None:
            only = np.full(n, -1, np.int32)
        sa = self.sa
        t0 = time.perf_counter()
        _brute_kernel(sa.verts, sa.tris, sa.mesh_tri_start, sa.inst_mesh, sa.inst_inv,
                      np.ascontiguousarray(sa.inst_alive, np.bool_), o, d,
                      tmin, tmax, only, anyhit, *hits)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + n
        return hits


# ----------------------------------------------------------------------------- BVH


class BVHAccelerator(Accelerator):
    """The two-level numba BVH (:mod:`.bvh`).

    Mesh BVHs are cached by a content hash of their triangles; :meth:`update` reuses them
    and rebuilds only the top level (and the concatenation the kernel reads). When the new
    packing shares the previous one's ``verts`` / ``tris`` arrays (a :class:`~.scene.Scene`
    repacked after moving objects), even the hashing is skipped: packed arrays are treated
    as immutable.
    """

    name = "BVH"

    def __init__(self, scene_arrays: SceneArrays) -> None:
        super().__init__(scene_arrays)
        self._cache: dict[bytes, bvh.MeshBVH] = {}
        self._mesh_keys: list[bytes] = []
        self._geometry = None  # (verts, tris, mesh_tri_start) identity of the last packing
        self._concat = None
        self.stats.update(meshes_built=0, meshes_reused=0, mesh_build_s=0.0, top_build_s=0.0)
        self._build(scene_arrays)

    def update(self, scene_arrays: SceneArrays) -> None:
        self._build(scene_arrays)

    def _build(self, sa: SceneArrays) -> None:
        t0 = time.perf_counter()
        same_geometry = (self._geometry is not None and self._geometry[0] is sa.verts
                         and self._geometry[1] is sa.tris
                         and np.array_equal(self._geometry[2], sa.mesh_tri_start))
        if not same_geometry:
            keys, built, reused = [], 0, 0
            cache: dict[bytes, bvh.MeshBVH] = {}
            for m in range(len(sa.mesh_tri_start) - 1):
                tv = bvh.mesh_triangles(sa, m)
                key = bvh.mesh_key(tv)
                mb = cache.get(key) or self._cache.get(key)
                if mb is None:
                    mb = bvh.build_mesh_bvh(tv)
                    built += 1
                    self.stats["mesh_build_s"] += mb.build_s
                else:
                    reused += 1
                cache[key] = mb
                keys.append(key)
            self._cache = cache  # meshes that left the scene are dropped
            self._mesh_keys = keys
            self._concat = bvh.concat_meshes([cache[k] for k in keys], sa.mesh_tri_start)
            self._geometry = (sa.verts, sa.tris, sa.mesh_tri_start.copy())
            self.stats["meshes_built"] += built
            self.stats["meshes_reused"] += reused
            log.debug("BVH: %d mesh BVHs built, %d reused", built, reused)
        t1 = time.perf_counter()
        live = np.flatnonzero(sa.inst_alive).astype(np.int32)
        top = bvh.build_top(sa.inst_aabb[live])  # tombstoned / hidden slots are left out
        top_inst = np.ascontiguousarray(live[top.perm], np.int32)
        bounds, child, tv, tri, mesh_root = self._concat
        self.sb = bvh.SceneBVH(top.bounds, top.child, top_inst, bounds, child, tv, tri,
                               mesh_root, np.ascontiguousarray(sa.inst_mesh, dtype=np.int32),
                               np.ascontiguousarray(sa.inst_inv, dtype=np.float64))
        self.sa = sa
        self.stats["top_build_s"] = time.perf_counter() - t1
        self.stats["build_s"] = time.perf_counter() - t0
        self.stats["nodes"] = int(len(child) + len(top.child))
        self.stats["sah_cost"] = {k.hex()[:8]: round(self._cache[k].sah_cost, 2)
                                  for k in self._mesh_keys}

    def _trace(self, o, d, tmin, tmax, only, anyhit):
        n = len(o)
        hits = empty_hits(n)
        if only is None:
            only = np.full(n, -1, np.int32)
        t0 = time.perf_counter()
        bvh.trace(self.sb, o, d, tmin, tmax, only, anyhit, hits, self._stop)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + n
        return hits


# ----------------------------------------------------------------------------- factory


def create_accelerator(name: str, scene_arrays: SceneArrays, **options) -> Accelerator:
    """Build the accelerator called ``name`` (one of :data:`NAMES`) over ``scene_arrays``.

    ``options`` go to accelerators that take them (``"VISIBILITY_FIELD"``: ``directions``,
    ``tiles``, ``memory_cap_mb``) and are ignored by the others. Raises
    :class:`AcceleratorUnavailable` for unknown names and for ``"EMBREE"`` when ``embreex``
    is not installed.
    """
    key = str(name).upper()
    if key == "BRUTE_FORCE":
        return BruteForce(scene_arrays)
    if key == "BVH":
        return BVHAccelerator(scene_arrays)
    if key == "EMBREE":
        from .embree import EmbreeAccelerator

        return EmbreeAccelerator(scene_arrays)
    if key == "VISIBILITY_FIELD":
        from .visibility_field import VisibilityField

        return VisibilityField(scene_arrays, **options)
    raise AcceleratorUnavailable(f"unknown accelerator {name!r}; choose from {list(NAMES)}")
