"""``bench frame``'s soft-light rows (issue 20 item 5): the scenes, the Mitsuba mapping of
the area and sphere lights and the world (checked by rendering both at a tiny size), the
pixels that see a light, and the row itself."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench import frame as bench_frame
from rstrace_engine.bench import frame_rough, frame_soft
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing.whitted import render


def test_soft_scenes_keep_what_mitsuba_models():
    lights = frame_soft.soft_scene("studio_lights", 32, 24)
    kept = [li for _, li in lights.live_lights()]
    assert sorted(li.kind for li in kept) == ["AREA", "POINT"]
    assert all(li.camera and not li.soft_falloff for li in kept if li.kind == "POINT")
    assert not lights.world_lights and lights.warnings == []
    for m in lights.materials:
        assert m.mirror == (0.0, 0.0, 0.0) and m.specular == (0.0, 0.0, 0.0)
    world = frame_soft.soft_scene("studio_world", 32, 24)
    assert world.n_lights == 0 and world.world_lights
    museum = frame_soft.soft_scene("museum_soft_lights", 32, 24)
    assert [li.kind for _, li in museum.live_lights()] == ["AREA", "AREA"]
    assert len(museum.warnings) == 2 and "'Sun'" in museum.warnings[1]
    with pytest.raises(ValueError, match="unknown soft-light row"):
        frame_soft.soft_scene("studio", 32, 24)


def test_seen_light_pixels_cover_the_light_and_its_edge():
    scene = frame_soft.soft_scene("studio_lights", 32, 24)
    img = np.full((24, 32, 3), 0.3)
    img[10:12, 20:23] = 30.0  # a light's surface (its radiance is 15-24 here)
    seen = frame_soft.seen_light_pixels(scene, img)
    assert seen[10:12, 20:23].all() and seen[9:13, 19:24].all()
    assert seen.sum() == 4 * 5
    assert frame_soft.seen_light_pixels(frame_soft.soft_scene("studio_world", 8, 6),
                                        img) is None


@pytest.mark.parametrize("name", ["studio_lights", "studio_world"])
def test_mitsuba_renders_the_same_light(name):
    """rstrace's converged frame against Mitsuba's (``scalar_rgb``, needs no LLVM): the
    same radiance from the area light, the sphere light and the world. Measured at 48 x 36
    (rstrace 32 pixel samples, Mitsuba 512 spp; 2026-11-26): studio_lights mean luminance
    within 0.3%, 8x8 blocks p98 1.3%; studio_world within 0.1%, p98 1.0%."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    w, h = 48, 36
    scene = frame_soft.soft_scene(name, w, h)
    ms = mi.load_dict(frame_soft.soft_scene_dict(scene, mi, w, h))
    ref = np.array(mi.render(ms, spp=512, seed=1))[::-1, :, :3].astype(np.float64)
    ours = render(scene, RenderSettings(samples=32, max_depth=2),
                  accel=create_accelerator("BVH", scene.arrays())).radiance
    skip = frame_soft.seen_light_pixels(scene, ref)
    keep = np.ones((h, w), bool) if skip is None else ~skip
    lum = frame_rough._luminance
    assert lum(ours)[keep].mean() == pytest.approx(lum(ref)[keep].mean(), rel=0.01)
    e = frame_rough.error_stats(ours, ref, skip)
    assert e["blocks"] >= 12 and e["block_p98"] < 0.04, e


def test_soft_row_runs_and_reports():
    res = bench_frame.run(["studio_lights"], width=32, height=24, depth=2, ref_spp=64,
                          ref_samples=4, mitsuba=False)
    row = res["frames"][0]
    assert row["scene"] == "studio_lights" and row["light_samples"] == 16
    assert row["time_s"] > 0 and row["time_4x4_s"] > 0 and row["shadow_rays"] > 32 * 24
    # 4 pixel samples of 4 light samples: about the shadow rays of 1 of 16 (within 20%)
    assert row["shadow_rays_4x4"] == pytest.approx(row["shadow_rays"], rel=0.2)
    assert row["mitsuba_unavailable"].startswith("not asked for")
    assert "studio_lights" in frame_soft.soft_lines(row)
