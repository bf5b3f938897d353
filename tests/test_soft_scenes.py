"""The soft-lit bench scenes (issue 20): what they hold, and that they render."""

from __future__ import annotations

import numpy as np

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing.whitted import render


def test_museum_soft_is_museum_1999_lit_softly():
    hard, soft = scenes.museum_1999(32, 24), scenes.museum_soft(32, 24)
    # the same objects, the room open at the skylight and four ceiling slabs around it
    assert len(soft.live_instances()) == len(hard.live_instances()) + 4
    kinds = {li.name: li.kind for li in soft.lights}
    assert kinds == {"Ceiling0": "AREA", "Ceiling1": "AREA", "Spot": "SPOT", "Sun": "SUN"}
    sun = soft.lights[soft.light_slot("Sun")]
    assert sun.angle > 0 and soft.world_lights
    np.testing.assert_array_equal(soft.camera.matrix, hard.camera.matrix)
    sa = soft.arrays()
    assert sa.light_ext.all()  # every light has an extent


def test_studio_and_museum_soft_render():
    for name in ("studio", "museum_soft"):
        sc = scenes.build(name, 32, 24)
        f = render(sc, RenderSettings(max_depth=2, light_samples=2))
        assert np.isfinite(f.radiance).all() and f.radiance.max() > 0.0, name
    studio = scenes.studio(32, 24)
    assert {li.kind for li in studio.lights} == {"AREA", "POINT"} and studio.world_lights
    assert studio.lights[studio.light_slot("Bulb")].radius > 0
