"""Interactive (viewport) rendering of a :class:`~rstrace_engine.session.Session` on a
worker thread: progressive refinement, interruption, and the newest image for the host.

A host (the Blender add-on's viewport, or ``python -m rstrace_engine.bench viewport``)
owns a :class:`ViewportWorker` and calls :meth:`ViewportWorker.submit` whenever something
changed: new edits (queued on the session with :meth:`Session.submit
<rstrace_engine.session.Session.submit>`, applied by the session on the worker under the
render lock), another session, a new view camera, new settings or a new size. Each
submission interrupts the frame in progress (a
:class:`~rstrace_engine.cancel.CancelFlag`: the renderers poll it between tiles of
:data:`VIEW_TILE_RAYS` rays and between the queries of a tile, the BVH kernels every few
dozen rays) and starts over with

1. a *coarse* frame at 1/:data:`COARSE_FACTOR` resolution (the base tracer with one light
   sample; a few thousand rays), so something appears within tens of milliseconds of any
   edit -- not when the session only relights its kept frame (BASE light edits,
   :meth:`Session.relights_only <rstrace_engine.session.Session.relights_only>`): then the
   full image comes as soon;
2. the *full*-resolution frame in the session's mode (BASE: the base tracer in tiles;
   INTERPOLANT: radiance interpolants, which are view-independent and survive camera
   moves);
3. *refinement* while idle: further jittered samples per pixel (stratified, the base
   tracer) averaged in, up to ``samples`` in all.

After each stage the newest :class:`ViewImage` replaces the previous one and ``notify()``
is called (on the worker thread: the host must only set a flag or schedule a redraw).
Kernels are numba ``nogil``: the worker runs while the host's main thread keeps going. The
worker never touches the host's data and calls no host code but ``notify``;
:meth:`ViewportWorker.stop` interrupts and joins it.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from .cancel import CancelFlag, cancelled
from .frame import CLASS_BACKGROUND, RenderSettings
from .geometry.cameras import camera_params
from .geometry.scene import Camera, SceneError
from .tracing.batches import SERIAL_BELOW, accumulate, row_tiles, threads_for
from .tracing.whitted import trace_pixels

log = logging.getLogger(__name__)

#: Primary rays per tile of an interactive frame: the cancel poll granularity (about 15 ms
#: of tracing on 2 idle cores for a depth-5 scene); at least ``batches.SERIAL_BELOW`` so
#: that full-resolution tiles run on every thread (smaller batches, like the coarse frame's,
#: run on one: on a busy machine each parallel region costs a scheduler time slice).
VIEW_TILE_RAYS = SERIAL_BELOW
#: The coarse first frame's resolution divisor.
COARSE_FACTOR = 8

STAGE_COARSE, STAGE_FULL, STAGE_REFINE = "coarse", "full", "refine"


@dataclass
class ViewImage:
    """One displayable image of the view (rows bottom-up, scene-linear RGBA float32).

    ``rgba`` may be smaller than the view (the coarse stage): the host stretches it over
    the view. ``border`` is the rendered region (x, y, w, h) in view pixels (None: all);
    pixels outside it have alpha 0.
    """

    rgba: np.ndarray  # (h, w, 4) float32
    stage: str
    samples: int  # samples per pixel averaged in (0 for the coarse stage)
    generation: int  # increases with every image the worker publishes
    job: int  # the submission this image belongs to
    view_size: tuple  # (width, height) of the view
    border: tuple | None = None
    stats: dict = field(default_factory=dict)


def trace_view(session, camera: Camera, settings: RenderSettings, cancel=None,
               border: tuple | None = None, sample: int = 0, samples: int = 1,
               tile_rays: int = VIEW_TILE_RAYS):
    """The base tracer's image of ``camera`` over the session's scene, in tiles.

    sample, samples : which stratified sample of ``samples`` per pixel to take (0 of 1: the
    pixel centre, exactly the base tracer's 1-sample frame). Returns ``(rgb (h, w, 3)
    float32, pclass (h, w) uint8, done)``; ``done`` is False when ``cancel()`` stopped it
    (the image then holds the tiles completed before it). With a
    :class:`~rstrace_engine.cancel.CancelFlag` the queries of a tile stop within a few
    dozen rays of it being set.
    """
    sa = session.scene.arrays()
    accel = session.accel
    cp = camera_params(camera)
    w, h = cp.width, cp.height
    rgb = np.zeros((h * w, 3), np.float32)
    pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
    bw = border[2] if border is not None else w
    rows = max(1, tile_rays // max(1, bw))
    for pix, jitter, _ in row_tiles(w, h, samples, int(settings.seed), rows, border):
        if cancelled(cancel):
            return rgb.reshape(h, w, 3), pclass.reshape(h, w), False
        k = sample % samples if samples > 1 else 0  # one sample: the pixel centres
        rad, inst = trace_pixels(sa, accel, cp, pix, jitter[k], int(settings.max_depth), cancel,
                                 gids=k * (w * h) + pix, seed=int(settings.seed),
                                 light_samples=int(settings.light_samples),
                                 glossy_samples=int(settings.glossy_samples), spp=samples)
        if cancelled(cancel):  # the tile is incomplete: keep nothing of it
            return rgb.reshape(h, w, 3), pclass.reshape(h, w), False
        with threads_for(len(pix)):
            out = np.empty((len(pix), 3), np.float32)
            cls = np.empty(len(pix), np.uint8)
            accumulate(rad, inst, 1, out, cls)
        rgb[pix] = out
        pclass[pix] = cls
    return rgb.reshape(h, w, 3), pclass.reshape(h, w), True


def coarse_camera(camera: Camera, factor: int = COARSE_FACTOR) -> Camera:
    """``camera`` at 1/``factor`` resolution (same view: the sensor fit is made explicit,
    since AUTO depends on the aspect that rounding may change)."""
    w = max(1, camera.width // factor)
    h = max(1, camera.height // factor)
    fit = camera.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if camera.width >= camera.height else "VERTICAL"
        sensor = camera.sensor_width
        camera = replace(camera, sensor_width=sensor, sensor_height=sensor)
    return replace(camera, width=w, height=h, sensor_fit=fit)


def _coarse_border(border, factor: int, w: int, h: int):
    if border is None:
        return None
    x0, y0, bw, bh = border
    cx0, cy0 = min(x0 // factor, w - 1), min(y0 // factor, h - 1)
    cx1 = min(max(cx0 + 1, -(-(x0 + bw) // factor)), w)
    cy1 = min(max(cy0 + 1, -(-(y0 + bh) // factor)), h)
    return (cx0, cy0, cx1 - cx0, cy1 - cy0)


def _rgba(rgb: np.ndarray, border, w: int, h: int) -> np.ndarray:
    out = np.empty((h, w, 4), np.float32)
    out[..., :3] = rgb
    if border is None:
        out[..., 3] = 1.0
    else:
        x0, y0, bw, bh = border
        out[..., 3] = 0.0
        out[y0:y0 + bh, x0:x0 + bw, 3] = 1.0
    return out


def _mask_border(rgb: np.ndarray, border) -> np.ndarray:
    if border is None:
        return rgb
    x0, y0, bw, bh = border
    out = np.zeros_like(rgb)
    out[y0:y0 + bh, x0:x0 + bw] = rgb[y0:y0 + bh, x0:x0 + bw]
    return out


class ViewportWorker:
    """A render thread for one view (see the module docstring).

    lock : held around every call that runs kernels (the host's render lock: the worker
    never runs kernels concurrently with another render); notify() : called on the worker
    thread when a new image is ready; samples : refinement target (samples per pixel).
    """

    def __init__(self, lock: threading.Lock | None = None, notify=None, samples: int = 4,
                 coarse_factor: int = COARSE_FACTOR, tile_rays: int = VIEW_TILE_RAYS,
                 name: str = "rstrace-viewport") -> None:
        self.lock = lock if lock is not None else threading.Lock()
        self.notify = notify
        self.samples = max(1, int(samples))
        self.coarse_factor = max(1, int(coarse_factor))
        self.tile_rays = int(tile_rays)
        self._cond = threading.Condition()
        self._job: dict = dict(session=None, camera=None, settings=None, border=None)
        self._submitted = 0  # job counter
        self._started = 0  # the job the worker is on
        self._t_submit = 0.0
        # numba's thread count is per thread: the worker takes the host's (the thread
        # that submits: the add-on's Blender thread setting, a benchmark's --threads)
        self._threads = numba.get_num_threads()
        self._stop = False
        # set by every submission and by stop(); cleared when the worker takes a job: the
        # renderers poll it between tiles and the BVH kernels inside their loops
        self._flag = CancelFlag()
        self._image: ViewImage | None = None
        self._generation = 0
        self.error: str | None = None
        self.last_frame = None  # the last full-resolution Frame (for scripts and tests)
        self.stats: dict = dict(interrupts=[], stages={})
        self._idle = threading.Event()
        self._idle.set()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    # -- host side -------------------------------------------------------------------

    def submit(self, session=None, camera: Camera | None = None,
               settings: RenderSettings | None = None, border=False) -> int:
        """Restart with what changed (None/False: unchanged): the
        :class:`~rstrace_engine.session.Session` to render (edits queued on it are applied
        on the worker, under the lock, before the next frame), the view's camera, settings
        and border. Returns the job number."""
        with self._cond:
            if session is not None:
                self._job["session"] = session
            if camera is not None:
                self._job["camera"] = camera
            if settings is not None:
                self._job["settings"] = settings
            if border is not False:
                self._job["border"] = border
            self._submitted += 1
            self._t_submit = time.perf_counter()
            self._threads = numba.get_num_threads()
            self._flag.set()
            self._idle.clear()
            self._cond.notify_all()
            return self._submitted

    def latest(self) -> ViewImage | None:
        """The newest image (never blocks)."""
        return self._image

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until every submitted job has rendered all its stages (tests, benches)."""
        return self._idle.wait(timeout)

    def wait_for(self, predicate, timeout: float = 10.0) -> ViewImage | None:
        """Block until ``predicate(latest image)`` holds; the image, or None on timeout."""
        end = time.perf_counter() + timeout
        while time.perf_counter() < end:
            img = self._image
            if img is not None and predicate(img):
                return img
            time.sleep(0.002)
        return None

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout: float = 10.0) -> bool:
        """Interrupt the frame in progress and join the thread; True when it ended."""
        with self._cond:
            self._stop = True
            self._flag.set()
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    # -- worker side -----------------------------------------------------------------

    def _cancelled(self) -> bool:
        """A newer submission or stop() came (what ``self._flag`` says, as a method)."""
        return self._flag()

    def _publish(self, rgba, stage, samples, job, view_size, border, stats) -> None:
        self._generation += 1
        self._image = ViewImage(rgba, stage, samples, self._generation, job, view_size,
                                border, stats)
        if self.notify is not None:
            try:
                self.notify()
            except Exception:  # a host callback must not kill the worker
                log.exception("viewport notify failed")

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop and self._started == self._submitted:
                    self._idle.set()
                    self._cond.wait()
                if self._stop:
                    self._idle.set()
                    return
                self._flag.clear()  # under the condition: a later submit sets it again
                self._started = job = self._submitted
                t_job = self._t_submit
                threads = self._threads
                spec = dict(self._job)
            if numba.get_num_threads() != threads:
                numba.set_num_threads(threads)
            try:
                self._render_job(job, t_job, spec)
            except SceneError as exc:
                self.error = str(exc)
                log.warning("viewport: %s", exc)
            except Exception as exc:  # keep the thread alive; the host shows the error
                self.error = f"internal error: {type(exc).__name__}: {exc}"
                log.exception("viewport render failed")

    def _interrupted(self) -> None:
        """Record how long after the newest submission this job gave up."""
        self.stats["interrupts"].append(max(0.0, time.perf_counter() - self._t_submit))

    def _render_job(self, job: int, t_job: float, spec: dict) -> None:
        session, camera = spec["session"], spec["camera"]
        settings, border = spec["settings"], spec["border"]
        if session is None or camera is None or settings is None:
            return
        with self.lock:
            session.apply()  # the queued edits (a new session is built here)
            # the session renders the view: its settings follow the view's
            settings = replace(settings, samples=1)
            if settings != session.settings:
                session.update_settings(settings)
            self.error = None
            w, h = camera.width, camera.height
            times = self.stats["stages"]
            # light edits the kept frame is relit for (BASE, per-light records): the full
            # image comes as soon as a preview would, so none is traced (a light drag)
            relight = session.relights_only(camera)
            if not relight:
                # 1. coarse: the base tracer at 1/coarse_factor resolution, without letting
                # go of the lock after the edits (a background warm-up would take it in
                # between)
                cam = coarse_camera(camera, self.coarse_factor)
                cb = _coarse_border(border, self.coarse_factor, cam.width, cam.height)
                # one light and one glossy sample (a metal's first rough bounce draws
                # two: glossy_rays.LOBE_COUNTS): the preview is shown once, never
                # averaged in, and soft lights and rough surfaces would multiply its cost by
                # their samples (the full image and the refinement take the scene's counts:
                # n passes give F12's n samples)
                rgb, _, done = trace_view(
                    session, cam, replace(settings, light_samples=1, glossy_samples=1),
                    self._flag, cb, tile_rays=self.tile_rays)
        if not relight:
            if not done:
                return self._interrupted()
            times["coarse_ms"] = 1e3 * (time.perf_counter() - t_job)
            self._publish(_rgba(rgb, cb, cam.width, cam.height), STAGE_COARSE, 0, job,
                          (w, h), border, dict(ms_since_edit=times["coarse_ms"]))
        # 2. full resolution in the session's mode (incremental when only edits happened),
        # through the view's camera (a CameraChange when the view moved)
        with self.lock:
            report = session.last_report
            frame = session.render(camera=camera, cancel=self._flag)
            moved = session.last_report is not report and session.last_report.camera_changed
        if frame.stats.get("cancelled"):
            return self._interrupted()
        times["full_ms"] = 1e3 * (time.perf_counter() - t_job)
        fs = frame.stats
        fstats = dict(ms_since_edit=times["full_ms"], mode=fs.get("mode"),
                      incremental=fs.get("incremental"), dirty_fraction=fs.get("dirty_fraction"),
                      interpolated_fraction=fs.get("interpolated_fraction"),
                      render_ms=1e3 * fs.get("time_s", 0.0))
        if moved:
            fstats["camera_changed"] = True
        rgb = _mask_border(frame.radiance, border)
        self.last_frame = frame
        self._publish(_rgba(rgb, border, w, h), STAGE_FULL, 1, job, (w, h), border, fstats)
        # 3. refinement: further stratified samples (the pixel centre was sample 0 of 1)
        n = self.samples
        acc = rgb.astype(np.float64) if n > 1 else None
        for k in range(1, n):
            with self.lock:
                rgb, _, done = trace_view(session, camera, settings, self._flag, border,
                                          sample=k, samples=n, tile_rays=self.tile_rays)
            if not done:
                return self._interrupted()
            acc += rgb
            img = (acc / (k + 1)).astype(np.float32)
            self._publish(_rgba(img, border, w, h), STAGE_REFINE, k + 1, job, (w, h), border,
                          dict(fstats, ms_since_edit=1e3 * (time.perf_counter() - t_job)))
