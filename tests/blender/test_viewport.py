"""The rendered viewport for real in bpy (background): view_update with real depsgraph
updates, the camera from region_data matrices, the worker (start, progressive stages,
interrupt, resize, teardown on free / file load / engine switch), drawing into a
GPUOffScreen and reading it back, and F12 while a viewport session is live."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from . import builders as b

W, H = 40, 30


@pytest.fixture(scope="module")
def gpu_context():
    """Background bpy draws with ``gpu`` only once a GPU context exists: one tiny EEVEE
    frame creates it."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "BLENDER_EEVEE"
    sc.render.resolution_x, sc.render.resolution_y = 16, 12
    sc.render.resolution_percentage = 100
    b.camera()
    bpy.ops.render.render()
    return True


def _view(w=W, h=H):
    """A stand-in for the 3D view's context: region size and region_data matrices of the
    scene camera (what Blender gives a camera view)."""
    sc = bpy.context.scene
    cam = sc.camera
    dg = bpy.context.evaluated_depsgraph_get()
    proj = cam.calc_matrix_camera(dg, x=w, y=h)
    rv3d = SimpleNamespace(view_matrix=cam.matrix_world.inverted(), window_matrix=proj,
                           view_perspective="PERSP", is_perspective=True)
    return SimpleNamespace(region=SimpleNamespace(width=w, height=h), region_data=rv3d,
                           space_data=SimpleNamespace(use_render_border=False))


class FakeEngine:
    def __init__(self):
        self.info = []

    def bind_display_space_shader(self, scene):
        pass

    def unbind_display_space_shader(self):
        pass

    def update_stats(self, stats, info):
        self.info.append(info)


def _start(mode="BASE", **settings):
    """A scene, a viewport renderer fed by depsgraph_update_post, and its first image
    (``settings``: more of the scene's RSTrace settings, set before the viewport starts)."""
    import addon

    sc = b.three_spheres_scene(W, H)
    sc.rstrace.mode = mode
    for key, value in settings.items():
        setattr(sc.rstrace, key, value)
    sc.rstrace.viewport_samples = 2
    vr = addon.viewport.ViewportRenderer()
    dg = bpy.context.evaluated_depsgraph_get()
    vr.view_update(None, dg)

    def handler(scene, depsgraph):
        vr.view_update(None, depsgraph)

    bpy.app.handlers.depsgraph_update_post.append(handler)
    return sc, vr


def _camera(ctx):
    import addon

    rv3d = ctx.region_data
    return addon.cameras.camera_from_view(rv3d.view_matrix, rv3d.window_matrix,
                                          ctx.region.width, ctx.region.height)


def _settled(vr, job=None, timeout=120):
    assert vr.worker.wait_idle(timeout)
    img = vr.worker.latest()
    assert img is not None and vr.worker.error is None, vr.worker.error
    if job is not None:
        assert img.job == job
    return img


def test_camera_from_view_matches_the_camera_object():
    import addon
    from rstrace_engine.geometry.cameras import camera_rays

    sc = b.three_spheres_scene(W, H)
    sc.camera.data.shift_x = 0.1
    ctx = _view()
    view_cam = _camera(ctx)
    dg = bpy.context.evaluated_depsgraph_get()
    obj_cam = addon.cameras.camera_from_object(sc.camera.evaluated_get(dg), W, H, sc.render,
                                               addon.materials.Notes())
    o1, d1, _, _ = camera_rays(view_cam)
    o2, d2, _, _ = camera_rays(obj_cam)
    np.testing.assert_allclose(o1, o2, atol=1e-5)
    np.testing.assert_allclose(d1, d2, atol=1e-5)
    # orthographic
    sc.camera.data.type = "ORTHO"
    view_cam = _camera(_view())
    obj_cam = addon.cameras.camera_from_object(sc.camera.evaluated_get(
        bpy.context.evaluated_depsgraph_get()), W, H, sc.render, addon.materials.Notes())
    np.testing.assert_allclose(camera_rays(view_cam)[1], camera_rays(obj_cam)[1], atol=1e-6)
    o1, o2 = camera_rays(view_cam)[0], camera_rays(obj_cam)[0]
    axis = np.asarray(obj_cam.matrix)[:3, 2]
    off = (o1 - o2) - np.outer((o1 - o2) @ axis, axis)  # same rays up to a shift along them
    assert np.abs(off).max() < 1e-5


