"""The batch ray-query interface every accelerator implements (:class:`Accelerator`), its
results (:class:`Hits`) and the checks of a ray batch.

The accelerators in their own modules (:mod:`.embree`, :mod:`.visibility_field`) build on
this module, not on :mod:`.accelerators`, whose factory imports them by name.
"""

from __future__ import annotations

import contextlib
from typing import NamedTuple

import numpy as np

from ..cancel import kernel_flag
from ..geometry.scene import SceneArrays, SceneError
from . import bvh


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
    and ``only`` arrays). Such an array given is returned as it is (not copied: the copies
    of every query's tmin and tmax were ~2% of a glossy frame, docs/bench-frame.md)."""
    a = np.asarray(x, dtype=dtype)
    if a.shape == (n,) and a.flags.c_contiguous and a.flags.writeable:
        return a
    a = np.ascontiguousarray(np.broadcast_to(a, (n,)))
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
    """Common batch interface; subclasses implement ``_trace`` and ``update``.

    Optional (the BVH's, :class:`~.accelerators.BVHAccelerator`): ``occluded_samples``
    and ``occluded``, the soft samples' and the hard shadow rays' occlusion queries,
    :meth:`any_hit`'s answer bit for bit; callers look them up by name and fall back to
    :meth:`any_hit` (:func:`~..tracing.whitted._occluded_by`,
    :func:`~..tracing.light_linking.any_hit_shadows`)."""

    name = "?"

    #: :meth:`any_hit` of a ray is, bit for bit, :meth:`occludes_object` of one of the live
    #: objects (the same object-space test, whichever tree reaches it): a ray that met
    #: nothing meets, after an edit, only what the edit placed (tracing/shadow_reshade.py
    #: tests kept visible samples against the edited objects alone). False where a query
    #: of the whole scene may differ (Embree's float32 scene)
    any_hit_by_object = False

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

    def closest_hit(self, origins, directions, tmin, tmax, skip=None) -> Hits:
        """The first hit of each ray between its bounds. ``skip`` as :meth:`any_hit`'s:
        an instance per ray the caller has proven the ray cannot meet, which the query
        may leave out (:func:`~..tracing.shaft_skip.own_reflections`)."""
        o, d, lo, hi = check_rays(origins, directions, tmin, tmax)
        return self._trace(o, d, lo, hi, None, False)

    def any_hit(self, origins, directions, tmin, tmax, skip=None) -> np.ndarray:
        """(n,) bool: ray ``r`` hits something between its bounds. ``skip`` (n,) int32 or
        None: per ray an instance the caller has proven it cannot meet (-1: none), which
        the query may leave out (the BVH's does;
        :func:`~..tracing.shaft_skip.own_instances`): the answer is the same either way."""
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
