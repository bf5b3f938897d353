"""Frames rendered with RI-trees (``mode = "RI_TREE"``) and the thickness view.

Which objects get an RI-tree ("model only what a scene requires", seed 004 section 3.1):
objects with a mirror or transmissive material (their exit rays are where tracing is
expensive), at least :data:`~.eligibility.MIN_TRIANGLES` triangles and no texture; in the
thickness view every object of at least that size. Everything else is traced by a second
accelerator over the other objects only.

The wavefront is the base tracer's (:mod:`..tracing.whitted`): per level, every ray is
intersected with the traced objects (``closest_hit``) and with the boxes of the RI-tree
objects; a ray that enters an RI-tree object's box from outside *queries* its tree
(:meth:`.cache.RITreeCache.query`), one that starts inside is traced against the object.
The nearest hit wins. Interpolated hits are shaded exactly as traced ones (direct light,
hard shadows, reflection and refraction from the interpolated point and normals); at an
interpolated glass hit the refracted ray is replaced by the interpolated *exit ray* with
the path's weight, ``nint`` levels further down. Rays leaving an interpolated hit ignore
that object's own surface nearer than ``RI_SELF_OFFSET_REL`` of its diagonal (a convex
object entirely). Shadow rays query the trees too.

After the frame's tiles, the continuation check (:mod:`.recheck`) traces again, with the
base tracer, the pixels whose interpolated samples met different things (objects, lights'
visibility) across their neighbourhood; they are the base frame's pixels, class ``traced``.

A pixel's class (Interpolation pass): ``interpolated`` when its primary hit came from a
tree, ``traced`` when it was traced (no tree, or the ray starts inside the object's box),
``fail_silhouette`` when the patch-class test failed (three or more classes, or too few
usable corners), ``fail_nonlinear`` when the angular threshold failed.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from .. import tolerances as tol
from ..accel.accelerators import Hits, create_accelerator
from ..frame import (
    CLASS_BACKGROUND,
    CLASS_INTERPOLATED,
    CLASS_NAMES,
    CLASS_TRACED,
    GLOSSY_SAMPLES_DEFAULT,
    LIGHT_SAMPLES_DEFAULT,
    Frame,
    RenderSettings,
)
from ..geometry.cameras import camera_params, camera_rays
from ..geometry.mesh_topology import mesh_topology_cached
from ..interpolants.linetree import expanded_boxes
from ..tracing.batches import TILE_RAYS, accumulate, frame_batches, scatter_add
from ..tracing.glossy_rays import has_glossy
from ..tracing.glossy_strata import frame_strata, lattices
from ..tracing.light_linking import any_hit_shadows
from ..tracing.soft_lights import has_soft_light, node_seeds, sample_seeds
from ..tracing.whitted import (
    shade_paths,
    shadow_rays,
    soft_direct,
    surfaces,
    trace,
)
from . import thickness as thick
from .candidates import _QUERY, _TRACE, candidates, pick
from .eligibility import eligible, subset
from .fallback import FrameCosts, Ledger, object_costs, tree_pays
from .patches import ST_FAIL_ANGLE, ST_FAIL_CLASS, ST_HIT, ST_MISS, ST_SPARSE
from .ray_tree import next_rays, primary_class
from .recheck import Continuations, node_keys, retrace
from .surfaces import interp_surface
from .thickness import render_thickness_exact  # noqa: F401 - re-exported (session, bench)
from .thickness_view import tile as thickness_tile
from .tree_cache import RITreeCache

log = logging.getLogger(__name__)

#: whether shadow rays query the trees (the paper's visibility queries). Off: a shadow ray
#: is tested exactly against an RI-tree object (one any-hit-like trace of that object,
#: ignoring the object of an interpolated origin nearer than the self-offset), which in this
#: engine costs less than a query with its traced fallbacks and leaves no error
SHADOW_QUERIES = False

#: rays per batch of an RI_TREE frame: larger than the base tracer's tiles, so that a batch
#: brings more queries to each leaf (the cost rule counts them) and the per-batch work of
#: the queries is spread over more rays
RI_TILE_RAYS = 4 * TILE_RAYS


# ----------------------------------------------------------------------------- renderer


#: material properties an RI-tree depends on (its exit paths and their gains, eligibility)
_OPTICAL = ("mat_mirror", "mat_transmission", "mat_ior", "mat_tex", "mat_model",
            "mat_specular", "mat_specular_ior", "mat_metallic", "mat_metal", "mat_metal_tint")


class RITreeRenderer:
    """The RI_TREE mode's state in a session: the RI-tree caches (shaded and thickness
    view) and the accelerator over the traced objects, kept while they stay valid.

    Edits reach it through :meth:`take_edits` (their effects, computed once by the
    session): the trees of the objects they touch are dropped, the others kept. A scene
    packing it was not told of starts over (the renderer never diffs scenes), and so does
    a change in the number of instance slots or in the meshes' surface classes.
    """

    #: after every frame, objects whose tree did not pay are traced (:mod:`.fallback`)
    auto_fallback = True
    #: pixels whose interpolated samples' continuations disagree are re-traced
    #: (:mod:`.recheck`; an addition of issue 22 like the exit-ray test, so with that test
    #: off, ``ri_probe_angle = 0``, the paper's settings, it is off too)
    recheck = True

    def __init__(self) -> None:
        self.caches: dict[bool, RITreeCache] = {}
        self._sa = None
        self._edited = None  # the packing take_edits moved to (the next frame's)
        self._accel = None
        self._sub = None  # (accelerator over traced objects, their ids) per view
        self.ri: dict[bool, np.ndarray] = {}
        self.convex = None
        self._box = None
        self._tri_class = None
        self._extent = None  # scene extent the trees' boxes were padded with
        #: per view: instance slots traced because their tree did not pay (:mod:`.fallback`)
        self.fallback: dict[bool, set[int]] = {False: set(), True: set()}
        self._ledger: Ledger | None = None  # the frame's, while it renders
        #: what the last complete frame measured (:class:`.fallback.FrameCosts` or None)
        self.last_costs: FrameCosts | None = None
        self._settings = None

    def reset(self) -> None:
        self.__init__()

    def invalidate(self, slots) -> int:
        """Drop the RI-trees of instance slots ``slots`` (an edit moved or changed them).

        Returns the number of trees dropped. The next frame rebuilds them on demand (an
        object traced because its tree did not pay gets a tree again)."""
        slots = [int(k) for k in slots]
        for view, fb in self.fallback.items():
            if fb.intersection(slots):
                fb.difference_update(slots)
                self.ri.pop(view, None)
        return sum(c.invalidate(slots) for c in self.caches.values())

    def take_edits(self, fx, old_sa, sa) -> int:
        """An edit batch's effects ``fx`` (:class:`~..geometry.edits.EditEffects`) from
        packing ``old_sa`` to ``sa``: drop the trees of the instance slots it touched (the
        objects named: transform, geometry, deletion, visibility, materials assigned) and of
        the objects using a material whose optical properties changed (a colour alone keeps
        them: trees hold geometry and exit paths only). Returns the trees dropped."""
        if not self.caches:
            return 0
        if (self._edited or self._sa) is not old_sa:
            self.reset()  # (not following this scene: nothing of it can be trusted)
            return 0
        self._edited = sa
        slots = set(int(k) for k in fx.objects)
        optical = [int(m) for m in fx.materials
                   if int(m) >= len(old_sa.mat_ior) or int(m) >= len(sa.mat_ior)
                   or any(not np.array_equal(getattr(old_sa, f)[int(m)], getattr(sa, f)[int(m)])
                          for f in _OPTICAL)]
        if optical:
            uses = np.isin(sa.inst_mat, optical)
            slot_of = np.repeat(np.arange(len(sa.inst_mesh)), np.diff(sa.inst_mat_start))
            slots.update(int(k) for k in np.unique(slot_of[uses]))
        return self.invalidate(sorted(slots)) if slots else 0

    # -- state ---------------------------------------------------------------------------

    def _sync(self, sa, accel, settings: RenderSettings) -> None:
        topo = mesh_topology_cached(sa)
        same_meshes = (self._sa is not None and self._sa.tris.shape == sa.tris.shape
                       and self._tri_class is not None
                       and np.array_equal(self._tri_class, topo.tri_class))
        told = sa is self._sa or sa is self._edited
        reset = (not told or accel is not self._accel or not same_meshes
                 or len(sa.inst_mesh) != len(self._sa.inst_mesh))
        if reset:
            # the boxes' padding scales with the extent of the scene the trees started in:
            # an edit that grows the scene box keeps the other objects' trees valid
            self._extent = float(sa.scene_extent)
        box = expanded_boxes(sa, self._extent)
        if reset:
            self.caches = {}
            self._sub = {}
            self.ri = {}
        elif sa is not self._sa:
            for c in self.caches.values():
                c.sa = sa
                c.box = box
                c.diag = np.linalg.norm(box[:, 1] - box[:, 0], axis=1)
            self._sub = {}
            self.ri = {}
        self._sa = sa
        self._edited = None
        self._box = box
        self._tri_class = topo.tri_class
        self._accel = accel
        self.convex = topo.mesh_convex[sa.inst_mesh].copy()
        view = bool(settings.thickness_view)
        c = self.caches.get(view)
        if c is None or not c.compatible(settings.ri_dist_thresh, settings.ri_ang_thresh,
                                         settings.ri_depth, view, settings.ri_probe_angle):
            self.caches[view] = RITreeCache(sa, accel, settings.ri_dist_thresh,
                                            settings.ri_ang_thresh, settings.ri_depth,
                                            settings.ri_cache_mb, view, self._extent,
                                            probe_deg=settings.ri_probe_angle)
            self.fallback[view] = set()  # new settings: every tree is given a new chance
            self.ri.pop(view, None)
        self.caches[view].cache_bytes = float(settings.ri_cache_mb) * 1e6
        self._settings = settings
        if view not in self.ri:
            self._split_objects(view)

    def _split_objects(self, view) -> None:
        """Which objects of ``view`` query a tree (``self.ri[view]``) and the accelerator
        over the others (eligible objects that fell back included: :mod:`.fallback`)."""
        sa, settings = self._sa, self._settings
        ri = eligible(sa, view)
        ri[sorted(self.fallback[view])] = False
        self.ri[view] = np.flatnonzero(ri).astype(np.int32)
        if not ri.any():  # every object traced: the scene's own accelerator
            self._sub[view] = (self._accel, np.arange(len(ri), dtype=np.int32))
            return
        keep = np.flatnonzero(~ri)
        sub = create_accelerator(settings.accelerator, subset(sa, keep),
                                 **settings.accelerator_options()) if len(keep) else None
        self._sub[view] = (sub, keep.astype(np.int32))

    # -- the fallback's ledger (:mod:`.fallback`) ----------------------------------------

    def _timed(self, key, n, fn, *args):
        return self._ledger.timed(key, n, fn, *args) if self._ledger else fn(*args)

    def _count(self, queried, failed, skipping, skipped) -> None:
        if self._ledger:
            self._ledger.count(queried, failed, skipping, skipped)

    def fall_back(self, view, objects, scene=None, costs: FrameCosts | None = None
                  ) -> list[str]:
        """Trace ``objects`` (instance slots) of ``view`` from the next frame on, freeing
        their trees; returns one message per object (with the costs that decided it)."""
        objects = [int(k) for k in objects if int(k) not in self.fallback[view]]
        if not objects:
            return []
        notes = []
        tree = traced = None
        if costs is not None:
            tree, traced = object_costs(costs)
        for k in objects:
            name = (scene.instances[k] or {}).get("name") if scene is not None else None
            note = f"RI-tree: '{name or k}' is traced (its tree does not pay"
            if tree is not None and costs.queries[k]:
                q = float(costs.queries[k])
                note += (f": {1e6 * tree[k] / q:.2f} us per query with the tree, "
                         f"{1e6 * traced[k] / q:.2f} us traced")
            notes.append(note + ")")
            log.info(notes[-1])
        self.fallback[view].update(objects)
        self.caches[view].invalidate(objects)
        self._split_objects(view)
        return notes

    # -- intersection --------------------------------------------------------------------

    def _intersect(self, view, o, d, t0, t1, self_inst, primary=False):
        """Nearest hits of a batch through traced objects and RI-trees (module doc).

        Returns dict(t, inst, prim, u, v, interp (index into the query result or -1),
        status (per ray, of the winning RI query; only for ``primary`` batches, else -1),
        q (QueryResult or None)).

        A ray that would query no tree and does not leave an interpolated point (it meets
        no RI-tree object's box from outside: e.g. one inside a wrap's box) is one closest-
        hit query of the whole scene, as in the base tracer (the same hit as the traced
        objects' and each met object's, in one traversal instead of several).
        """
        n = len(o)
        ri = self.ri[view]
        if n == 0 or len(ri) == 0 or self._sub[view][0] is self._accel:
            return self._intersect_ri(view, o, d, t0, t1, self_inst, primary)
        rows, _, kind, _ = candidates(o, d, t0, t1, np.full(n, np.inf), ri,
                                      self.caches[view].box, self.convex, self_inst,
                                      np.zeros(n))
        direct = self_inst < 0
        direct[rows[kind == _QUERY]] = False
        if not direct.any():
            return self._intersect_ri(view, o, d, t0, t1, self_inst, primary)
        k = np.flatnonzero(direct)
        if len(k) == n:
            h = self._timed("ray", n, self._accel.closest_hit, o, d, t0, t1)
            return dict(t=h.t, inst=h.inst, prim=h.prim, u=h.u, v=h.v,
                        interp=np.full(n, -1, np.int64), status=np.full(n, -1, np.int8),
                        q=None)
        h = self._timed("ray", len(k), self._accel.closest_hit, o[k], d[k], t0[k], t1[k])
        r = np.flatnonzero(~direct)
        out = self._intersect_ri(view, o[r], d[r], t0[r], t1[r], self_inst[r], primary)
        for key, fill, part in (("t", np.inf, h.t), ("inst", -1, h.inst),
                                ("prim", -1, h.prim), ("u", 0.0, h.u), ("v", 0.0, h.v),
                                ("interp", -1, None), ("status", -1, None)):
            a = np.full(n, fill, out[key].dtype)
            a[r] = out[key]
            if part is not None:
                a[k] = part
            out[key] = a
        return out

    def _intersect_ri(self, view, o, d, t0, t1, self_inst, primary=False):
        """:meth:`_intersect` through the traced objects' accelerator, the RI-tree
        objects' queries and their exact tests."""
        n = len(o)
        sub, ids = self._sub[view]
        cache = self.caches[view]
        best = np.full(n, np.inf)
        inst = np.full(n, -1, np.int32)
        prim = np.full(n, -1, np.int32)
        u = np.zeros(n)
        v = np.zeros(n)
        if sub is not None and n:
            h = self._timed("ray", n, sub.closest_hit, o, d, t0, t1)
            ok = h.inst >= 0
            best = np.where(ok, h.t, np.inf)
            inst = np.where(ok, ids[np.maximum(h.inst, 0)], -1).astype(np.int32)
            prim, u, v = h.prim, h.u, h.v
        out = dict(t=best, inst=inst, prim=prim, u=u, v=v, interp=np.full(n, -1, np.int64),
                   status=np.full(n, -1, np.int8), q=None)
        ri = self.ri[view]
        if len(ri) == 0 or n == 0:
            return out
        rows, objs, kind, tlo = candidates(o, d, t0, t1, best, ri, cache.box, self.convex,
                                           self_inst, self._self_tmin(cache.diag, d, self_inst))
        total = len(rows)
        if total == 0:
            return out
        qi = np.flatnonzero(kind == _QUERY)
        trace_pairs = [np.flatnonzero(kind == _TRACE)]
        q = None
        cand_rows, cand_t, cand_id = [], [], []
        if len(qi):
            qr = rows[qi]
            q = self._timed("query", 0, cache.query, objs[qi], o[qr], d[qr])
            hit = (q.status == ST_HIT) & (q.t > t0[qr]) & (q.t <= t1[qr])
            sel = np.flatnonzero(hit)
            cand_rows.append(qr[sel])
            cand_t.append(q.t[sel])
            cand_id.append(sel.astype(np.int64))  # >= 0: query result row
            # failed queries with the cheap test's exact hit need no second trace
            tested = np.flatnonzero((q.status != ST_HIT) & (q.status != ST_MISS)
                                    & (q.test_prim >= 0))
            okt = tested[(q.test_t[tested] > t0[qr[tested]]) & (q.test_t[tested]
                                                                   <= t1[qr[tested]])]
            cand_rows.append(qr[okt])
            cand_t.append(q.test_t[okt])
            cand_id.append(-2 - (len(qi) + okt).astype(np.int64))
            fail = np.flatnonzero(((q.status == ST_FAIL_CLASS) | (q.status == ST_FAIL_ANGLE)
                                   | (q.status == ST_SPARSE)) & (q.test_prim < 0))
            trace_pairs.append(qi[fail])
            glass = (q.status == ST_HIT) & (q.nint > 0)
            self._count(objs[qi], objs[qi[fail]], objs[qi[glass]], q.nint[glass])
            if primary:
                # the class of a primary pixel: the status of its nearest query
                st = out["status"]
                order = np.argsort(-q.t)
                st[qr[order]] = q.status[order]
        tp = np.concatenate(trace_pairs)
        th = None
        if len(tp):
            tr = rows[tp]
            th = self._timed("obj", len(tp), self._accel.intersect_object, objs[tp], o[tr],
                             d[tr], tlo[tp], t1[tr])
            ok = np.flatnonzero(th.inst >= 0)
            cand_rows.append(tr[ok])
            cand_t.append(th.t[ok])
            cand_id.append(-2 - (2 * total + ok).astype(np.int64))
        cr = np.concatenate(cand_rows)
        if not len(cr):
            return out
        ct = np.concatenate(cand_t)
        cid = np.concatenate(cand_id)
        win = np.full(n, -1, np.int64)
        pick(cr, ct, cid, best, win)
        interp = win >= 0
        out["interp"][interp] = win[interp]
        inst[interp] = objs[qi[win[interp]]]
        prim[interp] = -1
        # tested exact hits
        m = np.flatnonzero(win <= -2)
        code = -2 - win[m]
        tested = m[code < 2 * total]
        ti = code[code < 2 * total] - len(qi)
        if len(tested):
            inst[tested] = objs[qi[ti]]
            prim[tested] = q.test_prim[ti]
            u[tested] = q.test_u[ti]
            v[tested] = q.test_v[ti]
        traced = m[code >= 2 * total]
        k = code[code >= 2 * total] - 2 * total
        if len(traced):
            inst[traced] = objs[tp[k]]
            prim[traced] = th.prim[k]
            u[traced] = th.u[k]
            v[traced] = th.v[k]
        if primary:
            # a ray whose nearest hit is traced after a query attempt keeps the failure
            # class; one decided by a traced object keeps "traced"
            st = out["status"]
            st[(win == -1)] = -1
            st[interp] = ST_HIT
        out["q"] = q
        return out

    @staticmethod
    def _self_tmin(diag, d, self_inst):
        """Per ray: the parameter below which its origin's own object is ignored (rays
        leaving an interpolated hit; 0 elsewhere). diag: (I,) the trees' box diagonals."""
        out = np.zeros(len(d))
        k = np.flatnonzero(self_inst >= 0)
        if len(k):
            out[k] = (tol.RI_SELF_OFFSET_REL * diag[self_inst[k]]
                      / np.maximum(np.linalg.norm(d[k], axis=1), 1e-300))
        return out

    def _occluded(self, o, d, t1, self_inst):
        """Shadow rays: (n,) bool, blocked before ``t1``. A ray leaving a traced point is one
        any-hit query of the whole scene, as in the base tracer; one leaving an interpolated
        point ignores its own object nearer than the self-offset (module doc), so it is
        tested against the traced objects and, exactly, against each RI-tree object whose
        box it meets."""
        n = len(o)
        zero = np.zeros(n)
        vis = np.zeros(n, np.bool_)
        plain = self_inst < 0
        if plain.all():
            return any_hit_shadows(self._accel, o, d, t1)
        if SHADOW_QUERIES:
            return self._intersect(False, o, d, zero, t1, self_inst)["t"] < np.inf
        k = np.flatnonzero(plain)
        if len(k):
            vis[k] = any_hit_shadows(self._accel, o[k], d[k], t1[k])
        k = np.flatnonzero(~plain)
        ok, dk, t1k, sk = o[k], d[k], t1[k], self_inst[k]
        blocked = np.zeros(len(k), np.bool_)
        sub, _ = self._sub[False]
        if sub is not None:
            blocked = any_hit_shadows(sub, ok, dk, t1k)
        ri = self.ri[False]
        if len(ri):
            best = np.where(blocked, -np.inf, np.inf)
            rows, objs, _, tlo = candidates(ok, dk, zero[k], t1k, best, ri,
                                            self.caches[False].box, self.convex, sk,
                                            self._self_tmin(self.caches[False].diag, dk, sk))
            if len(rows):
                hit = self._accel.occludes_object(objs, ok[rows], dk[rows], tlo, t1k[rows])
                blocked[rows[hit]] = True
        vis[k] = blocked
        return vis

    # -- shaded frames -------------------------------------------------------------------

    def _trace_tile(self, sa, o, d, t0, t1, max_depth, counters, seeds=None,
                    light_samples=LIGHT_SAMPLES_DEFAULT,
                    glossy_samples=GLOSSY_SAMPLES_DEFAULT, strata=None):
        """Radiance of a batch of camera rays; returns (radiance (n, 3), class (n,) uint8,
        primary instance (n,), continuation key (n,) uint64, tainted (n,) bool:
        :mod:`.recheck`).

        Level by level, the base tracer's stages (:func:`~..tracing.whitted.surfaces`,
        :func:`~..tracing.whitted.shadow_rays`, :func:`~..tracing.whitted.shade_paths`) on the
        hits found through the trees (:meth:`_intersect`); every ray carries its own depth
        (an exit ray skips the levels inside its object: :func:`.ray_tree.next_rays`).
        Lights with an extent and the world are sampled as the base tracer samples them
        (``seeds`` (n,) uint64 of the camera rays,
        :func:`~..tracing.soft_lights.sample_seeds`, and each node's path). With every
        object traced (no tree: all fell back) the tile is the base tracer's own. Rough
        surfaces draw the base tracer's glossy samples at a path's first rough bounce
        (``glossy_samples`` by lobe, :func:`~..tracing.glossy_rays.glossy_counts`) and one at
        deeper ones, with the base tracer's seeds (:func:`~..tracing.whitted.shade_paths`)
        and lattices (``strata``, :mod:`~..tracing.glossy_strata`)."""
        view = False
        n = len(o)
        if not len(self.ri[view]):
            return self._base_tile(sa, o, d, t0, t1, max_depth, counters, seeds,
                                   light_samples, glossy_samples, strata) + (
                np.zeros(n, np.uint64), np.zeros(n, np.bool_))
        L = len(sa.light_kind)
        ckey = np.zeros(n, np.uint64)
        taint = np.zeros(n, np.bool_)
        on_tree = np.zeros(len(sa.inst_mesh) + 1, np.bool_)  # (index -1: a miss)
        on_tree[self.ri[view]] = True
        radiance = np.zeros((n, 3))
        pclass = np.full(n, CLASS_BACKGROUND, np.uint8)
        prim_inst = np.full(n, -1, np.int32)
        src = np.arange(n, dtype=np.int32)
        weight = np.ones((n, 3))
        level = np.zeros(n, np.int64)
        self_inst = np.full(n, -1, np.int32)
        path = np.ones(n, np.int64)
        fresh = np.ones(n, np.bool_)  # no glossy samples drawn yet on the path
        tag = np.zeros(n, np.uint64)  # hashed into the node seeds below a glossy sample
        soft_on = has_soft_light(sa)
        glossy_on = has_glossy(sa)
        if (soft_on or glossy_on) and seeds is None:
            seeds = sample_seeds(np.arange(n), 0)
        first = True
        while len(src):
            nb = len(src)
            H = self._intersect(view, o, d, t0, t1, self_inst, primary=first)
            counters["rays"] = counters.get("rays", 0) + nb
            interp = np.flatnonzero(H["interp"] >= 0)
            if first:
                prim_inst[:] = H["inst"]
                pclass[:] = primary_class(H, interp)
                counters["interpolated"] = counters.get("interpolated", 0) + len(interp)
                first = False
            q = H["q"]
            qi = H["interp"][interp]
            # every ray through the base tracer's surface stage (interpolated ones as
            # misses: their arrays are written next, from the query results)
            s_inst = H["inst"]
            if len(interp):
                s_inst = s_inst.copy()
                s_inst[interp] = -1
            surf = surfaces(sa, o, d, t1, Hits(H["t"], s_inst, H["prim"], H["u"], H["v"]))
            if len(interp):
                interp_surface(sa, interp.astype(np.int64), o, d, q.P[qi], q.NS[qi], q.NG[qi],
                               q.mat[qi], surf)
            # shadow rays (their origin's own object ignored near an interpolated point)
            todo, so, sd, stm = shadow_rays(sa, surf)
            vis = np.zeros(nb * L, np.bool_)
            hs = np.full(nb, -1, np.int32)
            hs[interp] = H["inst"][interp]
            if len(todo):
                vis[todo] = ~self._occluded(so, sd, stm, hs[todo // L])
                counters["shadow"] = counters.get("shadow", 0) + len(todo)
            soft = None
            nseeds = node_seeds(seeds, src, path) ^ tag if soft_on or glossy_on else None
            if soft_on:
                def occluded(so_, sd_, st_, rows_, hs=hs):
                    pt = np.where(rows_ >= 0, rows_ // max(L, 1), -1 - rows_)
                    return self._occluded(so_, sd_, st_, hs[pt])

                soft = soft_direct(sa, surf, nseeds, light_samples, vis, occluded, counters)
            taint[src[interp]] = True
            off = np.flatnonzero(~on_tree[H["inst"]]
                                 & (weight.max(axis=1) >= tol.RI_RECHECK_WEIGHT))
            np.add.at(ckey, src[off], node_keys(path[off], H["inst"][off],
                                                vis.reshape(nb, L)[off]))
            prim_safe = np.maximum(H["prim"], 0).astype(np.int32)
            lat = None if strata is None else (
                lambda g, c, s=src, p=path, f=fresh: lattices(strata, s, p, f, g, c))
            contrib, kids, gstart, glossy = shade_paths(
                sa, Hits(H["t"], H["inst"], prim_safe, H["u"], H["v"]), surf, vis, weight,
                soft, nseeds, fresh, glossy_samples, lat)
            scatter_add(radiance, src, contrib)
            o, d, weight, src, level, self_inst, path, fresh, tag = next_rays(
                sa, kids, H["inst"], q, interp, qi, src, level, max_depth, path, fresh, tag,
                gstart, glossy, nseeds)
            t0 = np.zeros(len(o))
            t1 = np.full(len(o), np.inf)
        return radiance, pclass, prim_inst, ckey, taint

    def _base_tile(self, sa, o, d, t0, t1, max_depth, counters, seeds, light_samples,
                   glossy_samples, strata=None):
        """:meth:`_trace_tile` with no tree: the base tracer's :func:`trace`, its pixels
        bit for bit."""
        accel = self._sub[False][0]
        hits = accel.closest_hit(o, d, t0, t1)
        cc: dict = {}
        rad, _ = trace(sa, accel, o, d, t0, t1, max_depth, primary=hits, counters=cc,
                       seeds=seeds, light_samples=light_samples,
                       glossy_samples=glossy_samples, strata=strata)
        for key in ("primary", "secondary"):
            counters["rays"] = counters.get("rays", 0) + cc.get(key, 0)
        counters["shadow"] = counters.get("shadow", 0) + cc.get("shadow", 0)
        inst = np.ascontiguousarray(hits.inst, np.int32)
        cls = np.where(inst >= 0, CLASS_TRACED, CLASS_BACKGROUND).astype(np.uint8)
        return rad, cls, inst

    def render(self, scene, settings: RenderSettings, accel, progress=None,
               cancel=None) -> Frame:
        """Render ``scene``'s camera in RI_TREE mode (or its thickness view)."""
        settings = settings.validated()
        t_start = time.perf_counter()
        sa = scene.arrays()
        self._sync(sa, accel, settings)
        view = bool(settings.thickness_view)
        cache = self.caches[view]
        c0 = dict(cache.counters)
        ri_objects = int(len(self.ri[view]))
        self._ledger = Ledger(cache)
        cp = camera_params(scene.camera)
        w, h = cp.width, cp.height
        spp = int(settings.samples)
        rows_per_tile = max(1, RI_TILE_RAYS // max(1, w * spp))
        image = np.zeros((h * w, 3), np.float32)
        pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
        counters: dict = {}
        cancelled = False
        bad_total = 0
        dist = thick.auto_distance(sa, settings.thickness_distance)
        on = self.recheck and not view and settings.ri_probe_angle > 0
        cont = Continuations(w, h, spp) if on else None
        for pix, jitter, y1 in frame_batches(w, h, spp, int(settings.seed), rows_per_tile,
                                             None):
            if cancel is not None and cancel():
                cancelled = True
                break
            rows = slice(int(pix[0]), int(pix[-1]) + 1)
            o, dr, tmin, tmax = camera_rays(cp, np.tile(pix, spp), jitter.reshape(-1, 2))
            if view:
                length, cls, pinst = thickness_tile(self, sa, o, dr, tmin, tmax, counters)
                rad = thick.display(length, dist)
            else:
                gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * h)
                        + pix[None, :]).ravel()
                rad, cls, pinst, ckey, taint = self._trace_tile(sa, o, dr, tmin, tmax,
                                                   int(settings.max_depth), counters,
                                                   sample_seeds(gids, int(settings.seed)),
                                                   int(settings.light_samples),
                                                   int(settings.glossy_samples),
                                                   frame_strata(sa, int(settings.max_depth),
                                                                gids, w * h,
                                                                int(settings.seed), spp))
                if cont is not None:
                    cont.store(pix, ckey, taint)
            tile_cls = np.empty(len(pix), np.uint8)
            bad_total += accumulate(rad, pinst, spp, image[rows], tile_cls)
            # a pixel's class: that of its first sample that hit something
            c = cls.reshape(spp, len(pix))
            firsthit = np.argmax(c != CLASS_BACKGROUND, axis=0)
            pclass[rows] = c[firsthit, np.arange(len(pix))]
            if progress is not None:
                progress(y1 / h, f"RI-tree {y1}/{h} rows")
        redone = 0
        if cont is not None and not cancelled and len(self.ri[view]):
            redo = cont.flagged()
            # charged to the trees (the fallback's query time): they are why it is needed
            redone = self._timed("query", 0, retrace, sa, accel, cp, redo, spp,
                                 int(settings.seed), int(settings.max_depth),
                                 int(settings.light_samples), int(settings.glossy_samples),
                                 image, pclass, counters, cancel)
            cancelled = redone < len(redo)
        notes = []
        costs = self.last_costs = None if cancelled else self._ledger.costs()
        if self.auto_fallback and len(self.ri[view]):
            if costs is not None:
                pays = tree_pays(costs)
                notes = self.fall_back(view, self.ri[view][~pays[self.ri[view]]], scene, costs)
        self._ledger = None
        elapsed = time.perf_counter() - t_start
        counts = np.bincount(pclass, minlength=len(CLASS_NAMES))
        hit_px = max(int(np.count_nonzero(pclass != CLASS_BACKGROUND)), 1)
        cc = cache.counters
        stats = dict(
            mode="RI_TREE", view="THICKNESS" if view else "SHADED", time_s=elapsed,
            width=w, height=h, samples=spp, max_depth=int(settings.max_depth),
            interpolated_fraction=float(counts[CLASS_INTERPOLATED]) / (w * h),
            traced_fraction=float(hit_px - counts[CLASS_INTERPOLATED]) / (w * h),
            ri_objects=ri_objects, ri_traced_objects=len(self.fallback[view]), ri_notes=notes,
            samples_traced=cc["samples_traced"] - c0["samples_traced"],
            retraced_pixels=int(redone),
            cells_split=cc["cells_split"] - c0["cells_split"],
            prunes=cc["prunes"] - c0["prunes"],
            memory_mb=cache.memory_bytes / 1e6, peak_memory_mb=cache.peak_bytes / 1e6,
            cache_mb=cache.cache_bytes / 1e6, dist_thresh=cache.dist_thresh,
            ang_thresh=cache.ang_thresh_deg, depth=cache.depth,
            rays_traced=counters.get("rays", 0), shadow_rays=counters.get("shadow", 0),
            class_counts={CLASS_NAMES[k]: int(counts[k]) for k in range(len(CLASS_NAMES))},
            cancelled=cancelled, nonfinite_samples=int(bad_total),
            accelerator=getattr(accel, "name", "?"),
        )
        return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats)
