"""Edits handed to a session from another thread: ``Session.submit`` queues them, the next
``apply()`` or ``render()`` applies them first; ``render(camera=)`` applies a new camera;
``build=False`` defers validation and the accelerator to the first apply or render; a queued
batch that fails marks the session failed."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import edits as E
from rstrace_engine.geometry.scene import Scene, SceneError
from rstrace_engine.session import Session

SETTINGS = RenderSettings(max_depth=2)


@pytest.fixture(scope="module")
def scene():
    return scenes.three_spheres(40, 30, subdivisions=2)


def _moved(scene, dx=0.2):
    key = scene.instances[1]["key"]
    m = scene.instances[1]["matrix"].copy()
    m[0, 3] += dx
    return E.ObjectTransform(key, m)


def test_a_queued_edit_rendered_equals_apply_then_render(scene):
    queued, applied = Session(scene, SETTINGS), Session(scene, SETTINGS)
    queued.render()
    applied.render()
    edit = _moved(scene)
    queued.submit([edit])
    assert queued.last_report is None  # submit runs nothing
    a = queued.render()
    report = applied.apply([edit])
    b = applied.render()
    np.testing.assert_array_equal(a.radiance, b.radiance)
    assert a.stats["incremental"] and b.stats["incremental"]
    assert queued.last_report.kinds == report.kinds == {"ObjectTransform": 1}
    assert queued.last_report.dirty_pixels == report.dirty_pixels
    fresh = Session(applied.scene, SETTINGS).render()
    np.testing.assert_array_equal(a.radiance, fresh.radiance)


def test_queued_edits_apply_in_order_before_the_given_ones(scene):
    s = Session(scene, SETTINGS)
    s.submit([_moved(scene, 0.1)])
    s.submit([_moved(scene, 0.3)])
    last = _moved(scene, -0.2)
    report = s.apply([last])
    assert report.edits == 3 and s.last_report is report
    np.testing.assert_array_equal(s.scene.instances[1]["matrix"], last.matrix)
    assert s.apply().edits == 0 and s.last_report is report  # nothing left to apply


def test_render_through_another_camera(scene):
    s = Session(scene, SETTINGS)
    s.render()
    report = s.last_report
    s.render(camera=replace(scene.camera))  # the same rays: nothing applied
    assert s.last_report is report
    cam = replace(scene.camera, matrix=scene.camera.matrix.copy())
    cam.matrix[0, 3] += 0.3
    s.submit([_moved(scene)])
    frame = s.render(camera=cam)
    assert s.last_report.camera_changed and s.last_report.kinds == {"CameraChange": 1}
    assert not frame.stats["incremental"]
    assert E.same_camera(s.scene.camera, cam)
    np.testing.assert_array_equal(s.scene.instances[1]["matrix"], _moved(scene).matrix)
    np.testing.assert_array_equal(frame.radiance, Session(s.scene, SETTINGS).render().radiance)


def test_build_false_defers_the_work_to_the_first_apply_or_render(scene):
    s = Session(scene, SETTINGS, build=False)
    assert s.accel is None
    s.submit([_moved(scene)])
    frame = s.render()
    assert s.accel is not None and s.last_report.kinds == {"ObjectTransform": 1}
    np.testing.assert_array_equal(frame.radiance,
                                  Session(s.scene, SETTINGS).render().radiance)
    # a scene that cannot be packed: refused by the first apply, which fails the session
    with pytest.raises(SceneError, match="no objects"):
        Session(Scene(), SETTINGS)
    lazy = Session(Scene(), SETTINGS, build=False)  # (nothing checked yet)
    with pytest.raises(SceneError, match="no objects"):
        lazy.apply()
    assert "no objects" in lazy.failed


def test_a_failed_queued_batch_fails_the_session(scene):
    s = Session(scene, SETTINGS)
    s.render()
    with pytest.raises(SceneError):  # a bad batch of the caller's own: refused, not failed
        s.apply([E.ObjectDelete("no such object")])
    assert s.failed is None
    s.submit([_moved(scene), E.ObjectDelete("no such object")])
    with pytest.raises(SceneError, match="no such object"):
        s.render()
    assert "no such object" in s.failed
    assert s.scene.instances[1]["matrix"][0, 3] == scene.instances[1]["matrix"][0, 3]
    with pytest.raises(SceneError, match="no such object"):  # sticky
        s.render()


def test_submit_from_many_threads_keeps_every_edit(scene):
    s = Session(scene, SETTINGS, build=False)
    edits = [_moved(scene, 0.01 * k) for k in range(40)]

    def hand(part):
        for e in part:
            s.submit([e])

    threads = [threading.Thread(target=hand, args=(edits[k::4],)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert s.apply().edits == 40
