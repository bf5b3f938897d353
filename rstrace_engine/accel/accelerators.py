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
``memory_cap_mb``). The interface itself (:class:`Accelerator`, :class:`Hits`) is defined
in :mod:`.interface` and re-exported here.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
from numba import njit, prange

from ..cancel import Cancelled
from ..frame import ACCELERATORS
from ..geometry.scene import SceneArrays
from . import bvh, bvh_mesh, bvh_occlusion
from .bvh import ray_to_object
from .interface import (  # noqa: F401 - re-exported: the interface's public names
    Accelerator,
    AcceleratorUnavailable,
    Hits,
    check_rays,
    empty_hits,
    instance_array,
    per_ray,
)
from .triangle import intersect, ray_shear

log = logging.getLogger(__name__)

NAMES = ACCELERATORS  # the one list lives in frame.py


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
    any_hit_by_object = True  # (every live object's triangles, one after another)

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

#: At most this many bytes of mesh BVHs are kept for later accelerators (:class:`KeptBVHs`);
#: a build whose mesh BVHs take more keeps none.
KEPT_BVH_MAX_BYTES = 2 << 30


class KeptBVHs:
    """The mesh BVHs of the last BVH built in this process, for the next accelerator.

    A new session (an F12 after a render setting changed, a viewport session after an F12)
    builds a new :class:`BVHAccelerator`; a mesh whose content hash (:func:`~.bvh_mesh.
    mesh_key`: its triangles' vertices, exactly) matches a kept one takes that tree instead
    of building it (the same tree: the build is deterministic). What is kept is the
    placement (:class:`~.bvh.PlacedMesh` views) of the accelerator built or updated last:
    at most one scene's meshes, and none past :data:`KEPT_BVH_MAX_BYTES` (while that
    accelerator lives, keeping them costs nothing; after it, the memory of its trees).
    :meth:`clear` lets them go.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._meshes: dict[bytes, bvh.PlacedMesh] = {}
        self.nbytes = 0

    def get(self, key: bytes) -> bvh.PlacedMesh | None:
        with self._lock:
            return self._meshes.get(key)

    def keep(self, meshes: dict, nbytes: int) -> None:
        """Keep ``meshes`` (key -> PlacedMesh, views of arrays of ``nbytes`` in all) in place
        of the previous ones."""
        with self._lock:
            if nbytes > KEPT_BVH_MAX_BYTES:
                self._meshes, self.nbytes = {}, 0
            else:
                self._meshes, self.nbytes = dict(meshes), nbytes

    def clear(self) -> None:
        with self._lock:
            self._meshes, self.nbytes = {}, 0

    def __len__(self) -> int:
        return len(self._meshes)


#: The process's kept mesh BVHs (:class:`KeptBVHs`): what the add-on's sessions share.
KEPT = KeptBVHs()


#: what the top level of :class:`BVHAccelerator` is built from (kept while a new packing
#: shares these arrays)
_TOP_FIELDS = ("inst_aabb", "inst_alive", "inst_mesh", "inst_inv")


class BVHAccelerator(Accelerator):
    """The two-level numba BVH (:mod:`.bvh`).

    Mesh BVHs are cached by a content hash of their triangles; :meth:`update` reuses them
    and rebuilds only the top level (and the concatenation the kernel reads). When the new
    packing shares the previous one's ``verts`` / ``tris`` arrays (a :class:`~.scene.Scene`
    repacked after moving objects), even the hashing is skipped: packed arrays are treated
    as immutable. Given ``kept`` (a :class:`KeptBVHs`, e.g. the process's :data:`KEPT`:
    what a host's sessions pass), a mesh is first looked up there (the trees of the last
    accelerator built with it: a new session over unchanged meshes builds none), and the
    accelerator's own trees are kept there after each build.
    """

    name = "BVH"
    # (the top level's boxes hold their objects' conservative boxes: the object-space test
    # of an object whose triangle a ray meets is reached whatever else the tree holds)
    any_hit_by_object = True

    def __init__(self, scene_arrays: SceneArrays, cancel=None,
                 kept: KeptBVHs | None = None) -> None:
        super().__init__(scene_arrays)
        self._kept = kept
        self._cache: dict[bytes, bvh.PlacedMesh] = {}
        self._mesh_keys: list[bytes] = []
        self._geometry = None  # (verts, tris, mesh_tri_start) identity of the last packing
        self._concat = None
        self.stats.update(meshes_built=0, meshes_reused=0, meshes_kept=0, mesh_build_s=0.0,
                          top_build_s=0.0)
        with self.cancellable(cancel):
            self._build(scene_arrays)

    def update(self, scene_arrays: SceneArrays) -> None:
        self._build(scene_arrays)

    def _build(self, sa: SceneArrays) -> None:
        """Build what changed; the bound stop flag (:meth:`cancellable`) is polled within
        and between mesh builds, and nothing is kept unless all of it completes
        (:class:`~rstrace_engine.cancel.Cancelled` otherwise)."""
        t0 = time.perf_counter()
        stop = self._stop
        same_geometry = (self._geometry is not None and self._geometry[0] is sa.verts
                         and self._geometry[1] is sa.tris
                         and np.array_equal(self._geometry[2], sa.mesh_tri_start))
        if not same_geometry:
            keys, built, reused, kept = [], 0, 0, 0
            cache: dict[bytes, bvh.PlacedMesh] = {}
            for m in range(len(sa.mesh_tri_start) - 1):
                if stop[0]:
                    raise Cancelled("BVH build cancelled")
                start, end = bvh_mesh.mesh_range(sa, m)
                tris = sa.tris[start:end]
                key = bvh_mesh.mesh_key(sa.verts, tris, stop)
                pm = cache.get(key) or self._cache.get(key)
                if pm is None and self._kept is not None:
                    pm = self._kept.get(key)
                    kept += pm is not None
                if pm is None:
                    if stop[0]:
                        raise Cancelled("BVH build cancelled")
                    mb = bvh_mesh.build_mesh_bvh_indexed(sa.verts, tris, stop=stop)
                    pm = bvh.PlacedMesh.built(mb)
                    built += 1
                    self.stats["mesh_build_s"] += mb.build_s
                else:
                    reused += 1
                cache[key] = pm
                keys.append(key)
            if stop[0]:
                raise Cancelled("BVH build cancelled")
            *concat, placed = bvh.concat_meshes([cache[k] for k in keys], sa.mesh_tri_start)
            # meshes that left the scene are dropped; the others are kept as views of the
            # concatenation (the arrays of the previous one are then freed)
            self._cache = dict(zip(keys, placed, strict=True))
            self._mesh_keys = keys
            self._concat = tuple(concat)
            self._geometry = (sa.verts, sa.tris, sa.mesh_tri_start.copy())
            self.stats["meshes_built"] += built
            self.stats["meshes_reused"] += reused - kept
            self.stats["meshes_kept"] += kept
            if self._kept is not None:
                self._kept.keep(self._cache, sum(a.nbytes for a in concat[:3]))
            log.debug("BVH: %d mesh BVHs built, %d reused", built, reused)
        t1 = time.perf_counter()
        old = self.sa if same_geometry else None
        if old is not None and all(getattr(old, f) is getattr(sa, f) for f in _TOP_FIELDS):
            # the same instances (a light or world edit repacks the lights alone,
            # Scene.repack_lights): the top level is kept
            self.sa = sa
            self.stats["top_build_s"] = 0.0
            self.stats["build_s"] = time.perf_counter() - t0
            return
        live = np.flatnonzero(sa.inst_alive).astype(np.int32)
        top = bvh_mesh.build_top(sa.inst_aabb[live])  # tombstoned / hidden slots are left out
        top_inst = np.ascontiguousarray(live[top.perm], np.int32)
        bounds, child, tri, mesh_root = self._concat
        # (the leaves read the scene's own triangles and vertices through ``tri``)
        self.sb = bvh.SceneBVH(top.bounds, top.child, top_inst, bounds, child, sa.verts,
                               sa.tris, tri, mesh_root,
                               np.ascontiguousarray(sa.inst_mesh, dtype=np.int32),
                               np.ascontiguousarray(sa.inst_inv, dtype=np.float64))
        self.sa = sa
        self.stats["top_build_s"] = time.perf_counter() - t1
        self.stats["build_s"] = time.perf_counter() - t0
        self.stats["nodes"] = int(len(child) + len(top.child))
        # (its own arrays: verts and tris are the scene's)
        self.stats["memory_mb"] = sum(a.nbytes for f, a in self.sb._asdict().items()
                                      if f not in ("verts", "tris")) / 2 ** 20
        self.stats["sah_cost"] = {k.hex()[:8]: round(self._cache[k].sah_cost, 2)
                                  for k in self._mesh_keys}

    def closest_hit(self, origins, directions, tmin, tmax, skip=None) -> Hits:
        """As :meth:`~.interface.Accelerator.closest_hit`; ``skip`` as :meth:`any_hit`'s."""
        o, d, lo, hi = check_rays(origins, directions, tmin, tmax)
        return self._trace(o, d, lo, hi, _skip_only(skip, len(o)), False)

    def any_hit(self, origins, directions, tmin, tmax, skip=None) -> np.ndarray:
        """As :meth:`~.interface.Accelerator.any_hit`; the instance ``skip[r]`` is left out
        of ray ``r``'s traversal (:func:`.bvh.trace_kernel`'s ``only <= -2``)."""
        o, d, lo, hi = check_rays(origins, directions, tmin, tmax)
        return self._trace(o, d, lo, hi, _skip_only(skip, len(o)), True).inst >= 0

    def occluded_samples(self, o, d, tmax, w, n: int, row_skip, row_proven):
        """The visibility of sampled shadow rays where they were drawn, ``n`` a row
        (:func:`.bvh_occlusion.occluded_samples`: each sample with ``w > 0`` of a row not
        ``row_proven`` traced from ``o`` along ``d`` to ``tmax``, leaving instance
        ``row_skip`` of its row out): what :meth:`any_hit` of those rays answers, bit for
        bit, without gathering them. Returns ``(vis (k,) bool, counts)``: rays traced,
        proven samples, rays that left an instance out."""
        t0 = time.perf_counter()
        vis, counts = bvh_occlusion.occluded_samples(self.sb, o, d, tmax, w, n, row_skip,
                                                     row_proven, self._stop)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + int(counts[0])
        return vis, counts

    def occluded(self, o, d, tmax, skip=None) -> np.ndarray:
        """(n,) bool: :meth:`any_hit` of the rays from ``tmin = 0`` (``skip`` as its), bit
        for bit, traced where they lie by the occlusion kernel
        (:func:`.bvh_occlusion.occluded_rays`): hard lights' shadow rays."""
        t0 = time.perf_counter()
        n = len(o)
        # (tmax as any_hit's: a scalar, or a read-only array -- another signature of the
        # kernel -- copied; the tracer's contiguous arrays are taken as they are; a NaN
        # refused as check_rays refuses it: the kernel would answer such a ray visible)
        hi = per_ray(tmax, n, np.float64)
        if np.isnan(hi).any():
            raise ValueError("rays: NaN tmin or tmax")
        blocked, counts = bvh_occlusion.occluded_rays(
            self.sb, o, d, hi, None if skip is None else per_ray(skip, n, np.int32),
            self._stop)
        self.stats["trace_s"] = self.stats.get("trace_s", 0.0) + time.perf_counter() - t0
        self.stats["rays"] = self.stats.get("rays", 0) + int(counts[0])
        return blocked

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


