"""A spot's frame (Blender's scaled spot: an elliptical cone) changed by an edit is a moved
light (``edits._light_geometry``): the next incremental frame is the fresh one, bit for bit
in BASE, within the bound in INTERPOLANT. (It was taken as a power or colour change: the
cone's new reach was left dark, 0.73 off on the room.)"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry.edits import LightSet, apply_edits
from rstrace_engine.session import Session

FRAME = (1.5, 0.0, 0.0, 0.0, 0.7, 0.0, 0.0, 0.0, 1.0)


def _edit(sess):
    li = sess.scene.lights[sess.scene.light_slot("Spot")]
    return [LightSet("Spot", replace(li, spot_frame=FRAME))]


def test_spot_frame_is_a_move():
    scene = SOAK_SCENES["room"](32, 24)
    li = scene.lights[scene.light_slot("Spot")]
    _, fx = apply_edits(scene, [LightSet("Spot", replace(li, spot_frame=FRAME))])
    assert scene.light_slot("Spot") in fx.lights_moved


@pytest.mark.parametrize("mode", ["BASE", "INTERPOLANT"])
@pytest.mark.parametrize("terms", [True, False])
def test_spot_frame_edit_frame(mode, terms):
    st = RenderSettings(mode=mode, epsilon=0.05, max_depth=3)
    sess = Session(SOAK_SCENES["room"](64, 48), st)
    sess.light_terms = terms
    sess.render()
    sess.apply(_edit(sess))
    frame = sess.render()
    assert frame.stats["incremental"]
    base = Session(sess.scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
    if mode == "BASE":
        np.testing.assert_array_equal(frame.radiance, base.radiance)
    else:
        assert image.compare(frame.radiance, base.radiance, 0.05)["max_error"] <= 0.05 + 1e-6
