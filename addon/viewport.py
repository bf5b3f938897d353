"""The rendered viewport: ``view_update`` and ``view_draw`` of the engine.

* ``view_update`` (main thread) hands ``depsgraph.updates`` to :func:`.sync.sync`, which
  queues their edits on the scene's core session (a new session is made, not built, here),
  and wakes the render worker; updates that cannot change the image (selection, colour
  management, frame and other scene-only settings) queue nothing and restart nothing.
* ``view_draw`` (main thread) builds the camera from ``region_data`` (view and window
  matrices: perspective, orthographic and camera views, lens shift, zoom) and the render
  border, restarts the worker when they changed (navigation calls only ``view_draw``), and
  draws the newest image with the ``gpu`` module: a float ``GPUTexture`` of scene-linear
  pixels through Blender's display-space shader, so colour management is Blender's and
  never restarts anything.
* The worker (:class:`rstrace_engine.interactive.ViewportWorker`) is handed the session and
  has it apply its queued edits and render, off the main thread under
  ``runtime.RENDER_LOCK`` (never concurrently with an F12 render, which shares the scene's
  session); it never touches ``bpy`` and calls no add-on code. It only sets a flag when an
  image is ready; a main-thread timer turns that into a redraw.
* :meth:`ViewportRenderer.free` stops and joins the worker: called when Blender frees the
  engine (leaving rendered shading, closing the file, switching engine), and for every
  viewport on file load, add-on unregister, and when the scene's engine is switched.

Layer: imports ``session``, ``sync``, ``cameras``, ``properties``, ``runtime``, ``kernels``;
imported by ``engine`` only.
"""

from __future__ import annotations

import logging
import threading
import weakref
from dataclasses import replace

import bpy
import numpy as np

from rstrace_engine.geometry.cameras import same_camera
from rstrace_engine.geometry.scene import SceneError
from rstrace_engine.interactive import ViewImage, ViewportWorker

from . import cameras, kernels, properties, runtime, session, sync

log = logging.getLogger(__name__)

#: Every live viewport renderer (weakly), so file load / unregister can stop them all.
_LIVE: weakref.WeakSet = weakref.WeakSet()
_TIMER_INTERVAL = 0.03  # seconds between checks for new images (main thread)


def viewport_settings(scene):
    """The scene's settings for the viewport: one sample per pass (refinement adds more).

    Light Samples stay the scene's for the first full image and every refinement pass:
    each pass takes them anew, so n passes give what F12 gives at n samples (n x Light
    Samples shadow rays per soft light and pixel); a count that changed between passes
    would change the session's settings, whose interpolants and incremental records are
    built for one setting (a full re-render each time). Only the coarse preview, shown
    once and never averaged in, takes one (``ViewportWorker``)."""
    return replace(properties.render_settings(scene.rstrace), samples=1)


