"""Edits: which interpolants an edit may change, freeing them, going on with the new scene.

Seed 000, section 5. Every valid interpolant, when it is built, leaves

* its tunnel sections (:mod:`.tunnels`) in the global ray segment trees
  (:mod:`.ray_segment_tree`): geometry edits find the interpolants whose tunnels meet the
  edited region (old and new world box of the edited object);
* membership entries (:mod:`.membership`) under every object its ray trees name (hit, or
  occluding a light) and every light (shading it, or occluded);
* a flag if some ray-tree node misses (the world colour shows).

:func:`invalidate` takes the union of what an edit names (seed 000, 5.2: the region query,
then the position-independent ray trees) and frees those interpolants: their linetree leaves
become empty (rebuilt lazily by the next frame that needs them, shown as ``CLASS_REBUILT``),
the samples only they kept are dropped, and the trees and lists are compacted once dead
entries outnumber live ones. :func:`take_edits` is the one entry point for an edit batch:
it takes the batch's :class:`~..geometry.edits.EditEffects` (computed once, by
:func:`~..geometry.edits.apply_edits`), invalidates what they name and moves the cache to
the edited scene: objects whose geometry or box changed get new, empty linetrees (their
expanded box, the parameterisation of their lines, is made anew; every other object keeps
its box and trees).
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

import numpy as np

from .. import tolerances as tol
from ..geometry.scene import LIGHT_SUN
from .added_light import add_dependencies, add_terms, can_add
from .linetree import EMPTY, expanded_boxes
from .membership import Membership
from .moved_light import movable_lights, move_terms, renew_dependencies
from .ray_segment_tree import RaySegmentTrees
from .relight import rescalable_lights, rescale
from .shafts import light_extents
from .term_pixels import term_edit
from .tunnels import (
    LIGHT_OCCLUDED,
    LIGHT_SHADES,
    OBJ_HIT,
    OBJ_OCCLUDES,
    cell_members,
    tunnel_sections,
)

log = logging.getLogger(__name__)


class Invalidation(NamedTuple):
    """What :func:`invalidate` did (or, ``restarted``, that the cache started over: every
    interpolant of the previous one is gone)."""

    count: int  # interpolants invalidated
    ids: np.ndarray  # (count,) int32 their ids (pool slots, free again now)
    query_ms: float  # RST traversal + membership + invalidation (leaves emptied, ids freed;
    # the memory they held is compacted by take_edits or the next frame)
    rst_visits: int  # RST nodes visited
    tunnel_tests: int  # tunnel sections tested against a region
    live_before: int  # live interpolants before the edit
    failed_retried: int  # failed cells naming an edited object, emptied to be tried again
    restarted: bool = False
    #: interpolants kept with their radiance rescaled by a light's power or colour change
    #: (:mod:`.relight`): their pixels change, their cells are not rebuilt
    rescaled: np.ndarray | None = None
    rescale_broken: int = 0  # invalidated: the radiance test failed after the rescale
    rescale_no_terms: int = 0  # invalidated: their samples keep no per-light shares
    #: interpolants kept with an added light's term (:mod:`.added_light`), and those
    #: invalidated because it could not be proven on them
    terms_added: int = 0
    add_failed: int = 0
    #: interpolants kept with a moved light's new term (:mod:`.moved_light`), and those
    #: invalidated because it could not be proven on them
    terms_moved: int = 0
    move_failed: int = 0
    #: what the kept interpolants' pixels take instead of being rendered again
    #: (:class:`~.term_pixels.TermEdit`, or None)
    terms: object = None

    @classmethod
    def nothing(cls, live: int, restarted: bool = False) -> Invalidation:
        """Nothing was queried (no content changed), or, ``restarted``, the cache started
        over and all ``live`` interpolants are gone."""
        return cls(live if restarted else 0, np.zeros(0, np.int32), 0.0, 0, 0, live, 0,
                   restarted)


def rst_domain(sa) -> np.ndarray:
    """The ray segment trees' domain (2, 3): the scene box with its lights (a point or spot
    light's position, the box of a sphere light's ball or an area light's rectangle),
    padded (:data:`~..tolerances.RST_DOMAIN_PAD_REL`)."""
    lo = np.array(sa.scene_aabb[0], np.float64)
    hi = np.array(sa.scene_aabb[1], np.float64)
    elo, ehi, _ = light_extents(sa)
    kind = np.asarray(sa.light_kind)
    keep = (kind != LIGHT_SUN) & (kind >= 0) & np.all(np.isfinite(elo), axis=1) & np.all(
        np.isfinite(ehi), axis=1)
    if np.any(keep):
        lo = np.minimum(lo, elo[keep].min(axis=0))
        hi = np.maximum(hi, ehi[keep].max(axis=0))
    pad = (tol.RST_DOMAIN_PAD_REL * float(np.linalg.norm(hi - lo))
           + tol.RST_DOMAIN_PAD_MAG * (1.0 + float(np.abs([lo, hi]).max())))
    return np.stack([lo - pad, hi + pad])


class Dependencies:
    """The ray segment trees and the membership indexes of one cache."""

    def __init__(self, sa) -> None:
        self._set_domain(rst_domain(sa))
        self.rst = RaySegmentTrees(self.domain, self.slack)
        self.objects = Membership()
        self.lights = Membership()
        self.failed = Membership()  # failed linetree leaves, by the objects they name
        self.next_fail = 1
        self._warm = False

    def _set_domain(self, domain: np.ndarray) -> None:
        self.domain = domain
        mag = float(np.linalg.norm(domain[1] - domain[0]) + np.abs(domain).max())
        self.slack = tol.SHAFT_SLACK_REL * mag
        self.reach = 4.0 * mag  # sun shafts end this far (then prolonged as infinite)

    def follow_scene(self, sa, pool) -> bool:
        """Grow the trees' domain when the edited scene left it (objects moved away, lights
        added far off): the trees are rebuilt over the union (tunnels leaving the domain
        are answered by brute force meanwhile, correct but slower). Returns whether."""
        want = rst_domain(sa)
        if np.all(want[0] >= self.domain[0]) and np.all(want[1] <= self.domain[1]):
            return False
        self._set_domain(np.stack([np.minimum(want[0], self.domain[0]),
                                   np.maximum(want[1], self.domain[1])]))
        self.rst.compact(pool.serial, pool.live, True, self.domain, self.slack)
        return True

    @property
    def memory_bytes(self) -> int:
        return (self.rst.memory_bytes + self.objects.memory_bytes + self.lights.memory_bytes
                + self.failed.memory_bytes)

    def add(self, cache, pids, inst, face, depth, coord, zlo, zhi, cell_samples,
            nsamp, sa=None) -> None:
        """Record the tunnels and memberships of new interpolants ``pids`` (their cells'
        data as :meth:`~.cache.InterpolantCache._build` has it); ``sa`` the packing whose
        lights they name (default the cache's)."""
        sa = cache.sa if sa is None else sa
        sm = cache.samples.view()
        nc = len(pids)
        ids = np.ascontiguousarray(cell_samples, np.int32)
        ns = np.ascontiguousarray(nsamp, np.int32)
        lk = np.ascontiguousarray(sa.light_kind, np.int32)
        elo, ehi, chord = light_extents(sa)
        ld = np.ascontiguousarray(sa.light_dir, np.float64).reshape(-1, 3)
        args = (inst.astype(np.int32), face.astype(np.int8), depth.astype(np.int64),
                np.ascontiguousarray(coord, np.int64), np.ascontiguousarray(zlo),
                np.ascontiguousarray(zhi), ids, ns)
        counts, ta, tb, tinf = tunnel_sections(
            sm, cache.box, sa.inst_aabb, lk, np.ones(len(lk), np.bool_), True, elo, ehi,
            chord, ld, self.reach, self.slack, *args)
        pool = cache.pool
        q = np.repeat(pids, counts).astype(np.int32)
        self.rst.add_tunnels(ta, tb, tinf, q, pool.serial[q])
        okeys, oc, lkeys, lc, world = _members(sm, ids, np.ones(nc, np.int32))
        qo = np.repeat(pids, oc).astype(np.int32)
        ql = np.repeat(pids, lc).astype(np.int32)
        self.objects.add(okeys, qo, pool.serial[qo])
        self.lights.add(lkeys, ql, pool.serial[ql])
        pool.world[pids] = world

    def add_failed(self, cache, nodes, cell_samples, nsamp) -> None:
        """Remember which objects the ray trees of failed cells (leaves ``nodes`` that were
        shaded) name: when one of them is edited, the cell is tried again (seed 000, 5.2:
        no subdivision stays around a shadow that no longer exists)."""
        if len(nodes) == 0:
            return
        sm = cache.samples.view()
        okeys, oc, _, _, _ = _members(sm, np.ascontiguousarray(cell_samples, np.int32),
                                      np.ascontiguousarray(nsamp, np.int32))
        lt = cache.trees.arrays
        stamps = np.arange(self.next_fail, self.next_fail + len(nodes), dtype=np.int64)
        self.next_fail += len(nodes)
        lt.fstamp[nodes] = stamps
        self.failed.add(okeys, np.repeat(nodes, oc).astype(np.int32), np.repeat(stamps, oc))

    def warm(self, cache) -> None:
        """Run the query kernels once on nothing (numba loads compiled kernels on their
        first call: some 30 ms, which the first edit should not pay)."""
        if self._warm:
            return
        self._warm = True
        nothing = np.array([[[1.0, 1.0, 1.0], [-1.0, -1.0, -1.0]]])  # an empty box
        affected(cache, nothing, objects=(-1,), lights=(-1,))
        self.rst.query_brute(nothing, cache.pool.serial, cache.pool.live,
                             np.zeros(cache.pool.cap, np.bool_))

    def compact(self, pool, trees, force: bool = False) -> None:
        self.rst.compact(pool.serial, pool.live, force)
        self.objects.compact(pool.serial, pool.live, force)
        self.lights.compact(pool.serial, pool.live, force)
        n = trees.n_nodes
        self.failed.compact(trees.arrays.fstamp[:n], trees.arrays.leaf[:n] < EMPTY, force)


def _members(sm, ids, ns):
    """Membership keys of cells (:func:`.tunnels.cell_members`): ``okeys, ocount, lkeys,
    lcount, world``."""
    nc = len(ids)
    oc = np.zeros(nc, np.int64)
    lc = np.zeros(nc, np.int64)
    world = np.zeros(nc, np.bool_)
    e = np.empty(0, np.int64)
    cell_members(sm, ids, ns, False, oc, lc, oc, lc, e, e, world)
    os_ = np.concatenate([[0], np.cumsum(oc)[:-1]]).astype(np.int64)
    ls_ = np.concatenate([[0], np.cumsum(lc)[:-1]]).astype(np.int64)
    okeys = np.empty(int(oc.sum()), np.int64)
    lkeys = np.empty(int(lc.sum()), np.int64)
    cell_members(sm, ids, ns, True, os_, ls_, oc, lc, okeys, lkeys, world)
    return okeys, oc, lkeys, lc, world


def _material_objects(sa, materials) -> np.ndarray:
    """Instances with a slot using one of ``materials``."""
    mats = np.asarray(sorted(int(m) for m in materials), np.int64)
    if len(mats) == 0 or len(sa.inst_mat) == 0:
        return np.empty(0, np.int64)
    uses = np.isin(sa.inst_mat, mats)
    slot_inst = np.repeat(np.arange(len(sa.inst_mesh)), np.diff(sa.inst_mat_start))
    return np.unique(slot_inst[uses[:len(slot_inst)]]).astype(np.int64)


class Affected(NamedTuple):
    """What an edit may change (:func:`affected`), nothing freed yet."""

    ids: np.ndarray  # (m,) int32 live interpolants
    retry: np.ndarray  # (r,) int32 failed linetree leaves naming an edited object
    rst_visits: int
    tunnel_tests: int


def affected(cache, regions, objects=(), lights=(), materials=(), world: bool = False,
             light_shading=(), retry: bool = False) -> Affected:
    """The interpolants an edit may change (the arguments of :func:`invalidate`), and the
    failed cells it may let pass (``retry``: every failed cell that was shaded, as after a
    light moved); changes nothing."""
    pool = cache.pool
    deps: Dependencies = cache.deps
    hit = np.zeros(pool.cap, np.bool_)
    regions = np.asarray(regions, np.float64).reshape(-1, 2, 3)
    visits, tests = deps.rst.query(regions, pool.serial, pool.live, hit)
    okeys = [2 * int(o) + k for o in objects for k in (OBJ_HIT, OBJ_OCCLUDES)]
    mkeys = [2 * int(o) + OBJ_HIT for o in _material_objects(cache.sa, materials)]
    deps.objects.query(okeys + mkeys, pool.serial, pool.live, hit)
    lkeys = [2 * int(j) + k for j in lights for k in (LIGHT_SHADES, LIGHT_OCCLUDED)]
    lkeys += [2 * int(j) + LIGHT_SHADES for j in light_shading]
    deps.lights.query(lkeys, pool.serial, pool.live, hit)
    if world:
        hit |= pool.world & pool.live
    ids = np.flatnonzero(hit & pool.live).astype(np.int32)
    # failed cells whose ray trees name an edited object are tried again, and after a light
    # moved every failed cell that was shaded (their light states are all stale)
    lt = cache.trees
    n = lt.n_nodes
    failed = np.zeros(n, np.bool_)
    if okeys:
        deps.failed.query(okeys, lt.arrays.fstamp[:n], lt.arrays.leaf[:n] < EMPTY, failed)
    if len(lights) or retry:
        failed |= (lt.arrays.leaf[:n] < EMPTY) & (lt.arrays.fstamp[:n] > 0)
    return Affected(ids, np.flatnonzero(failed).astype(np.int32), visits, tests)


def invalidate(cache, regions, objects=(), lights=(), materials=(), world: bool = False,
               light_shading=(), everything: bool = False, extra=None,
               retry: bool = False) -> Invalidation:
    """Invalidate every interpolant an edit may change, and free it.

    regions : (k, 2, 3) world boxes (old and new box of every object whose geometry,
    transform, presence or visibility changed); objects : instance slots the edits name (a
    geometry, transform, material, visibility edit or a deletion: every interpolant whose
    ray trees name the object); lights : lights changed in any way (every interpolant
    shaded by or occluded from them); materials : material ids whose parameters changed
    (every interpolant whose ray trees hit an object using them); world : the world colour
    changed (every interpolant with a ray-tree node that misses); light_shading : lights
    whose power or colour alone changed (only interpolants they shade); everything: every
    interpolant (a world colour change where the world lights); extra: interpolant ids
    to invalidate as well (a rescale broke their bound, :mod:`.relight`); retry: the failed
    cells that were shaded are tried again (lights moved, :mod:`.moved_light`). Camera edits
    invalidate nothing (call nothing).

    Invalidated interpolants are freed at once (their pool ids are free, their tree and
    list entries dead); their cells are rebuilt by the next frame that needs them. Failed
    cells whose ray trees named an edited object are emptied too (tried again). The memory
    (samples only freed interpolants kept, emptied linetree blocks, dead entries) is
    compacted by :func:`take_edits`, or by the next frame.
    """
    t0 = time.perf_counter()
    pool = cache.pool
    live_before = pool.n_live
    a = affected(cache, regions, objects, lights, materials, world, light_shading, retry)
    ids, retry = a.ids, a.retry
    if everything:
        ids = np.flatnonzero(pool.live).astype(np.int32)
    elif extra is not None and len(extra):
        ids = np.union1d(ids, np.asarray(extra, np.int32)).astype(np.int32)
    lt = cache.trees
    lt.clear_dirty()
    pool.rebuilt[:] = False
    lt.mark_dirty(pool.node[ids])
    lt.mark_dirty(retry)
    lt.arrays.leaf[retry] = EMPTY
    cache.evict(ids, invalidated=True)
    # samples no live interpolant keeps may be stale now: dropped before anything is built
    # again (take_edits, or the next frame), with the linetree and list compaction
    cache.samples_stale = True
    t1 = time.perf_counter()
    log.debug("invalidate: %d of %d interpolants, %.3f ms", len(ids), live_before,
              1e3 * (t1 - t0))
    return Invalidation(len(ids), ids, 1e3 * (t1 - t0), a.rst_visits, a.tunnel_tests,
                        live_before, len(retry))


def _remap_classes(cache, old, new, meshes_changed) -> None:
    """Surface class ids are global triangle indices (the least of the class,
    :func:`.mesh_topology.mesh_topology`): when a mesh changes size, the triangles of the
    meshes after it move. Move the class ids the kept interpolants and samples hold
    (unchanged meshes keep their classes; ids on changed meshes, ``meshes_changed``,
    become -2, matching nothing a fresh sample has)."""
    if np.array_equal(old.mesh_tri_start, new.mesh_tri_start):
        return
    f = np.full(len(old.tris) + 1, -2, np.int64)
    for m in range(min(len(old.mesh_tri_start), len(new.mesh_tri_start)) - 1):
        a0, a1 = int(old.mesh_tri_start[m]), int(old.mesh_tri_start[m + 1])
        b0, b1 = int(new.mesh_tri_start[m]), int(new.mesh_tri_start[m + 1])
        if a1 - a0 == b1 - b0 and m not in meshes_changed:
            f[a0:a1] = np.arange(b0, b1)

    def remap(c):
        return np.where(c >= 0, f[np.clip(c, 0, len(f) - 1)], c).astype(c.dtype)

    p, sm = cache.pool, cache.samples
    live = np.flatnonzero(p.live)
    p.cls[live] = remap(p.cls[live])
    sm._cls[:sm.n] = remap(sm._cls[:sm.n])
    sm._ncls[:sm.n_nodes] = remap(sm._ncls[:sm.n_nodes])


def take_edits(cache, fx, sa, accel) -> Invalidation:
    """Hand the effects ``fx`` of an edit batch (:class:`~..geometry.edits.EditEffects`,
    computed once by :func:`~..geometry.edits.apply_edits`) to ``cache`` and move it to the
    edited scene ``sa`` (accelerator ``accel`` over it), keeping every interpolant still
    valid. Returns what :func:`invalidate` did.

    Instance slots are stable (a deleted object's slot is a tombstone, an added object
    takes a new or a freed slot). An object whose mesh, transform, box or visibility changed
    (``fx.geometry``) gets new empty linetrees over its new expanded box; the other objects
    keep theirs. The number of light slots may grow only by lights added in a batch of
    light and world edits (:func:`.added_light.can_add`: their terms are added where they
    are proven, :func:`.added_light.add_terms`); any other change of it starts a new cache
    (:class:`~.render.InterpolantRenderer`; the ray trees record a state per light). The
    lights moved in a batch of light and world edits keep the cells their new place is
    proven on (:mod:`.moved_light`).
    """
    old = cache.sa
    added = None
    slots: list = []
    if len(sa.light_kind) != len(old.light_kind):
        if not can_add(old, sa, fx):
            raise ValueError("take_edits: the number of light slots changed with other "
                             "edits (start a new cache)")
        # lights added into new slots: one term more where it is proven (added_light.py)
        slots = list(range(len(old.light_kind), len(sa.light_kind)))
        added = add_terms(cache, old, sa, accel, slots)
    # lights moved or resized (not in a batch that adds lights): the old term dropped, the
    # new one added where it is proven (moved_light.py)
    moved = [] if slots else movable_lights(cache, old, sa, fx)
    mv = move_terms(cache, old, sa, accel, moved) if moved else None
    if fx.scene_content_changed:
        # a world that starts or stops lighting shades every surface: all interpolants (its
        # term at the roots was or was not left out of the samples; cells with a surface
        # below the root failed while it lit). One that lights before and after changes
        # what interpolants hold only where their ray trees show it (``fx.world``, below):
        # the samples leave its term at the root out (world_term.py)
        lit_old = bool(np.any(old.world_light > 0.0))
        lit_new = bool(np.any(sa.world_light > 0.0))
        everything = fx.world and (lit_old or lit_new) and not (lit_old and lit_new)
        # a light whose power or colour alone changed, or that was deleted, rescales what
        # it shades (relight.py)
        resc = rescalable_lights(old, sa, fx.lights_shading) if cache.light_terms else []
        r = rescale(cache, old, sa, resc)
        extra = [r.broken, r.no_terms] + ([added.failed] if added is not None else []) + (
            [mv.failed] if mv is not None else [])
        inv = invalidate(cache, fx.region_array(), fx.objects,
                         set(fx.lights_moved) - set(slots) - set(moved), fx.materials,
                         fx.world, set(fx.lights_shading) - set(resc) - set(slots),
                         everything, np.concatenate(extra), retry=bool(moved))
        kept = r.rescaled[cache.pool.live[r.rescaled]]
        inv = inv._replace(rescaled=kept, rescale_broken=len(r.broken),
                           rescale_no_terms=len(r.no_terms))
        cache.totals["rescaled"] = cache.totals.get("rescaled", 0) + len(kept)
        changed = quiet = np.zeros(0, np.int32)
        if added is not None:
            live = cache.pool.live
            took = added.kept[live[added.kept]]
            add_dependencies(cache, sa, took, slots)
            changed = added.changed[live[added.changed]]
            quiet = np.setdiff1d(took, changed)
            inv = inv._replace(rescaled=np.union1d(kept, changed).astype(np.int32),
                               terms_added=len(took), add_failed=len(added.failed))
        renewed = None
        if mv is not None:
            live = cache.pool.live
            took = mv.kept[live[mv.kept]]
            renewed = renew_dependencies(cache, sa, took)  # (the old shafts and states go)
            changed = mv.changed[live[mv.changed]]
            quiet = np.setdiff1d(took, changed)
            inv = inv._replace(rescaled=np.union1d(kept, changed).astype(np.int32),
                               terms_moved=len(took), move_failed=len(mv.failed))
        # the pixels of the kept cells take the batch's terms (term_pixels.py)
        inv = inv._replace(terms=term_edit(
            cache, old, sa, slots, changed, quiet, kept, resc, moved=moved,
            delta=None if mv is None else mv.delta, renewed=renewed))
    else:
        inv = Invalidation.nothing(cache.pool.n_live)
    n_new = len(sa.inst_mesh)
    trees = cache.trees
    trees.grow_instances(n_new)
    reset = np.asarray(sorted(k for k in fx.geometry if k < n_new), np.int64)
    held = trees.reset_trees(reset)
    held = held[cache.pool.live[held]]
    if len(held):
        cache.evict(held, invalidated=True)
    trees.fresh_dirty[reset[reset < len(trees.fresh_dirty)]] = True
    box = np.empty((n_new, 2, 3))
    box[:min(len(cache.box), n_new)] = cache.box[:n_new]
    if len(reset):
        box[reset] = expanded_boxes(sa, cache.box_extent)[reset]
    cache.box = np.ascontiguousarray(box)
    cache.compact_samples()
    _remap_classes(cache, old, sa, fx.meshes)
    cache.sa = sa
    cache.accel = accel
    cache.drop_scene_structures()
    trees.collapse()
    cache.deps.compact(cache.pool, trees)
    cache.deps.follow_scene(sa, cache.pool)
    log.debug("take_edits: %d objects with new linetrees, %d interpolants kept", len(reset),
              cache.pool.n_live)
    return inv
