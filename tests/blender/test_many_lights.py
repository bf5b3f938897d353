"""Issue 21's 100-light row through Blender: a scene of more than 64 lights (the records'
light sets take a word per 64 slots, ``rstrace_engine/tracing/light_bits.py``) renders by F12
and a light in a slot past 64, edited through the depsgraph, relights the kept frame from its
per-light records and equals a fresh render bit for bit."""

from __future__ import annotations

import bpy
import numpy as np

from . import builders as b
from .test_edits import _f12, _relit_each, _scene


def test_f12_relights_a_light_past_slot_64_of_a_hundred():
    sc = _scene(32, 24)
    sc.rstrace.mode = "BASE"
    for k in range(98):
        b.point_light(f"Grid{k:02d}", (-4.0 + (k % 10) * 0.9, -3.0 + (k // 10) * 0.7, 5.0),
                      12.0, (1.0, 0.9 - 0.004 * k, 0.8))
    _f12()
    lamp = bpy.data.objects["Grid97"]
    lamp.data.energy *= 0.9  # (the session's first light edit: its records start)
    bpy.context.view_layer.update()
    _, stats = _f12()
    assert not stats.get("relit") and stats["light_records_mb"] > 0.0, stats
    import addon

    core = addon.session.state_for(sc).session
    assert len(core.scene.lights) == 100
    slot = next(j for j, li in enumerate(core.scene.lights) if li.name == "Grid97")
    assert slot >= 64, slot
    changes = [
        ("power", lambda: setattr(lamp.data, "energy", lamp.data.energy * 6.0)),
        ("colour", lambda: setattr(lamp.data, "color", (0.2, 0.4, 1.0))),
        ("move", lambda: setattr(lamp.location, "x", lamp.location.x - 1.5)),
    ]
    before = _f12()[0]
    for name, inc in _relit_each(sc, changes):
        assert not np.array_equal(inc, before), name
        before = inc
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])  # and a fresh export