class ViewportRenderer:
    """The viewport half of one ``RenderEngine`` instance."""

    def __init__(self) -> None:
        self.worker: ViewportWorker | None = None
        self.scene_key: int | None = None
        self.session = None  # the core session the worker was handed
        self.camera = None
        self.border = None
        self.settings = None
        self.samples = 1
        self.new_image = threading.Event()
        self._drawn = None  # (generation, GPUTexture)
        self.last_edits = 0  # edits queued by the last view_update (tests, stats)
        self.updates_seen = 0
        self.error: str | None = None
        self.view_error: str | None = None  # the view's camera or border cannot be rendered
        self._settings_error: str | None = None  # the last invalid setting draw_settings saw
        self.freed = False
        self._status_set = False
        _LIVE.add(self)

    # -- view_update -----------------------------------------------------------------

    def view_update(self, context, depsgraph) -> None:
        if self.freed:
            return
        scene = depsgraph.scene
        try:
            self._update(scene, depsgraph)
        except SceneError as exc:
            self.error = str(exc)
        except Exception as exc:  # never raise into Blender's draw loop
            log.exception("RSTrace viewport update failed")
            self.error = f"internal error: {type(exc).__name__}: {exc}"

    def _update(self, scene, depsgraph) -> None:
        kernels.start_warmup(scene.rstrace.mode)
        key = scene.original.session_uid
        first = self.worker is None or key != self.scene_key
        if first:
            self._start(key, scene)
        self.updates_seen += 1
        settings = viewport_settings(scene)
        samples = max(1, int(scene.rstrace.viewport_samples))
        synced = sync.sync(self.state, depsgraph, "VIEWPORT", settings, updates=not first)
        self.last_edits = synced.edits
        new = synced.session is not self.session
        if new or synced.edits or settings != self.settings or samples != self.samples:
            self.error = None
            self.session = synced.session
            self._submit_settings(settings, samples)

    def _submit_settings(self, settings, samples: int) -> None:
        self.settings, self.samples = settings, samples
        self.worker.samples = samples
        self.worker.submit(session=self.session, settings=settings)

    def draw_settings(self, scene) -> None:
        """Restart the worker when the scene's RSTrace settings changed with no depsgraph
        update: a setting set from Python (a script, the console) sends none, and the
        viewport went on in the old mode or epsilon until some unrelated edit came; Blender
        redraws the view after any property change, so ``view_draw`` looks."""
        if self.settings is None or self.freed:
            return
        try:
            settings = viewport_settings(scene)
        except SceneError as exc:
            self.error = self._settings_error = str(exc)
            return
        samples = max(1, int(scene.rstrace.viewport_samples))
        if settings != self.settings or samples != self.samples:
            if self.error is not None and self.error == self._settings_error:
                self.error = None  # the setting was fixed (other errors stay said)
            kernels.start_warmup(scene.rstrace.mode)
            self._submit_settings(settings, samples)

    def _start(self, key: int, scene) -> None:
        """A worker for the scene ``key`` (a scene switch replaces the previous one)."""
        if self.worker is not None:
            self.worker.stop()
        self.scene_key = key
        self.state = session.state_for(scene)
        self.camera = self.border = self.settings = self.session = None
        self._drawn = None
        self.worker = ViewportWorker(runtime.RENDER_LOCK, notify=self.new_image.set,
                                     name="rstrace-viewport")
        _ensure_timer()

    # -- view_draw -------------------------------------------------------------------

    def view_draw(self, engine, context, depsgraph) -> None:
        if self.worker is None:
            return
        region, rv3d = context.region, context.region_data
        w, h = int(region.width), int(region.height)
        if w < 1 or h < 1 or rv3d is None:
            return
        try:
            camera = cameras.camera_from_view(rv3d.view_matrix, rv3d.window_matrix, w, h)
            border = view_border(context, depsgraph.scene, w, h)
        except SceneError as exc:
            # said until a view that can be rendered comes (navigation alone clears it)
            self.view_error = str(exc)
            engine.update_stats("", self.status(None))
            return
        self.view_error = None
        # the original: the evaluated copy lags until the next depsgraph update (which is
        # when view_update reads it)
        self.draw_settings(depsgraph.scene.original)
        self.follow_session()
        self.draw_view(camera, border)
        img = self.worker.latest()
        if img is not None and img.view_size == (w, h):
            scene = depsgraph.scene
            gpu_state = _begin_display(engine, scene)
            try:
                self.draw_image(img, w, h)
            finally:
                _end_display(engine, gpu_state)
        engine.update_stats("", self.status(img))
        self._status_bar(context)

    def _status_bar(self, context) -> None:
        """Kernel compile progress in Blender's status bar while a warm-up runs."""
        progress = kernels.progress_text()
        if progress is None and not self._status_set:
            return
        workspace = getattr(context, "workspace", None)
        if workspace is None:
            return
        workspace.status_text_set(f"RSTrace: {progress}" if progress else None)
        self._status_set = progress is not None

    def follow_session(self) -> None:
        """Hand the worker the scene's session when an F12 render started it afresh (after
        an error) since the last ``view_update``: the old one is no longer synced."""
        current = self.state.session
        if current is not None and current is not self.session and self.worker is not None:
            self.session = current
            self.worker.submit(session=current)

    def draw_view(self, camera, border) -> None:
        """Restart the worker when the view's camera or border changed."""
        if not same_camera(camera, self.camera) or border != self.border:
            self.camera, self.border = camera, border
            self.worker.submit(camera=camera, border=border)

    def texture(self, img: ViewImage):
        """The ``GPUTexture`` of ``img`` (made once per image)."""
        import gpu

        if self._drawn is not None and self._drawn[0] == img.generation:
            return self._drawn[1]
        h, w = img.rgba.shape[:2]
        buf = gpu.types.Buffer("FLOAT", w * h * 4, np.ascontiguousarray(img.rgba).ravel())
        tex = gpu.types.GPUTexture((w, h), format="RGBA32F", data=buf)
        self._drawn = (img.generation, tex)
        return tex

    def draw_image(self, img: ViewImage, width: int, height: int) -> None:
        """Draw ``img`` stretched over a ``width`` x ``height`` region (current framebuffer)."""
        from gpu_extras.presets import draw_texture_2d

        # (between bind/unbind_display_space_shader in view_draw, as Blender's own example
        # of a RenderEngine viewport does: the display transform is Blender's)
        draw_texture_2d(self.texture(img), (0, 0), width, height)
        self.new_image.clear()

    def status(self, img: ViewImage | None) -> str:
        """The viewport's status text (kernel progress, stage, samples, errors)."""
        err = self.view_error or self.error or (self.worker.error if self.worker is not None
                                                else None)
        if err:
            return f"RSTrace | error: {err}"
        progress = kernels.progress_text()
        if img is None:
            return f"RSTrace | {progress or 'rendering'}"
        stage = {"coarse": "preview", "full": "1 sample"}.get(img.stage,
                                                             f"{img.samples} samples")
        extra = ""
        fs = img.stats
        if fs.get("interpolated_fraction"):
            extra += f" | interpolated {100 * fs['interpolated_fraction']:.0f}%"
        if fs.get("incremental"):
            extra += f" | dirty {100 * (fs.get('dirty_fraction') or 0.0):.1f}%"
        text = f"RSTrace | {stage}{extra} | {fs.get('ms_since_edit', 0.0):.0f} ms"
        return f"{text} | {progress}" if progress else text

    # -- teardown --------------------------------------------------------------------

    def free(self) -> None:
        """Stop and join the worker (idempotent). Blender freeing the engine calls this."""
        self.freed = True
        worker, self.worker = self.worker, None
        if worker is not None and not worker.stop(timeout=30.0):
            log.error("RSTrace viewport worker did not stop within 30 s")
        self._drawn = None
        _LIVE.discard(self)