def test_worker_renders_progressively_and_draws_into_an_offscreen(gpu_context):
    import gpu
    from mathutils import Matrix

    from rstrace_engine.session import Session

    _, vr = _start()
    try:
        ctx = _view()
        engine = FakeEngine()
        vr.view_draw(engine, ctx, bpy.context.evaluated_depsgraph_get())
        img = _settled(vr)
        stages = vr.worker.stats["stages"]
        assert "coarse_ms" in stages and "full_ms" in stages
        assert img.stage == "refine" and img.samples == 2 and img.view_size == (W, H)
        # the full-resolution frame equals a fresh render of the same camera (BASE, 1 spp)
        import addon

        state = addon.session.state_for(bpy.context.scene)
        fresh = Session(state.session.scene, state.session.settings).render()
        np.testing.assert_array_equal(vr.worker.last_frame.radiance, fresh.radiance)
        # draw into an offscreen in region pixel space and read it back
        off = gpu.types.GPUOffScreen(W, H, format="RGBA32F")
        with off.bind():
            fb = gpu.state.active_framebuffer_get()
            fb.clear(color=(0.0, 0.0, 0.0, 0.0))
            with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                gpu.matrix.load_matrix(Matrix.Identity(4))
                proj = Matrix.Identity(4)
                proj[0][0], proj[1][1] = 2.0 / W, 2.0 / H
                proj[0][3], proj[1][3] = -1.0, -1.0
                gpu.matrix.load_projection_matrix(proj)
                vr.view_draw(engine, ctx, bpy.context.evaluated_depsgraph_get())
            px = np.array(fb.read_color(0, 0, W, H, 4, 0, "FLOAT").to_list(), np.float32)
        off.free()
        px = px.reshape(H, W, 4)
        np.testing.assert_allclose(px, vr.worker.latest().rgba, atol=1e-3)
        assert px[..., :3].max() > 0.05
        assert engine.info and engine.info[-1].startswith("RSTrace | 2 samples")
    finally:
        vr.free()


def test_edit_interrupts_and_rerenders_incrementally():
    import addon

    sc, vr = _start()
    try:
        ctx = _view()
        vr.draw_view(_camera(ctx), None)
        _settled(vr)
        state = addon.session.state_for(sc)
        session = state.session
        red = bpy.data.objects["RedSphere"]
        red.location.x += 0.3
        bpy.context.view_layer.update()  # -> depsgraph_update_post -> view_update
        assert vr.last_edits == 1
        img = _settled(vr)
        assert state.session is session  # edits applied, not a rebuild
        assert img.stats.get("incremental") and img.stats["dirty_fraction"] < 0.5
        # selection and colour management are not edits: nothing restarts
        jobs = vr.worker._submitted
        red.select_set(True)
        sc.view_settings.exposure = 0.5
        bpy.context.view_layer.update()
        assert vr.worker._submitted == jobs and vr.last_edits == 0
        # interrupt: a camera change while refining
        vr.worker.samples = 64
        cam = _camera(ctx)
        cam.matrix[2, 3] += 0.05
        job = vr.worker.submit(camera=cam)
        assert vr.worker.wait_for(lambda im: im.job == job and im.stage == "refine", 60)
        moved = _camera(_view())
        moved.matrix[0, 3] += 0.1
        n = len(vr.worker.stats["interrupts"])
        job = vr.worker.submit(camera=moved)
        vr.worker.samples = 2
        img = _settled(vr, job)
        assert len(vr.worker.stats["interrupts"]) == n + 1
        assert img.stage == "refine"
    finally:
        vr.free()


def test_resize_rerenders_without_rebuilding_the_session():
    import addon

    sc, vr = _start()
    try:
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        session = addon.session.state_for(sc).session
        vr.draw_view(_camera(_view(24, 20)), None)
        img = _settled(vr)
        assert img.view_size == (24, 20) and img.rgba.shape == (20, 24, 4)
        assert addon.session.state_for(sc).session is session
        # a render border: only its pixels are drawn
        vr.draw_view(_camera(_view(24, 20)), (4, 5, 10, 8))
        img = _settled(vr)
        alpha = img.rgba[..., 3]
        assert alpha[5:13, 4:14].min() == 1.0 and alpha.sum() == 80
    finally:
        vr.free()


def _alive(vr) -> bool:
    return vr.worker is not None and vr.worker.alive


def test_teardown_on_free_file_load_and_engine_switch():
    import addon

    threads = set(threading.enumerate())
    sc, vr = _start()
    vr.draw_view(_camera(_view()), None)
    worker = vr.worker
    vr.free()
    assert not worker.alive and vr.worker is None
    vr.free()  # idempotent
    # leaving rendered shading / closing the file: Blender frees the engine -> free();
    # loading a file stops every viewport
    sc, vr = _start()
    vr.draw_view(_camera(_view()), None)
    worker = vr.worker
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert not worker.alive
    # switching the scene's engine stops its viewports
    sc, vr = _start()
    vr.draw_view(_camera(_view()), None)
    worker = vr.worker
    sc.render.engine = "BLENDER_WORKBENCH"
    bpy.context.view_layer.update()
    assert not worker.alive
    left = [t for t in threading.enumerate() if t not in threads
            and t.name == "rstrace-viewport"]
    assert not left
    assert addon.viewport.live_viewports() == [] or all(
        v.worker is None for v in addon.viewport.live_viewports())


