"""F12 in INTERPOLANT mode: bounded error against BASE, the Interpolation pass, reuse."""

from __future__ import annotations

import bpy
import numpy as np

from rstrace_engine.frame import CLASS_COLORS, CLASS_INTERPOLATED
from rstrace_engine.image import to_display

from . import builders as b

# These small scenes are where cells do not pay, and the measured fallback (default on)
# rightly traces them: with cells forced (the fallback off), process CPU, 1 thread, against
# the base frame, median of 6 alternated repeats (a loaded 2-core machine):
# three_spheres 160x120 1 spp depth 2 -- first frame 0.42x, the same camera again 0.80x,
# orbits of 2 and 4 degrees 0.38x / 0.51x (18-19% interpolated); the image-texture floor
# below -- 0.16x / 0.76x / 0.09x / 0.24x (57-58% interpolated: its base ray costs 0.3 us).
# So the tests of the cells turn the fallback off (setting ``interpolant_fallback``), and
# ``test_f12_reports_what_the_fallback_decided`` tests the fallback itself.


def _stats():
    import addon

    return addon.session.state_for(bpy.context.scene).stats


def _base_then_interpolant(tmp_path, width: int, height: int):
    """``three_spheres`` (1 sample, depth 2) by F12 in BASE, then INTERPOLANT (epsilon 0.02):
    the scene and both EXRs."""
    sc = b.three_spheres_scene(width, height)
    sc.rstrace.samples, sc.rstrace.max_ray_depth = 1, 2
    base = b.render_exr(tmp_path / "base.exr")
    sc.rstrace.mode, sc.rstrace.epsilon = "INTERPOLANT", 0.02
    return sc, base, b.render_exr(tmp_path / "interpolant.exr")


def test_f12_interpolant_mode_matches_base_within_epsilon(tmp_path):
    sc = b.three_spheres_scene(160, 120)
    sc.rstrace.samples = 1
    sc.rstrace.max_ray_depth = 2
    base = b.render_exr(tmp_path / "base.exr")["Combined"][..., :3]

    eps = 0.02
    sc.rstrace.mode = "INTERPOLANT"
    sc.rstrace.epsilon = eps
    sc.rstrace.interpolant_fallback = False  # cells, to test them (they do not pay here: above)
    out = b.render_exr(tmp_path / "interp.exr")
    first = _stats()
    assert first["mode"] == "INTERPOLANT" and first["cells_built"] > 0

    # the Interpolation pass shows Plate B colours, and interpolated pixels are green
    classes = out["Interpolation"].reshape(-1, 1, 3)
    match = np.all(np.isclose(classes, CLASS_COLORS[None]), axis=-1)
    assert match.any(axis=1).all()
    green = match[:, CLASS_INTERPOLATED].mean()
    print(f"interpolated {green:.1%}, cells built {first['cells_built']}")
    assert green > 0.05, f"only {green:.1%} of pixels interpolated"

    # bounded error in display space against the base tracer's frame of the same scene
    err = np.abs(to_display(out["Combined"][..., :3]) - to_display(base)).max(axis=-1)
    assert np.isfinite(out["Combined"]).all()
    # every pixel (float32 EXR: 1e-6 of display slack, see tests/test_interpolant_bound.py)
    assert err.max() <= eps + 1e-6, f"max error {err.max():.5f}, {(err > eps).sum()} over"

    # what the bound only tests (reflections, refractions) is said in the render's messages
    import addon

    state = addon.session.state_for(bpy.context.scene)
    info = [text for level, text in state.messages if level == "INFO"]
    assert info == list(first.get("bound_notes") or []), (info, first.get("bound_notes"))
    assert "bound_notes" in first

    # a second F12 with nothing changed reuses every interpolant of the persistent session
    again = b.render_exr(tmp_path / "again.exr")["Combined"][..., :3]
    assert _stats()["cells_built"] == 0
    np.testing.assert_allclose(again, out["Combined"][..., :3], atol=1e-6)


