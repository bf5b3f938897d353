"""The viewport session without Blender (rstrace_engine.interactive): progressive stages,
edits queued on the session, interruption, stop, and images equal to the base tracer's."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import edits as E
from rstrace_engine.geometry.cameras import same_camera
from rstrace_engine.interactive import (
    STAGE_COARSE,
    STAGE_FULL,
    STAGE_REFINE,
    ViewportWorker,
    coarse_camera,
    trace_view,
)
from rstrace_engine.session import Session
from rstrace_engine.tracing.whitted import render


@pytest.fixture
def session():
    scene = scenes.three_spheres(48, 36, subdivisions=2)
    return Session(scene, RenderSettings(max_depth=2))


def test_trace_view_is_the_base_tracer(session):
    cam = session.scene.camera
    rgb, cls, done = trace_view(session, cam, session.settings, tile_rays=500)
    ref = render(session.scene, replace(session.settings, samples=1), accel=session.accel)
    assert done
    np.testing.assert_array_equal(rgb, ref.radiance)
    np.testing.assert_array_equal(cls, ref.pixel_class)
    # a border renders only its rectangle; cancel stops between tiles
    rgb_b, _, _ = trace_view(session, cam, session.settings, border=(5, 6, 10, 7))
    np.testing.assert_array_equal(rgb_b[6:13, 5:15], ref.radiance[6:13, 5:15])
    assert rgb_b.sum() == rgb_b[6:13, 5:15].sum()
    calls = []
    _, _, done = trace_view(session, cam, session.settings, tile_rays=48 * 4,
                            cancel=lambda: len(calls) > 2 or calls.append(1))
    assert not done


def test_coarse_camera_keeps_the_view():
    cam = scenes.three_spheres(64, 40).camera
    c = coarse_camera(cam, 8)
    assert (c.width, c.height) == (8, 5) and c.sensor_fit == "HORIZONTAL"
    tall = replace(cam, width=40, height=64)
    assert coarse_camera(tall, 8).sensor_fit == "VERTICAL"
    assert same_camera(cam, replace(cam)) and not same_camera(cam, c)


def test_worker_stages_edits_interrupt_and_stop(session):
    lock = threading.Lock()
    ready = []
    worker = ViewportWorker(lock, notify=lambda: ready.append(1), samples=3)
    try:
        cam = session.scene.camera
        job = worker.submit(session=session, camera=cam, settings=session.settings)
        assert worker.wait_idle(300)
        img = worker.latest()
        assert img.job == job and img.stage == STAGE_REFINE and img.samples == 3
        assert img.rgba.shape == (36, 48, 4) and len(ready) == 4  # coarse, full, 2 refines
        ref = render(session.scene, replace(session.settings, samples=1), accel=session.accel)
        np.testing.assert_array_equal(worker.last_frame.radiance, ref.radiance)
        # an edit: applied on the worker, then coarse -> full (incremental: camera unchanged)
        key = session.scene.instances[1]["key"]
        m = session.scene.instances[1]["matrix"].copy()
        m[0, 3] += 0.2
        stages = []
        worker.notify = lambda: stages.append(worker.latest().stage)
        session.submit([E.ObjectTransform(key, m)])
        job = worker.submit()
        assert worker.wait_idle(300)
        assert stages[:2] == [STAGE_COARSE, STAGE_FULL]
        full = worker.last_frame
        assert full.stats["incremental"] and full.stats["dirty_fraction"] < 1.0
        fresh = Session(session.scene, session.settings).render()
        np.testing.assert_array_equal(full.radiance, fresh.radiance)
        # interrupt: many refinement samples, then a camera move
        worker.samples = 200
        moved = replace(cam, matrix=cam.matrix.copy())
        moved.matrix[0, 3] += 0.05
        job = worker.submit(camera=moved)
        assert worker.wait_for(lambda im: im.job == job and im.stage == STAGE_REFINE, 60)
        n = len(worker.stats["interrupts"])
        worker.samples = 2
        job = worker.submit(camera=cam)
        assert worker.wait_idle(300) and worker.latest().job == job
        assert len(worker.stats["interrupts"]) == n + 1
        # resize: same session, new size
        small = replace(cam, width=24, height=18)
        job = worker.submit(camera=small)
        assert worker.wait_idle(300)
        assert worker.latest().rgba.shape == (18, 24, 4) and worker.latest().job == job
    finally:
        assert worker.stop() and not worker.alive


def test_coarse_preview_takes_one_light_sample(session, monkeypatch):
    """The coarse preview traces one light sample (it is shown once and never averaged
    in); the refinement passes take the settings' Light Samples, as F12 does."""
    import rstrace_engine.interactive as interactive

    seen = []
    real = interactive.trace_view

    def recording(session, camera, settings, *args, **kwargs):
        seen.append((camera.width, int(settings.light_samples)))
        return real(session, camera, settings, *args, **kwargs)

    monkeypatch.setattr(interactive, "trace_view", recording)
    settings = replace(session.settings, light_samples=8)
    worker = ViewportWorker(threading.Lock(), samples=2)
    try:
        worker.submit(session=session, camera=session.scene.camera, settings=settings)
        assert worker.wait_idle(300)
    finally:
        assert worker.stop()
    coarse = coarse_camera(session.scene.camera, worker.coarse_factor).width
    assert seen == [(coarse, 1), (48, 8)]  # the coarse preview, then one refinement pass


