"""A light's power or colour change rescales interpolants instead of invalidating them.

Issue 21, item 4. A sample's radiance ``R`` (the part interpolants hold: the root's own light
at a rough root, without the world's term where the world lights) is linear in the lights'
intensities: the shade kernel adds, at every node of its ray tree, ``w * a_j * I_j`` for a
hard light ``j`` (``a_j`` its BRDF times irradiance over the intensity ``I_j``) and ``w * b_j *
R_j`` for a light with an extent (its estimate over its radiance ``R_j``), the terms
:mod:`~..tracing.light_records` recombines in BASE. A sample that keeps its *share* of every
light, ``S_j = sum over its nodes of w * a_j`` (or ``w * b_j``), follows a change of light
``j``'s intensity from ``I`` to ``I'`` as ``R' = R + S_j (I' - I)`` per channel, no ray traced.

The interpolation error does not follow linearly: the radiance test compares in display space
(clamped, sRGB), so a cell whose test lines were within ``0.5 epsilon`` may not be after the
rescale (a light turned up saturates one corner and not the line between). So a rescaled cell
keeps what its radiance test needs -- its test lines' samples, with their shares -- and the
test (:func:`~.predicate.radiance_ok`, the one a fresh build runs) is run again on the rescaled
samples: a cell that passes keeps its interpolant with the rescaled corners, a cell that fails
is invalidated (rebuilt by the next frame that needs it, as today). Cells whose samples keep
no shares (built before the session kept them, a textured root, over the memory cap) are
invalidated as before.

Which interpolants a light shades is the membership index's answer (``LIGHT_SHADES``, the same
set the invalidation of a power change took): a cell not in it has ``S_j = 0`` at every
sample. A deleted light is rescaled to zero (its term dropped; the other lights' proofs
and the cell's geometry do not depend on it, the radiance test is run again). A light that
changes anything else but its intensity (reshaped, linked, made invisible to diffuse or
glossy rays) takes the invalidation path; an added one, :mod:`.added_light`; a hard light
moved, turned or re-coned, :mod:`.moved_light`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .predicate import radiance_ok
from .samples import textured_roots
from .tunnels import LIGHT_SHADES

#: per-light arrays of the scene packing that must be equal for a light's change to be a
#: rescale (everything but its intensity / radiance)
_SAME = ("light_kind", "light_pos", "light_dir", "light_cos_outer", "light_cos_inner",
         "light_ext", "light_radius", "light_soft", "light_half", "light_u", "light_v",
         "light_size", "light_ellipse", "light_spread", "light_bound", "light_vis",
         "light_spot_scaled", "light_spot_frame")


def light_scale(sa) -> np.ndarray:
    """(L, 3) what a light's terms are multiplied by: its intensity, or its radiance for a
    light with an extent (as :meth:`~..tracing.light_records.LightRecords.recombine`)."""
    ext = np.asarray(sa.light_ext, bool)
    return np.where(ext[:, None], np.asarray(sa.light_radiance, np.float64),
                    np.asarray(sa.light_intensity, np.float64))


def light_shares(segments: list, n: int, L: int) -> np.ndarray:
    """(n, L, 3) the per-light shares of ``n`` traced lines from the ``segments`` of
    :func:`~..tracing.whitted.trace` with ``terms=True``: per node, path weight times each
    light's term (slots ``0 .. L - 1``; the world's and the emission's are not rescaled)."""
    share = np.zeros((n, L, 3))
    for lv in segments:
        on = np.asarray(lv["t_on"])[:, :L]
        val = np.where(on[:, :, None], np.asarray(lv["t_val"])[:, :L], 0.0)
        np.add.at(share, np.asarray(lv["ray"], np.int64),
                  val * np.asarray(lv["weight"])[:, None, :])
    return share


def sample_shares(sa, segments: list, hits, flag: np.ndarray):
    """``(share (n, L, 3), shared (n,) bool)`` of ``n`` lines traced with ``segments``
    and light terms (:func:`light_shares`), their root ``hits`` and sample ``flag``: a line
    whose root is textured keeps none (its ``R`` is traced with every texel 0 and its
    texture's term apart, ``R + texel D``), nor one whose flags fail its cells anyway."""
    n = len(flag)
    share = light_shares(segments, n, len(sa.light_kind))
    tex_root = np.empty(n, np.bool_)
    textured_roots(sa, np.ascontiguousarray(hits.inst, np.int32),
                   np.ascontiguousarray(np.maximum(hits.prim, 0), np.int32), tex_root)
    return share, ~tex_root & (np.asarray(flag) == 0)