def test_f12_interpolant_mode_fine_image_texture_within_epsilon(tmp_path):
    """An image texture with detail far finer than the interpolants' test lines (a dark grid
    line every 8 texels): INTERPOLANT applies it per pixel, so every pixel stays within
    epsilon of BASE while much of the floor is interpolated."""
    sc = b.setup_render(160, 120, samples=1, max_depth=1)
    b.set_world((0.0, 0.0, 0.0))
    size = 128
    img = bpy.data.images.new("Grid", size, size)
    px = np.full((size, size, 4), 0.9, np.float32)
    px[..., 3] = 1.0
    px[::8, :, :3] = 0.05
    px[:, ::8, :3] = 0.05
    img.pixels.foreach_set(px.ravel())
    mat = b.diffuse("Tiles")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    mat.node_tree.links.new(tex.outputs["Color"],
                            mat.node_tree.nodes["Diffuse BSDF"].inputs["Color"])
    b.add_object("Floor", b.grid("Floor", 8.0), material=mat)
    b.point_light("Lamp", (-1.0, -1.0, 4.0), 800.0)
    b.camera((0.0, -5.5, 4.5), (0.0, 0.3, 0.0))
    base = b.render_exr(tmp_path / "base.exr")["Combined"][..., :3]
    eps = 0.02
    sc.rstrace.mode = "INTERPOLANT"
    sc.rstrace.epsilon = eps
    sc.rstrace.interpolant_fallback = False  # cells, to test them (they do not pay here: above)
    out = b.render_exr(tmp_path / "interp.exr")
    err = np.abs(to_display(out["Combined"][..., :3]) - to_display(base)).max(axis=-1)
    assert err.max() <= eps + 1e-6, f"max error {err.max():.5f}, {(err > eps).sum()} over"
    classes = out["Interpolation"].reshape(-1, 3)
    green = np.all(np.isclose(classes, CLASS_COLORS[CLASS_INTERPOLATED]), axis=-1).mean()
    assert green > 0.2, f"only {green:.1%} of pixels interpolated"


def test_f12_reports_what_the_fallback_decided(tmp_path, monkeypatch):
    """The measured fallback (on by default) traces where cells do not pay, and says so: in
    the frame's statistics, the status line and an INFO message of the render. Its
    decision is made certain here (an interpolated ray credited with saving nothing, and an
    allowance that lets the first frame walk every ray: that frame is judged); the frames
    after it are the base tracer's, bit for bit."""
    import addon
    from rstrace_engine.interpolants import fallback

    monkeypatch.setattr(fallback, "SAVE_SHARE", 0.0)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e9)
    # (judged whether or not a kernel loads during it: the add-on's warm-up may be loading)
    monkeypatch.setattr(fallback, "SKIP_COMPILED", False)
    sc = b.three_spheres_scene(160, 120)
    sc.rstrace.samples, sc.rstrace.max_ray_depth = 1, 2
    sc.rstrace.mode, sc.rstrace.epsilon = "INTERPOLANT", 0.02
    assert sc.rstrace.interpolant_fallback  # (the default)
    b.render_exr(tmp_path / "first.exr")
    first = _stats()
    assert first["fallback"]["all_traced"] and first["fallback"]["walked_rays"] > 0
    assert first["cells_built"] > 0  # (it walked: the decision is the ledger's, measured)
    assert first["fallback_notes"] and "cost more than they save" in first["fallback_notes"][0]
    state = addon.session.state_for(sc)
    info = [text for level, text in state.messages if level == "INFO"]
    assert first["fallback_notes"][0] in info
    assert "traced: cells did not pay" in addon.session.status_line(first)

    sc.camera.location.x += 0.05  # a new frame: the base tracer's, as the fallback decided
    out = b.render_exr(tmp_path / "next.exr")
    after = _stats()
    assert after["fallback"]["all_traced"] and after["interpolated_fraction"] == 0.0
    assert after["fallback_notes"] == first["fallback_notes"]  # (the same measurement)
    classes = out["Interpolation"].reshape(-1, 3)
    assert not np.all(np.isclose(classes, CLASS_COLORS[CLASS_INTERPOLATED]), axis=-1).any()
    sc.rstrace.mode = "BASE"
    base = b.render_exr(tmp_path / "base.exr")
    np.testing.assert_array_equal(out["Combined"], base["Combined"])

    # with the setting off, the same scene is interpolated and nothing is reported
    sc.rstrace.mode, sc.rstrace.interpolant_fallback = "INTERPOLANT", False
    sc.camera.location.x -= 0.05
    out = b.render_exr(tmp_path / "cells.exr")
    cells = _stats()
    assert "fallback" not in cells and not cells.get("fallback_notes")
    assert cells["interpolated_fraction"] > 0.05
    assert "cells did not pay" not in addon.session.status_line(cells)


