"""The RI_TREE frame's ray tree between levels: the pixel classes of primary rays
(:func:`primary_class`) and the next level's rays (:func:`next_rays`: an interpolated glass
hit's refracted ray becomes its interpolated exit ray, and the internal reflection where the
path refracts out is traced from there)."""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from ..frame import (
    CLASS_BACKGROUND,
    CLASS_FAIL_NONLINEAR,
    CLASS_FAIL_SILHOUETTE,
    CLASS_INTERPOLATED,
    CLASS_TRACED,
)
from ..tracing.glossy_rays import glossy_materials
from ..tracing.whitted import Spawned, child_paths
from .patches import ST_FAIL_ANGLE, ST_FAIL_CLASS


def primary_class(H: dict, interp: np.ndarray) -> np.ndarray:
    """Pixel classes of a tile's primary rays from their hits ``H`` (:meth:`_intersect`)
    and the rows ``interp`` that were interpolated."""
    st = H["status"]
    hit = H["inst"] >= 0
    cls = np.where(hit, CLASS_TRACED, CLASS_BACKGROUND).astype(np.uint8)
    cls[(st == ST_FAIL_CLASS) & hit] = CLASS_FAIL_SILHOUETTE
    cls[(st == ST_FAIL_ANGLE) & hit] = CLASS_FAIL_NONLINEAR
    cls[interp] = CLASS_INTERPOLATED
    return cls


def next_rays(sa, kids: Spawned, inst, q, interp, qi, src, level, max_depth, path, fresh, tag,
              gstart=None, glossy=None, nseeds=None):
    """The next level's rays from a level's spawned rays ``kids``.

    Rays past ``max_depth`` are dropped (``level`` (nb,): each ray's depth). Rays leaving an
    interpolated hit (rows ``interp``, query rows ``qi`` of ``q``, on instances ``inst``)
    ignore their own object near the hit; at an interpolated glass hit the refracted ray
    becomes the interpolated exit ray, ``nint`` levels further down, and the internal
    reflection where the path refracts out is traced from there. ``path`` (nb,) int64: the
    rays' ray-tree paths (root 1, reflect child 2p, refract child 2p + 1; the internal
    reflection at an exit and the exit ray as the base tracer's paths through the glass
    go), which seed the soft lights' and glossy samples; ``fresh``
    (nb,) bool, ``tag`` (nb,) uint64: whether their paths have drawn no glossy samples yet,
    and what their node seeds hash in (:func:`~..tracing.whitted.child_paths`). Point i's
    ray pairs are ``gstart[i]:gstart[i + 1]`` (None: one pair each), ``glossy``, ``nseeds``
    as :func:`~..tracing.whitted.shade_paths` was given and returned them. Returns ``(o, d,
    weight, src, level, self_inst, path, fresh, tag)``."""
    c_o, c_d, c_w, c_ok = kids
    nb = len(src)
    counts = np.ones(nb, np.int64) if gstart is None else np.diff(gstart)
    first = np.arange(nb) if gstart is None else gstart[:-1]  # each point's first pair
    pt = np.repeat(np.arange(nb), 2 * counts)  # the point of each slot
    c_ok &= ~(level >= max_depth)[pt]
    child_level = level[pt] + 1
    child_self = np.full(len(c_ok), -1, np.int32)
    child_path = 2 * path[pt] + (np.arange(len(c_ok)) & 1)
    if len(interp):
        # every reflected ray of an interpolated point (a rough one draws several)
        from_interp = np.zeros(nb, np.bool_)
        from_interp[interp] = True
        refl = np.flatnonzero(from_interp[pt] & (np.arange(len(c_ok)) % 2 == 0))
        child_self[refl] = inst[pt[refl]]
        # glass: the refracted ray becomes the interpolated exit ray
        ni = q.nint[qi].astype(np.int64)
        tr = 2 * first[interp] + 1
        glass = (q.OD[qi] != 0).any(axis=1) & (ni >= 0) & c_ok[tr]
        # rough glass: its sampled refracted rays are traced as they are (an exit ray would
        # be a sharp one)
        rough = glossy_materials(sa)[np.maximum(q.mat[qi], 0)]
        has_tr = np.flatnonzero(c_ok[tr] & is_transmissive(sa, q.mat[qi]) & ~rough)
        keep = has_tr[glass[has_tr] & (level[interp[has_tr]] + ni[has_tr] < max_depth)]
        drop = np.setdiff1d(has_tr, keep)
        c_ok[tr[drop]] = False
        kt = tr[keep]
        qk = qi[keep]
        w_in = c_w[kt].copy()  # the weight of the path past the entry
        c_o[kt] = q.OP[qk]
        c_d[kt] = q.OD[qk]
        c_w[kt] *= q.gain[qk]
        child_level[kt] = level[interp[keep]] + ni[keep] + 1
        child_self[kt] = inst[interp[keep]]
        c_ok[kt] &= (c_w[kt].max(axis=1) > tol.PATH_WEIGHT_MIN)
        # the internal reflection where the path refracts out: traced from there (from
        # inside, so the object itself is traced), as the base tracer splits
        rw = w_in * q.rgain[qk]
        rsel = np.flatnonzero(rw.max(axis=1) > tol.PATH_WEIGHT_MIN)
        x_o, x_d, x_w = q.RP[qk[rsel]], q.RD[qk[rsel]], rw[rsel]
        x_src = interp[keep[rsel]]
        x_level = level[x_src] + ni[keep[rsel]] + 1
        # the base tracer's paths through the glass (they seed the samples below): the
        # entry's refraction 2p + 1, a reflection 2q per total internal reflection, the
        # exit's refraction 2q + 1 (nint - 1 reflections and the exit; nint 0: none)
        inside = (2 * path[interp[keep]] + 1) << np.maximum(ni[keep] - 1, 0)
        child_path[kt] = np.where(ni[keep] > 0, 2 * inside + 1, inside)
        x_path = 2 * inside[rsel]  # the reflection split off at the exit
    else:
        x_o = x_d = x_w = np.empty((0, 3))
        x_src = x_level = x_path = np.empty(0, np.int64)
    slots = np.flatnonzero(c_ok)
    which, c_fresh, c_tag = child_paths(slots, gstart, glossy, fresh, tag, nseeds)
    return (np.concatenate([c_o[slots], x_o]), np.concatenate([c_d[slots], x_d]),
            np.concatenate([c_w[slots], x_w]), np.concatenate([src[which], src[x_src]]),
            np.concatenate([child_level[slots], x_level]),
            np.concatenate([child_self[slots], np.full(len(x_src), -1, np.int32)]),
            np.concatenate([child_path[slots], x_path]),
            np.concatenate([c_fresh, fresh[x_src]]), np.concatenate([c_tag, tag[x_src]]))


def is_transmissive(sa, mats) -> np.ndarray:
    return (sa.mat_transmission[np.maximum(mats, 0)] > 0).any(axis=1) & (mats >= 0)
