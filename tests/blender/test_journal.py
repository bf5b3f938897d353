"""Sync that follows the edit (issue 26): between renders the add-on's journal
(:mod:`addon.journal`, fed by ``depsgraph_update_post``) says which meshes may have changed,
so an F12 after a move reads and fingerprints nothing; whatever the journal cannot vouch
for (a gap: undo, file load, the handler gone; a mesh that depends on the frame; a modifier
reading another object) falls back to the exact fingerprint check. Every F12 must equal a
render from nothing (a new mirror and cache, not only a new session); BASE bit for bit.

Also: a long first F12 says what it does in the status line and Esc stops it within 0.5 s,
leaving the scene's session as it was (tests with a build made slow on purpose)."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from . import builders as b
from .test_glue import FakeEngine


@pytest.fixture
def counted(monkeypatch):
    """Counts the fingerprint checks of cached meshes (calls before any array was read:
    a new read passes the arrays it read)."""
    import addon

    calls = []
    real = addon.export.mesh_fingerprint

    def fingerprint(me, raw=None):
        if not raw:
            calls.append(me.name)
        return real(me, raw)

    monkeypatch.setattr(addon.export, "mesh_fingerprint", fingerprint)
    return calls


def _scene():
    sc = b.three_spheres_scene(32, 24)
    sc.rstrace.samples = 1
    big = bpy.data.objects["MirrorSphere"]
    return sc, big


def _f12(engine=None):
    """F12 on the scene's persistent session (the viewport depsgraph, as the glue tests)."""
    import addon

    sc = bpy.context.scene
    engine = engine or FakeEngine()
    addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
    state = addon.session.state_for(sc)
    assert not engine.errors, engine.errors
    return state.frame.radiance.copy(), dict(state.stats)


def _fresh():
    """A render from nothing: no session, no mirror, no cached mesh (the scene's state is
    put back afterwards)."""
    import addon

    sc = bpy.context.scene
    key = sc.session_uid
    saved = addon.session._STATES.pop(key, None)
    try:
        return _f12()[0]
    finally:
        addon.session._STATES.pop(key, None)
        if saved is not None:
            addon.session._STATES[key] = saved


def _check(step: str, expect_checks: bool, counted, reads=None):
    bpy.context.view_layer.update()
    n = len(counted)
    inc, stats = _f12()
    checks = len(counted) - n
    assert (checks > 0) == expect_checks, (step, counted[n:], stats["meshes_trusted"])
    if reads is not None:
        assert stats["meshes_read"] == reads, (step, stats["meshes_read"])
    np.testing.assert_array_equal(inc, _fresh(), err_msg=step)
    return stats


def test_a_move_reads_and_fingerprints_nothing(counted):
    sc, big = _scene()
    _f12()
    stats = _check("nothing", False, counted, reads=0)
    assert stats["meshes_trusted"] == 4  # (the floor and three spheres)
    red = bpy.data.objects["RedSphere"]
    red.location.x += 0.3
    stats = _check("move", False, counted, reads=0)
    assert stats["meshes_trusted"] == 4 and stats["edit_kinds"] == {"ObjectTransform": 1}


def test_mesh_edits_are_read_and_equal_a_fresh_render(counted):
    sc, big = _scene()
    _f12()
    me = big.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    co[2::3] *= 1.3
    me.vertices.foreach_set("co", co)  # (Blender 5 tags the mesh itself)
    # the journal names the edited mesh: the exact check, then the read (its arrays once)
    _check("foreach_set", True, counted, reads=1)
    me.vertices[0].co.z += 0.4  # an RNA property set
    _check("rna set", True, counted, reads=1)
    me.update()  # tagged, unchanged: checked, not read
    stats = _check("update", True, counted, reads=0)
    assert stats["meshes_trusted"] == 3
    # a modifier reading another object: the depsgraph names the modified object
    empty = bpy.data.objects.new("Target", None)
    sc.collection.objects.link(empty)
    warp = big.modifiers.new("Warp", "WARP")
    warp.object_from, warp.object_to = empty, bpy.data.objects["BlueSphere"]
    warp.strength = 0.5
    _check("modifier added", False, counted, reads=1)  # (a new key: its own mesh)
    bpy.data.objects["BlueSphere"].location.x += 0.5
    _check("modifier input moved", True, counted, reads=1)
    _check("nothing since", False, counted, reads=0)