def test_f12_says_why_its_first_walk_was_declined(tmp_path, monkeypatch):
    """A frame on an empty cache whose first walk its scene priced above its allowance
    walks nothing (:data:`~rstrace_engine.interpolants.fallback.PRICE_FIRST_WALK`): the
    base frame, and an INFO message of the render says why. The price is given (as if
    learned on this scene: 1e6 traced rays a ray walked), the allowance made large enough
    that the scene's structures owed do not turn the frame away first."""
    import addon
    from rstrace_engine.interpolants import fallback

    init = fallback.Fallback.__init__

    def priced(self, n_inst):
        init(self, n_inst)
        self.first_walk = 1e6

    monkeypatch.setattr(fallback.Fallback, "__init__", priced)
    monkeypatch.setattr(fallback, "ALLOWANCE", 10.0)
    sc, base, out = _base_then_interpolant(tmp_path, 160, 120)
    st = _stats()
    assert st["fallback"]["declined"] and st["fallback"]["walked_rays"] == 0
    note = st["fallback_notes"][0]
    assert "walked no cell" in note and "after 8 such frames" in note
    info = [text for level, text in addon.session.state_for(sc).messages if level == "INFO"]
    assert note in info
    np.testing.assert_array_equal(out["Combined"], base["Combined"])


def test_f12_with_the_cell_build_compiling_beside_is_the_base_tracers(tmp_path, monkeypatch):
    """A first INTERPOLANT F12 while the cell build's kernels are not compiled (a cold
    kernel cache: ``rstrace_engine.interpolants.build_beside``, stood in for here: "not
    compiled", and a compile that sleeps) is the base tracer's frame, bit for bit, and says
    why in its statistics, the status line and an INFO message; unregistering the add-on
    stops the background compile (none outlives the Blender session)."""
    import addon
    from rstrace_engine.interpolants import build_beside

    monkeypatch.setattr(build_beside, "BESIDE", True)
    monkeypatch.setattr(build_beside, "ready", lambda: False)
    monkeypatch.setattr(build_beside, "_CODE", "import time; time.sleep(120)")
    monkeypatch.setattr(build_beside, "_STATE", {"proc": None, "since": None,
                                                 "failed": False})
    sc, base, out = _base_then_interpolant(tmp_path, 96, 72)
    stats = _stats()
    assert stats["fallback"]["build_compiling"] and stats["cells_built"] == 0
    np.testing.assert_array_equal(out["Combined"], base["Combined"])
    state = addon.session.state_for(sc)
    info = [text for level, text in state.messages if level == "INFO"]
    assert any("compiling in the background" in t for t in info), info
    assert "cell build compiling" in addon.session.status_line(stats)
    proc = build_beside._STATE["proc"]
    assert proc is not None and proc.poll() is None
    try:
        addon.unregister()
        assert proc.poll() is not None  # stopped with the add-on
    finally:
        addon.register()