def view_border(context, scene, width: int, height: int):
    """The render border in region pixels (x, y, w, h), or None for the whole view.

    Outside a camera view it is the 3D view's own render region; in a camera view the
    scene's border, placed on the camera frame as Blender draws it.
    """
    space = context.space_data
    rv3d = context.region_data
    if rv3d.view_perspective == "CAMERA":
        if not scene.render.use_border or scene.camera is None:
            return None
        from bpy_extras.view3d_utils import location_3d_to_region_2d

        cam = scene.camera
        frame = [cam.matrix_world @ v for v in cam.data.view_frame(scene=scene)]
        pts = [location_3d_to_region_2d(context.region, rv3d, v) for v in frame]
        if any(p is None for p in pts):
            return None
        xs, ys = [p.x for p in pts], [p.y for p in pts]
        x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
        r = scene.render
        box = (x0 + r.border_min_x * (x1 - x0), y0 + r.border_min_y * (y1 - y0),
               x0 + r.border_max_x * (x1 - x0), y0 + r.border_max_y * (y1 - y0))
    elif getattr(space, "use_render_border", False):
        box = (space.render_border_min_x * width, space.render_border_min_y * height,
               space.render_border_max_x * width, space.render_border_max_y * height)
    else:
        return None
    return clip_border(box, width, height)


def clip_border(box, width: int, height: int):
    """(x0, y0, x1, y1) in pixels -> (x, y, w, h) inside the view (at least 1 pixel)."""
    x0 = int(min(max(box[0], 0), width - 1))
    y0 = int(min(max(box[1], 0), height - 1))
    x1 = int(min(max(box[2], x0 + 1), width))
    y1 = int(min(max(box[3], y0 + 1), height))
    return (x0, y0, x1 - x0, y1 - y0)


def _begin_display(engine, scene):
    import gpu

    gpu.state.blend_set("ALPHA_PREMULT")
    engine.bind_display_space_shader(scene)


def _end_display(engine, _state) -> None:
    import gpu

    engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")


# ----------------------------------------------------------------------------- redraws


def _tick():
    """Main-thread timer: redraw rendered 3D views when a worker has a new image."""
    live = list(_LIVE)
    if not live:
        return None
    if any(v.new_image.is_set() for v in live):
        for v in live:
            v.new_image.clear()
        wm = getattr(bpy.context, "window_manager", None)
        for window in (wm.windows if wm is not None else ()):
            for area in window.screen.areas:
                if area.type == "VIEW_3D":
                    area.tag_redraw()
    return _TIMER_INTERVAL


def _ensure_timer() -> None:
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=_TIMER_INTERVAL, persistent=True)


def free(engine) -> None:
    """Stop the viewport worker of ``engine`` (its ``__del__``), if it ever had one."""
    try:
        renderer = engine.viewport
    except (AttributeError, ReferenceError):
        return
    renderer.free()


def live_viewports() -> list:
    return list(_LIVE)


def stop_all() -> None:
    """Stop every viewport worker (file load, unregister)."""
    for v in list(_LIVE):
        v.free()


def stop_for_scene(scene_key: int) -> None:
    for v in list(_LIVE):
        if v.scene_key == scene_key:
            v.free()


def _on_load_pre(*_args) -> None:
    stop_all()


def _on_depsgraph_update(scene, _depsgraph) -> None:
    """Stop the viewports of a scene whose render engine is no longer RSTrace; start the
    kernel warm-up when it is (the engine was just selected)."""
    if scene.render.engine != "RSTRACE":
        stop_for_scene(scene.original.session_uid)
    else:
        kernels.start_warmup(scene.rstrace.mode)


_on_load_pre = bpy.app.handlers.persistent(_on_load_pre)
_on_depsgraph_update = bpy.app.handlers.persistent(_on_depsgraph_update)


def register() -> None:
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)
    if _on_depsgraph_update not in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.append(_on_depsgraph_update)


def unregister() -> None:
    stop_all()
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    if _on_depsgraph_update in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.remove(_on_depsgraph_update)
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)


__all__ = ["ViewportRenderer", "clip_border", "free", "live_viewports", "stop_all",
           "view_border", "viewport_settings"]