def _skip_only(skip, n: int):
    """The traversal's ``only`` (n,) int32 of per-ray instances to leave out (``skip``, -1
    none), None without any."""
    if skip is None:
        return None
    s = per_ray(skip, n, np.int32)
    return np.where(s >= 0, -2 - s, -1).astype(np.int32)


# ----------------------------------------------------------------------------- factory


def create_accelerator(name: str, scene_arrays: SceneArrays, cancel=None,
                       kept: KeptBVHs | None = None, **options) -> Accelerator:
    """Build the accelerator called ``name`` (one of :data:`NAMES`) over ``scene_arrays``.

    ``options`` go to accelerators that take them (``"VISIBILITY_FIELD"``: ``directions``,
    ``tiles``, ``memory_cap_mb``) and are ignored by the others. ``cancel``: a
    :class:`~rstrace_engine.cancel.CancelFlag` the BVH's build polls (it then raises
    :class:`~rstrace_engine.cancel.Cancelled`); the others finish their build. Raises
    :class:`AcceleratorUnavailable` for unknown names and for ``"EMBREE"`` when ``embreex``
    is not installed. ``kept``: the :class:`KeptBVHs` a BVH takes unchanged meshes' trees
    from and leaves its own in (the others ignore it).
    """
    key = str(name).upper()
    if key == "BRUTE_FORCE":
        return BruteForce(scene_arrays)
    if key == "BVH":
        return BVHAccelerator(scene_arrays, cancel, kept)
    if key == "EMBREE":
        from .embree import EmbreeAccelerator

        return EmbreeAccelerator(scene_arrays)
    if key == "VISIBILITY_FIELD":
        from .visibility_field import VisibilityField

        return VisibilityField(scene_arrays, **options)
    raise AcceleratorUnavailable(f"unknown accelerator {name!r}; choose from {list(NAMES)}")
