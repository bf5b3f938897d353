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
entries outnumber live ones. :func:`set_scene` then moves the cache to the edited scene:
objects whose geometry or box changed get new, empty linetrees (their expanded box, the
parameterisation of their lines, is made anew; every other object keeps its box and trees).
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

import numpy as np

from .. import tolerances as tol
from ..geometry.scene import LIGHT_SUN
from .linetree import EMPTY, expanded_boxes
from .membership import Membership
from .ray_segment_tree import RaySegmentTrees
from .tunnels import (
    LIGHT_OCCLUDED,
    LIGHT_SHADES,
    OBJ_HIT,
    OBJ_OCCLUDES,
    cell_members,
    cell_tunnels,
)

log = logging.getLogger(__name__)


class Invalidation(NamedTuple):
    """What :func:`invalidate` did."""

    count: int  # interpolants invalidated
    ids: np.ndarray  # (count,) int32 their ids (pool slots, free again now)
    query_ms: float  # RST traversal + membership + invalidation (leaves emptied, ids freed;
    # the memory they held is compacted by set_scene or the next frame)
    rst_visits: int  # RST nodes visited
    tunnel_tests: int  # tunnel sections tested against a region
    live_before: int  # live interpolants before the edit
    failed_retried: int  # failed cells naming an edited object, emptied to be tried again


def rst_domain(sa) -> np.ndarray:
    """The ray segment trees' domain: the scene box with its point and spot lights, padded
    by 1% of its diagonal (2, 3)."""
    lo = np.array(sa.scene_aabb[0], np.float64)
    hi = np.array(sa.scene_aabb[1], np.float64)
    pos = np.asarray(sa.light_pos, np.float64).reshape(-1, 3)
    kind = np.asarray(sa.light_kind)
    pts = pos[(kind != LIGHT_SUN) & (kind >= 0) & np.all(np.isfinite(pos), axis=1)]
    if len(pts):
        lo = np.minimum(lo, pts.min(axis=0))
        hi = np.maximum(hi, pts.max(axis=0))
    pad = 0.01 * float(np.linalg.norm(hi - lo)) + 1e-6 * (1.0 + float(np.abs([lo, hi]).max()))
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
            nsamp) -> None:
        """Record the tunnels and memberships of new interpolants ``pids`` (their cells'
        data as :meth:`~.cache.InterpolantCache._build` has it)."""
        sa = cache.sa
        sm = cache.samples.view()
        nc = len(pids)
        ids = np.ascontiguousarray(cell_samples, np.int32)
        ns = np.ascontiguousarray(nsamp, np.int32)
        lk = np.ascontiguousarray(sa.light_kind, np.int32)
        lp = np.ascontiguousarray(sa.light_pos, np.float64).reshape(-1, 3)
        ld = np.ascontiguousarray(sa.light_dir, np.float64).reshape(-1, 3)
        args = (inst.astype(np.int32), face.astype(np.int8), depth.astype(np.int64),
                np.ascontiguousarray(coord, np.int64), np.ascontiguousarray(zlo),
                np.ascontiguousarray(zhi), ids, ns)
        counts = np.zeros(nc, np.int64)
        none = np.empty((0, 6))
        cell_tunnels(sm, cache.box, sa.inst_aabb, lk, lp, ld, self.reach, self.slack, *args,
                     False, counts, counts, none, none, np.empty(0, np.bool_))
        start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        m = int(counts.sum())
        ta = np.empty((m, 6))
        tb = np.empty((m, 6))
        tinf = np.empty(m, np.bool_)
        cell_tunnels(sm, cache.box, sa.inst_aabb, lk, lp, ld, self.reach, self.slack, *args,
                     True, start, counts, ta, tb, tinf)
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
             light_shading=()) -> Affected:
    """The interpolants an edit may change (the arguments of :func:`invalidate`), and the
    failed cells it may let pass; changes nothing."""
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
    if len(lights):
        failed |= (lt.arrays.leaf[:n] < EMPTY) & (lt.arrays.fstamp[:n] > 0)
    return Affected(ids, np.flatnonzero(failed).astype(np.int32), visits, tests)


