"""One persistent ``rstrace_engine`` session per Blender scene, shared by F12 / animation
renders and the viewport, and the F12 render path of the engine (:class:`FrameRenderer`).

Per scene, a :class:`SceneState` keeps the core :class:`~rstrace_engine.session.Session`,
the :class:`~.depsgraph_diff.SceneMirror` of what it holds, the statistics of the last
render and its messages. An F12 render (or an animation frame) brings the session up to
date through :func:`.sync.sync` (the viewport's path too), applies the edits and renders
through the scene's camera, so that a render after an edit re-renders incrementally when
the camera did not move. :func:`last_render_stats` gives a script the last render's numbers.

Threads: ``state.lock`` guards the mirror and the session object; every call that runs
kernels holds ``runtime.RENDER_LOCK`` (taken before ``state.lock``, never after). States are
dropped when a file is loaded and when the add-on is unregistered.

Layer: imports ``properties``, ``export``, ``depsgraph_diff``, ``sync``, ``kernels`` and
``runtime``;
never ``viewport``, ``engine`` or ``ui``.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.app.handlers import persistent

from rstrace_engine.frame import CLASS_BACKGROUND, CLASS_NAMES, Frame
from rstrace_engine.geometry.scene import SceneError

from . import export, kernels, properties, runtime, sync
from .depsgraph_diff import SceneMirror

log = logging.getLogger(__name__)

INTERPOLATION_PASS = "Interpolation"
#: The view layer's passes the engine writes besides Combined: (flag, pass name, channels,
#: channel ids, type), as Cycles registers them (tracing.camera_passes computes them)
DATA_PASSES = (("use_pass_z", "Depth", 1, "Z", "VALUE"),
               ("use_pass_normal", "Normal", 3, "XYZ", "VECTOR"))
INTERRUPTED = "render interrupted (Ctrl+C): cancelled, nothing written"


@dataclass
class SceneState:
    """What survives between renders of one Blender scene."""

    session: object = None  # rstrace_engine.session.Session
    renders: int = 0
    stats: dict = field(default_factory=dict)  # of the last render (export + frame)
    messages: list = field(default_factory=list)  # (level, text) of the last render
    # messages reported by this render / the scene's previous one: a message is reported
    # when it is new against the previous render (once per scene and change, not at every
    # frame of an animation or F12 of an edit loop); state.messages and the statistics
    # still list every one of every render
    reported: set = field(default_factory=set)
    reported_before: set = field(default_factory=set)
    error: str | None = None
    frame: object = None  # the last rstrace_engine Frame, for scripts (linear radiance)
    mirror: SceneMirror = field(default_factory=SceneMirror)
    lock: threading.RLock = field(default_factory=threading.RLock)
    dirty_mask: object = None  # (h, w) bool pixels the last F12 re-rendered; None: all


_STATES: dict[int, SceneState] = {}


def state_for(scene) -> SceneState:
    """The persistent state of a Blender scene (created on first use)."""
    key = scene.original.session_uid
    state = _STATES.get(key)
    if state is None:
        state = _STATES[key] = SceneState()
    return state


def peek_state(scene) -> SceneState | None:
    """The state of ``scene`` if it was ever rendered, without creating one."""
    return _STATES.get(scene.original.session_uid)


def forget_all() -> None:
    """Drop every session and the mesh BVHs kept for the next one (file load, unregister)."""
    _STATES.clear()
    accelerators = sys.modules.get("rstrace_engine.accel.accelerators")
    if accelerators is not None:  # (not imported: nothing kept, and no numba to import)
        accelerators.KEPT.clear()


def last_render_stats(scene) -> dict:
    """The statistics of the last F12 / animation render of ``scene`` (a copy; {} if none).

    Keys include ``mode``, ``width``, ``height``, ``objects``, ``triangles``, ``lights``;
    times in seconds: ``sync_seconds`` (depsgraph walk and diff), ``apply_seconds`` (edits
    into the session), ``render_seconds``, ``total_seconds``; ``edits`` and ``edit_kinds``
    (what changed since the previous render), ``meshes_read``, ``meshes_trusted`` (taken
    from the cache on the journal's word, neither read nor fingerprinted); ``incremental``
    (only dirty pixels re-rendered), ``dirty_fraction`` (of the pixels), ``interpolated_fraction``
    (INTERPOLANT mode), ``invalidated_interpolants``; ``memory_mb`` (the session's: scene
    arrays, accelerator, the mode's cache, per-pixel records); ``renders`` (count).
    """
    state = peek_state(scene)
    return dict(state.stats) if state is not None else {}


@persistent
def _on_load_pre(*_args) -> None:
    forget_all()


# ----------------------------------------------------------------------------- rendering


class FrameRenderer:
    """F12 and animation renders for one ``RenderEngine`` instance."""

    def __init__(self, engine) -> None:
        self.engine = engine

    # -- passes ----------------------------------------------------------------------------

    def update_render_passes(self, scene, render_layer) -> None:
        """Declare our passes to Blender (compositor sockets, EXR layers): Combined, the
        Interpolation false colours, and Depth and Normal where the view layer asks for
        them (as Cycles names them)."""
        self.engine.register_pass(scene, render_layer, "Combined", 4, "RGBA", "COLOR")
        self.engine.register_pass(scene, render_layer, INTERPOLATION_PASS, 3, "RGB", "COLOR")
        for flag, name, channels, chan_id, kind in DATA_PASSES:
            if getattr(render_layer, flag, False):
                self.engine.register_pass(scene, render_layer, name, channels, chan_id, kind)

    # -- render ----------------------------------------------------------------------------

    def render(self, depsgraph) -> None:
        scene = depsgraph.scene
        state = state_for(scene)
        state.reported_before, state.reported = state.reported, set()
        state.messages = []
        state.error = None
        state.stats = {}
        try:
            self._render(depsgraph, scene, state)
        except SceneError as exc:
            self._error(state, str(exc))
        except KeyboardInterrupt:
            # Ctrl+C (SIGINT) in a background render: a cancel. Escaping into Blender, it
            # crashed writing a result never started (EXR) or wrote a blank image (PNG); an
            # error report makes Blender stop the job and write nothing.
            # The session may have stopped between any two steps: the next render starts
            # afresh.
            log.warning("RSTrace render interrupted")
            sync.drop_session(state)
            self._error(state, INTERRUPTED)
        except Exception as exc:  # never let an exception escape into Blender's render job
            log.exception("RSTrace render failed")
            self._error(state, f"internal error: {type(exc).__name__}: {exc}")

    def _render(self, depsgraph, scene, state: SceneState) -> None:
        engine = self.engine
        t0 = time.perf_counter()
        settings = properties.render_settings(scene.rstrace)
        check_available(settings)
        engine.update_stats("", "RSTrace | syncing scene")
        status = kernels.progress_text() or runtime.kernel_status()
        if status:
            engine.update_stats("", f"RSTrace | {status}")
        with sync.HeldLock(runtime.RENDER_LOCK) as held:
            threads = runtime.set_threads(scene.render)
            t1 = time.perf_counter()
            try:
                synced = sync.sync(state, depsgraph, "RENDER", settings,
                                   camera_object=engine.camera_override,
                                   cancel=engine.test_break, progress=self._status,
                                   lock=held)
            except export.Cancelled:
                # Esc while meshes were read or the structures built: the session and
                # its mirror are as they were; nothing is written
                state.stats = dict(cancelled=True, total_seconds=time.perf_counter() - t0)
                engine.update_stats("", "RSTrace | cancelled")
                return
            session, snap = synced.session, synced.snapshot
            try:
                session.update_settings(settings)
                report = session.apply()
            except BaseException:
                sync.drop_session(state)  # the next render starts afresh
                raise
            t_apply = time.perf_counter() - t1 - synced.seconds
            for message in snap.warnings + list(session.scene.warnings):
                self._warn(state, message)
            if engine.test_break():
                return
            mask, before = session.dirty_mask, session.last_report
            t2 = time.perf_counter()
            known = set(session.scene.warnings)
            frame = session.render(camera=snap.camera, progress=self._progress,
                                   cancel=engine.test_break)
            t_render = time.perf_counter() - t2
            for message in session.scene.warnings:  # (what the mode's render said)
                if message not in known:
                    self._warn(state, message)
            # what the session applied for this frame: the edits, and a new camera (render)
            reports = [report] + ([session.last_report] if session.last_report is not before
                                  else [])
            passes = _camera_passes(session, snap, state.mirror.cache, depsgraph.view_layer,
                                    frame, engine.test_break)
            runtime.mark_kernels_ready()
            runtime.start_host_compile()  # shipped portable kernels: this CPU's, for later
            session_stats = dict(getattr(session, "stats", {}) or {})
        state.dirty_mask = mask if frame.stats.get("incremental") else None

        for message in unwritten_passes(depsgraph.view_layer):
            self._warn(state, message)
        self._write_result(depsgraph, scene, frame, passes)
        state.frame = frame
        state.renders += 1
        core = session.scene
        # the frame's own numbers; from the session only what is not per frame
        stats = {k: session_stats[k] for k in ("accel_build_s", "accel_update_s",
                                               "accelerator") if k in session_stats}
        stats.update(frame.stats or {})
        stats.update(
            objects=len(snap.objects), lights=len(snap.lights), meshes=len(core.meshes),
            materials=len(core.materials), triangles=core.triangle_count,
            sync_seconds=synced.seconds, export_seconds=synced.seconds,
            apply_seconds=t_apply, meshes_read=synced.stats.get("meshes_read", 0),
            meshes_trusted=synced.stats.get("meshes_trusted", 0),
            edits=sum(r.edits for r in reports), edit_kinds=_kinds(reports),
            render_seconds=t_render,
            total_seconds=time.perf_counter() - t0, threads=threads, width=snap.width,
            height=snap.height, mode=settings.mode, accelerator=settings.accelerator,
            renders=state.renders, pixel_classes=_class_counts(frame),
            export_warnings=snap.warnings + list(core.warnings),
            invalidated_interpolants=sum(r.invalidated_interpolants for r in reports),
            new_session=synced.new_session)
        stats.setdefault("interpolated_fraction", 0.0)
        stats["memory_mb"] = _memory_mb(stats, core)
        state.stats = stats
        dropped = int(stats.get("nonfinite_samples") or 0)
        if dropped:
            self._warn(state, f"{dropped} sample(s) with NaN, infinite or too large radiance "
                              f"(>= 1e30, e.g. emission) were left out of the image")
        # INTERPOLANT: what is only tested, and what its fallback traced because cells did
        # not pay; RI_TREE: objects traced because their tree did not pay
        for note in ((stats.get("bound_notes") or []) + (stats.get("fallback_notes") or [])
                     + (stats.get("ri_notes") or [])):
            self._report(state, "INFO", note)
        # BASE: per-light records off or cut by their cap (light edits re-trace)
        for key in ("relight_off", "relight_moves_off"):
            if stats.get(key):
                self._report(state, "INFO", stats[key])
        engine.update_memory_stats(memory_used=stats["memory_mb"],
                                   memory_peak=stats["memory_mb"])
        engine.update_stats("", status_line(stats))
        engine.update_progress(1.0)

    def _status(self, message: str) -> None:
        self.engine.update_stats("", f"RSTrace | {message}")

    def _progress(self, fraction: float, message: str = "") -> None:
        self.engine.update_progress(float(min(max(fraction, 0.0), 1.0)))
        if message:
            self.engine.update_stats("", f"RSTrace | {message}")

    def _write_result(self, depsgraph, scene, frame: Frame, passes=None) -> None:
        """Combined (linear radiance, alpha: holdouts cut out), the Interpolation
        false-colour pass, Depth and Normal where asked (``passes``: a
        :class:`~rstrace_engine.tracing.camera_passes.CameraPasses` or None).

        With a render region (border) Blender's result covers only that region, addressed
        from its own corner; the frame is rendered whole and the region copied out.
        """
        h, w = frame.pixel_class.shape
        rgba = np.empty((h, w, 4), np.float32)
        rgba[..., :3] = frame.radiance
        rgba[..., 3] = 1.0
        if scene.render.film_transparent:
            rgba[frame.pixel_class == CLASS_BACKGROUND] = 0.0
        if passes is not None and passes.alpha is not None:
            # holdouts: premultiplied colour of the other samples, alpha their share
            rgba[..., :3] = passes.radiance
            rgba[..., 3] *= passes.alpha
        data = {}
        if passes is not None:
            data = {"Depth": passes.depth, "Normal": passes.normal}
        classes = frame.class_image()
        x0, y0, bw, bh = _region(scene.render, w, h)
        engine = self.engine
        layer_name = depsgraph.view_layer.name
        engine.add_pass(INTERPOLATION_PASS, 3, "RGB", layer=layer_name)
        result = engine.begin_result(0, 0, bw, bh, layer=layer_name)
        try:
            bw, bh = min(bw, result.resolution_x), min(bh, result.resolution_y)
            layer = result.layers[0]
            layer.passes["Combined"].rect.foreach_set(
                np.ascontiguousarray(rgba[y0:y0 + bh, x0:x0 + bw]).ravel())
            ipass = layer.passes.get(INTERPOLATION_PASS)
            if ipass is not None:
                ipass.rect.foreach_set(
                    np.ascontiguousarray(classes[y0:y0 + bh, x0:x0 + bw]).ravel())
            for name, values in data.items():
                dpass = layer.passes.get(name)
                if dpass is not None and values is not None:
                    dpass.rect.foreach_set(np.ascontiguousarray(
                        values[y0:y0 + bh, x0:x0 + bw], np.float32).ravel())
        finally:
            engine.end_result(result)

    # -- messages -----------------------------------------------------------------------------

    def _warn(self, state: SceneState, message: str) -> None:
        self._report(state, "WARNING", message)

    def _report(self, state: SceneState, level: str, message: str) -> None:
        """Listed in ``state.messages`` always; reported to Blender (the info editor, the
        console) only when the scene's previous render did not report it too."""
        state.messages.append((level, message))
        if (level, message) not in state.reported:
            state.reported.add((level, message))
            if (level, message) not in state.reported_before:
                self.engine.report({level}, f"RSTrace: {message}")

    def _error(self, state: SceneState, message: str) -> None:
        log.error("RSTrace: %s", message)
        state.messages.append(("ERROR", message))
        state.error = message
        self.engine.report({"ERROR"}, f"RSTrace: {message}")
        self.engine.error_set(f"RSTrace: {message}")
        self.engine.update_stats("", f"RSTrace | error: {message}")


def _camera_passes(session, snap, cache, view_layer, frame: Frame, cancel):
    """Depth and Normal (where the view layer asks for them) and the holdouts of an F12
    frame (:func:`rstrace_engine.tracing.camera_passes.camera_passes`), or None when there
    is nothing to do."""
    from rstrace_engine.tracing.camera_passes import camera_passes

    depth = bool(getattr(view_layer, "use_pass_z", False))
    normal = bool(getattr(view_layer, "use_pass_normal", False))
    core = session.scene
    insts, mats = [], set()
    for key, rec in snap.objects.items():
        if rec.holdout:
            insts.append(core.instance_slot(key))
        for mk in rec.material_keys:
            entry = cache.materials.get(mk)
            if entry is not None and getattr(entry, "holdout", False):
                mats.add(core.material_id(mk))
    if not (depth or normal or insts or mats) or frame.stats.get("cancelled"):
        return None
    return camera_passes(core, session.accel, session.settings, frame=frame,
                         holdout_mats=sorted(mats), holdout_insts=insts, depth=depth,
                         normal=normal, cancel=cancel)


def unwritten_passes(view_layer) -> list[str]:
    """A message naming the render passes ``view_layer`` enables that the engine does
    not write (Mist, Ambient Occlusion, Diffuse Direct, ..., Cycles' own: volume, shadow
    catcher, denoising data, debug; AOVs, light groups); [] when there are none."""
    if view_layer is None:
        return []
    written = {"use_pass_combined", "use_pass_cryptomatte_accurate"} | {
        flag for flag, *_ in DATA_PASSES}
    names = []
    # the view layer's own passes and Cycles' (EEVEE's are EEVEE's settings, as Cycles
    # ignores them)
    for holder in (view_layer, getattr(view_layer, "cycles", None)):
        if holder is None:
            continue
        for prop in holder.bl_rna.properties:
            ident = prop.identifier
            if (ident.startswith(("use_pass_", "pass_")) or ident == "denoising_store_passes") \
                    and ident not in written and prop.type == "BOOLEAN" \
                    and getattr(holder, ident, False):
                names.append(prop.name)
    for label, items in (("AOV", getattr(view_layer, "aovs", ())),
                         ("light group", getattr(view_layer, "lightgroups", ()))):
        names += [f"{label} '{item.name}'" for item in items]
    if not names:
        return []
    return [f"render passes not written by RSTrace (left empty): {', '.join(names)}: "
            f"'{view_layer.name}'"]


def check_available(settings) -> None:
    """Refuse, with a clear message, a mode the renderer does not offer yet (rather than
    render something else). Accelerators are checked by the core when it builds one."""
    from rstrace_engine import session as core

    available = getattr(core, "AVAILABLE_MODES", ("BASE",))
    if settings.mode not in available:
        label = dict((k, n) for k, n, _ in properties.MODE_ITEMS).get(settings.mode)
        raise SceneError(f"mode '{label}' is not available yet in this version of RSTrace "
                         f"(available: {', '.join(available)}); choose another mode in Render "
                         f"Properties > RSTrace")


def _region(render, w: int, h: int) -> tuple[int, int, int, int]:
    """The render region (border) in pixels: x, y, width, height; the whole frame if unset.

    Truncated as Blender does (``disprect = border * size``, converted to int).
    """
    if not render.use_border:
        return 0, 0, w, h
    x0 = min(max(int(render.border_min_x * w), 0), w - 1)
    x1 = min(max(int(render.border_max_x * w), x0 + 1), w)
    y0 = min(max(int(render.border_min_y * h), 0), h - 1)
    y1 = min(max(int(render.border_max_y * h), y0 + 1), h)
    return x0, y0, x1 - x0, y1 - y0


def _kinds(reports) -> dict:
    """Edit class name -> count over several ``EditReport``s."""
    kinds: dict = {}
    for r in reports:
        for name, n in r.kinds.items():
            kinds[name] = kinds.get(name, 0) + n
    return kinds


def _class_counts(frame: Frame) -> dict:
    counts = np.bincount(frame.pixel_class.ravel(), minlength=len(CLASS_NAMES))
    return {name: int(c) for name, c in zip(CLASS_NAMES, counts[:len(CLASS_NAMES)], strict=True)
            if c}


def _memory_mb(stats: dict, scene) -> float:
    """Memory of the session in MB: scene arrays + accelerator (``accel_memory_mb``) + the
    mode's cache (INTERPOLANT's interpolants and ray segment trees, RI_TREE's trees: the
    frame's ``memory_mb``) + per-pixel records."""
    try:
        arrays = sum(getattr(a, "nbytes", 0) for a in scene.arrays()) / 1e6
    except SceneError:
        arrays = 0.0
    cache = stats.get("memory_mb") if stats.get("mode") in ("INTERPOLANT", "RI_TREE") else 0.0
    return float(arrays + (stats.get("accel_memory_mb") or 0.0) + (cache or 0.0)
                 + (stats.get("records_mb") or 0.0))


def shadow_rays_per_pixel(stats: dict) -> float | None:
    """Shadow rays of the last frame per pixel of the image (a soft light takes Light
    Samples of them per shading point), or None where the frame does not count them."""
    rays = stats.get("shadow_rays")
    pixels = int(stats.get("width") or 0) * int(stats.get("height") or 0)
    return None if rays is None or not pixels else rays / pixels


def shadow_rays_text(stats: dict) -> str | None:
    """The Last Render panel's line for :func:`shadow_rays_per_pixel`, with the samples
    proven unoccluded and not traced (``shadow_rays_skipped``, docs/SOFT_LIGHT.md) where
    there were any."""
    per_pixel = shadow_rays_per_pixel(stats)
    if per_pixel is None:
        return None
    text = f"{int(stats['shadow_rays']):,} shadow rays, {per_pixel:.1f} per pixel"
    skipped = int(stats.get("shadow_rays_skipped") or 0)
    if skipped:
        pixels = int(stats["width"]) * int(stats["height"])
        text += f" (+{skipped / pixels:.1f} proven, not traced)"
    return text


def fallback_text(stats: dict) -> str | None:
    """INTERPOLANT: what the measured fallback decided (``stats["fallback"]``,
    :mod:`rstrace_engine.interpolants.fallback`) -- the frame traced because its cells cost
    more than they save, or objects traced, or the frame traced while the cell build's
    kernels compile in the background (:mod:`rstrace_engine.interpolants.build_beside`) --
    for the status line and the Last Render panel; None while cells are used wherever they
    may be."""
    fb = stats.get("fallback") or {}
    if fb.get("build_compiling"):
        return "traced: cell build compiling in the background"
    if fb.get("all_traced"):
        return "traced: cells did not pay"
    n = int(fb.get("traced_objects") or 0)
    return f"{n} object(s) traced: cells did not pay" if n else None


def status_line(stats: dict) -> str:
    """The status-line summary of a finished render."""
    parts = [f"RSTrace | {stats.get('mode', '?')} | {stats.get('width')}x{stats.get('height')}",
             f"{stats.get('triangles', 0):,} tris, {stats.get('objects', 0)} objects",
             f"export {stats.get('export_seconds', 0.0):.2f}s",
             f"render {stats.get('render_seconds', 0.0):.2f}s"]
    per_pixel = shadow_rays_per_pixel(stats)
    if per_pixel is not None:
        parts.append(f"{per_pixel:.1f} shadow rays/px")
    classes = stats.get("pixel_classes") or {}
    total = sum(classes.values())
    if total and classes.get("interpolated"):
        parts.append(f"interpolated {100.0 * classes['interpolated'] / total:.1f}%")
    fallback = fallback_text(stats) if stats.get("mode") == "INTERPOLANT" else None
    if fallback:
        parts.append(fallback)
    if stats.get("cancelled"):
        parts.append("cancelled")
    warnings = stats.get("export_warnings") or []
    if warnings:
        parts.append(f"{len(warnings)} warning{'s' if len(warnings) > 1 else ''} "
                     f"(RSTrace > Last Render)")
    return " | ".join(parts)


def register() -> None:
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)


def unregister() -> None:
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    forget_all()