def test_gaps_fall_back_to_the_fingerprint(counted):
    import addon

    sc, big = _scene()
    _f12()
    bpy.ops.ed.undo_push(message="start")
    big.location.z += 0.2
    bpy.context.view_layer.update()
    bpy.ops.ed.undo_push(message="moved")
    bpy.ops.ed.undo()
    sc, big = bpy.context.scene, bpy.data.objects["MirrorSphere"]  # (undo: new Python objects)
    _check("undo", True, counted)
    _check("after the check", False, counted)
    # the handler taken away (a script cleared the list): nothing is trusted
    handlers = bpy.app.handlers.depsgraph_update_post
    handlers.remove(addon.journal._on_update)
    try:
        me = big.data
        me.vertices[3].co.x += 0.3
        _check("no handler", True, counted, reads=1)
    finally:
        handlers.append(addon.journal._on_update)
        addon.journal.JOURNAL.listening = True
    _check("handler back: a gap first", True, counted)
    _check("then trusted", False, counted)
    # another view layer's updates: its depsgraph may hold what this one did not report
    # (a batch as that layer's depsgraph hands it over: Blender makes one only for a
    # window showing the layer)
    layer = sc.view_layers.new("Other")
    addon.journal.JOURNAL.note(SimpleNamespace(mode="VIEWPORT", scene=sc, view_layer=layer,
                                               updates=[]))
    _check("other view layer", True, counted)


def test_frame_dependent_meshes_are_checked_at_each_frame(counted):
    sc, big = _scene()
    # shape keys animated over frames: the same data-block, another mesh at each frame
    big.shape_key_add(name="Basis")
    key = big.shape_key_add(name="Squash")
    for p in key.data:
        p.co.z *= 0.5
    key.value = 0.0
    key.keyframe_insert("value", frame=1)
    key.value = 1.0
    key.keyframe_insert("value", frame=3)
    # a modifier whose result depends on the frame
    red = bpy.data.objects["RedSphere"]
    wave = red.modifiers.new("Wave", "WAVE")
    wave.height = 0.3
    sc.frame_set(1)
    _f12()
    for frame in (2, 3):
        sc.frame_set(frame)
        n = len(counted)
        _check(f"frame {frame}", True, counted)
        # the static meshes beside them are not checked: only those two
        assert sorted(counted[n:]) == sorted([big.data.name, red.data.name]), counted[n:]
    sc.frame_set(3)  # the same frame again: nothing to check
    _check("frame 3 again", False, counted)


def test_real_f12_after_a_move_trusts_the_meshes(counted):
    import addon

    sc, _ = _scene()
    sc.render.image_settings.media_type = "IMAGE"
    sc.render.image_settings.file_format = "PNG"
    bpy.ops.render.render()
    red = bpy.data.objects["RedSphere"]
    red.location.x += 0.3
    n = len(counted)
    bpy.ops.render.render()  # (flushes the updates to the journal before rendering)
    stats = addon.last_render_stats(sc)
    assert counted[n:] == [] and stats["meshes_read"] == 0
    assert stats["meshes_trusted"] >= 3 and stats["edit_kinds"] == {"ObjectTransform": 1}
    inc = addon.session.peek_state(sc).frame.radiance.copy()
    me = bpy.data.objects["BlueSphere"].data
    me.vertices[0].co.z += 0.5
    bpy.ops.render.render()
    stats = addon.last_render_stats(sc)
    assert stats["meshes_read"] == 1
    inc = addon.session.peek_state(sc).frame.radiance.copy()
    key = sc.session_uid
    saved = addon.session._STATES.pop(key)
    try:
        bpy.ops.render.render()
        ref = addon.session.peek_state(sc).frame.radiance.copy()
    finally:
        addon.session._STATES[key] = saved
    np.testing.assert_array_equal(inc, ref)


class _Esc(FakeEngine):
    """Esc pressed ``after`` seconds after the first test_break."""

    def __init__(self, after: float):
        super().__init__()
        self.after = after
        self.t0 = None
        self.pressed = None

    def test_break(self):
        now = time.perf_counter()
        if self.t0 is None:
            self.t0 = now
        if now - self.t0 >= self.after:
            if self.pressed is None:
                self.pressed = now
            return True
        return False


def test_esc_stops_a_long_first_build_and_leaves_no_session(monkeypatch):
    import addon
    from rstrace_engine.session import Session

    sc, _ = _scene()
    real = Session.apply
    finished = threading.Event()

    def slow_apply(self, edits=(), cancel=None):
        if self.accel is None:
            time.sleep(2.0)  # a long build that polls no flag
            try:
                return real(self, edits)
            finally:
                finished.set()
        return real(self, edits, cancel=cancel)

    monkeypatch.setattr(Session, "apply", slow_apply)
    engine = _Esc(0.3)
    addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
    returned = time.perf_counter()
    assert engine.pressed is not None and returned - engine.pressed <= 0.5
    assert not engine.errors and not engine.results  # nothing written, no error
    assert any("its BVH over" in i and "Esc cancels" in i for i in engine.info), engine.info
    state = addon.session.state_for(sc)
    assert state.session is None and not state.mirror.synced
    assert state.stats.get("cancelled")
    # the abandoned build holds the render lock until it is done, then lets it go
    assert addon.runtime.RENDER_LOCK.locked()
    assert finished.wait(30)
    deadline = time.perf_counter() + 10
    while addon.runtime.RENDER_LOCK.locked() and time.perf_counter() < deadline:
        time.sleep(0.01)
    assert not addon.runtime.RENDER_LOCK.locked()
    monkeypatch.setattr(Session, "apply", real)
    inc, stats = _f12()
    assert stats["new_session"]
    np.testing.assert_array_equal(inc, _fresh())