def _row_equal(a, b, j: int) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    if a.ndim == 0 or a.shape[0] == 0:
        return True
    return bool(np.array_equal(a[j], b[j]))


def rescalable_lights(old_sa, new_sa, lights) -> list[int]:
    """The lights of ``lights`` (slots whose power or colour alone changed, or that were
    deleted, by the edit effects) whose change is an intensity change only: same kind, the
    same in every other per-light array (:data:`_SAME`, light and shadow linking), a finite
    new intensity -- or deleted (its term dropped: the tombstone's intensity is zero, and
    no other light's proof depended on it)."""
    out = []
    if len(old_sa.light_kind) != len(new_sa.light_kind):
        return out
    s_new = light_scale(new_sa)
    for j in sorted(int(j) for j in lights):
        if not 0 <= j < len(new_sa.light_kind) or int(old_sa.light_kind[j]) < 0:
            continue
        if int(new_sa.light_kind[j]) < 0:
            out.append(j)  # deleted: its term dropped (rescaled to its tombstone's zero)
            continue
        if not all(_row_equal(getattr(old_sa, f), getattr(new_sa, f), j) for f in _SAME):
            continue
        if not (_row_equal(old_sa.light_recv, new_sa.light_recv, j)
                and _row_equal(old_sa.light_block, new_sa.light_block, j)):
            continue
        if np.all(np.isfinite(s_new[j])):
            out.append(j)
    return out


class Rescale(NamedTuple):
    """What :func:`rescale` did."""

    rescaled: np.ndarray  # (k,) int32 interpolants kept, their corners rescaled
    broken: np.ndarray  # (b,) int32 whose radiance test fails after the rescale
    no_terms: np.ndarray  # (u,) int32 whose samples keep no shares (or no test lines)


def rescale(cache, old_sa, new_sa, lights) -> Rescale:
    """Rescale the samples and interpolants of ``cache`` for the intensity changes of
    ``lights`` (from :func:`rescalable_lights`) between ``old_sa`` and ``new_sa``; re-run
    the radiance test of every interpolant they shade. Returns which interpolants were
    rescaled and which must be invalidated (the caller does: nothing is freed here)."""
    none = np.zeros(0, np.int32)
    pool, sm = cache.pool, cache.samples
    lights = [int(j) for j in lights]
    if not lights or pool.n_live == 0:
        return Rescale(none, none, none)
    hit = np.zeros(pool.cap, np.bool_)
    cache.deps.lights.query([2 * j + LIGHT_SHADES for j in lights], pool.serial, pool.live,
                            hit)
    ids = np.flatnonzero(hit & pool.live).astype(np.int32)
    if len(ids) == 0:
        return Rescale(none, none, none)
    if not sm.shares_on:
        return Rescale(none, none, ids)
    share, shared = sm.shares()
    cs = np.concatenate([pool.samples[ids], pool.tests[ids]], axis=1)
    nsamp = (16 + np.count_nonzero(pool.tests[ids] >= 0, axis=1)).astype(np.int32)
    has = (pool.tests[ids, 0] >= 0) & np.all(shared[np.maximum(cs, 0)] | (cs < 0), axis=1)
    delta = np.zeros((share.shape[1], 3))
    delta[lights] = light_scale(new_sa)[lights] - light_scale(old_sa)[lights]
    rad = sm.radiance()
    rows = np.flatnonzero(shared)
    new_rad = rad.copy()
    new_rad[rows] += np.einsum("nlc,lc->nc", share[rows][:, lights], delta[lights])
    ok = np.zeros(len(ids), np.bool_)
    if np.any(has):
        ok[has] = radiance_ok(new_rad, cs[has], nsamp[has], cache.epsilon,
                              sm.texture_terms(), cache.tex_max)
    # every sample with shares follows the light (a cell not shaded by it has zero shares);
    # those of broken cells are dropped with them unless a kept cell holds them too
    rad[rows] = new_rad[rows]
    kept = ids[ok]
    pool.rad[kept] = rad[pool.samples[kept]]
    return Rescale(kept, ids[has & ~ok], ids[~has])