def test_f12_while_the_viewport_is_live(tmp_path):
    import addon

    sc, vr = _start()
    try:
        sc.render.resolution_x, sc.render.resolution_y = W, H
        vr.draw_view(_camera(_view()), None)
        vr.worker.samples = 64  # keep the worker busy refining
        vr.worker.wait_for(lambda im: im.stage == "refine", 60)
        out = b.render_exr(tmp_path / "f12.exr")  # real F12 (bpy.ops.render.render)
        state = addon.session.state_for(sc)
        assert state.error is None, state.messages
        from rstrace_engine.session import Session

        fresh = Session(state.session.scene, state.session.settings).render()
        np.testing.assert_allclose(out["Combined"][..., :3], fresh.radiance, atol=1e-3)
        # the viewport goes on afterwards, on the same session
        vr.worker.samples = 2
        job = vr.worker.submit(camera=_camera(_view()))
        img = _settled(vr, job)
        assert img.stage == "refine" and addon.session.state_for(sc).session is state.session
    finally:
        vr.free()


def test_orthographic_view_with_clipping_behind_the_eye():
    """Blender's orthographic user views clip from -far/2: the eye moves back so that the
    camera's clipping range starts at 0 and still covers what the view shows."""
    import addon
    from rstrace_engine.geometry.cameras import camera_rays

    near, far, half = -50.0, 50.0, 4.0
    proj = np.eye(4)
    proj[0, 0], proj[1, 1] = 1.0 / half, 1.0 / (half * 0.75)
    proj[2, 2], proj[2, 3] = -2.0 / (far - near), -(far + near) / (far - near)
    view = np.eye(4)
    view[2, 3] = -10.0  # eye at z = 10 looking down -z
    cam = addon.cameras.camera_from_view(view, proj, 40, 30)
    assert cam.kind == "ORTHO" and cam.clip_start == 0.0
    assert np.isclose(cam.clip_end, 100.0) and np.isclose(cam.ortho_scale, 8.0)
    o, d, tmin, tmax = camera_rays(cam)
    assert np.allclose(d, [0.0, 0.0, -1.0])
    assert np.allclose(o[:, 2], 60.0)  # 10 + 50: the near plane behind the eye
    assert np.isclose(o[:, 0].min(), -4.0 + 0.1) and np.isclose(o[:, 0].max(), 4.0 - 0.1)


def _orbit(cam, degrees: float, centre=(0.0, 0.0, 0.5)):
    """``cam`` turned about the vertical axis through ``centre``."""
    from dataclasses import replace

    from rstrace_engine.geometry import shapes

    return replace(cam, matrix=shapes.orbit_z(degrees, centre) @ np.asarray(cam.matrix))


def test_orbit_reuses_the_interpolants():
    """INTERPOLANT mode: interpolants are view-independent; orbiting the view invalidates
    none (the same cache, every interpolant of the first view still live) and the frames
    stay within epsilon of the base tracer's."""
    from dataclasses import replace

    import addon
    from rstrace_engine.image import compare
    from rstrace_engine.session import Session

    # cells, to test them: here they do not pay, and the measured fallback would trace
    # (tests/blender/test_interpolant_mode.py, the note at its top)
    sc, vr = _start("INTERPOLANT", interpolant_fallback=False)
    sc.rstrace.max_ray_depth = 2
    try:
        cam = _camera(_view(160, 120))  # (big enough to interpolate)
        vr.draw_view(cam, None)
        _settled(vr)
        state = addon.session.state_for(sc)
        cache = state.session.interpolants.cache
        live = np.flatnonzero(cache.pool.live)
        serial = cache.pool.serial[live].copy()
        assert len(live) > 0
        for deg in (2.0, 4.0):
            vr.draw_view(_orbit(cam, deg), None)
            img = _settled(vr)
            assert img.stats.get("camera_changed")
        session = state.session
        assert session.interpolants.cache is cache and session.last_report.camera_changed
        assert session.last_report.invalidated_interpolants == 0
        assert cache.pool.live[live].all() and np.array_equal(cache.pool.serial[live], serial)
        base = Session(session.scene, replace(session.settings, mode="BASE")).render()
        eps = session.settings.epsilon
        m = compare(vr.worker.last_frame.radiance, base.radiance, eps)
        assert m["max_error"] <= eps + 1e-6, m
    finally:
        vr.free()


