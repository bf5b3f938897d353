"""Frame reuse: what a session keeps of its last frame to render the next one incrementally.

With the camera and the settings unchanged, a frame after an edit re-renders only its
*dirty* pixels -- pixels whose per-pixel records (:mod:`.pixel_records`) touch what the edit
changed, and pixels that used an interpolant the edit invalidated -- over a copy of the last
frame. :class:`FrameReuse` is the one home of that state: the last frame, its records, the
settings key and camera it was rendered with, the dirty and rebuilt pixels accumulated since,
and (INTERPOLANT) which kept pixels' interpolants the ray segment trees no longer track.

BASE frames also keep every node's light terms (:mod:`.light_records`): a batch that only
edits lights and the world (power, colour, position, extent, cone, adding or deleting a
light, the world's colour) dirties no pixel; the next frame first *relights* the kept
pixels (:meth:`FrameReuse.relight`: the moved lights shaded again with their own shadow
rays, then the frame recombined from the terms, bit for bit a fresh frame's) and re-traces
only what other edits made dirty. Batches that mix in other edits, a world that starts to
light, or records over their memory cap take the per-pixel records' path as before.

Under soft light (BASE, with those terms) an object edit goes further, at the level of
rays: a sample whose only rays the edit may cross are its hits' shadow rays to lights with
an extent or the world's rays (:meth:`~.pixel_records.PixelRecords.dirty_split`) is not
traced again; the next frame shades those lights (or the world) again at those nodes,
primary or secondary, through the edited scene, and recombines it (:mod:`.shadow_reshade`: of
their samples, only those that may cross an edited box are traced, the others' visibility
kept as bits). A later batch that edits lights turns the pending ones into dirty pixels.

The session drives it: :meth:`FrameReuse.take_edits` after every applied batch (with the
batch's :class:`~..geometry.edits.EditEffects` and what the interpolant cache invalidated),
:meth:`FrameReuse.plan` before a frame, :meth:`FrameReuse.relight` over its base frame (BASE)
and :meth:`FrameReuse.finish` after it.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..frame import CLASS_INTERPOLATED, CLASS_REBUILT, Frame
from ..geometry.cameras import camera_params, same_camera
from ..geometry.edits import EditEffects
from .edit_kernels import load_kernels
from .light_linking import links_shadows
from .light_nodes import RECORD_SLOTS
from .light_subset import recombine_pixels
from .pixel_records import FLAG_ALWAYS, PixelRecords
from .sample_proofs import placed_balls
from .seen_lights import any_seen
from .shadow_reshade import reshade
from .soft_lights import has_soft_light, world_lights

#: the most placed objects whose rays the re-shade tests one by one (more: the whole scene)
PLACED_MAX = 8


class FrameReuse:
    """The last frame and what the next one may keep of it (see the module doc)."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        """Keep nothing: the next frame is a full one."""
        self.frame: Frame | None = None  # the last complete frame
        self.records: PixelRecords | None = None  # its per-pixel records
        self.key = None  # the settings the frame was rendered with (Session.settings_key)
        self.camera = None  # and its camera
        self.dirty: np.ndarray | None = None  # (h * w,) bool pixels the next frame redoes
        self.rebuilt: np.ndarray | None = None  # dirty through an invalidated interpolant
        # INTERPOLANT: the serial of every interpolant id when the last frame ended, and the
        # kept pixels whose interpolant was evicted since (no longer tracked by the RSTs)
        self.snap: np.ndarray | None = None
        self.untracked: np.ndarray | None = None
        # BASE: the next frame recombines the kept pixels from their light terms, after
        # shading these light slots again
        self.relight_due = False
        self.relight_moved: set = set()
        self.relight_stats: dict = {}  # of the last relight (relit, relight_s, ...)
        # INTERPOLANT: pixels of kept interpolants that take a light edit's term without
        # being rendered again: ``(pixels (h * w,) bool, TermEdit)`` per batch
        # (interpolants/term_pixels.py), and the sample terms the last relight added
        self.term_jobs: list = []
        self.term_rows: tuple | None = None
        # BASE under soft light: the samples whose primary node shades these lights (bits)
        # and the world again (their shadow rays alone may cross an edited box), or None
        self.reshade_lights: np.ndarray | None = None
        self.reshade_world: np.ndarray | None = None
        # the same at the kept samples' secondary nodes (their order in the records)
        self.reshade_s_lights: np.ndarray | None = None
        self.reshade_s_world: np.ndarray | None = None
        self.reshade_regions: list = []  # the edited objects since: (lo, hi, c, r, tag)
        self.reshade_changed: set = set()  # and their instance slots
        # the samples of those nodes the records' queries found may cross them
        # (sample_rays.SampleCandidates), or None
        self.reshade_cand = self.reshade_s_cand = None

    def keep_only(self, frame: Frame | None) -> None:
        """A frame without records (RI_TREE, the thickness view): kept for scripts, but the
        next frame is a full one."""
        self.clear()
        self.frame = frame

    @property
    def dirty_mask(self) -> np.ndarray | None:
        """(h, w) bool: the pixels the next frame re-renders; None when it is a full frame."""
        if self.dirty is None or self.frame is None:
            return None
        return self.dirty.reshape(self.frame.pixel_class.shape).copy()

    @property
    def term_mask(self) -> np.ndarray | None:
        """(h, w) bool: the kept pixels the next frame gives a light edit's term from their
        cells (INTERPOLANT, :meth:`_term_samples`) unless it finds them dirty; None when
        it is a full frame."""
        if self.dirty is None or self.frame is None:
            return None
        out = np.zeros(len(self.dirty), bool)
        for mask, _ in self.term_jobs:
            out |= mask
        return (out & ~self.dirty).reshape(self.frame.pixel_class.shape)

    @property
    def reshade_mask(self) -> np.ndarray | None:
        """(h, w) bool: the kept pixels whose soft lights the next frame shades again at
        their primary hits (:mod:`.shadow_reshade`); None when it is a full frame."""
        if self.dirty is None or self.frame is None:
            return None
        return self.reshade_pixels.reshape(self.frame.pixel_class.shape)

    @property
    def records_bytes(self) -> int:
        return self.records.nbytes if self.records is not None else 0

    @property
    def light_records(self):
        """The last frame's :class:`~.light_records.LightRecords`, when it has them."""
        rec = self.records
        lr = rec.light if rec is not None else None
        if lr is None or lr.overflow is not None or lr.p is None:
            return None
        return lr

    @property
    def light_records_bytes(self) -> int:
        lr = self.light_records
        return lr.nbytes if lr is not None else 0

    def matches(self, key, camera) -> bool:
        """The last frame was rendered with these settings and this camera."""
        return self.key is not None and key == self.key and same_camera(camera, self.camera)

    # -- edits -------------------------------------------------------------------------

    def take_edits(self, fx, old_sa, new_sa, camera, ids, interpolants_lost: bool,
                   report, rescaled=None, terms=None, accel=None) -> None:
        """Mark the pixels an applied edit batch makes dirty.

        fx : the batch's :class:`~..geometry.edits.EditEffects`; old_sa, new_sa : the
        packings before and after it; camera : the scene's camera after it; ids : the
        interpolants the cache invalidated (None: none invalidated, or no cache);
        interpolants_lost : the frame's interpolants are all gone (the cache started over);
        rescaled : interpolants kept with their radiance rescaled (a light's power or
        colour, :mod:`~..interpolants.relight`): their pixels are dirty, not rebuilt;
        terms : the batch's :class:`~..interpolants.term_pixels.TermEdit` or None -- the
        pixels whose samples its kept cells interpolated take its term in the next frame's
        relight instead (neither dirty nor rendered). accel : the accelerator over
        ``new_sa`` (the soft samples the objects the batch placed prove blocked are not
        re-shaded where its shadow query allows it, :meth:`_placed_balls`).
        Fills ``report``'s ``full_frame``, ``dirty_pixels``, ``dirty_fraction`` and
        ``records_query_ms``.
        """
        f, rec = self.frame, self.records
        rebuilt = None
        if f is not None and f.pixel_interpolant is not None and ids is not None and len(ids):
            # pixels of invalidated interpolants (with several samples per pixel, -2: the
            # samples used different interpolants, any of which may be gone)
            pi = f.pixel_interpolant.reshape(-1)
            rebuilt = np.isin(pi, ids) | (pi == -2)
            if not fx.camera:
                self.rebuilt = rebuilt if self.rebuilt is None else self.rebuilt | rebuilt
        if (f is None or rec is None or self.dirty is None or fx.camera or interpolants_lost
                or not np.array_equal(old_sa.scene_aabb, new_sa.scene_aabb)):
            # no previous frame to keep, the camera moved, every interpolant is gone, or
            # the scene box changed (spawn offsets scale with it, so every pixel may change
            # in the last bits)
            self._full_frame(report)
            if not fx.camera and not interpolants_lost and f is not None and rec is not None:
                report.messages.append("full frame: the scene's bounding box changed")
            return
        if (fx.lights_moved or len(old_sa.light_kind) != len(new_sa.light_kind)
                or world_lights(old_sa) != world_lights(new_sa)):
            rec.drop_visibility()  # (the kept soft samples' visibility may change)
        if self._relights(fx, old_sa, new_sa):
            # light / world edits only: no pixel is dirty, the next frame relights
            self._flush_reshade()
            if f.pixel_interpolant is not None:
                # INTERPOLANT: its traced pixels are relit; the pixels of invalidated
                # interpolants, and those with interpolated samples that the edit touches,
                # are rendered again -- but for the world's colour (lighting before and
                # after), the interpolated samples whose world term was kept
                # (world_samples.py): recombined too; and the pixels of cells kept with a
                # light's term added or rescaled take it from them (``terms``: the next
                # relight's _term_samples), or are unchanged (an added light's dark cells)
                t0 = time.perf_counter()
                lr = self.light_records
                cp = camera_params(camera)
                dirty = np.zeros(rec.n_pixels, bool)
                pi = f.pixel_interpolant.reshape(-1)
                take = None
                if terms is not None:
                    if terms.renewed is not None:
                        self._renewed(terms.renewed)
                    # (samples traced, or re-rendered by every frame, take nothing)
                    traced = lr.ok | ((rec.t_flags[rec.p_combo] & FLAG_ALWAYS) != 0)
                    take, gain = terms.pixels(pi, traced, rec.spp)
                if fx.lights:
                    lit = rec.dirty_pixels(old_sa, cp, replace(fx, world=False,
                                                               world_lights=False))
                    lit &= ~lr.relit_pixels(rec.spp, rec.n_pixels)
                    if take is not None and set(fx.lights_moved) <= terms.added | terms.moved:
                        # (an added or moved light dirties every hit: its cells tell)
                        lit &= ~take
                    dirty |= lit
                if fx.world:
                    dirty |= rec.dirty_pixels(old_sa, cp, EditEffects(
                        world=True, world_lights=fx.world_lights)) & ~lr.relit_pixels(
                            rec.spp, rec.n_pixels, world=True)
                if rebuilt is not None:
                    dirty |= rebuilt
                if rescaled is not None and len(rescaled):
                    r = np.isin(pi, rescaled)
                    dirty |= r if take is None else r & ~take
                dirty |= pi == -2
                if self.untracked is not None:
                    dirty |= self.untracked
                report.records_query_ms = 1e3 * (time.perf_counter() - t0)
                self.dirty |= dirty
                if take is not None and gain.any():
                    self.term_jobs.append((gain, terms))
            _drop_sampled(self.light_records, fx, old_sa, new_sa)
            self.relight_due = True
            self.relight_moved |= set(fx.lights_moved)
            if fx.seen_regions or fx.seen_sky or any_seen(old_sa) or any_seen(new_sa):
                # a light's own surface seen is in no light term: those samples re-trace
                self.dirty |= rec.dirty_pixels(old_sa, camera_params(camera), EditEffects(
                    seen_regions=fx.seen_regions, seen_camera=fx.seen_camera,
                    seen_sky=fx.seen_sky))
            report.relight = True
            report.full_frame = False
            report.dirty_pixels = int(np.count_nonzero(self.dirty))
            report.dirty_fraction = report.dirty_pixels / max(len(self.dirty), 1)
            return
        lr = self.light_records
        if (lr is not None and lr.has_geometry
                and not np.array_equal(old_sa.mesh_tri_start, new_sa.mesh_tri_start)):
            # the kept nodes' triangle numbers would point at other triangles
            lr.forget_geometry("the scene's triangles were renumbered (a mesh added, "
                               "deleted or re-meshed): moved lights re-trace the pixels "
                               "they touch until the next full frame")
            if self.relight_due and self.relight_moved:
                # a light moved by an earlier batch still waits to be shaded again, which
                # needs the geometry just dropped; what it touches is no longer known here
                self._full_frame(report)
                report.messages.append("full frame: a moved light could not be relit "
                                       "after the scene's triangles were renumbered")
                return
        if lr is not None and lr.no_geometry is not None and fx.lights_moved:
            names = ", ".join(str(j) for j in sorted(fx.lights_moved))
            report.messages.append(f"light slot(s) {names} re-traced, not relit: "
                                   f"{lr.no_geometry}")
        reshades = self._reshades(fx, old_sa, new_sa)
        if not reshades:
            self._flush_reshade()
        t0 = time.perf_counter()
        if reshades:
            dirty = self._split(rec.dirty_split(old_sa, camera_params(camera), fx,
                                                self._placed_balls(fx, old_sa, new_sa, accel)))
            # the edited objects, old and new apart, each by its box and its sphere (grown
            # as the records grow the boxes)
            lo, hi, c, r, tag = fx.part_arrays()
            margin = rec.margin(old_sa)
            if len(lo):
                self.reshade_regions.append((lo - margin, hi + margin, c,
                                             r + float(np.linalg.norm(margin)), tag))
            self.reshade_changed |= fx.geometry
            report.reshade_pixels = int(np.count_nonzero(self.reshade_pixels))
        else:
            dirty = rec.dirty_pixels(old_sa, camera_params(camera), fx)
        if rebuilt is not None:
            dirty |= rebuilt
        if f.pixel_interpolant is not None and rescaled is not None and len(rescaled):
            dirty |= np.isin(f.pixel_interpolant.reshape(-1), rescaled)
        if f.pixel_interpolant is not None and fx.scene_content_changed:
            # pixels whose interpolant the RSTs no longer track (evicted by the memory cap
            # after the pixel was rendered), and pixels whose samples used several
            dirty |= f.pixel_interpolant.reshape(-1) == -2
            if self.untracked is not None:
                dirty |= self.untracked
        report.records_query_ms = 1e3 * (time.perf_counter() - t0)
        self.dirty |= dirty
        if lr is not None:
            # INTERPOLANT: the world and sampled terms kept of samples rendered again may
            # change (an object in their rays): traced again (world_term.kept_world_term,
            # sampled_term.add_sampled_terms)
            rays = np.flatnonzero(np.tile(self.dirty, rec.spp))
            for kept in (lr.world, lr.sampled):
                if kept is not None:
                    kept.forget(rays)
            _drop_sampled(lr, fx, old_sa, new_sa)
        report.full_frame = False
        report.dirty_pixels = int(np.count_nonzero(self.dirty))
        report.dirty_fraction = report.dirty_pixels / max(len(self.dirty), 1)

    def _reshades(self, fx, old_sa, new_sa) -> bool:
        """The batch ``fx`` may keep samples whose shadow rays alone it touches, shading
        those lights (or the world) again at their primary nodes (:mod:`.shadow_reshade`):
        a BASE frame with the per-light records' geometry, soft light, and no edit of a
        light or the world (their terms then follow the light edits' own path)."""
        lr = self.light_records
        if (lr is None or lr.partial or not lr.has_geometry or self.records.p_wnorm is None
                or self.frame.pixel_interpolant is not None):
            return False
        if fx.lights or fx.world or fx.lights_moved or fx.seen_regions or fx.seen_sky:
            return False
        if len(old_sa.light_kind) != len(new_sa.light_kind):
            return False
        return has_soft_light(old_sa) and has_soft_light(new_sa)

    def _split(self, split) -> np.ndarray:
        """The dirty pixels of :meth:`~.pixel_records.PixelRecords.dirty_split`'s ``(full,
        lights, world)``: those with a sample dirty in full; the other samples' lights and
        world to shade again are added to the pending ones."""
        full, lights, world, s_lights, s_world, cand, s_cand = split
        rec = self.records
        spp, n = rec.spp, rec.n_pixels
        dirty = full.reshape(spp, n).any(axis=0)
        keep = ~np.tile(dirty | self.dirty, spp)
        lights = np.where(keep[:, None], lights, np.uint64(0))
        world = world & keep
        s_keep = keep[rec.secondary_rays()]
        s_lights = np.where(s_keep[:, None], s_lights, np.uint64(0))
        s_world = s_world & s_keep
        if self.reshade_lights is None:
            self.reshade_lights, self.reshade_world = lights, world
            self.reshade_s_lights, self.reshade_s_world = s_lights, s_world
            self.reshade_cand, self.reshade_s_cand = cand, s_cand
        else:
            self.reshade_lights |= lights
            self.reshade_world |= world
            self.reshade_s_lights |= s_lights
            self.reshade_s_world |= s_world
            self.reshade_cand = self.reshade_cand.merged(cand)
            self.reshade_s_cand = self.reshade_s_cand.merged(s_cand)
        return dirty

    @property
    def reshade_pixels(self) -> np.ndarray:
        """(h * w,) bool: the kept pixels whose samples shade lights again next frame."""
        rec = self.records
        if self.reshade_lights is None or rec is None:
            return np.zeros(0 if rec is None else rec.n_pixels, bool)
        due = self.reshade_lights.any(axis=1) | self.reshade_world
        if len(self.reshade_s_lights):
            s_due = self.reshade_s_lights.any(axis=1) | self.reshade_s_world
            due[rec.secondary_rays()[s_due]] = True
        return due.reshape(rec.spp, -1).any(axis=0) & ~self.dirty

    def _full_frame(self, report) -> None:
        """The next frame is traced in full (nothing kept is pending)."""
        self.dirty = None
        self._no_reshade()
        self.term_jobs, self.term_rows = [], None
        report.full_frame = True
        report.dirty_pixels = -1
        report.dirty_fraction = 1.0

    def _flush_reshade(self) -> None:
        """The pending shading of lights again (:meth:`_split`) becomes dirty pixels (a
        later batch edits lights, or cannot take that path)."""
        if self.reshade_lights is not None and self.dirty is not None:
            self.dirty |= self.reshade_pixels
        self._no_reshade()

    def _no_reshade(self) -> None:
        self.reshade_lights = self.reshade_world = None
        self.reshade_s_lights = self.reshade_s_world = None
        self.reshade_regions = []
        self.reshade_changed = set()
        self.reshade_cand = self.reshade_s_cand = None

    def _placed(self, sa, accel) -> tuple | None:
        """The live objects (instance slots of ``sa``) the pending edits placed -- moved,
        added, re-meshed or shown since the records' frame: a kept sample that was
        unblocked can meet no other (:func:`~.shadow_reshade._blocked`) -- or None where
        the whole scene is queried: an accelerator whose scene query is not its objects'
        (:attr:`~..accel.interface.Accelerator.any_hit_by_object`), shadow linking (a
        ray's blockers are per light), or more than :data:`PLACED_MAX` objects."""
        if not getattr(accel, "any_hit_by_object", False) or links_shadows(sa):
            return None
        alive = np.asarray(sa.inst_alive, bool)
        live = tuple(sorted(i for i in self.reshade_changed if 0 <= i < len(alive)
                            and alive[i]))
        return live if len(live) <= PLACED_MAX else None

    @staticmethod
    def _placed_balls(fx, old_sa, new_sa, accel) -> tuple | None:
        """The world balls of the live objects the batch ``fx`` placed (moved, added,
        re-meshed, shown: :func:`~.sample_proofs.placed_balls` over ``new_sa``), which
        prove a blocked soft sample stays blocked -- or None where ``accel``'s shadow query
        is not its objects' watertight test, under shadow linking, or past
        :data:`PLACED_MAX` objects (as :meth:`_placed`)."""
        if (not getattr(accel, "any_hit_by_object", False) or links_shadows(old_sa)
                or links_shadows(new_sa)):
            return None
        alive = np.asarray(new_sa.inst_alive, bool)
        live = sorted(i for i in fx.geometry if 0 <= i < len(alive) and alive[i])
        return placed_balls(new_sa, live) if 0 < len(live) <= PLACED_MAX else None

    def _relights(self, fx, old_sa, new_sa) -> bool:
        """The batch ``fx`` edits only lights and the world, and the light terms can
        follow it: kept, and the world's samples unchanged where it lights (their seeds do
        not depend on the light slots, :func:`~.soft_lights.row_hash`, so a light added or
        deleted is one term more or less; they are never taken while it did not light)."""
        if self.light_records is None or not (fx.lights or fx.world):
            return False
        if fx.regions or fx.objects or fx.geometry or fx.meshes or fx.materials:
            return False
        if self.light_records.partial and fx.world and not (
                world_lights(old_sa) and world_lights(new_sa)):
            # INTERPOLANT: a light's power or colour (its interpolants rescaled), a moved
            # light (its interpolants invalidated by its shafts; the traced samples shaded
            # again, as BASE's), the world's colour or strength while it lights (the
            # interpolants leave its term out, the samples kept it apart); a world that
            # starts or stops lighting (every interpolant invalidated) and a background's
            # colour (the pixels that show it) take the interpolants' path
            return False
        if fx.lights_moved and links_shadows(old_sa) != links_shadows(new_sa):
            # a moved (or relinked) light is shaded again with its links (its receivers
            # read from the nodes' hit instances, its blockers in its shadow rays:
            # light_reshade), the other lights' terms kept. Shadow linking turned on or
            # off changes the query every light's shadow rays make (light_linking: the
            # first blocker's closest hit, or any hit): traced again
            return False
        if world_lights(new_sa) and not world_lights(old_sa):
            return False
        if len(new_sa.light_kind) > RECORD_SLOTS:
            return False  # (the records name slots in a byte: re-traced, LightRecords.widen)
        if fx.lights_moved and not self.light_records.has_geometry:
            return False  # (over the memory cap: moved lights re-trace, see take_edits)
        return True

    def relight(self, sa, accel, settings, base: Frame) -> Frame:
        """The base frame of an incremental BASE frame: ``base`` itself, or, after light
        edits (:meth:`take_edits`), recombined from the light terms (the moved lights
        shaded again first, with ``accel`` over ``sa``) -- bit for bit a fresh frame's."""
        lr = self.light_records
        self.relight_stats = {}
        shading = self.reshade_pixels.any()
        if not (self.relight_due or shading) or lr is None:
            return base
        t0 = time.perf_counter()
        counters: dict = {}
        moved = sorted(self.relight_moved) if self.relight_due else []
        split = counters.setdefault("split", {})
        for j in moved:
            if j < len(sa.light_kind):
                p_bits, s_bits = lr.relight(sa, accel, j, int(settings.light_samples),
                                            counters, (self.records.n_pixels,
                                                       self.camera.width))
                t1 = time.perf_counter()
                self.records.set_light_bits(j, p_bits, s_bits)
                split["light_bits"] = split.get("light_bits", 0.0) + time.perf_counter() - t1
        rec = self.records
        reshaded = 0
        if shading:
            # soft light: the lights' (and the world's) terms whose shadow rays alone an
            # object edit may cross, at the kept samples' primary nodes
            keep = ~np.tile(self.dirty, rec.spp)
            lights = np.where(keep[:, None], self.reshade_lights, np.uint64(0))
            world = self.reshade_world & keep
            reshaded = int(np.count_nonzero(self.reshade_pixels))
            t1 = time.perf_counter()
            regions = None
            if rec.p_vis is not None and self.reshade_regions:
                regions = tuple(np.ascontiguousarray(np.concatenate(r))
                                for r in zip(*self.reshade_regions, strict=True))
            elif rec.p_vis is not None:
                rec.drop_visibility()  # (no region to test the kept samples against)
            changed = self._placed(sa, accel)
            done = reshade(lr, sa, accel, lights, world, int(settings.light_samples),
                           int(settings.max_depth) > 0,
                           rec.p_vis if regions is not None else None, regions, counters,
                           changed=changed, cand=self.reshade_cand)
            rec.set_lit_at(done)
            # and at their secondary nodes (mirror and refraction hits)
            s_keep = keep[rec.secondary_rays()]
            s_lights = np.where(s_keep[:, None], self.reshade_s_lights, np.uint64(0))
            s_world = self.reshade_s_world & s_keep
            if s_lights.any() or s_world.any():
                done = reshade(lr, sa, accel, s_lights, s_world, int(settings.light_samples),
                               rec.secondary_depths() < int(settings.max_depth),
                               rec.s_vis if regions is not None else None, regions,
                               counters, secondary=True, changed=changed,
                               cand=self.reshade_s_cand)
                rec.set_lit_at(done, secondary=True)
            split["reshade"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        gain = self._term_samples(settings) if self.term_jobs else None
        split["terms"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        if not (self.relight_due or lr.partial or gain is not None):
            # an object edit's re-shade alone: the pixels whose samples shaded something
            # again recombined, every other pixel's value kept (light_subset)
            pix = np.flatnonzero(self.reshade_pixels)
            rad = base.radiance.reshape(-1, 3).copy()
            rad[pix] = recombine_pixels(lr, sa, rec.secondary_rays(), rec.spp, rec.n_pixels,
                                        pix)
        else:
            rad = lr.recombine(sa, rec.secondary_rays(), rec.spp, rec.n_pixels,
                               world=lr.partial, extra=gain)
        took = 0
        if lr.partial:  # (INTERPOLANT: its traced pixels; the others as they were)
            ok = lr.relit_pixels(rec.spp, rec.n_pixels, world=world_lights(sa))
            rad = np.where(ok[:, None], rad, base.radiance.reshape(-1, 3))
            if gain is not None:
                # the pixels that take a term and are not recombined (their world term not
                # kept apart): their value plus the mean of their samples' terms (all their
                # samples were interpolated, :meth:`_term_samples`)
                px = gain[0] % rec.n_pixels
                add = _sum_rows(px, gain[1], rec.n_pixels)
                mine = np.zeros(rec.n_pixels, bool)
                mine[px] = True
                took = int(np.count_nonzero(mine))
                mine &= ~ok
                rad[mine] = rad[mine] + add[mine] / rec.spp
        split["recombine"] = time.perf_counter() - t1
        # (relight_due stays set until the frame is finished: shading a light again and
        # recombining are idempotent, so a frame that fails is relit again next time)
        self.relight_stats = dict(relit=self.relight_due,
                                  relight_s=time.perf_counter() - t0, term_pixels=took,
                                  relit_lights=moved, reshaded_pixels=reshaded,
                                  relight_shadow_rays=counters.get("shadow", 0),
                                  relight_shadow_skipped=counters.get("shadow_skipped", 0),
                                  relight_shadow_proven=counters.get("shadow_proven", 0),
                                  relight_split_s=split)
        return Frame(rad.reshape(base.radiance.shape), base.pixel_class.copy(),
                     dict(base.stats), base.pixel_interpolant)

    def _renewed(self, renewed) -> None:
        """Cells a moved light kept, their dependencies recorded again under new serials
        (``renewed``: ``(ids, old serials, new serials)``, :func:`~..interpolants.
        moved_light.renew_dependencies`): still tracked, and still taking the terms of the
        batches before."""
        for _, te in self.term_jobs:
            te.follow(renewed)
        if self.snap is not None:
            ids, old, new = renewed
            inside = ids < len(self.snap)
            ids, old, new = ids[inside], old[inside], new[inside]
            same = self.snap[ids] == old
            self.snap[ids[same]] = new[same]

    def _term_samples(self, settings):
        """INTERPOLANT: the samples of the kept pixels that take the pending batches' terms
        (:attr:`term_jobs`) and what each gains, ``(rows (m,) int64 sample ids, value (m,
        3))`` or None (:meth:`~..interpolants.term_pixels.TermEdit.deltas`, with
        ``settings``' seed). A pixel whose term cannot be taken (its cell gone, its line
        not in it) becomes dirty -- in place: :attr:`dirty` is the array :meth:`plan`
        returned, which the frame renders. Kept in :attr:`term_rows` for :meth:`finish`
        (the samples whose world term is kept apart take theirs into its radiance there)."""
        rec = self.records
        n, spp = rec.n_pixels, rec.spp
        pi = self.frame.pixel_interpolant.reshape(-1)
        cp = camera_params(self.camera)
        rows, vals = [np.zeros(0, np.int64)], [np.zeros((0, 3))]
        for mask, te in self.term_jobs:
            pix = np.flatnonzero(mask & ~self.dirty)
            delta, good = te.deltas(cp, pix, pi[pix], spp, int(settings.seed))
            self.dirty[pix[~good]] = True
            rows.append((np.arange(spp)[:, None] * n + pix[good][None, :]).reshape(-1))
            vals.append(delta[:, good].reshape(-1, 3))
        r = np.concatenate(rows)
        v = np.concatenate(vals)
        keep = ~self.dirty[r % n]  # (a pixel a later batch could not take)
        r, v = r[keep], v[keep]
        if len(self.term_jobs) > 1:  # (a sample in several batches: their terms summed)
            r, at = np.unique(r, return_inverse=True)
            v = _sum_rows(at, v, len(r))
        self.term_rows = (r, v) if len(r) else None
        return self.term_rows

    # -- frames ------------------------------------------------------------------------

    def plan(self, key, camera, samples: int, scene_aabb, keep: bool = True,
             light_terms: tuple | None = None):
        """What the next frame renders: ``(records, pixels, base)`` -- pixels (h * w,) bool
        and the base frame to render them over, or ``None, None`` for a full frame; records
        to fill (the kept ones for an incremental frame). ``keep`` False: a full frame
        whatever changed (e.g. a new interpolant cache). ``light_terms``: ``(light slots,
        cap bytes)`` to keep the light terms of a full frame too (BASE)."""
        if (keep and self.frame is not None and self.records is not None
                and self.dirty is not None and self.matches(key, camera)):
            return self.records, self.dirty, self.frame
        self.relight_due = False
        self.relight_moved = set()
        self._no_reshade()
        self.term_jobs, self.term_rows = [], None
        rec = PixelRecords(camera.width, camera.height, samples, scene_aabb)
        if light_terms is not None:
            rec.keep_light_terms(*light_terms)
        return rec, None, None

    def finish(self, frame: Frame, records: PixelRecords, pixels, key, camera, samples: int,
               cache=None, pool0=None, sa=None) -> Frame:
        """Keep ``frame`` (rendered from :meth:`plan`'s ``records``, ``pixels``) for the
        next one; returns the frame to show, whose pixels rebuilt from invalidated
        interpolants are marked ``CLASS_REBUILT`` (the kept frame says "interpolated").
        cache, pool0 : the interpolant cache and ``(cache, next_serial, n_live)`` of its pool
        before the frame (INTERPOLANT), for :meth:`_track_interpolants`. sa : the frame's
        scene packing (BASE under soft light: the re-shade's kernels are loaded once)."""
        rebuilt = self.rebuilt if self.matches(key, camera) else None
        stored = frame
        if frame.pixel_interpolant is not None and rebuilt is not None and rebuilt.any():
            pc = frame.pixel_class.reshape(-1)
            stored = Frame(frame.radiance, pc.copy().reshape(frame.pixel_class.shape),
                           frame.stats, frame.pixel_interpolant)
            pc[rebuilt & (pc == CLASS_INTERPOLATED)] = CLASS_REBUILT
        terms, self.term_jobs, self.term_rows = self.term_rows, [], None
        if frame.stats.get("cancelled"):
            # a part-done frame: its records are incomplete, the next frame is a full one
            self.frame = self.records = self.dirty = None
            return frame
        records.finish(drop_rays=None if pixels is None else np.tile(pixels, samples))
        lr = records.light
        if terms is not None and lr is not None and lr.world is not None:
            # the samples that took a term keep it in their kept radiance (a later world
            # edit recombines them with it)
            w = lr.world.row[terms[0]]
            lr.world.rest[w[w >= 0]] += terms[1][w >= 0]
        self.relight_due = False
        self.relight_moved = set()
        self._no_reshade()
        if records.light is not None and records.light.p is not None:
            load_kernels(records, sa, camera)  # (once per process each: edit_kernels.py)
        self._track_interpolants(stored, pixels, cache, pool0)
        n = camera.width * camera.height
        self.frame, self.records, self.key, self.camera = stored, records, key, camera
        self.dirty = np.zeros(n, bool)
        self.rebuilt = np.zeros(n, bool)
        return frame

    def _track_interpolants(self, frame: Frame, pixels, cache, pool0) -> None:
        """After an INTERPOLANT frame: note the pixels whose interpolant the RSTs no longer
        track -- kept pixels whose interpolant was evicted since it was used, and, when the
        memory cap evicted anything during the frame, every pixel it interpolated (an id
        may have been freed and reused within the frame) -- so that the next content edit
        re-renders them; snapshot the serials."""
        pi = frame.pixel_interpolant
        if cache is None or pi is None:
            self.snap = self.untracked = None
            return
        pi = pi.reshape(-1)
        pool = cache.pool
        untracked = np.zeros(len(pi), bool)
        # a cache made during the frame started with serial 1 and nothing live
        s0, live0 = (pool0[1], pool0[2]) if pool0 is not None and pool0[0] is cache else (1, 0)
        evicted = (pool.next_serial - s0) - (pool.n_live - live0) > 0
        if evicted:
            rendered = np.ones(len(pi), bool) if pixels is None else pixels
            untracked |= rendered & (pi != -1)
        if pixels is not None and self.snap is not None and self.untracked is not None:
            kept = ~pixels & (pi >= 0)
            idx = pi[kept]
            n = min(len(pool.serial), len(self.snap))
            inside = idx < n
            safe = np.where(inside, idx, 0)
            gone = ~inside | ~pool.live[safe] | (pool.serial[safe] != self.snap[safe])
            untracked[np.flatnonzero(kept)[gone]] = True
            untracked |= self.untracked & ~pixels
        self.untracked = untracked
        self.snap = pool.serial.copy()


def _sum_rows(at: np.ndarray, value: np.ndarray, n: int) -> np.ndarray:
    """(n, 3): the rows of ``value`` (m, 3) summed by their index ``at`` (m,)."""
    return np.stack([np.bincount(at, weights=value[:, c], minlength=n) for c in range(3)],
                    axis=1)


def _drop_sampled(lr, fx, old_sa, new_sa) -> None:
    """Forget the kept sampled terms (:class:`~.world_samples.TermSamples`) when the batch
    ``fx`` edits a light with an extent (before or after it): its terms change."""
    if lr is None or lr.sampled is None:
        return
    for sa in (old_sa, new_sa):
        ext = np.asarray(sa.light_ext, bool)
        if any(0 <= j < len(ext) and ext[j] for j in fx.lights):
            lr.sampled = None
            return
