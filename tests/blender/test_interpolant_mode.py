"""F12 in INTERPOLANT mode: bounded error against BASE, the Interpolation pass, reuse."""

from __future__ import annotations

import bpy
import numpy as np

from rstrace_engine.frame import CLASS_COLORS, CLASS_INTERPOLATED
from rstrace_engine.image import to_display

from . import builders as b


def _stats():
    import addon

    return addon.session.state_for(bpy.context.scene).stats


def test_f12_interpolant_mode_matches_base_within_epsilon(tmp_path):
    sc = b.three_spheres_scene(160, 120)
    sc.rstrace.samples = 1
    sc.rstrace.max_ray_depth = 2
    base = b.render_exr(tmp_path / "base.exr")["Combined"][..., :3]

    eps = 0.02
    sc.rstrace.mode = "INTERPOLANT"
    sc.rstrace.epsilon = eps
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
