"""The session glue driven by a stand-in for Blender's RenderEngine: progress, statistics,
memory, cancelling between batches, the "compiling kernels" status, and two renders at once
(viewport and F12 run on different threads in Blender)."""

from __future__ import annotations

import threading
import time

import bpy
import numpy as np

from . import builders as b


class _Pass:
    def __init__(self, channels: int, w: int, h: int):
        self.channels, self.size = channels, w * h
        self.rect = self
        self.data = None

    def foreach_set(self, values):
        values = np.asarray(values)
        assert values.size == self.size * self.channels
        self.data = values


class _Result:
    def __init__(self, w, h, extra):
        passes = {"Combined": _Pass(4, w, h)}
        passes.update({name: _Pass(ch, w, h) for name, ch in extra})
        self.layers = [type("Layer", (), {"passes": passes})()]
        self.resolution_x, self.resolution_y = w, h


class FakeEngine:
    """Records what the glue asks of Blender; ``cancel_after`` progress calls, test_break."""

    is_animation = False
    camera_override = None

    def __init__(self, cancel_after: int | None = None):
        self.cancel_after = cancel_after
        self.progress, self.info, self.memory, self.reports = [], [], [], []
        self.errors, self.extra, self.results = [], [], []

    def test_break(self):
        return self.cancel_after is not None and len(self.progress) >= self.cancel_after

    def update_progress(self, f):
        self.progress.append(f)

    def update_stats(self, stats, info):
        self.info.append(info)

    def update_memory_stats(self, memory_used=0.0, memory_peak=0.0):
        self.memory.append((memory_used, memory_peak))

    def report(self, kind, message):
        self.reports.append((kind, message))

    def error_set(self, message):
        self.errors.append(message)

    def add_pass(self, name, channels, chan_id, layer=""):
        self.extra.append((name, channels))

    def begin_result(self, x, y, w, h, layer="", view=""):
        result = _Result(w, h, self.extra)
        self.results.append(result)
        return result

    def end_result(self, result, cancel=False, highlight=False, do_merge_results=False):
        pass


def _render(engine):
    import addon

    dg = bpy.context.evaluated_depsgraph_get()
    addon.session.FrameRenderer(engine).render(dg)
    return addon.session.state_for(bpy.context.scene)


def _nothing_to_report():
    """The three spheres' rough plastics without their specular layer: no rough reflection
    to report, so the scene has nothing the engine does not model."""
    for mat in bpy.data.materials:
        node = mat.node_tree.nodes.get("Principled BSDF") if mat.node_tree else None
        if node is not None and node.inputs["Metallic"].default_value == 0.0:
            node.inputs["Specular IOR Level"].default_value = 0.0


def test_progress_stats_memory_and_passes():
    b.three_spheres_scene(40, 30)
    b.set_world((0.0, 0.0, 0.0))
    _nothing_to_report()
    engine = FakeEngine()
    state = _render(engine)
    assert not engine.errors and state.error is None
    assert engine.progress and engine.progress == sorted(engine.progress)
    assert engine.progress[-1] == 1.0
    assert engine.info[-1].startswith("RSTrace | BASE | 40x30")
    assert engine.memory and engine.memory[-1][0] > 0.0
    assert "warning" not in engine.info[-1]
    passes = engine.results[-1].layers[0].passes
    combined = passes["Combined"].data.reshape(30, 40, 4)
    assert np.all(combined[..., 3] == 1.0) and combined[..., :3].max() > 0.1
    assert passes["Interpolation"].data.shape == (30 * 40 * 3,)


def test_cancel_between_batches_keeps_a_partial_frame():
    sc = b.three_spheres_scene(64, 48)
    sc.rstrace.samples = 64  # 16 rows per batch: three batches
    engine = FakeEngine(cancel_after=1)
    state = _render(engine)
    assert not engine.errors
    assert state.stats["cancelled"] and 0 < state.stats["rows_done"] < 48
    assert "cancelled" in engine.info[-1]
    combined = engine.results[-1].layers[0].passes["Combined"].data.reshape(48, 64, 4)
    rows = state.stats["rows_done"]
    assert combined[:rows, :, :3].max() > 0.1 and combined[rows:, :, :3].max() == 0.0


def test_status_line_counts_warnings():
    b.three_spheres_scene(16, 12)
    b.set_world((0.0, 0.0, 0.0))
    _nothing_to_report()
    bpy.data.lights["Fill"].use_shadow = False  # not modelled: said by name
    engine = FakeEngine()
    state = _render(engine)
    assert "1 warning" in engine.info[-1]
    assert any("shadows turned off" in w for w in state.stats["export_warnings"])
    assert [k for k, m in engine.reports] == [{"WARNING"}] and "'Fill'" in engine.reports[0][1]


def test_status_line_and_panel_give_shadow_rays_per_pixel():
    """Soft lights cost Light Samples shadow rays each: the status line and the Last Render
    panel say how many the frame traced per pixel."""
    from addon import session

    sc = b.three_spheres_scene(16, 12)
    bpy.data.lights["Key"].shadow_soft_size = 0.5
    sc.rstrace.light_samples = 4
    engine = FakeEngine()
    state = _render(engine)
    rays = state.stats["shadow_rays"]
    assert rays > 16 * 12  # the key light takes 4 per shading point, the fill 1
    per_pixel = f"{rays / (16 * 12):.1f} shadow rays/px"
    assert per_pixel in engine.info[-1]
    skipped = state.stats["shadow_rays_skipped"]  # proven unoccluded (shaft_skip.py)
    assert session.shadow_rays_text(state.stats) == (
        f"{rays:,} shadow rays, {rays / (16 * 12):.1f} per pixel"
        + (f" (+{skipped / (16 * 12):.1f} proven, not traced)" if skipped else ""))
    assert session.shadow_rays_per_pixel({"width": 4, "height": 2}) is None


def test_first_render_says_compiling_kernels(tmp_path, monkeypatch):
    from addon import runtime

    b.three_spheres_scene(16, 12)
    monkeypatch.setitem(runtime._state, "cache_dir", str(tmp_path))  # an empty cache
    monkeypatch.setitem(runtime._state, "kernels_ready", False)
    engine = FakeEngine()
    _render(engine)
    assert any("compiling kernels" in line for line in engine.info)
    assert runtime._state["kernels_ready"]
    engine = FakeEngine()
    _render(engine)
    assert not any("kernels" in line for line in engine.info)


def test_two_renders_at_once_are_serialised(monkeypatch):
    from rstrace_engine import session as core

    b.three_spheres_scene(32, 24)
    intervals = []
    original = core.Session.render

    def timed(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            intervals.append((t0, time.perf_counter()))

    monkeypatch.setattr(core.Session, "render", timed)
    engines = [FakeEngine(), FakeEngine()]
    dg = bpy.context.evaluated_depsgraph_get()
    import addon

    threads = [threading.Thread(target=addon.session.FrameRenderer(e).render, args=(dg,))
               for e in engines]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not any(t.is_alive() for t in threads)
    assert all(not e.errors for e in engines)
    (a0, a1), (b0, b1) = sorted(intervals)
    assert a1 <= b0  # no overlap: the lock serialised the two renders
    images = [e.results[-1].layers[0].passes["Combined"].data for e in engines]
    np.testing.assert_array_equal(images[0], images[1])
