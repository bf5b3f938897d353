"""Cancelling inside a frame (rstrace_engine.cancel): a CancelFlag stops the BVH's kernel and
the tile in progress, leaves nothing incomplete marked done, never touches persistent
caches, and changes nothing at all while it is not set."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.cancel import CancelFlag
from rstrace_engine.frame import CLASS_BACKGROUND, RenderSettings
from rstrace_engine.geometry.cameras import camera_params, camera_rays
from rstrace_engine.interactive import trace_view
from rstrace_engine.session import Session
from rstrace_engine.tracing.whitted import render


@pytest.fixture(scope="module")
def scene():
    return scenes.three_spheres(40, 30, subdivisions=2)


def _rays(scene):
    cp = camera_params(scene.camera)
    return camera_rays(cp, np.arange(cp.width * cp.height, dtype=np.int64), None)


def test_flag_stops_the_bvh_kernel_only_when_bound_and_set(scene):
    session = Session(scene, RenderSettings())
    accel = session.accel
    o, d, t0, t1 = _rays(scene)
    ref = accel.closest_hit(o, d, t0, t1)
    assert (ref.inst >= 0).sum() > 100
    flag = CancelFlag()
    with accel.cancellable(flag):  # bound, not set: the same hits
        same = accel.closest_hit(o, d, t0, t1)
    for a, b in zip(ref, same, strict=True):
        np.testing.assert_array_equal(a, b)
    flag.set()
    with accel.cancellable(flag):  # set before the query: every work item is skipped
        stopped = accel.closest_hit(o, d, t0, t1)
    assert (stopped.inst < 0).all()
    # outside the block the accelerator is not cancellable any more
    again = accel.closest_hit(o, d, t0, t1)
    np.testing.assert_array_equal(again.inst, ref.inst)
    # a plain callable binds nothing
    with accel.cancellable(lambda: True):
        np.testing.assert_array_equal(accel.closest_hit(o, d, t0, t1).inst, ref.inst)


def test_unset_flag_changes_nothing(scene):
    settings = RenderSettings(max_depth=2, samples=2)
    session = Session(scene, settings)
    ref = render(scene, settings, accel=session.accel)
    flagged = render(scene, settings, accel=session.accel, cancel=CancelFlag())
    np.testing.assert_array_equal(flagged.radiance, ref.radiance)
    np.testing.assert_array_equal(flagged.pixel_class, ref.pixel_class)
    assert not flagged.stats["cancelled"]
    cam = scene.camera
    rgb, _, done = trace_view(session, cam, settings, tile_rays=300)
    rgb_f, _, done_f = trace_view(session, cam, settings, cancel=CancelFlag(), tile_rays=300)
    assert done and done_f
    np.testing.assert_array_equal(rgb, rgb_f)
    isettings = RenderSettings(mode="INTERPOLANT", epsilon=0.05, max_depth=2)
    a = Session(scene, isettings).render()
    b = Session(scene, isettings).render(cancel=CancelFlag())
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.pixel_class, b.pixel_class)


class _SetOnQuery:
    """Sets ``flag`` just before query number ``at`` of ``accel.closest_hit`` (a cancel that
    arrives while a tile's kernels run)."""

    def __init__(self, accel, flag, at):
        self.accel, self.flag, self.at, self.calls = accel, flag, at, 0
        self.inner = accel.closest_hit
        accel.closest_hit = self

    def __call__(self, *args):
        self.calls += 1
        if self.calls == self.at:
            self.flag.set()
        return self.inner(*args)

    def remove(self):
        del self.accel.closest_hit


def test_cancel_mid_tile_drops_the_tile(scene, monkeypatch):
    import rstrace_engine.tracing.whitted as whitted

    settings = RenderSettings(max_depth=1)
    session = Session(scene, settings)
    ref = session.render()
    monkeypatch.setattr(whitted, "TILE_RAYS", scene.camera.width * 10)  # tiles of 10 rows
    flag = CancelFlag()
    # query 1: tile 1's primary rays, 2: its reflections, 3: tile 2's primary rays
    spy = _SetOnQuery(session.accel, flag, 3)
    frame = render(scene, settings, accel=session.accel, cancel=flag)
    spy.remove()
    assert spy.calls == 3  # nothing was queried after the cancel
    assert frame.stats["cancelled"] and frame.stats["rows_done"] == 10
    np.testing.assert_array_equal(frame.radiance[:10], ref.radiance[:10])
    assert (frame.radiance[10:] == 0).all()
    assert (frame.pixel_class[10:] == CLASS_BACKGROUND).all()


def test_cancelled_session_frame_is_dropped_and_next_is_exact(scene):
    """A frame cancelled inside its kernels is not kept as the base of incremental frames
    (nor its records); the next frame equals a fresh one. INTERPOLANT: a cancel during the
    visibility query builds no interpolant."""
    for mode in ("BASE", "INTERPOLANT"):
        settings = RenderSettings(mode=mode, epsilon=0.05, max_depth=2)
        fresh = Session(scene, settings).render()
        session = Session(scene, settings)
        flag = CancelFlag()
        spy = _SetOnQuery(session.accel, flag, 1)
        frame = session.render(cancel=flag)
        spy.remove()
        assert frame.stats["cancelled"]
        assert session.frame is None and session.records is None
        if mode == "INTERPOLANT":
            assert session.interpolants.cache.pool.n_live == 0
        again = session.render()
        assert not again.stats["cancelled"] and not again.stats["incremental"]
        np.testing.assert_array_equal(again.radiance, fresh.radiance)
        np.testing.assert_array_equal(again.pixel_class, fresh.pixel_class)


def test_trace_view_cancel_mid_tile(scene):
    session = Session(scene, RenderSettings(max_depth=1))
    cam = scene.camera
    flag = CancelFlag()
    spy = _SetOnQuery(session.accel, flag, 2)  # during the first tile's reflections
    rgb, _, done = trace_view(session, cam, session.settings, cancel=flag,
                              tile_rays=cam.width * 30)
    spy.remove()
    assert not done and (rgb == 0).all()  # nothing of the incomplete tile is kept
    flag.clear()
    rgb2, _, done2 = trace_view(session, replace(cam), session.settings, cancel=flag)
    ref, _, _ = trace_view(session, cam, session.settings)
    assert done2
    np.testing.assert_array_equal(rgb2, ref)
