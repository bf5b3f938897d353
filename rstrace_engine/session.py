"""A persistent render session: one per Blender scene, kept across frames and edits.

The session owns the :class:`~rstrace_engine.geometry.scene.Scene`, its accelerator, the
interpolant and RI-tree caches and the last frame (:class:`~.tracing.frame_reuse.FrameReuse`).
Scene changes arrive as :mod:`~rstrace_engine.geometry.edits`: queued by :meth:`Session.submit`
(cheap, from any thread) and applied by the next :meth:`Session.apply` or
:meth:`Session.render`, or given to :meth:`Session.apply` directly; a whole new export goes
through :meth:`Session.update_scene`, which diffs it into the same edits
(:func:`~rstrace_engine.geometry.edits.diff_scenes`, the core's one scene diff). An edit batch

* is applied all or nothing (a bad edit raises :class:`SceneError` naming the object and the
  session keeps its previous state);
* yields its :class:`~rstrace_engine.geometry.edits.EditEffects` once, which are handed down,
  one call each: the accelerator (only the top level when meshes are unchanged), the
  interpolant cache (its ray segment trees and membership find what to invalidate), the
  RI-trees (the edited objects' trees dropped) and the frame reuse (with the camera fixed,
  the *dirty* pixels: the next frame re-renders only those and keeps the rest of the
  previous frame; in BASE mode that frame equals a fresh one bit for bit). Camera edits
  invalidate nothing.

``BASE`` mode renders with the Whitted tracer (:func:`rstrace_engine.tracing.whitted.render`);
``INTERPOLANT`` mode with radiance interpolants kept across frames, camera moves and edits
(:class:`~rstrace_engine.interpolants.render.InterpolantRenderer`); ``RI_TREE`` mode with
per-object RI-trees (:class:`~rstrace_engine.ri_tree.render.RITreeRenderer`); RI_TREE frames
are always full frames (no per-pixel records). With ``thickness_view`` set, BASE and
INTERPOLANT render the thickness view exactly (full frames too) and RI_TREE interpolates it.
"""

from __future__ import annotations

import logging
import threading
import time

from .accel.accelerators import create_accelerator
from .cancel import Cancelled, bound
from .frame import AVAILABLE_MODES, Frame, RenderSettings
from .geometry.cameras import same_camera
from .geometry.edits import CameraChange, EditEffects, EditReport, apply_edits, diff_scenes
from .geometry.lights import seen_extent
from .geometry.scene import Camera, Scene, SceneError
from .interpolants.render import InterpolantRenderer
from .ri_tree.render import RITreeRenderer, render_thickness_exact
from .tracing.frame_reuse import FrameReuse
from .tracing.light_linking import links_shadows
from .tracing.soft_lights import has_soft_light
from .tracing.whitted import render as whitted_render

log = logging.getLogger(__name__)

__all__ = ["AVAILABLE_MODES", "Session"]  # AVAILABLE_MODES: frame.py's, re-exported

#: a frame's ``relight_off`` with the records' cap at 0
RELIGHT_OFF = ("setting 'relight_memory_mb' is 0: no per-light records, light edits re-trace "
               "the pixels they touch")