def invalidate(cache, regions, objects=(), lights=(), materials=(), world: bool = False,
               light_shading=(), new_edit: bool = True) -> Invalidation:
    """Invalidate every interpolant an edit may change, and free it.

    regions : (k, 2, 3) world boxes (old and new box of every object whose geometry,
    transform, presence or visibility changed); objects : instance slots the edits name (a
    geometry, transform, material, visibility edit or a deletion: every interpolant whose
    ray trees name the object); lights : lights changed in any way (every interpolant
    shaded by or occluded from them); materials : material ids whose parameters changed
    (every interpolant whose ray trees hit an object using them); world : the world colour
    changed (every interpolant with a ray-tree node that misses); light_shading : lights
    whose power or colour alone changed (only interpolants they shade). Camera edits
    invalidate nothing (call nothing). ``new_edit`` False: part of the same edit as the
    last call (the cells it emptied stay marked as rebuilt after an edit).

    Invalidated interpolants are freed at once (their pool ids are free, their tree and
    list entries dead); their cells are rebuilt by the next frame that needs them. Failed
    cells whose ray trees named an edited object are emptied too (tried again). Call
    :func:`set_scene` with the edited scene before the next frame: it compacts the memory
    (samples only freed interpolants kept, emptied linetree blocks, dead entries).
    """
    t0 = time.perf_counter()
    pool = cache.pool
    live_before = pool.n_live
    a = affected(cache, regions, objects, lights, materials, world, light_shading)
    ids, retry = a.ids, a.retry
    lt = cache.trees
    if new_edit:
        lt.clear_dirty()
        pool.rebuilt[:] = False
    cache.edit_pending = True
    lt.mark_dirty(pool.node[ids])
    lt.mark_dirty(retry)
    lt.arrays.leaf[retry] = EMPTY
    cache.evict(ids, invalidated=True)
    # samples no live interpolant keeps may be stale now: dropped before anything is built
    # again (set_scene, or the next frame), with the linetree and list compaction
    cache.samples_stale = True
    t1 = time.perf_counter()
    log.debug("invalidate: %d of %d interpolants, %.3f ms", len(ids), live_before,
              1e3 * (t1 - t0))
    return Invalidation(len(ids), ids, 1e3 * (t1 - t0), a.rst_visits, a.tunnel_tests,
                        live_before, len(retry))


_TRI_DATA = ("tri_normals", "tri_uvs", "tri_slot")


def _mesh_changed(old, new) -> np.ndarray:
    """Per mesh of ``new``: its triangles (positions, normals, uvs, slots) differ from
    ``old``'s mesh of the same id."""
    nm = len(new.mesh_tri_start) - 1
    om = len(old.mesh_tri_start) - 1
    if (om == nm and np.array_equal(old.mesh_tri_start, new.mesh_tri_start)
            and np.array_equal(old.tris, new.tris) and np.array_equal(old.verts, new.verts)
            and all(np.array_equal(getattr(old, k), getattr(new, k)) for k in _TRI_DATA)):
        return np.zeros(nm, bool)
    out = np.ones(nm, bool)
    for m in range(min(nm, om)):
        a0, a1 = old.mesh_tri_start[m], old.mesh_tri_start[m + 1]
        b0, b1 = new.mesh_tri_start[m], new.mesh_tri_start[m + 1]
        if a1 - a0 == b1 - b0:
            out[m] = not (np.array_equal(old.verts[old.tris[a0:a1]], new.verts[new.tris[b0:b1]])
                          and all(np.array_equal(getattr(old, k)[a0:a1], getattr(new, k)[b0:b1])
                                  for k in _TRI_DATA))
    return out


