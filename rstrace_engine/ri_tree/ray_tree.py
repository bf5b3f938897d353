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
from ..tracing.whitted import Spawned, glossy_materials
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


def next_rays(sa, kids: Spawned, inst, q, interp, qi, src, level, max_depth, path):
    """The next level's rays from a level's spawned rays ``kids``.

    Rays past ``max_depth`` are dropped (``level`` (nb,): each ray's depth). Rays leaving an
    interpolated hit (rows ``interp``, query rows ``qi`` of ``q``, on instances ``inst``)
    ignore their own object near the hit; at an interpolated glass hit the refracted ray
    becomes the interpolated exit ray, ``nint`` levels further down, and the internal
    reflection where the path refracts out is traced from there. ``path`` (nb,) int64: the
    rays' ray-tree paths (root 1, reflect child 2p, refract child 2p + 1; the internal
    reflection at an exit 4p + 2), which seed the soft lights' samples. Returns ``(o, d,
    weight, src, level, self_inst, path)``."""
    c_o, c_d, c_w, c_ok = kids
    stop = level >= max_depth
    c_ok[0::2] &= ~stop
    c_ok[1::2] &= ~stop
    child_level = np.repeat(level + 1, 2)
    child_self = np.full(len(c_ok), -1, np.int32)
    if len(interp):
        child_self[2 * interp] = inst[interp]
        # glass: the refracted ray becomes the interpolated exit ray
        ni = q.nint[qi].astype(np.int64)
        glass = (q.OD[qi] != 0).any(axis=1) & (ni >= 0) & c_ok[2 * interp + 1]
        tr = 2 * interp + 1
        # rough glass: its sampled refracted ray is traced as it is (an exit ray would be
        # a sharp one)
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
    else:
        x_o = x_d = x_w = np.empty((0, 3))
        x_src = x_level = np.empty(0, np.int64)
    slots = np.flatnonzero(c_ok)
    which = slots // 2
    return (np.concatenate([c_o[slots], x_o]), np.concatenate([c_d[slots], x_d]),
            np.concatenate([c_w[slots], x_w]), np.concatenate([src[which], src[x_src]]),
            np.concatenate([child_level[slots], x_level]),
            np.concatenate([child_self[slots], np.full(len(x_src), -1, np.int32)]),
            np.concatenate([path[which] * 2 + (slots & 1), path[x_src] * 4 + 2]))


def is_transmissive(sa, mats) -> np.ndarray:
    return (sa.mat_transmission[np.maximum(mats, 0)] > 0).any(axis=1) & (mats >= 0)