class Session:
    """Scene + accelerator + settings + caches, reused from frame to frame.

    ``stats`` (a dict) holds the numbers for the status line: the last frame's statistics
    plus accelerator build/update times and the scene's counts and warnings.
    ``last_report`` is the :class:`EditReport` of the last :meth:`apply` (or :meth:`render`)
    that applied edits. ``failed`` is None, or the message of a queued batch that could not
    be applied (sticky: the host, which counted those edits as held, drops the session).

    build : False defers validating, packing and the accelerator to the first
    :meth:`apply` or :meth:`render` (a host's main thread makes the session, its render
    thread builds it; a bad scene then raises there).
    """

    #: Keep every BASE frame's per-light terms (:mod:`.tracing.light_records`), so that
    #: light and world edits relight instead of tracing: ``None`` (auto) from the session's
    #: first light or world edit on (the terms cost a full frame about 20% more time and 25
    #: bytes per ray-tree node and light: a session that never edits a light does not pay;
    #: the frame after its first light edit is a full one) -- and in BASE from the first
    #: frame on where the scene has soft light (a light with an extent or a world that
    #: lights: object edits then shade those lights again at the kept pixels instead of
    #: tracing them, :mod:`.tracing.shadow_reshade`; on *studio* at 640x480 no measurable
    #: first-frame time, 36 MB, docs/bench-edit.md), ``True`` always, ``False`` never.
    #: In INTERPOLANT mode the same switch makes the interpolants' samples keep per-light
    #: shares, so a light's power or colour rescales them (:mod:`.interpolants.relight`),
    #: and the frame's traced samples keep the per-light terms, so its traced pixels are
    #: recombined as BASE's are.
    light_terms: bool | None = None
    #: Where the BVH takes unchanged meshes' trees from and leaves its own
    #: (:class:`~.accel.accelerators.KeptBVHs`; the add-on gives its sessions the process's
    #: ``KEPT``, so a new session over unchanged meshes builds no mesh BVH); None: none.
    kept_bvhs = None

    def __init__(self, scene: Scene, settings: RenderSettings | None = None,
                 build: bool = True) -> None:
        self.settings = settings or RenderSettings()
        self.scene = scene.copy()  # the host may go on changing its own scene object
        self.accel = None
        self.stats: dict = {}
        self.interpolants = InterpolantRenderer()
        self.ri_tree = RITreeRenderer()
        self.reuse = FrameReuse()
        self.last_report: EditReport | None = None
        self.failed: str | None = None
        self._lights_edited = False
        self._terms_kept = False  # whether the kept frame was asked for its light terms
        self._queue: list = []
        self._queue_lock = threading.Lock()
        if build:
            self._build()

    # -- state -------------------------------------------------------------------------

    @property
    def frame(self) -> Frame | None:
        """The last complete frame."""
        return self.reuse.frame

    @property
    def records(self):
        """The per-pixel records of the last frame (BASE / INTERPOLANT), or None."""
        return self.reuse.records

    @property
    def dirty_mask(self):
        """(h, w) bool: the pixels the next frame re-renders; None when it is a full frame."""
        return self.reuse.dirty_mask

    @property
    def reshade_mask(self):
        """(h, w) bool: kept pixels (not in :attr:`dirty_mask`) whose soft lights' terms the
        next frame shades again, their shadow rays alone touched by object edits; None when
        it is a full frame."""
        return self.reuse.reshade_mask

    def relights_only(self, camera: Camera | None = None) -> bool:
        """Whether the next frame (through ``camera``, default the scene's) only relights
        the kept one from its per-light records (BASE light edits, no dirty pixel): a
        viewport shows it without a coarse preview first."""
        r = self.reuse
        return (self.settings.mode == "BASE" and not self._queue and r.relight_due
                and r.dirty is not None and not r.dirty.any() and r.frame is not None
                and r.matches(self.settings_key(), camera or self.scene.camera))

    @property
    def records_bytes(self) -> int:
        """Memory of the per-pixel records of the last frame (bytes)."""
        return self.reuse.records_bytes

    def _build_accelerator(self, kind: str | None = None,
                           settings: RenderSettings | None = None, cancel=None) -> None:
        sa = self.scene.arrays()
        t0 = time.perf_counter()
        self.accel = create_accelerator(kind or self.settings.accelerator, sa, cancel,
                                        self.kept_bvhs,
                                        **(settings or self.settings).accelerator_options())
        self.stats["accel_build_s"] = time.perf_counter() - t0
        self.stats["accelerator"] = self.accel.name
        self._accel_memory()
        log.info("session: built %s over %d instances in %.3f s", self.accel.name,
                 len(sa.inst_mesh), self.stats["accel_build_s"])

    def _build(self, cancel=None) -> None:
        """Validate the settings and the scene, build the accelerator (once; ``cancel``:
        :meth:`apply`)."""
        if self.accel is None:
            self.settings = self.settings.validated()
            self.scene.arrays()  # validated before anything is built
            self._build_accelerator(cancel=cancel)

    def _accel_memory(self) -> None:
        """The accelerator's own memory count (MB), where it keeps one."""
        mb = self.accel.stats.get("memory_mb")
        if mb is None:
            self.stats.pop("accel_memory_mb", None)
        else:
            self.stats["accel_memory_mb"] = float(mb)

    # -- edits -------------------------------------------------------------------------

    def submit(self, edits) -> None:
        """Queue ``edits`` for the next :meth:`apply` or :meth:`render`, which applies every
        queued edit, in order, before anything else. Thread-safe and cheap: runs no kernels
        (a UI thread calls it while a render thread applies and renders)."""
        edits = list(edits)
        with self._queue_lock:
            self._queue += edits

    def apply(self, edits=(), cancel=None) -> EditReport:
        """Apply the queued edits (:meth:`submit`) and then ``edits`` as one batch of
        :mod:`~rstrace_engine.geometry.edits`, all or nothing.

        ``cancel``: a :class:`~rstrace_engine.cancel.CancelFlag` that the accelerator's
        build (the first, or its update for the batch) polls; set, the build stops and
        :class:`~rstrace_engine.cancel.Cancelled` is raised with the session as it was (the
        queued edits queued again, not failed).

        Raises :class:`SceneError` (naming the object) for a bad edit; the session then
        keeps its previous state. When the batch held queued edits (or the session could
        not be built), ``failed`` is set first: the host already counts those edits as held,
        so it must drop the session; a failed session refuses every later apply and render
        (:class:`SceneError` with the same message). Returns an :class:`EditReport` (empty,
        and ``last_report`` left as it is, when there was nothing to apply).
        """
        if self.failed is not None:
            raise SceneError(self.failed)
        with self._queue_lock:
            queued, self._queue = self._queue, []
        edits = queued + list(edits)
        built = self.accel is not None
        try:
            self._build(cancel)
            if not edits:
                return EditReport()
            t0 = time.perf_counter()
            new_scene, fx = apply_edits(self.scene, edits)
            return self._commit(new_scene, fx, len(edits), t0, cancel)
        except Cancelled:
            with self._queue_lock:
                self._queue[:0] = queued
            raise
        except BaseException as exc:
            if queued or not built:
                self.failed = str(exc) if isinstance(exc, SceneError) else (
                    f"internal error: {type(exc).__name__}: {exc}")
            raise

    def update_scene(self, scene: Scene) -> EditReport:
        """Take a new export of the whole scene: it is diffed against the current one by
        key (:func:`~rstrace_engine.geometry.edits.diff_scenes`) and applied as edits."""
        t0 = time.perf_counter()
        scene.arrays()  # a bad export is refused before anything is compared
        self._build()
        edits = diff_scenes(self.scene, scene)
        new_scene, fx = apply_edits(self.scene, edits)
        new_scene.warnings = list(scene.warnings)
        new_scene.stats = dict(scene.stats)
        return self._commit(new_scene, fx, len(edits), t0)

    def _commit(self, new_scene: Scene, fx: EditEffects, n_edits: int, t0: float,
                cancel=None) -> EditReport:
        """The new scene and the batch's effects, handed down once to each structure."""
        old_sa = self.scene.arrays()
        new_sa = new_scene.arrays()
        report = EditReport(edits=n_edits, kinds=dict(fx.kinds), camera_changed=fx.camera,
                            regions=len(fx.regions))
        if new_sa is not old_sa:
            t1 = time.perf_counter()
            with bound(self.accel, cancel):  # (a cancelled update changes nothing)
                self.accel.update(new_sa)  # (the BVH reuses unchanged mesh structures)
            self.stats["accel_update_s"] = time.perf_counter() - t1
            self._accel_memory()
        self.scene = new_scene
        if fx.lights or fx.world:
            self._lights_edited = True
        dropped = self.ri_tree.take_edits(fx, old_sa, new_sa)
        if dropped:
            self.stats["ri_trees_invalidated"] = int(dropped)
        inv = self.interpolants.take_edits(fx, new_sa, self.accel)
        ids = None
        if inv is not None and fx.scene_content_changed:
            report.rst_query_ms = inv.query_ms  # (the query; moving the cache is apply_ms's)
            report.invalidated_interpolants = int(inv.count)
            if inv.rescaled is not None:
                report.rescaled_interpolants = len(inv.rescaled)
                report.rescale_invalidated = int(inv.rescale_broken)
            if inv.restarted:
                report.messages.append("interpolant cache started over: full frame")
            else:
                ids = inv.ids
        lost = (inv is not None and inv.restarted and self.settings.mode == "INTERPOLANT")
        self.reuse.take_edits(fx, old_sa, new_sa, self.scene.camera, ids, lost, report,
                              rescaled=None if inv is None else inv.rescaled,
                              terms=None if inv is None else inv.terms, accel=self.accel)
        report.apply_ms = 1e3 * (time.perf_counter() - t0)
        self.last_report = report
        log.info("session: %d edit(s) %s, %d interpolants invalidated, %s dirty pixels, "
                 "%.2f ms", n_edits, report.kinds, report.invalidated_interpolants,
                 report.dirty_pixels, report.apply_ms)
        return report

    def update_settings(self, settings: RenderSettings) -> None:
        """New settings; the accelerator is rebuilt only when its kind (or the visibility
        field's directions / tiles) changes."""
        settings = settings.validated()
        if self.accel is None:  # (not built yet: the first apply or render builds it)
            self.settings = settings
            return
        if (settings.accelerator != self.settings.accelerator
                or settings.accelerator_options() != self.settings.accelerator_options()
                and settings.accelerator == "VISIBILITY_FIELD"):
            # raises before anything changes
            self._build_accelerator(settings.accelerator, settings)
            self.interpolants.reset()
        self.settings = settings

    # -- rendering ---------------------------------------------------------------------

    def settings_key(self) -> tuple:
        """What of the settings a kept frame depends on (its camera is compared apart,
        with :func:`~rstrace_engine.geometry.cameras.same_camera`)."""
        s = self.settings
        return (s.mode, s.samples, s.seed, s.max_depth, s.epsilon, s.depth_cap,
                s.light_samples, s.glossy_samples, s.accelerator,
                s.interpolant_fallback if s.mode == "INTERPOLANT" else None,
                tuple(sorted(s.accelerator_options().items())))

    def render(self, camera: Camera | None = None, progress=None, cancel=None) -> Frame:
        """Render through ``camera`` (default: the scene's). progress(fraction, message);
        cancel() -> bool.

        The queued edits are applied first (:meth:`apply`); then a ``camera`` other than
        the scene's (:func:`~rstrace_engine.geometry.cameras.same_camera`) is applied as a
        :class:`~rstrace_engine.geometry.edits.CameraChange` (``last_report`` says
        ``camera_changed``). With
        the camera and settings unchanged since the last frame, only the pixels the edits
        since then made dirty are re-rendered (BASE and INTERPOLANT; RI_TREE frames and
        thickness views are always full frames). Raises
        :class:`~rstrace_engine.geometry.scene.SceneError` for a mode that is not available.
        """
        self.apply()
        if camera is not None and not same_camera(camera, self.scene.camera):
            self.apply([CameraChange(camera)])
        mode = self.settings.mode
        if mode not in AVAILABLE_MODES:
            raise SceneError(f"setting 'mode': {mode!r} is not available yet (available: "
                             f"{', '.join(AVAILABLE_MODES)})")
        if mode != "BASE" and links_shadows(self.scene.arrays()):
            self.scene.warn(f"shadow linking (blocker collections) is modelled in BASE mode "
                            f"only: in {mode} mode every object casts every light's shadow")
        if mode == "RI_TREE":
            seen = [li.name for li in self.scene.lights
                    if li is not None and seen_extent(li) is not None]
            if seen:
                self.scene.warn(f"lights seen directly ({', '.join(sorted(seen))}): their "
                                f"own surfaces are shown to camera, mirror and refraction "
                                f"rays in BASE and INTERPOLANT mode; RI_TREE mode shows "
                                f"them only in tiles it traces without RI-trees")
        if mode == "RI_TREE" or self.settings.thickness_view:
            return self._render_full(mode, progress, cancel)
        key = self.settings_key()
        sa = self.scene.arrays()
        cam = self.scene.camera
        new_cache = False
        if mode == "INTERPOLANT":
            cache, new_cache = self.interpolants.prepare(sa, self.settings, self.accel)
            # samples keep per-light shares: light power / colour edits rescale interpolants
            cache.keep_light_terms(self._keeps_light_terms(),
                                   float(self.settings.relight_memory_mb))
        terms = None
        keep = not new_cache
        relight_off = self.settings.relight_memory_mb == 0.0
        if self._keeps_light_terms() and not relight_off:
            # per-light records: light edits relight (tracing.light_records; INTERPOLANT:
            # its traced samples); a kept frame without them cannot be relit: this one is a
            # full frame
            terms = (len(sa.light_kind), 1e6 * float(self.settings.relight_memory_mb),
                     mode == "INTERPOLANT")
            keep = keep and self._terms_kept
        records, pixels, base = self.reuse.plan(key, cam, self.settings.samples,
                                                sa.scene_aabb, keep=keep,
                                                light_terms=terms)
        if pixels is None:
            self._terms_kept = terms is not None
        c0 = self.interpolants.cache
        pool0 = (c0, c0.pool.next_serial, c0.pool.n_live) if c0 is not None else None
        if pixels is not None:
            base = self.reuse.relight(sa, self.accel, self.settings, base)
        if mode == "INTERPOLANT":
            frame = self.interpolants.render(self.scene, self.settings, self.accel,
                                             progress=progress, cancel=cancel,
                                             records=records, pixels=pixels, base=base)
        else:
            frame = whitted_render(self.scene, self.settings, accel=self.accel,
                                   progress=progress, cancel=cancel, records=records,
                                   pixels=pixels, base=base)
        if pixels is not None:
            frame.stats.update(self.reuse.relight_stats)
        if mode == "BASE" and self._keeps_light_terms() and relight_off:
            frame.stats["relight_off"] = RELIGHT_OFF
        if mode == "INTERPOLANT":
            c = self.interpolants.cache
            frame.stats["interpolant_shares_mb"] = c.samples.share_bytes / 1e6
            if c.shares_overflow is not None:
                frame.stats["relight_off"] = c.shares_overflow
            elif self._keeps_light_terms() and relight_off:
                frame.stats["relight_off"] = RELIGHT_OFF
        frame = self.reuse.finish(frame, records, pixels, key, cam, self.settings.samples,
                                  self.interpolants.cache, pool0, sa)
        n = cam.width * cam.height
        frame.stats["incremental"] = pixels is not None
        frame.stats["dirty_pixels"] = int(pixels.sum()) if pixels is not None else n
        return self._finish_stats(frame, mode)

    def _keeps_light_terms(self) -> bool:
        if self.light_terms is not None:
            return bool(self.light_terms)
        return self._lights_edited or (self.settings.mode == "BASE"
                                       and has_soft_light(self.scene.arrays()))

    @property
    def starts_light_terms(self) -> bool:
        """Whether the next BASE frame is a full one because it starts keeping the per-light
        terms (:attr:`light_terms`; the kept frame has none)."""
        return (self.settings.mode == "BASE" and self._keeps_light_terms()
                and not self._terms_kept and self.reuse.frame is not None)

    def _render_full(self, mode: str, progress, cancel) -> Frame:
        """An RI_TREE frame or a thickness view: always a full frame, without per-pixel
        records (the next BASE / INTERPOLANT frame is a full one too)."""
        if mode != "RI_TREE":
            frame = render_thickness_exact(self.scene, self.settings, self.accel,
                                           progress=progress, cancel=cancel)
        else:
            frame = self.ri_tree.render(self.scene, self.settings, self.accel,
                                        progress=progress, cancel=cancel)
        self.reuse.keep_only(None if frame.stats.get("cancelled") else frame)
        cam = self.scene.camera
        frame.stats["incremental"] = False
        frame.stats["dirty_pixels"] = cam.width * cam.height
        return self._finish_stats(frame, mode)

    def _finish_stats(self, frame: Frame, mode: str) -> Frame:
        n = frame.pixel_class.size
        frame.stats["dirty_fraction"] = frame.stats["dirty_pixels"] / max(n, 1)
        frame.stats["records_mb"] = self.records_bytes / 1e6
        frame.stats["light_records_mb"] = self.reuse.light_records_bytes / 1e6
        lr = self.records.light if self.records is not None else None
        if lr is not None and lr.overflow is not None:
            frame.stats["relight_off"] = lr.overflow
        elif lr is not None and lr.no_geometry is not None:
            frame.stats["relight_moves_off"] = lr.no_geometry
        frame.stats["accel_build_s"] = self.stats.get("accel_build_s", 0.0)
        if "accel_update_s" in self.stats:
            frame.stats["accel_update_s"] = self.stats["accel_update_s"]
        if "accel_memory_mb" in self.stats:
            frame.stats["accel_memory_mb"] = self.stats["accel_memory_mb"]
        frame.stats["mode"] = mode
        self.stats.update(frame.stats)
        return frame