def test_scene_switch_replaces_the_worker():
    """The viewport showing another scene: the first scene's worker is stopped and joined,
    the other scene gets its own session."""
    import addon

    sc, vr = _start()
    try:
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        first = vr.worker
        # (a viewport gets view_update from its own depsgraph only: the test's forwarding of
        # every depsgraph_update_post stops here)
        bpy.app.handlers.depsgraph_update_post.pop()
        other = bpy.data.scenes.new("Other")
        other.render.engine = "RSTRACE"
        for ob in bpy.data.objects:
            other.collection.objects.link(ob)
        other.camera = sc.camera
        dg = other.view_layers[0].depsgraph
        dg.update()  # (evaluated: Blender does this before view_update)
        vr.view_update(None, dg)
        assert not first.alive and vr.worker is not first
        vr.draw_view(_camera(_view()), None)
        _settled(vr)
        assert vr.scene_key == other.session_uid
        assert addon.session.state_for(other).session is not None
        assert addon.session.state_for(other).session is not addon.session.state_for(sc).session
    finally:
        vr.free()


def test_status_shows_kernel_progress_and_new_images_ask_for_a_redraw(monkeypatch):
    """First use: the viewport's status text and Blender's status bar say how far the
    kernel warm-up is; a new image sets the flag the main-thread timer turns into redraws."""
    import addon

    sc, vr = _start()
    try:
        monkeypatch.setattr(addon.kernels, "progress_text", lambda: "compiling kernels 3/15")
        assert vr.status(None) == "RSTrace | compiling kernels 3/15"
        said = []
        ctx = SimpleNamespace(workspace=SimpleNamespace(status_text_set=said.append))
        vr._status_bar(ctx)
        assert said == ["RSTrace: compiling kernels 3/15"]
        monkeypatch.setattr(addon.kernels, "progress_text", lambda: None)
        vr._status_bar(ctx)
        assert said[-1] is None  # cleared once the warm-up is done
        vr.new_image.clear()
        vr.draw_view(_camera(_view()), None)
        img = _settled(vr)
        assert vr.new_image.is_set()  # the worker's notify()
        assert addon.viewport._tick() == addon.viewport._TIMER_INTERVAL
        assert not vr.new_image.is_set()  # redraws were asked for, the flag cleared
        assert vr.status(img).startswith("RSTrace | 2 samples")
    finally:
        vr.free()


def test_a_bad_view_is_said_until_a_good_one_and_settings_set_from_python_restart(
        gpu_context):
    """(1) A view whose camera cannot be rendered (a NaN view matrix) is said in the status
    line, and navigating to a good view clears it (the error used to stay until some edit
    came). (2) A setting set from Python sends no depsgraph update: the next draw sees it
    and the viewport renders in the new mode (it went on in the old one)."""
    from mathutils import Matrix

    import addon

    sc, vr = _start()
    try:
        engine = FakeEngine()
        dg = bpy.context.evaluated_depsgraph_get()
        good = _view()
        vr.view_draw(engine, good, dg)
        _settled(vr)
        bad = _view()
        bad.region_data.view_matrix = Matrix([[float("nan")] * 4] * 4)
        vr.view_draw(engine, bad, dg)
        assert engine.info[-1].startswith("RSTrace | error:") and "view" in engine.info[-1]
        vr.view_draw(engine, good, dg)
        assert vr.view_error is None and not engine.info[-1].startswith("RSTrace | error")
        # a mode set from Python: no depsgraph update, the next draw restarts the worker
        jobs = vr.worker._submitted
        sc.rstrace.mode = "INTERPOLANT"
        vr.view_draw(engine, good, dg)
        assert vr.worker._submitted == jobs + 1 and vr.settings.mode == "INTERPOLANT"
        img = _settled(vr)
        state = addon.session.state_for(sc)
        assert state.session.settings.mode == "INTERPOLANT"
        assert img.stats["mode"] == "INTERPOLANT"
        vr.view_draw(engine, good, dg)  # nothing changed: nothing restarts
        assert vr.worker._submitted == jobs + 1
    finally:
        vr.free()


def test_light_drag_relights_the_viewport():
    """Issue 21: dragging a light in the viewport (depsgraph light moves, one after the
    other) relights the kept frame from the per-light records: after the session's first
    light edit (a full frame that starts them), every step's full image is relit, no pixel
    traced."""
    sc, vr = _start()
    try:
        ctx = _view()
        vr.draw_view(_camera(ctx), None)
        _settled(vr)
        lamp = next(o for o in bpy.data.objects if o.type == "LIGHT")
        lamp.data.energy *= 0.9
        bpy.context.view_layer.update()
        _settled(vr)
        for _ in range(3):
            lamp.location.x += 0.05
            bpy.context.view_layer.update()
            assert vr.last_edits == 1
            _settled(vr)
            stats = vr.worker.last_frame.stats
            assert stats.get("relit") and stats["traced_pixels"] == 0, stats
    finally:
        vr.free()
