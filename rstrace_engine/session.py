"""A persistent render session: one per Blender scene, kept across frames and edits.

The session owns the :class:`~rstrace_engine.geometry.scene.Scene` and its accelerator. A new export
of the scene goes through :meth:`Session.update_scene`, which hands the new packing to the
accelerator's ``update`` so that per-mesh structures of unchanged meshes are reused and only
the top level is rebuilt. ``BASE`` mode renders with the Whitted tracer
(:func:`rstrace_engine.tracing.whitted.render`); ``INTERPOLANT`` mode with radiance
interpolants kept across frames and camera moves
(:class:`~rstrace_engine.interpolants.render.InterpolantRenderer`); ``RI_TREE`` mode with
per-object RI-trees (:class:`~rstrace_engine.ri_tree.render.RITreeRenderer`). With
``thickness_view`` set, BASE and INTERPOLANT render the thickness view exactly and RI_TREE
interpolates it.
"""

from __future__ import annotations

import logging
import time

from .accel.accelerators import create_accelerator
from .frame import Frame, RenderSettings
from .geometry.scene import Scene, SceneError
from .interpolants.render import InterpolantRenderer
from .ri_tree.render import RITreeRenderer, render_thickness_exact
from .tracing.whitted import render as whitted_render

log = logging.getLogger(__name__)

AVAILABLE_MODES = ("BASE", "INTERPOLANT", "RI_TREE")


class Session:
    """Scene + accelerator + settings, reused from frame to frame.

    ``stats`` (a dict) holds the numbers for the status line: the last frame's statistics
    plus accelerator build/update times and the scene's counts and warnings.
    """

    def __init__(self, scene: Scene, settings: RenderSettings | None = None) -> None:
        self.settings = (settings or RenderSettings()).validated()
        self.scene = scene
        self.accel = None
        self.stats: dict = {}
        self.interpolants = InterpolantRenderer()
        self.ri_tree = RITreeRenderer()  # invalidate(slots) drops edited objects' RI-trees
        self._build_accelerator()

    # -- state -------------------------------------------------------------------------

    def _build_accelerator(self, kind: str | None = None) -> None:
        sa = self.scene.arrays()
        t0 = time.perf_counter()
        self.accel = create_accelerator(kind or self.settings.accelerator, sa)
        self.stats["accel_build_s"] = time.perf_counter() - t0
        self.stats["accelerator"] = self.accel.name
        log.info("session: built %s over %d instances in %.3f s", self.accel.name,
                 len(sa.inst_mesh), self.stats["accel_build_s"])

    def update_scene(self, scene: Scene) -> None:
        """Take a new export of the scene; the accelerator reuses unchanged meshes."""
        sa = scene.arrays()  # validates and packs before anything is replaced
        self.scene = scene
        t0 = time.perf_counter()
        self.accel.update(sa)
        self.stats["accel_update_s"] = time.perf_counter() - t0
        log.info("session: accelerator updated in %.3f s", self.stats["accel_update_s"])

    def update_settings(self, settings: RenderSettings) -> None:
        """New settings; the accelerator is rebuilt only when its kind changes."""
        settings = settings.validated()
        if settings.accelerator != self.settings.accelerator:
            self._build_accelerator(settings.accelerator)  # raises before anything changes
        self.settings = settings

    # -- rendering ---------------------------------------------------------------------

    def render(self, progress=None, cancel=None) -> Frame:
        """Render the scene's camera. progress(fraction, message); cancel() -> bool.

        Raises :class:`~rstrace_engine.geometry.scene.SceneError` for a mode that is not available.
        """
        mode = self.settings.mode
        if mode not in AVAILABLE_MODES:
            raise SceneError(f"setting 'mode': {mode!r} is not available yet (available: "
                             f"{', '.join(AVAILABLE_MODES)})")
        if self.settings.thickness_view and mode != "RI_TREE":
            frame = render_thickness_exact(self.scene, self.settings, self.accel,
                                           progress=progress, cancel=cancel)
        elif mode == "RI_TREE":
            frame = self.ri_tree.render(self.scene, self.settings, self.accel,
                                        progress=progress, cancel=cancel)
        elif mode == "INTERPOLANT":
            frame = self.interpolants.render(self.scene, self.settings, self.accel,
                                             progress=progress, cancel=cancel)
        else:
            frame = whitted_render(self.scene, self.settings, accel=self.accel,
                                   progress=progress, cancel=cancel)
        frame.stats["accel_build_s"] = self.stats.get("accel_build_s", 0.0)
        if "accel_update_s" in self.stats:
            frame.stats["accel_update_s"] = self.stats["accel_update_s"]
        frame.stats["mode"] = mode
        self.stats.update(frame.stats)
        return frame
