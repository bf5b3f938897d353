"""A moved light is its old term dropped and its new one added, where the new one is proven.

Issue 21, item 3 in INTERPOLANT mode. A light moved, turned, re-coned or resized in its
slot ``j`` used to invalidate every interpolant with a state for it (its ``LIGHT_SHADES``
/ ``LIGHT_OCCLUDED`` membership: every cell with a hit), so every interpolated pixel was
built or traced again. Now, in a batch of light and world edits (:func:`movable_lights`),
the move is taken as a deletion of the old light and an addition of the new one
(:mod:`.added_light`):

* every kept sample (corners and test lines of the live cells) is shaded again with the
  moved light alone (:func:`~.added_light._shade_samples`: the same tree, the light's new
  state per node and share ``S'_j``; for a light with an extent, its sampled term taken
  off the share as a new sample's is, :mod:`.sampled_term`); its ``R`` becomes
  ``R - S_j I_j + S'_j I'_j`` (the old share kept by the samples, :mod:`.relight`);
* every live cell is checked for the light in its new place as a fresh build checks it
  (:func:`~.predicate.check_cells` with the other lights off: for a light with an extent
  the soft-light proof, its shaft to the whole new extent clear and the closed form's
  horizon conditions over the slab -- or a sun's umbra), then the radiance test on the
  new ``R``;
* a cell that passes keeps its interpolant with the new corners; the tunnel sections and
  membership entries it recorded for the old light are dropped and the new ones recorded
  (:func:`renew_dependencies`: its entries die with its old serial, and all of them are
  recorded again under a new one, as a build records them); its pixels take the
  difference of the corners (:mod:`.term_pixels`) -- but where the light, before or
  after, is sampled per pixel at the cell's root (a glossy lobe under a light with an
  extent, a light without a closed form): those pixels are rendered again;
* a cell that fails is invalidated (rebuilt by the next frame that needs it), as is one with
  a sample that keeps no shares (a textured root, over the share cap, built before the
  session kept them), whose tree changed, or that the light now lights from behind at a
  rough interface.

A changed kind, light or shadow linking or ray visibility, a light newly seen by mirror or
refraction rays, or a batch that also edits objects, materials or meshes or adds lights:
the invalidation path as before.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..tracing.seen_lights import first_seen_below
from .added_light import _ramp, _shade_samples, proven_cells
from .relight import _row_equal, light_scale

#: per-light arrays that must be equal for a light's change to be a move
#: (:func:`movable_lights`): its kind, what it reaches (ray visibility, light and shadow
#: linking); everything else -- place, direction, cone, intensity, its extent's size and
#: shape -- is its new term, shaded again
_KEEPS = ("light_kind", "light_vis", "light_recv", "light_block")


class MoveResult(NamedTuple):
    """What :func:`move_terms` did."""

    kept: np.ndarray  # (k,) int32 live interpolants kept with the moved lights' new terms
    changed: np.ndarray  # (c,) int32 of those, the ones whose corners changed
    failed: np.ndarray  # (f,) int32 interpolants to invalidate (the caller does)
    delta: np.ndarray  # (n, 3) what each stored sample's R gained (the kept ones')
    slots: list  # the moved light slots


def movable_lights(cache, old_sa, sa, fx) -> list[int]:
    """The slots of ``fx.lights_moved`` that :func:`move_terms` can take: a batch of light
    and world edits only, the same light slots, the samples keeping their shares, and each
    light of the same kind before and after, with the same linking and visibility (its
    place, direction, cone, intensity, and its extent -- a sphere's radius, an area
    light's size or shape, a sun's angle -- may change)."""
    L = len(sa.light_kind)
    if (not fx.lights_moved or len(old_sa.light_kind) != L or not cache.light_terms
            or not cache.samples.shares_on):
        return []
    if fx.regions or fx.objects or fx.geometry or fx.meshes or fx.materials:
        return []
    if first_seen_below(old_sa, sa):
        # a light's surface newly seen by mirror or refraction rays: the samples were not
        # flagged for it (:func:`~.samples.seen_flags`)
        return []
    out = []
    for j in sorted(int(j) for j in fx.lights_moved):
        if not 0 <= j < L or int(old_sa.light_kind[j]) < 0 or int(sa.light_kind[j]) < 0:
            continue
        if not all(_row_equal(getattr(old_sa, f), getattr(sa, f), j) for f in _KEEPS):
            continue
        if np.all(np.isfinite(light_scale(sa)[j])):
            out.append(j)
    return out


def move_terms(cache, old_sa, sa, accel, slots) -> MoveResult:
    """Take the lights moved in ``slots`` (from :func:`movable_lights`) into ``cache``'s
    samples and interpolants (see the module doc). Returns which interpolants were kept
    and which to invalidate (nothing is freed here)."""
    pool, sm = cache.pool, cache.samples
    slots = [int(j) for j in slots]
    cache.compact_samples()  # (only the live cells' samples are shaded)
    live = np.flatnonzero(pool.live).astype(np.int32)
    none = np.zeros(0, np.int32)
    if len(live) == 0:
        return MoveResult(none, none, none, np.zeros((sm.n, 3)), slots)
    parts = [_shade_samples(cache, sa, accel, [j]) for j in slots]  # (one light each)
    occ = np.concatenate([p[0] for p in parts], axis=1)
    share = np.concatenate([p[1] for p in parts], axis=1)
    good = np.logical_and.reduce([p[2] for p in parts])
    old_share, shared = sm.shares()
    good &= shared & np.all(np.isfinite(share), axis=(1, 2))
    rad = sm.radiance()
    delta = (np.einsum("nlc,lc->nc", share, light_scale(sa)[slots])
             - np.einsum("nlc,lc->nc", old_share[:, slots], light_scale(old_sa)[slots]))
    delta[~good] = 0.0
    new_rad = rad + delta
    # the samples take the moved lights' new states and shares (the proof reads the states)
    g = np.flatnonzero(good)
    cnt = sm._ncount[g].astype(np.int64)
    rows = np.repeat(sm._nstart[g], cnt) + _ramp(cnt)
    sm._nocc[rows[:, None], np.asarray(slots)[None, :]] = occ[rows]
    sm._share[g[:, None], np.asarray(slots)[None, :]] = share[g]
    ok = proven_cells(cache, sa, sm, live, good, slots, new_rad)
    rad[:] = new_rad  # (the samples of failed cells are dropped with them)
    kept = live[ok]
    pool.rad[kept] = rad[pool.samples[kept]]
    changed = kept[np.any(delta[pool.samples[kept]] != 0.0, axis=(1, 2))]
    cache.totals["terms_moved"] = cache.totals.get("terms_moved", 0) + len(kept)
    return MoveResult(kept, changed, live[~ok], delta, slots)


def renew_dependencies(cache, sa, ids) -> tuple:
    """Drop every tunnel section and membership entry of interpolants ``ids`` (a new serial
    each: the old entries die, as a freed interpolant's do) and record them again from
    their samples' trees over ``sa`` (:meth:`~.invalidation.Dependencies.add`, as their
    build did): the moved lights' old shafts and states go, the new ones come. Returns
    ``(ids, old serials, new serials)``."""
    pool = cache.pool
    ids = np.asarray(ids, np.int32)
    old = pool.serial[ids].copy()
    if len(ids) == 0:
        return ids, old, old
    pool.serial[ids] = np.arange(pool.next_serial, pool.next_serial + len(ids))
    pool.next_serial += len(ids)
    a = cache.trees.arrays
    node = pool.node[ids]
    tree = a.tree[node].astype(np.int64)
    cs = np.ascontiguousarray(np.concatenate([pool.samples[ids], pool.tests[ids]], axis=1))
    ns = (16 + np.count_nonzero(pool.tests[ids] >= 0, axis=1)).astype(np.int32)
    cache.deps.add(cache, ids, tree // 6, tree % 6, a.depth[node], a.coord[node],
                   pool.zlo[ids], pool.zhi[ids], cs, ns, sa=sa)
    return ids, old, pool.serial[ids].copy()
