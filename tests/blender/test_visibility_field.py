"""Accelerator = Visibility Field in Blender: F12 and an animation with a moving object,
pixel for pixel against the BVH."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from . import builders as b
from .exr import read_exr, read_pass


def _state():
    import addon

    return addon.session.state_for(bpy.context.scene)


def _small_field(sc) -> None:
    sc.rstrace.vf_directions = 34  # small settings keep the test fast
    sc.rstrace.vf_tiles = 8


def test_f12_with_visibility_field_equals_bvh(tmp_path):
    sc = b.three_spheres_scene(32, 24)
    sc.rstrace.max_ray_depth = 2
    _small_field(sc)
    out = {}
    for acc in ("BVH", "VISIBILITY_FIELD"):
        sc.rstrace.accelerator = acc
        out[acc] = b.render_exr(tmp_path / f"{acc}.exr")["Combined"]
        state = _state()
        assert state.error is None and state.stats["accelerator"] == acc, state.messages
    assert state.stats["accel_memory_mb"] > 0
    assert state.session.accel.stats["directions"] == 34
    assert out["BVH"][..., :3].max() > 0.05  # lit geometry, not an empty frame
    np.testing.assert_array_equal(out["VISIBILITY_FIELD"], out["BVH"])
    # settings past the field's memory cap: a clean error naming them, then it renders again
    sc.rstrace.vf_directions, sc.rstrace.vf_tiles = 2050, 1024
    with pytest.raises(RuntimeError, match="RSTrace: .*over the cap"):
        b.render_exr(tmp_path / "big.exr")
    _small_field(sc)
    assert b.render_exr(tmp_path / "again.exr") and _state().error is None


def _animate(tmp_path, accelerator: str) -> list[np.ndarray]:
    import addon

    addon.session.forget_all()
    sc = bpy.context.scene
    sc.rstrace.accelerator = accelerator
    sc.render.filepath = str(tmp_path / f"{accelerator}_")
    bpy.ops.render.render(animation=True)
    files = sorted(tmp_path.glob(f"{accelerator}_*.exr"))
    assert len(files) == 3
    return [read_pass(read_exr(f), "Combined", components="RGB") for f in files]


def test_animation_with_a_moving_object_equals_bvh(tmp_path):
    sc = b.three_spheres_scene(32, 24)
    _small_field(sc)
    ob = bpy.data.objects["RedSphere"]
    sc.frame_start, sc.frame_end = 1, 3
    for frame, x in ((1, -2.2), (3, 0.2)):
        ob.location.x = x
        ob.keyframe_insert("location", frame=frame)
    vf = _animate(tmp_path, "VISIBILITY_FIELD")
    stats = _state().session.accel.stats
    # frames 2 and 3 moved the sphere: it became dynamic, written under a new GV each time
    assert stats["dynamic_instances"] == 1 and stats["gv"] == 2 and stats["rebuilds"] == 0
    bvh = _animate(tmp_path, "BVH")
    assert np.abs(vf[0] - vf[2]).max() > 0.05  # the red sphere moved
    for a, c in zip(vf, bvh, strict=True):
        np.testing.assert_array_equal(a, c)