class SceneDiff(NamedTuple):
    """What changed between two packings of a scene, as :func:`invalidate` takes it."""

    regions: np.ndarray  # (k, 2, 3)
    objects: set
    lights: set
    light_shading: set
    materials: set
    world: bool
    geometry: np.ndarray  # (max(I_old, I_new),) bool slots whose mesh, transform or box changed


_MAT = ("mat_diffuse", "mat_specular", "mat_roughness", "mat_mirror", "mat_transmission",
        "mat_ior", "mat_emission", "mat_tex")
_LIGHT_GEOMETRY = ("light_kind", "light_pos", "light_dir", "light_cos_outer", "light_cos_inner")


def _rows_differ(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: row i of a and b differ (NaN equal to NaN)."""
    a = np.asarray(a).reshape(len(a), -1)[:n]
    b = np.asarray(b).reshape(len(b), -1)[:n]
    return ~np.all((a == b) | ((a != a) & (b != b)), axis=1)


def scene_diff(old, new, mesh_changed: np.ndarray | None = None) -> SceneDiff:
    """Diff two packings of one scene with stable instance and light slots (same number
    of light slots): the edits that lead from ``old`` to ``new``."""
    if mesh_changed is None:
        mesh_changed = _mesh_changed(old, new)
    n_old, n_new = len(old.inst_mesh), len(new.inst_mesh)
    m = min(n_old, n_new)
    geo = np.ones(max(n_old, n_new), bool)
    same = ((old.inst_mesh[:m] == new.inst_mesh[:m])
            & ~_rows_differ(old.inst_xform, new.inst_xform, m)
            & ~_rows_differ(old.inst_aabb, new.inst_aabb, m))
    if len(mesh_changed):
        same &= ~mesh_changed[np.clip(new.inst_mesh[:m], 0, len(mesh_changed) - 1)]
    geo[:m] = ~same
    objects = set(np.flatnonzero(geo).tolist())
    if not (np.array_equal(old.inst_mat_start[:m + 1], new.inst_mat_start[:m + 1])
            and np.array_equal(old.inst_mat[:old.inst_mat_start[m]],
                               new.inst_mat[:new.inst_mat_start[m]])):
        for k in range(m):
            if not np.array_equal(old.inst_mat[old.inst_mat_start[k]:old.inst_mat_start[k + 1]],
                                  new.inst_mat[new.inst_mat_start[k]:new.inst_mat_start[k + 1]]):
                objects.add(k)
    boxes = [sa_.inst_aabb[k] for k in np.flatnonzero(geo)
             for sa_ in (old, new) if k < len(sa_.inst_aabb)]
    boxes = [b for b in boxes if np.all(b[0] <= b[1]) and np.all(np.isfinite(b))]
    regions = np.stack(boxes) if boxes else np.zeros((0, 2, 3))
    nm = min(len(old.mat_diffuse), len(new.mat_diffuse))
    mat = np.zeros(nm, bool)
    for k in _MAT:
        mat |= _rows_differ(getattr(old, k), getattr(new, k), nm)
    if not (np.array_equal(old.tex_start, new.tex_start) and np.array_equal(
            old.tex_size, new.tex_size) and np.array_equal(old.tex_data, new.tex_data)):
        mat |= new.mat_tex[:nm] >= 0  # a texture changed: every textured material
    L = min(len(old.light_kind), len(new.light_kind))
    moved = np.zeros(L, bool)
    for k in _LIGHT_GEOMETRY:
        moved |= _rows_differ(getattr(old, k), getattr(new, k), L)
    shade = _rows_differ(old.light_intensity, new.light_intensity, L) & ~moved
    world = not np.array_equal(old.world_color, new.world_color)
    return SceneDiff(regions, objects, set(np.flatnonzero(moved).tolist()),
                     set(np.flatnonzero(shade).tolist()), set(np.flatnonzero(mat).tolist()),
                     world, geo)


def _remap_classes(cache, old, new, mesh_changed) -> None:
    """Surface class ids are global triangle indices (the least of the class,
    :func:`.mesh_topology.mesh_topology`): when a mesh changes size, the triangles of the
    meshes after it move. Move the class ids the kept interpolants and samples hold
    (unchanged meshes keep their classes; ids on changed meshes become -2, matching
    nothing a fresh sample has)."""
    if np.array_equal(old.mesh_tri_start, new.mesh_tri_start):
        return
    f = np.full(len(old.tris) + 1, -2, np.int64)
    for m in range(min(len(old.mesh_tri_start), len(new.mesh_tri_start)) - 1):
        a0, a1 = int(old.mesh_tri_start[m]), int(old.mesh_tri_start[m + 1])
        b0, b1 = int(new.mesh_tri_start[m]), int(new.mesh_tri_start[m + 1])
        if a1 - a0 == b1 - b0 and not mesh_changed[m]:
            f[a0:a1] = np.arange(b0, b1)

    def remap(c):
        return np.where(c >= 0, f[np.clip(c, 0, len(f) - 1)], c).astype(c.dtype)

    p, sm = cache.pool, cache.samples
    live = np.flatnonzero(p.live)
    p.cls[live] = remap(p.cls[live])
    sm._cls[:sm.n] = remap(sm._cls[:sm.n])
    sm._ncls[:sm.n_nodes] = remap(sm._ncls[:sm.n_nodes])


def set_scene(cache, sa, accel) -> Invalidation | None:
    """Move ``cache`` to the edited scene ``sa`` (accelerator ``accel`` over it), keeping
    every interpolant still valid.

    Call :func:`invalidate` with the edits first (that is the fast, timed path); whatever
    changed that it was not told of is found here by diffing the two packings
    (:func:`scene_diff`) and invalidated too, so a host that only hands over a new export
    loses only what the changes affect. Returns that second invalidation, if any.

    Instance slots are stable (a deleted object's slot is a tombstone, an added object
    takes a new or a freed slot). An object whose mesh, transform or box changed gets new
    empty linetrees over its new expanded box; the other objects keep theirs. A change in
    the number of light slots starts over (the ray trees record a state per light).
    """
    old = cache.sa
    if len(sa.light_kind) != len(old.light_kind):
        cache.__init__(sa, accel, cache.epsilon, cache.depth_cap,
                       cache.memory_cap_bytes / 1e6, cache.max_depth)
        return None
    n_new = len(sa.inst_mesh)
    mesh_changed = _mesh_changed(old, sa)
    d = scene_diff(old, sa, mesh_changed)
    extra = None
    if len(d.regions) or d.objects or d.lights or d.light_shading or d.materials or d.world:
        extra = invalidate(cache, d.regions, d.objects, d.lights, d.materials, d.world,
                           d.light_shading, new_edit=not cache.edit_pending)
    cache.edit_pending = False
    changed = d.geometry
    trees = cache.trees
    trees.grow_instances(n_new)
    reset = np.flatnonzero(changed)
    held = trees.reset_trees(reset)
    held = held[cache.pool.live[held]]
    if len(held):
        cache.evict(held, invalidated=True)
    trees.fresh_dirty[reset[reset < len(trees.fresh_dirty)]] = True
    box = np.empty((n_new, 2, 3))
    box[:min(len(cache.box), n_new)] = cache.box[:n_new]
    fresh = expanded_boxes(sa, cache.box_extent)
    ch = changed[:n_new]
    box[ch] = fresh[ch]
    cache.box = np.ascontiguousarray(box)
    cache.compact_samples()
    _remap_classes(cache, old, sa, mesh_changed)
    cache.sa = sa
    cache.accel = accel
    cache.drop_scene_structures()
    trees.collapse()
    cache.deps.compact(cache.pool, trees)
    cache.deps.follow_scene(sa, cache.pool)
    log.debug("set_scene: %d objects with new linetrees, %d interpolants kept", len(reset),
              cache.pool.n_live)
    return extra
