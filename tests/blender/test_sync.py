"""One route for a change (``addon.sync``): F12 and the viewport both reach the scene's core
session through ``sync.sync`` and nowhere else; the viewport's worker runs no add-on code
(the session applies the edits it was handed); a queued batch that fails on the worker makes
the next viewport update start afresh, and the view renders right again."""

from __future__ import annotations

import threading
from pathlib import Path

import bpy
import numpy as np

from .test_glue import FakeEngine
from .test_viewport import _camera, _settled, _start, _view


def test_f12_and_the_viewport_go_through_one_sync(monkeypatch):
    """Every sync of either path is one ``sync.sync`` call, and the mirror is diffed and
    committed, and the session told, only inside it."""
    import addon
    from rstrace_engine.session import Session

    calls, outside = [], []
    depth = [0]
    real_sync = addon.sync.sync

    def counted(state, depsgraph, source, *args, **kwargs):
        calls.append(source)
        depth[0] += 1
        try:
            return real_sync(state, depsgraph, source, *args, **kwargs)
        finally:
            depth[0] -= 1

    def inside_only(name, real):
        def check(*args, **kwargs):
            if depth[0] == 0:
                outside.append(name)
            return real(*args, **kwargs)
        return check

    monkeypatch.setattr(addon.sync, "sync", counted)
    Mirror = addon.depsgraph_diff.SceneMirror
    for name in ("diff", "commit"):
        monkeypatch.setattr(Mirror, name, inside_only(name, getattr(Mirror, name)))
    monkeypatch.setattr(Session, "submit", inside_only("submit", Session.submit))

    sc, vr = _start()
    try:
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        bpy.data.objects["RedSphere"].location.x += 0.2
        bpy.context.view_layer.update()  # -> view_update
        _settled(vr)
        assert calls == ["VIEWPORT", "VIEWPORT"]
        engine = FakeEngine()
        addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
        assert not engine.errors, engine.errors
        assert calls == ["VIEWPORT", "VIEWPORT", "RENDER"]
        assert addon.last_render_stats(sc)["new_session"] is False  # the viewport's session
    finally:
        vr.free()
    assert outside == []


def test_the_viewport_worker_runs_no_addon_code():
    """Every Python function the worker thread calls, from its start through a first image
    and an edit's image, comes from outside the add-on package: it is handed a core session
    (and the view), never a callable into the add-on."""
    import addon
    from rstrace_engine.session import Session

    addon_dir = str(Path(addon.__file__).parent)
    called: set = set()

    def profile(frame, event, _arg):
        if event == "call":
            called.add((threading.get_ident(), frame.f_code.co_filename))

    threading.setprofile(profile)  # (threads started from now on: the worker)
    try:
        sc, vr = _start()
    finally:
        threading.setprofile(None)
    try:
        worker = vr.worker
        assert not any(callable(v) for v in worker._job.values())
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        bpy.data.objects["RedSphere"].location.x += 0.2
        bpy.context.view_layer.update()
        img = _settled(vr)
        assert img.stats.get("incremental")
        assert isinstance(worker._job["session"], Session)
        mine = {f for t, f in called if t == worker._thread.ident}
        assert any("rstrace_engine" in f for f in mine)  # (the profile saw the worker)
        assert not [f for f in mine if f.startswith(addon_dir)]
    finally:
        vr.free()


def test_a_failed_queued_batch_starts_the_viewport_afresh():
    """A queued batch fails on the worker (the mirror already counted it as held): the
    session is marked failed, the worker says so; the next view_update drops it, walks the
    whole scene into a new session, and the view renders that scene right."""
    import addon
    from rstrace_engine.geometry import edits as E
    from rstrace_engine.session import Session

    sc, vr = _start()
    try:
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        state = addon.session.state_for(sc)
        broken = state.session
        broken.submit([E.ObjectDelete("no such object")])  # as if synced and committed
        vr.worker.submit()
        assert vr.worker.wait_idle(60) and "no such object" in vr.worker.error
        assert "no such object" in broken.failed
        red = bpy.data.objects["RedSphere"]
        red.location.x += 0.3
        bpy.context.view_layer.update()  # -> view_update -> sync: afresh
        img = _settled(vr)
        session = state.session
        assert session is not broken and session.failed is None
        assert vr.worker._job["session"] is session
        assert img.stats.get("incremental") is False  # a new session: a full frame
        slot = session.scene.instance_slot(red.session_uid)
        np.testing.assert_allclose(session.scene.instances[slot]["matrix"],
                                   np.array(red.matrix_world), atol=1e-6)
        fresh = Session(session.scene, session.settings).render()
        np.testing.assert_array_equal(vr.worker.last_frame.radiance, fresh.radiance)
        # and edits go on incrementally on the new session
        red.location.x -= 0.3
        bpy.context.view_layer.update()
        img = _settled(vr)
        assert state.session is session and img.stats.get("incremental")
    finally:
        vr.free()


def test_f12_starts_afresh_after_a_failed_viewport_session():
    """F12 after the viewport's session failed: a new session (not the failed one), and the
    viewport follows it at its next draw."""
    import addon
    from rstrace_engine.geometry import edits as E

    sc, vr = _start()
    try:
        sc.render.resolution_x, sc.render.resolution_y = 40, 30
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        state = addon.session.state_for(sc)
        broken = state.session
        broken.submit([E.ObjectDelete("no such object")])
        vr.worker.submit()
        assert vr.worker.wait_idle(60) and broken.failed
        engine = FakeEngine()
        addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
        assert not engine.errors, engine.errors
        assert addon.last_render_stats(sc)["new_session"] and state.session is not broken
        vr.follow_session()  # (view_draw calls it)
        img = _settled(vr)
        assert vr.worker._job["session"] is state.session and img.stage == "refine"
    finally:
        vr.free()



def test_the_f12_build_thread_keeps_the_renders_thread_count():
    """``sync.build`` runs the scene's construction and its BVH build on a thread of its
    own; numba's thread count is thread-local (a new thread starts at
    ``NUMBA_NUM_THREADS``), so the render's Threads setting (``runtime.set_threads``, on
    the render thread) must be carried over: else a Fixed 1 would still run the builds'
    parallel loops and ``rstrace_engine.beside`` on two threads (main: this fails)."""
    import numba
    import pytest

    from addon import sync

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one thread only here")
    seen = []

    class Made:
        def apply(self, cancel=None):
            seen.append(("apply", numba.get_num_threads()))

    def make(flag):
        seen.append(("make", numba.get_num_threads(), threading.get_ident()))
        return Made()

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        sync.build(make, 0, cancel=lambda: False)
    finally:
        numba.set_num_threads(before)
    assert seen[0][2] != threading.get_ident()  # (the build's own thread)
    assert [s[:2] for s in seen] == [("make", 1), ("apply", 1)]