def test_worker_reports_errors_and_keeps_running(session):
    worker = ViewportWorker(threading.Lock(), samples=1)
    try:
        session.submit([E.ObjectDelete("broken")])  # (no such object)
        worker.submit(session=session, camera=session.scene.camera, settings=session.settings)
        assert worker.wait_idle(60) and "broken" in worker.error
        worker.submit(session=Session(session.scene, session.settings))
        assert worker.wait_idle(300) and worker.error is None
        assert worker.latest().stage == STAGE_FULL
    finally:
        worker.stop()


def test_light_drag_relights_without_a_coarse_preview():
    """A BASE session keeping per-light records: each small move of a light is relit from
    them (no pixel traced), shown at once as the full image (no coarse preview), equal to a
    fresh render bit for bit."""
    from rstrace_engine.bench.soak import SOAK_SCENES

    scene = SOAK_SCENES["room"](32, 24)
    settings = RenderSettings(mode="BASE", max_depth=3)
    session = Session(scene, settings)
    session.light_terms = True
    worker = ViewportWorker(threading.Lock(), samples=1)
    try:
        worker.submit(session=session, camera=scene.camera, settings=settings)
        assert worker.wait_idle(300)
        for _ in range(3):
            li = session.scene.lights[session.scene.light_slot("Lamp")]
            x, y, z = li.position
            session.submit([E.LightSet("Lamp", replace(li, position=(x + 0.05, y, z)))])
            worker.stats["stages"].clear()
            job = worker.submit()
            assert worker.wait_idle(300)
            img = worker.latest()
            assert img.job == job and img.stage == "full"
            assert "coarse_ms" not in worker.stats["stages"]
            stats = worker.last_frame.stats
            assert stats["relit"] and stats["traced_pixels"] == 0, stats
            ref = Session(session.scene.copy(), settings).render().radiance
            np.testing.assert_array_equal(worker.last_frame.radiance, ref)
    finally:
        worker.stop()


def test_worker_takes_the_hosts_thread_count(session, monkeypatch):
    """numba's thread count is per thread: the worker renders with the count of the thread
    that submits (Blender's thread setting, a benchmark's ``--threads``), not numba's
    default (it once ran every viewport frame on all threads)."""
    import numba

    seen = []
    render = Session.render

    def spy(self, *a, **kw):
        seen.append(numba.get_num_threads())
        return render(self, *a, **kw)

    monkeypatch.setattr(Session, "render", spy)
    saved = numba.get_num_threads()
    worker = ViewportWorker(threading.Lock(), samples=1)
    try:
        numba.set_num_threads(1)
        worker.submit(session=session, camera=session.scene.camera, settings=session.settings)
        assert worker.wait_idle(300) and worker.error is None
        numba.set_num_threads(saved)
        worker.submit(camera=replace(session.scene.camera))
        assert worker.wait_idle(300) and worker.error is None
    finally:
        numba.set_num_threads(saved)
        worker.stop()
    assert seen[0] == 1 and seen[-1] == saved



def test_viewport_samples_share_the_pixels_glossy_strata(monkeypatch):
    """A rough scene at 4 samples: the viewport's passes (``trace_view(sample=k,
    samples=4)``, one per sample) take each pixel's glossy strata from the frame's samples
    per pixel, so their mean is the base tracer's 4-sample frame (to float32 rounding of
    the sums); passes that each drew their own lattice (strata of one sample, the same
    jitter) give another image."""
    from rstrace_engine.tracing import glossy_strata as gs

    scene = scenes.rough_materials(32, 24)
    st = RenderSettings(max_depth=5, samples=4, glossy_samples=4, seed=3)
    s = Session(scene, st)
    ref = render(scene, st, accel=s.accel).radiance

    def passes():
        return np.mean([trace_view(s, scene.camera, st, sample=k, samples=4)[0]
                        for k in range(4)], axis=0)

    np.testing.assert_allclose(passes(), ref, rtol=1e-5, atol=1e-6)
    real = gs.pixel_strata
    monkeypatch.setattr(gs, "pixel_strata", lambda g, n, seed, spp: real(g, n, seed, 1))
    assert np.abs(passes() - ref).max() > 1e-3
