"""A persistent render session: one per Blender scene, kept across frames and edits.

The session owns the :class:`~rstrace_engine.geometry.scene.Scene`, its accelerator, the
interpolant cache and the last frame with its per-pixel records. Scene changes arrive as
:mod:`~rstrace_engine.geometry.edits` through :meth:`Session.apply`, or queued from any thread
by :meth:`Session.submit` for the next :meth:`~Session.apply` or :meth:`~Session.render` (a
host's UI thread hands edits to a render thread this way), or as a whole new export through
:meth:`Session.update_scene`, which diffs it against the current scene by key into the same
edits: all paths share one implementation. An edit

* is applied all or nothing (a bad edit raises :class:`SceneError` naming the object and the
  session keeps its previous state);
* updates the accelerator (only the top level when meshes are unchanged);
* invalidates the interpolants it may affect (ray segment trees and membership, in the
  interpolant cache) -- camera edits invalidate nothing;
* with the camera fixed, marks the *dirty* pixels: the next frame re-renders only those
  (the per-pixel records of :mod:`~rstrace_engine.tracing.pixel_records`) and keeps the rest
  of the previous frame. In BASE mode that frame equals a fresh one bit for bit.

``BASE`` mode renders with the Whitted tracer (:func:`rstrace_engine.tracing.whitted.render`);
``INTERPOLANT`` mode with radiance interpolants kept across frames, camera moves and edits
(:class:`~rstrace_engine.interpolants.render.InterpolantRenderer`); ``RI_TREE`` mode with
per-object RI-trees (:class:`~rstrace_engine.ri_tree.render.RITreeRenderer`), whose trees an
edit drops for the instance slots it touches; RI_TREE frames are always full frames (no
per-pixel records). With ``thickness_view`` set, BASE and INTERPOLANT render the thickness
view exactly (full frames too) and RI_TREE interpolates it.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from .accel.accelerators import create_accelerator
from .frame import AVAILABLE_MODES, CLASS_INTERPOLATED, CLASS_REBUILT, Frame, RenderSettings
from .geometry.cameras import camera_params
from .geometry.edits import (
    CameraChange,
    EditEffects,
    EditReport,
    apply_edits,
    diff_scenes,
    same_camera,
)
from .geometry.scene import Scene, SceneError
from .interpolants.render import InterpolantRenderer, render_frame
from .ri_tree.render import RITreeRenderer, render_thickness_exact
from .tracing.pixel_records import PixelRecords
from .tracing.whitted import render as whitted_render

log = logging.getLogger(__name__)

__all__ = ["AVAILABLE_MODES", "Session"]  # AVAILABLE_MODES: frame.py's, re-exported

#: material properties an RI-tree depends on (its exit paths and their gains, eligibility)
_OPTICAL = ("mat_mirror", "mat_transmission", "mat_ior", "mat_tex", "mat_model",
            "mat_specular", "mat_specular_ior", "mat_metallic", "mat_metal")


class Session:
    """Scene + accelerator + settings + caches, reused from frame to frame.

    ``stats`` (a dict) holds the numbers for the status line: the last frame's statistics
    plus accelerator build/update times and the scene's counts and warnings.
    ``last_report`` is the :class:`EditReport` of the last :meth:`apply` (or :meth:`render`)
    that applied edits. ``failed`` is None, or the message of a queued batch that could not
    be applied (sticky: the host, which counted those edits as held, drops the session).

    With ``build=False`` the constructor only keeps a copy of ``scene`` and ``settings``
    (cheap, for a UI thread); the first :meth:`apply` or :meth:`render` validates them and
    builds the accelerator, raising :class:`SceneError` there.
    """

    def __init__(self, scene: Scene, settings: RenderSettings | None = None,
                 build: bool = True) -> None:
        self.settings = settings or RenderSettings()
        self.scene = scene.copy()  # the host may go on changing its own scene object
        self.accel = None
        self.stats: dict = {}
        self.interpolants = InterpolantRenderer()
        self.frame: Frame | None = None  # the last complete frame
        self.records: PixelRecords | None = None  # its per-pixel records (BASE / INTERPOLANT)
        self.last_report: EditReport | None = None
        self._frame_key = None
        self._dirty: np.ndarray | None = None  # (h * w,) bool pixels the next frame redoes
        self._rebuilt: np.ndarray | None = None  # dirty through an invalidated interpolant
        # INTERPOLANT: the serial of every interpolant id when the last frame ended, and the
        # kept pixels whose interpolant was evicted since (no longer tracked by the RSTs)
        self._snap: np.ndarray | None = None
        self._untracked: np.ndarray | None = None
        self.ri_tree = RITreeRenderer()  # invalidate(slots) drops edited objects' RI-trees
        self.failed: str | None = None
        self._queued: list = []  # edits submitted, not applied yet
        self._queue_lock = threading.Lock()
        if build:
            self._build()

    def _build(self) -> None:
        """Validate the settings and the scene, build the accelerator (once)."""
        if self.accel is None:
            self.settings = self.settings.validated()
            self.scene.arrays()  # validated before anything is built
            self._build_accelerator()

    # -- state -------------------------------------------------------------------------

    def _build_accelerator(self, kind: str | None = None,
                           settings: RenderSettings | None = None) -> None:
        sa = self.scene.arrays()
        t0 = time.perf_counter()
        self.accel = create_accelerator(kind or self.settings.accelerator, sa,
                                        **(settings or self.settings).accelerator_options())
        self.stats["accel_build_s"] = time.perf_counter() - t0
        self.stats["accelerator"] = self.accel.name
        self._accel_memory()
        log.info("session: built %s over %d instances in %.3f s", self.accel.name,
                 len(sa.inst_mesh), self.stats["accel_build_s"])

    def _accel_memory(self) -> None:
        """The accelerator's own memory count (MB), where it keeps one."""
        mb = self.accel.stats.get("memory_mb")
        if mb is None:
            self.stats.pop("accel_memory_mb", None)
        else:
            self.stats["accel_memory_mb"] = float(mb)


    def submit(self, edits) -> None:
        """Queue ``edits`` for the next :meth:`apply` or :meth:`render`, which applies every
        queued edit, in order, before anything else. Thread-safe and cheap: runs no kernels
        (a UI thread calls it while a render thread applies and renders)."""
        edits = list(edits)
        with self._queue_lock:
            self._queued += edits

    def apply(self, edits=()) -> EditReport:
        """Apply the queued edits (:meth:`submit`) and then ``edits`` as one batch of
        :mod:`~rstrace_engine.geometry.edits`, all or nothing.

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
            queued, self._queued = self._queued, []
        edits = queued + list(edits)
        built = self.accel is not None
        try:
            self._build()
            if not edits:
                return EditReport()
            t0 = time.perf_counter()
            new_scene, fx = apply_edits(self.scene, edits)
            return self._commit(new_scene, fx, len(edits), t0)
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
        edits = diff_scenes(self.scene, scene)
        new_scene, fx = apply_edits(self.scene, edits)
        new_scene.warnings = list(scene.warnings)
        new_scene.stats = dict(scene.stats)
        return self._commit(new_scene, fx, len(edits), t0)

    def _commit(self, new_scene: Scene, fx: EditEffects, n_edits: int, t0: float
                ) -> EditReport:
        old_sa = self.scene.arrays()
        new_sa = new_scene.arrays()
        report = EditReport(edits=n_edits, kinds=dict(fx.kinds), camera_changed=fx.camera,
                            regions=len(fx.regions))
        if new_sa is not old_sa:
            t1 = time.perf_counter()
            self.accel.update(new_sa)  # (the BVH reuses unchanged mesh structures)
            self.stats["accel_update_s"] = time.perf_counter() - t1
            self._accel_memory()
        self.scene = new_scene
        self._invalidate_ri_trees(old_sa, new_sa, fx)
        ids = self._invalidate_interpolants(new_sa, fx, report)
        self._mark_dirty(old_sa, new_sa, fx, ids, report)
        report.apply_ms = 1e3 * (time.perf_counter() - t0)
        self.last_report = report
        log.info("session: %d edit(s) %s, %d interpolants invalidated, %s dirty pixels, "
                 "%.2f ms", n_edits, report.kinds, report.invalidated_interpolants,
                 report.dirty_pixels, report.apply_ms)
        return report

    def _invalidate_ri_trees(self, old_sa, new_sa, fx: EditEffects) -> None:
        """Drop the RI-trees of the instance slots the edits touched: the objects named
        (transform, geometry, deletion, visibility, materials assigned) and the objects
        using a material whose optical properties changed (a colour alone keeps them:
        trees hold geometry and exit paths only). The next RI_TREE frame also compares
        per-slot fingerprints (:func:`~.ri_tree.eligibility.instance_fingerprints`)."""
        if not self.ri_tree.caches or not (fx.objects or fx.materials):
            return
        slots = set(int(k) for k in fx.objects)
        optical = []
        n_old = len(old_sa.mat_ior)
        for m in fx.materials:
            m = int(m)
            if m >= n_old or m >= len(new_sa.mat_ior) or any(
                    not np.array_equal(getattr(old_sa, f)[m], getattr(new_sa, f)[m])
                    for f in _OPTICAL):
                optical.append(m)
        if optical:
            uses = np.isin(new_sa.inst_mat, optical)
            slot_of = np.repeat(np.arange(len(new_sa.inst_mesh)),
                                np.diff(new_sa.inst_mat_start))
            slots.update(int(k) for k in np.unique(slot_of[uses]))
        if slots:
            n = self.ri_tree.invalidate(sorted(slots))
            self.stats["ri_trees_invalidated"] = int(n)
            log.info("session: %d RI-tree(s) of %d slot(s) dropped", n, len(slots))

    def _invalidate_interpolants(self, sa, fx: EditEffects, report: EditReport):
        """Invalidate what the edits may affect in the interpolant cache (its ray segment
        trees and membership index) and move it to the edited scene; returns the ids."""
        c = self.interpolants.cache
        if c is None or not fx.scene_content_changed:
            if c is not None and c.sa is not sa:
                c.set_scene(sa, self.accel)
            return None
        t0 = time.perf_counter()
        live = c.pool.n_live
        inv = c.invalidate(fx.region_array(), set(fx.objects), set(fx.lights_moved),
                           set(fx.materials), world=fx.world,
                           light_shading=set(fx.lights) - set(fx.lights_moved))
        report.rst_query_ms = 1e3 * (time.perf_counter() - t0)
        c.set_scene(sa, self.accel)
        report.invalidated_interpolants = int(inv.count)
        if c.pool.n_live < live - int(inv.count):
            # the cache dropped more than it reported (it started over, e.g. when the
            # number of light slots changed): no pixel of the last frame can be trusted
            report.messages.append("interpolant cache started over: full frame")
            return None
        return np.asarray(inv.ids)

    def _mark_dirty(self, old_sa, new_sa, fx: EditEffects, ids, report: EditReport) -> None:
        f, rec = self.frame, self.records
        rebuilt = None
        if f is not None and f.pixel_interpolant is not None and ids is not None and len(ids):
            # pixels of invalidated interpolants (with several samples per pixel, -2: the
            # samples used different interpolants, any of which may be gone)
            pi = f.pixel_interpolant.reshape(-1)
            rebuilt = np.isin(pi, ids) | (pi == -2)
            if not fx.camera:
                self._rebuilt = rebuilt if self._rebuilt is None else self._rebuilt | rebuilt
        interp_lost = (self.settings.mode == "INTERPOLANT" and self.interpolants.cache is not None
                       and fx.scene_content_changed and ids is None)
        if (f is None or rec is None or self._dirty is None or fx.camera or interp_lost
                or not np.array_equal(old_sa.scene_aabb, new_sa.scene_aabb)):
            # no previous frame to keep, the camera moved, or the scene box changed (spawn
            # offsets scale with it, so every pixel may change in the last bits)
            self._dirty = None
            report.full_frame = True
            report.dirty_pixels = -1
            report.dirty_fraction = 1.0
            if not fx.camera and f is not None and rec is not None:
                report.messages.append("full frame: the scene's bounding box changed")
            return
        t0 = time.perf_counter()
        dirty = rec.dirty_pixels(old_sa, camera_params(self.scene.camera), fx)
        if rebuilt is not None:
            dirty |= rebuilt
        if f.pixel_interpolant is not None and fx.scene_content_changed:
            # pixels whose interpolant the RSTs no longer track (evicted by the memory cap
            # after the pixel was rendered), and pixels whose samples used several
            dirty |= f.pixel_interpolant.reshape(-1) == -2
            if self._untracked is not None:
                dirty |= self._untracked
        report.records_query_ms = 1e3 * (time.perf_counter() - t0)
        self._dirty |= dirty
        report.full_frame = False
        report.dirty_pixels = int(np.count_nonzero(self._dirty))
        report.dirty_fraction = report.dirty_pixels / max(len(self._dirty), 1)

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

    def _track_interpolants(self, frame: Frame, pixels, pool0) -> None:
        """After an INTERPOLANT frame: note the pixels whose interpolant the RSTs no longer
        track -- kept pixels whose interpolant was evicted since it was used, and, when the
        memory cap evicted anything during the frame, every pixel it interpolated (an id
        may have been freed and reused within the frame) -- so that the next content edit
        re-renders them; snapshot the serials."""
        c = self.interpolants.cache
        pi = frame.pixel_interpolant
        if c is None or pi is None:
            self._snap = self._untracked = None
            return
        pi = pi.reshape(-1)
        pool = c.pool
        untracked = np.zeros(len(pi), bool)
        # a cache made during the frame started with serial 1 and nothing live
        s0, live0 = (pool0[1], pool0[2]) if pool0 is not None and pool0[0] is c else (1, 0)
        evicted = (pool.next_serial - s0) - (pool.n_live - live0) > 0
        if evicted:
            rendered = np.ones(len(pi), bool) if pixels is None else pixels
            untracked |= rendered & (pi != -1)
        if pixels is not None and self._snap is not None and self._untracked is not None:
            kept = ~pixels & (pi >= 0)
            idx = pi[kept]
            n = min(len(pool.serial), len(self._snap))
            inside = idx < n
            safe = np.where(inside, idx, 0)
            gone = ~inside | ~pool.live[safe] | (pool.serial[safe] != self._snap[safe])
            untracked[np.flatnonzero(kept)[gone]] = True
            untracked |= self._untracked & ~pixels
        self._untracked = untracked
        self._snap = pool.serial.copy()

    @property
    def dirty_mask(self) -> np.ndarray | None:
        """(h, w) bool: the pixels the next frame re-renders; None when it is a full frame."""
        if self._dirty is None or self.frame is None:
            return None
        return self._dirty.reshape(self.frame.pixel_class.shape).copy()

    @property
    def records_bytes(self) -> int:
        """Memory of the per-pixel records of the last frame (bytes)."""
        return self.records.nbytes if self.records is not None else 0

    # -- rendering ---------------------------------------------------------------------

    def _key(self) -> tuple:
        s, cam = self.settings, self.scene.camera
        return (s.mode, s.samples, s.seed, s.max_depth, s.epsilon, s.depth_cap,
                s.accelerator, tuple(sorted(s.accelerator_options().items())),
                cam.matrix.tobytes(), cam.kind, cam.lens, cam.sensor_width,
                cam.sensor_height, cam.sensor_fit, cam.shift_x, cam.shift_y, cam.clip_start,
                cam.clip_end, cam.ortho_scale, cam.width, cam.height)

    def render(self, camera=None, progress=None, cancel=None) -> Frame:
        """Render through ``camera`` (default: the scene's). progress(fraction, message);
        cancel() -> bool.

        The queued edits are applied first (:meth:`apply`); then a ``camera`` other than
        the scene's (:func:`~rstrace_engine.geometry.edits.same_camera`) is applied as a
        :class:`~rstrace_engine.geometry.edits.CameraChange` (``last_report`` says
        ``camera_changed``). With the camera and settings unchanged since the last frame,
        only the pixels the edits since then made dirty are re-rendered (BASE and
        INTERPOLANT; RI_TREE frames and thickness views are always full frames). Raises
        :class:`~rstrace_engine.geometry.scene.SceneError` for a mode that is not available.
        """
        self.apply()
        if camera is not None and not same_camera(camera, self.scene.camera):
            self.apply([CameraChange(camera)])
        mode = self.settings.mode
        if mode not in AVAILABLE_MODES:
            raise SceneError(f"setting 'mode': {mode!r} is not available yet (available: "
                             f"{', '.join(AVAILABLE_MODES)})")
        if mode == "RI_TREE" or self.settings.thickness_view:
            return self._render_full(mode, progress, cancel)
        key = self._key()
        sa = self.scene.arrays()
        cam = self.scene.camera
        new_cache = False
        if mode == "INTERPOLANT":
            cache, new_cache = self.interpolants.prepare(sa, self.settings, self.accel)
        incremental = (not new_cache and self.frame is not None and self.records is not None
                       and self._dirty is not None and key == self._frame_key)
        if incremental:
            records = self.records
            pixels = self._dirty
        else:
            records = PixelRecords(cam.width, cam.height, self.settings.samples, sa.scene_aabb)
            pixels = None
        c0 = self.interpolants.cache
        pool0 = (c0, c0.pool.next_serial, c0.pool.n_live) if c0 is not None else None
        if mode == "INTERPOLANT":
            frame = render_frame(cache, self.scene, self.settings, progress=progress,
                                 cancel=cancel, records=records, pixels=pixels,
                                 base=self.frame if incremental else None)
            frame.stats["interpolated_pct"] = 100.0 * frame.stats["interpolated_fraction"]
        else:
            frame = whitted_render(self.scene, self.settings, accel=self.accel,
                                   progress=progress, cancel=cancel, records=records,
                                   pixels=pixels, base=self.frame if incremental else None)
        rebuilt = self._rebuilt if key == self._frame_key else None
        stored = frame
        if mode == "INTERPOLANT" and rebuilt is not None and rebuilt.any():
            # pixels of invalidated interpolants, interpolated again: "rebuilt after an
            # edit" (magenta) in this frame; the kept frame says "interpolated"
            pc = frame.pixel_class.reshape(-1)
            stored = Frame(frame.radiance, pc.copy().reshape(frame.pixel_class.shape),
                           frame.stats, frame.pixel_interpolant)
            pc[rebuilt & (pc == CLASS_INTERPOLATED)] = CLASS_REBUILT
        if frame.stats.get("cancelled"):
            # a part-done frame: its records are incomplete, the next frame is a full one
            self.frame = self.records = self._dirty = None
        else:
            records.finish(drop_rays=None if pixels is None
                           else np.tile(pixels, self.settings.samples))
            self._track_interpolants(stored, pixels if incremental else None, pool0)
            self.frame, self.records, self._frame_key = stored, records, key
            self._dirty = np.zeros(cam.width * cam.height, bool)
            self._rebuilt = np.zeros(cam.width * cam.height, bool)
        n = cam.width * cam.height
        frame.stats["incremental"] = bool(incremental)
        frame.stats["dirty_pixels"] = int(np.count_nonzero(pixels)) if incremental else n
        return self._finish_stats(frame, mode)

    def _render_full(self, mode: str, progress, cancel) -> Frame:
        """An RI_TREE frame or a thickness view: always a full frame, without per-pixel
        records (the next BASE / INTERPOLANT frame is a full one too)."""
        if mode != "RI_TREE":
            frame = render_thickness_exact(self.scene, self.settings, self.accel,
                                           progress=progress, cancel=cancel)
        else:
            frame = self.ri_tree.render(self.scene, self.settings, self.accel,
                                        progress=progress, cancel=cancel)
        self.frame = None if frame.stats.get("cancelled") else frame
        self.records = self._dirty = self._rebuilt = None
        self._snap = self._untracked = None
        self._frame_key = None
        cam = self.scene.camera
        frame.stats["incremental"] = False
        frame.stats["dirty_pixels"] = cam.width * cam.height
        return self._finish_stats(frame, mode)

    def _finish_stats(self, frame: Frame, mode: str) -> Frame:
        n = frame.pixel_class.size
        frame.stats["dirty_fraction"] = frame.stats["dirty_pixels"] / max(n, 1)
        frame.stats["records_mb"] = self.records_bytes / 1e6
        frame.stats["accel_build_s"] = self.stats.get("accel_build_s", 0.0)
        if "accel_update_s" in self.stats:
            frame.stats["accel_update_s"] = self.stats["accel_update_s"]
        if "accel_memory_mb" in self.stats:
            frame.stats["accel_memory_mb"] = self.stats["accel_memory_mb"]
        frame.stats["mode"] = mode
        self.stats.update(frame.stats)
        return frame
