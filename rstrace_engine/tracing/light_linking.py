"""Shadow linking: shadow rays that only a light's blockers stop (Cycles' blocker
collection, ``SceneArrays.light_block``).

Without shadow linking in the scene a shadow ray is the plain any-hit query
(:func:`any_hit_shadows`: the BVH's occlusion kernel, else the accelerator's ``any_hit``),
as before. With it, the rays of a light that has blockers are traced hit by hit: the closest
hit either belongs to one of the light's blockers (the ray is stopped there) or the ray goes
on from just past it (``tolerances.LINK_SKIP_REL``), batched, every pass over the rays still
going. Light linking's other half (which objects a light lights, ``light_recv``) is a mask
the surface and shade kernels read (:mod:`.shader`).
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol


def links_shadows(sa) -> bool:
    """Whether some light of ``sa`` has a blocker collection."""
    return sa.light_block.shape[0] > 0


def first_blocker(sa, accel, o, d, tmax, lights) -> np.ndarray:
    """The instance that stops each shadow ray ``o + t d`` (unit ``d``, ``0 < t < tmax``)
    toward light ``lights`` (k,) (-1, or L and above: the world, which every object
    shadows), or -1 where none does: the first hit, or where the light has blockers the
    first of them along the ray. (k,) int32."""
    o = np.ascontiguousarray(o, np.float64)
    d = np.ascontiguousarray(d, np.float64)
    tmax = np.ascontiguousarray(tmax, np.float64)
    lights = np.asarray(lights, np.int64)
    k = len(o)
    out = np.full(k, -1, np.int32)
    if k == 0:
        return out
    nl = sa.light_block.shape[0]
    j = np.where((lights >= 0) & (lights < nl), lights, -1)
    linked = np.zeros(k, np.bool_)
    if nl:
        some = ~sa.light_block.all(axis=1)  # lights with blockers (not every object)
        linked = (j >= 0) & some[np.maximum(j, 0)]
    plain = np.flatnonzero(~linked)
    if len(plain):
        out[plain] = accel.closest_hit(o[plain], d[plain], np.zeros(len(plain)),
                                       tmax[plain]).inst
    idx = np.flatnonzero(linked)
    tmin = np.zeros(len(idx))
    for _ in range(tol.LINK_MAX_SKIPS + 1):
        if not len(idx):
            break
        h = accel.closest_hit(o[idx], d[idx], tmin, tmax[idx])
        inst = np.asarray(h.inst)
        hit = inst >= 0
        stop = hit & (sa.light_block[j[idx], np.maximum(inst, 0)] != 0)
        out[idx[stop]] = inst[stop]
        t = np.asarray(h.t) * (1.0 + tol.LINK_SKIP_REL) + tol.LINK_SKIP_REL
        go = hit & ~stop & (t < tmax[idx])
        idx = idx[go]
        tmin = t[go]
    return out


def occluded(sa, accel, o, d, tmax, lights) -> np.ndarray:
    """Whether each shadow ray is stopped (:func:`first_blocker`), (k,) bool; the plain
    any-hit query (:func:`any_hit_shadows`) where no light has blockers."""
    if not links_shadows(sa):
        return any_hit_shadows(accel, o, d, tmax)
    return first_blocker(sa, accel, o, d, tmax, lights) >= 0


def any_hit_shadows(accel, o, d, tmax, skip=None) -> np.ndarray:
    """The plain any-hit query of shadow rays from ``t = 0``, (k,) bool: the accelerator's
    ``occluded`` where it has one (the BVH's occlusion kernel, the same answer bit for bit:
    :func:`~..accel.bvh_occlusion.occluded_rays`), else its ``any_hit``. ``skip`` as
    ``any_hit``'s."""
    f = getattr(accel, "occluded", None)
    if f is not None:
        return f(o, d, tmax, skip)
    extra = () if skip is None else (skip,)
    return np.asarray(accel.any_hit(o, d, np.zeros(len(o)), tmax, *extra), np.bool_)