def test_esc_stops_a_build_at_the_core_flag_and_joins_it(monkeypatch):
    """A build that polls the core's CancelFlag (the BVH build does) stops there: the
    thread is joined and the render lock is free when the render returns."""
    import addon
    from rstrace_engine.cancel import Cancelled
    from rstrace_engine.session import Session

    sc, _ = _scene()
    real = Session.apply
    threads = set()

    def polling_apply(self, edits=(), cancel=None):
        if self.accel is None:
            threads.add(threading.current_thread())
            deadline = time.perf_counter() + 30.0
            while not cancel() and time.perf_counter() < deadline:
                time.sleep(0.01)
            raise Cancelled
        return real(self, edits, cancel=cancel)

    monkeypatch.setattr(Session, "apply", polling_apply)
    engine = _Esc(0.3)
    addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
    assert engine.pressed is not None and time.perf_counter() - engine.pressed <= 0.5
    assert not engine.errors and not engine.results
    assert addon.session.state_for(sc).stats.get("cancelled")
    assert threads and not any(t.is_alive() for t in threads)
    assert not addon.runtime.RENDER_LOCK.locked()
    monkeypatch.setattr(Session, "apply", real)
    inc, stats = _f12()
    assert stats["new_session"]
    np.testing.assert_array_equal(inc, _fresh())


def test_esc_while_reading_a_new_mesh_leaves_the_session_as_it_was():
    import addon

    sc, _ = _scene()
    _f12()
    state = addon.session.state_for(sc)
    session, objects = state.session, set(state.mirror.objects)
    b.add_object("Extra", b.uv_sphere("ExtraMesh", 0.4, 16, 8), (0.0, -1.5, 0.5))
    bpy.context.view_layer.update()
    engine = _Esc(0.0)
    addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
    assert not engine.errors and not engine.results and state.stats.get("cancelled")
    assert state.session is session and set(state.mirror.objects) == objects
    assert session.last_report is None or "ObjectAdd" not in session.last_report.kinds
    inc, stats = _f12()
    assert stats["edit_kinds"].get("ObjectAdd") == 1 and not stats["new_session"]
    np.testing.assert_array_equal(inc, _fresh())


def test_a_render_stamps_its_reads_when_it_started(counted):
    """An edit made after a render started may be missing from the render depsgraph it
    reads (GUI F12 renders on a thread): what it reads is stamped with the number at
    ``render_pre``, so the next F12 checks that mesh again."""
    import addon

    sc, big = _scene()
    _f12()
    addon.journal._on_render_pre()
    try:
        big.data.vertices[0].co.z += 0.3
        _check("edited after the render started", True, counted, reads=1)
    finally:
        addon.journal._on_render_end()
    n = len(counted)
    _check("the next F12 checks it again", True, counted, reads=0)
    assert counted[n:] == [big.data.name]
    _check("then it is trusted", False, counted, reads=0)


def test_a_new_session_over_unchanged_meshes_builds_no_mesh_bvh():
    """The mesh BVHs outlive their session (``accelerators.KEPT``): after the session is
    dropped (a render setting that restarts it, an error), the next F12 builds a new
    session whose unchanged meshes take the kept trees, and renders what a render from
    nothing renders."""
    import addon
    from rstrace_engine.accel.accelerators import KEPT

    sc, _ = _scene()
    KEPT.clear()
    _f12()
    state = addon.session.state_for(sc)
    first = state.session.accel.stats
    assert first["meshes_built"] > 0 and len(KEPT) == first["meshes_built"]
    addon.sync.drop_session(state)
    inc, stats = _f12()
    assert stats["new_session"]
    second = state.session.accel.stats
    assert second["meshes_built"] == 0 and second["meshes_kept"] == first["meshes_built"]
    KEPT.clear()
    np.testing.assert_array_equal(inc, _fresh())
    assert len(KEPT) > 0
    addon.session.forget_all()  # a file load (load_pre) lets them go with the sessions
    assert len(KEPT) == 0
