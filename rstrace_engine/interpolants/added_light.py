"""A light added to the scene adds one term to the interpolants it can be proven on.

Issue 21, item 3 in INTERPOLANT mode. An interpolant's 16 corner samples hold ``R``, a sum
over their ray-tree nodes of each light's term (:mod:`.relight`); a light added into a new
slot ``j`` adds ``S_j I_j`` to every sample, ``S_j`` its share (path weight times the shade
kernel's term over its intensity) and ``I_j`` its intensity. So the cache is kept (it used
to start over: every cell rebuilt, every pixel traced) and, for a *hard* light (a point,
spot or sun without an angle; one with an extent below):

* every kept sample (corners and test lines of the live cells) is shaded again with the
  new light alone (the scene packing with its slot only and the world dark, as
  :func:`~..tracing.light_reshade._one_light` relights a BASE node): its ray tree is
  traced again from its lattice line, which must give the same nodes (paths, objects), the
  new light's state per node (occluder, or -2 not facing) and its share ``S_j``; the
  samples' ``R`` gain ``S_j I_j``;
* each live cell is checked for that light as a fresh build checks every light
  (:func:`~.predicate.check_cells` with the other lights switched off: they were proven
  when the cell was built and nothing else changed): the corners and test lines agree on
  its state, a lit light's shaft meets only the object, an occluded one is covered by its
  occluder, a light off at the corners is off over the whole slab, a spot's step edge does
  not cross it; then the radiance test (:func:`~.predicate.radiance_ok`) on the new ``R``;
* a cell that passes keeps its interpolant (its corners updated; its pixels take the term
  interpolated from them, :mod:`.term_pixels`, not rendered again), and gains the new
  light's tunnels (its shafts, into the ray segment trees) and membership entries (so a
  later edit of the light or of what it names finds it); a cell that fails is
  invalidated (rebuilt by the next frame that needs it, or traced), as is a cell whose
  samples cannot take the term: a sample whose tree changed, a textured root the light
  reaches (its ``R + texel D`` split would change), a rough interface the light now
  lights from its far side, a cell whose test lines were not kept (built before the
  session kept light terms).

A light with an extent (a sphere light, an area light, a sun with an angle) is taken the
same way, as a moved one is (:mod:`.moved_light`): its 16 shadow samples per node shaded
at the kept samples, its *sampled term* taken off the shares as a build takes it off a new
sample's (:func:`~.sampled_term.without_sampled`: the glossy lobe under it, or all of a
light without a closed form, is traced per pixel), then the soft-light proof of
:func:`~.predicate.check_cells` for it alone (the shaft from the cell's slab to its whole
extent clear, the closed form's horizon conditions, or a sun's umbra) and the radiance
test. The shadow rays a shaft proves unoccluded over a cell's roots are not traced
(:mod:`~..tracing.shaft_skip`, one group per cell, :func:`_cell_keys`: bit for bit the
same trees and shares). The kept cells' pixels take the term (:mod:`.term_pixels`) but
where the light is sampled per pixel at their root: those are rendered again, their
cells kept. A light that mirror or refraction rays see keeps the cache where such rays
already saw another light (the samples below a root are flagged whichever light it is,
``render._newly_seen``). Only batches that edit lights and the world take this path
(:func:`can_add`); any other edit with a new light slot starts a new cache as before.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

from ..frame import LIGHT_SAMPLES_DEFAULT
from ..tracing.light_reshade import _one_light
from ..tracing.whitted import trace
from .line_samples import _unpack, front_hits
from .linetree import lattice_lines
from .predicate import VALID, check_cells, radiance_ok
from .relight import light_scale, light_shares
from .sampled_term import per_pixel_query, sampled_possible, without_sampled
from .samples import TEX_MISMATCH, glossy_flags
from .shafts import glossy_materials, light_extents, light_fields
from .tunnels import LIGHT_OCCLUDED, LIGHT_SHADES, OBJ_OCCLUDES, tunnel_sections


class AddResult(NamedTuple):
    """What :func:`add_terms` did."""

    kept: np.ndarray  # (k,) int32 live interpolants that took the new lights' terms
    changed: np.ndarray  # (c,) int32 of those, the ones whose corners changed
    failed: np.ndarray  # (f,) int32 interpolants to invalidate (the caller does)
    slots: list  # the added light slots


def can_add(old_sa, sa, fx) -> bool:
    """Whether the edit batch ``fx`` (``old_sa`` -> ``sa``) adds light slots the cache can
    take as terms: more slots, every new one an added light, and no edit but of lights
    and the world (an object, material or mesh edit in the same batch starts a new cache,
    as any change of the number of slots did before)."""
    L0, L1 = len(old_sa.light_kind), len(sa.light_kind)
    if L1 <= L0:
        return False
    if fx.regions or fx.objects or fx.geometry or fx.meshes or fx.materials:
        return False
    new = set(range(L0, L1))
    return new <= set(fx.lights_moved) and bool(np.all(np.asarray(sa.light_kind)[L0:] >= 0))


def keeps_cache(old_sa, sa, fx) -> bool:
    """Whether a cache over ``old_sa`` can take the batch ``fx`` to ``sa``: as many light
    slots, or lights added (:func:`can_add`)."""
    return len(sa.light_kind) == len(old_sa.light_kind) or can_add(old_sa, sa, fx)


def _only(sa, slots):
    """``sa`` with only light ``slots`` (and the world dark): :func:`_one_light` for
    several consecutive slots."""
    if len(slots) == 1:
        return _one_light(sa, slots[0])
    a, b = slots[0], slots[-1] + 1
    return sa._replace(world_light=np.zeros(3), **{
        f: getattr(sa, f)[a:b] for f in sa._fields
        if f.startswith("light_") and getattr(sa, f).shape[0] > 0})


def _query(cache, sa, slots):
    """The cache's predicate structures with ``sa``'s lights, all but ``slots`` off (their
    kind ``-1``, skipped by the light tests)."""
    kind = np.full(len(sa.light_kind), -1, np.int32)
    kind[slots] = np.asarray(sa.light_kind, np.int32)[slots]
    f = light_fields(sa)
    f.update(light_kind=kind, mat_glossy=glossy_materials(sa))
    # (the geometry is the same: a batch of light and world edits; the cache's ``qs`` may
    # hold its packing's per-pixel adjustment, undone by ``mat_glossy`` above)
    return per_pixel_query(cache.qs._replace(**f), sa)


def _shade_samples(cache, sa, accel, slots):
    """Shade every stored sample again with lights ``slots`` alone. Returns ``(occ (n_nodes,
    k) int32 in the store's node order, share (n, k, 3), good (n,) bool)``: ``good`` False
    where the tree traced now differs from the stored one or the lights make a rough root
    lit from its far side."""
    sm = cache.samples
    n, k = sm.n, len(slots)
    occ = np.full((sm.n_nodes, k), -2, np.int32)
    if n == 0:
        return occ, np.zeros((0, k, 3)), np.zeros(0, bool)
    k1, k2 = sm.keys.k1[:n], sm.keys.k2[:n]
    inst = (k1 >> 3).astype(np.int32)
    face = (k1 & 7).astype(np.int8)
    lattice = np.empty((n, 4), np.int64)
    _unpack(k2, lattice)
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    lattice_lines(cache.box, inst, face, lattice, o, d)
    hits = front_hits(sa, accel, inst, o, d)
    one = _only(sa, slots)
    segs: list = []
    own = partial(trace, glossy_samples=1, roots="own", camera_lights=False)
    # (the shadow rays of a light with an extent that a shaft proves unoccluded over a
    # cell's root points are not traced: the same trees and shares bit for bit, shaft_skip)
    counters: dict = {}
    _, tree = own(one, accel, o, d, 0.0, 1.0, cache.max_depth, record=True, primary=hits,
                  segments=segs, terms=True, skip_keys=_cell_keys(cache.pool, n),
                  counters=counters)
    for c in ("shadow", "shadow_skipped"):  # (traced and skipped shadow rays, in totals)
        cache.totals[f"terms_{c}"] = cache.totals.get(f"terms_{c}", 0) + counters.get(c, 0)
    share = light_shares(segs, n, k)
    good = hits.inst == sm._inst[:n]
    if sampled_possible(one):  # a light with an extent: its sampled term is per pixel,
        # taken off the shares as a build takes it off a new sample's (a textured root with
        # a sampled term flagged: its texture split traced other samples)
        _, flag = without_sampled(one, accel, o, d, hits, np.zeros((n, 3)),
                                  sm.texture_terms()[0][:n], np.zeros(n, np.uint8),
                                  cache.max_depth, LIGHT_SAMPLES_DEFAULT, share=share)
        good &= (flag & TEX_MISMATCH) == 0
    order = np.argsort(tree.node_ray, kind="stable")
    count = np.bincount(tree.node_ray, minlength=n)[:n]
    good &= count == sm._ncount[:n]
    # the stored node rows of each sample (where the counts agree)
    cnt = np.where(good, count, 0)
    start_new = np.concatenate([[0], np.cumsum(count)[:-1]])
    rows_new = order[np.repeat(start_new[good], cnt[good])
                     + _ramp(cnt[good])]
    rows_old = np.repeat(sm._nstart[:n][good], cnt[good]) + _ramp(cnt[good])
    same = ((tree.node_path[rows_new] == sm._npath[rows_old])
            & (tree.node_inst[rows_new] == sm._ninst[rows_old]))
    owner = np.repeat(np.flatnonzero(good), cnt[good])
    good[owner[~same]] = False
    occ[rows_old] = tree.node_occluder[rows_new].reshape(-1, k)
    good &= glossy_flags(one, tree, n) == 0  # a rough interface lit from its far side
    return occ, share, good


def _cell_keys(pool, n: int) -> np.ndarray:
    """(n,) int64: a live interpolant holding each of the ``n`` stored samples (a corner or
    a test line; -1 none): the groups whose root points :mod:`~..tracing.shaft_skip`
    proves a light with an extent fully visible from, one shaft per cell."""
    live = np.flatnonzero(pool.live)
    cs = np.concatenate([pool.samples[live], pool.tests[live]], axis=1)
    owner = np.repeat(live.astype(np.int64), cs.shape[1])
    flat = cs.reshape(-1)
    m = (flat >= 0) & (flat < n)
    keys = np.full(n, -1, np.int64)
    keys[flat[m]] = owner[m]
    return keys


def _ramp(cnt):
    """0..c-1 for every count c, concatenated."""
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    return np.arange(total) - np.repeat(start, cnt)


def add_terms(cache, old_sa, sa, accel, slots) -> AddResult:
    """Take the lights added in ``slots`` (new slots of ``sa``) into ``cache``'s samples
    and interpolants (see the module doc); widens the samples to ``sa``'s light slots.
    Returns which interpolants were kept and which to invalidate (nothing is freed here)."""
    pool, sm = cache.pool, cache.samples
    none = np.zeros(0, np.int32)
    cache.compact_samples()  # (only the live cells' samples are shaded)
    live = np.flatnonzero(pool.live).astype(np.int32)
    L0, L1 = len(old_sa.light_kind), len(sa.light_kind)
    k = L1 - L0
    if len(live) == 0 or not np.any(pool.tests[live, 0] >= 0):  # (no test lines: none passes)
        _widen(sm, np.full((sm.n_nodes, k), -2, np.int32), np.zeros((sm.n, k, 3)))
        return AddResult(none, none, live, list(slots))
    occ, share, good = _shade_samples(cache, sa, accel, list(slots))
    dif, _, flag = sm.texture_terms()
    reach = np.any(share != 0.0, axis=(1, 2))
    good &= (flag == 0) & ~(np.any(dif != 0.0, axis=1) & reach)
    good &= np.all(np.isfinite(share), axis=(1, 2))
    _widen(sm, occ, share)
    scale = light_scale(sa)[list(slots)]  # (k, 3)
    rad = sm.radiance()
    new_rad = rad + np.einsum("nlc,lc->nc", share, scale)
    ok = proven_cells(cache, sa, sm, live, good, list(slots), new_rad)
    # the samples take the term (those of failed cells are dropped with them)
    rad[:] = new_rad
    kept = live[ok]
    pool.rad[kept] = rad[pool.samples[kept]]
    changed = kept[np.any(reach[pool.samples[kept]], axis=1)]
    cache.totals["terms_added"] = cache.totals.get("terms_added", 0) + len(kept)
    return AddResult(kept, changed, live[~ok], list(slots))


def proven_cells(cache, sa, sm, live, good, slots, new_rad) -> np.ndarray:
    """(len live,) bool: which live cells ``live`` keep their interpolant for the lights
    ``slots`` of ``sa``: every sample and test line shaded ``good``, the predicate proven
    for those lights (:func:`check_cells` over the samples' states in ``sm``) and the
    radiance test passed on their new radiance ``new_rad``."""
    pool = cache.pool
    cs = np.concatenate([pool.samples[live], pool.tests[live]], axis=1)
    nsamp = (16 + np.count_nonzero(pool.tests[live] >= 0, axis=1)).astype(np.int32)
    ok = (pool.tests[live, 0] >= 0) & np.all(good[np.maximum(cs, 0)] | (cs < 0), axis=1)
    go = np.flatnonzero(ok)
    if len(go):
        a = cache.trees.arrays
        node = pool.node[live[go]]
        tree = a.tree[node].astype(np.int64)
        status = np.empty(len(go), np.int32)
        detail = np.empty(len(go), np.int8)
        zlo = np.zeros(len(go))
        zhi = np.zeros(len(go))
        cls = np.zeros(len(go), np.int32)
        check_cells(_query(cache, sa, slots), cache.box, sm.view(),
                    (tree // 6).astype(np.int32), (tree % 6).astype(np.int8),
                    a.depth[node].astype(np.int64), a.coord[node].astype(np.int64),
                    np.ascontiguousarray(cs[go]), nsamp[go], status, detail, zlo, zhi, cls)
        valid = status == VALID
        ok[go[~valid]] = False
        go = go[valid]
        if len(go):
            lin = radiance_ok(new_rad, cs[go], nsamp[go], cache.epsilon, sm.texture_terms(),
                              cache.tex_max)
            ok[go[~lin]] = False
    return ok


def _widen(sm, occ, share) -> None:
    """The sample store with ``occ.shape[1]`` more light slots: their states per node and
    (while shares are kept) their shares per sample."""
    k = occ.shape[1]
    nocc = np.empty((len(sm._nocc), sm.L + k), np.int32)
    nocc[:, :sm.L] = sm._nocc
    nocc[:, sm.L:] = -2
    nocc[:sm.n_nodes, sm.L:] = occ
    sm._nocc = nocc
    if sm.shares_on:
        sh = np.zeros((len(sm._share), sm.L + k, 3))
        sh[:, :sm.L] = sm._share
        sh[:sm.n, sm.L:] = share
        sm._share = sh
    sm.L += k


def add_dependencies(cache, sa, ids, slots) -> None:
    """The new lights' tunnels and membership entries of the kept interpolants ``ids``
    (what :meth:`~.invalidation.Dependencies.add` records for a light at a cell's build),
    ``sa`` the packing with the new lights."""
    ids = np.asarray(ids, np.int32)
    if len(ids) == 0:
        return
    deps, pool = cache.deps, cache.pool
    sm = cache.samples.view()
    a = cache.trees.arrays
    node = pool.node[ids]
    tree = a.tree[node].astype(np.int64)
    inst = (tree // 6).astype(np.int32)
    face = (tree % 6).astype(np.int8)
    depth = a.depth[node].astype(np.int64)
    coord = np.ascontiguousarray(a.coord[node], np.int64)
    cs = np.ascontiguousarray(np.concatenate([pool.samples[ids], pool.tests[ids]], axis=1))
    ns = (16 + np.count_nonzero(pool.tests[ids] >= 0, axis=1)).astype(np.int32)
    mask = np.zeros(len(sa.light_kind), np.bool_)
    mask[list(slots)] = True
    lk = np.ascontiguousarray(sa.light_kind, np.int32)
    elo, ehi, chord = light_extents(sa)
    ld = np.ascontiguousarray(sa.light_dir, np.float64).reshape(-1, 3)
    zlo = np.ascontiguousarray(pool.zlo[ids])
    zhi = np.ascontiguousarray(pool.zhi[ids])
    counts, ta, tb, tinf = tunnel_sections(sm, cache.box, sa.inst_aabb, lk, mask, False, elo,
                                           ehi, chord, ld, deps.reach, deps.slack, inst,
                                           face, depth, coord, zlo, zhi, cs, ns)
    q = np.repeat(ids, counts).astype(np.int32)
    deps.rst.add_tunnels(ta, tb, tinf, q, pool.serial[q])
    # membership: over the first corner's tree (a valid cell's samples share one tree)
    s0 = pool.samples[ids, 0]
    cnt = sm.node_count[s0].astype(np.int64)
    rows = np.repeat(sm.node_start[s0], cnt) + _ramp(cnt)
    cell = np.repeat(ids, cnt)
    hit = sm.node_inst[rows] >= 0
    okeys, oq, lkeys, lq = [], [], [], []
    for j in slots:
        oc = sm.node_occ[rows, j]
        occl = hit & (oc >= 0)
        lkeys.append(np.where(oc[hit] >= 0, 2 * j + LIGHT_OCCLUDED, 2 * j + LIGHT_SHADES))
        lq.append(cell[hit])
        okeys.append(2 * oc[occl].astype(np.int64) + OBJ_OCCLUDES)
        oq.append(cell[occl])
    for keys, qs, index in ((okeys, oq, deps.objects), (lkeys, lq, deps.lights)):
        kk = np.concatenate(keys).astype(np.int64)
        qq = np.concatenate(qs).astype(np.int64)
        if len(kk) == 0:
            continue
        pair = np.unique(np.stack([qq, kk], axis=1), axis=0)
        index.add(pair[:, 1], pair[:, 0].astype(np.int32), pool.serial[pair[:, 0]])
