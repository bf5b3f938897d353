"""A warning about the scene is reported once per scene and change (issue 25): an edit loop
of F12s or an animation does not repeat it; a warning that goes away and comes back is
reported again; the render's statistics and messages still list it every time."""

from __future__ import annotations

import bpy

from . import builders as b

WARNING = "shadows turned off"


def _state():
    import addon

    return addon.session.state_for(bpy.context.scene)


def _f12(tmp_path, capfd) -> int:
    capfd.readouterr()
    b.render_exr(tmp_path / "f.exr")
    printed = capfd.readouterr()
    return (printed.out + printed.err).count(WARNING)


def test_a_scene_warning_is_reported_once_per_change(tmp_path, capfd):
    b.three_spheres_scene(32, 24)
    lamp = bpy.data.lights["Fill"]
    lamp.use_shadow = False  # not modelled: a warning
    printed = [_f12(tmp_path, capfd)]
    bpy.data.objects["RedSphere"].location.x += 0.3  # the edit loop: edit, F12, ...
    printed.append(_f12(tmp_path, capfd))
    printed.append(_f12(tmp_path, capfd))
    assert printed == [1, 0, 0]
    state = _state()
    assert any(WARNING in text for level, text in state.messages if level == "WARNING")
    assert any(WARNING in text for text in state.stats["export_warnings"])

    lamp.use_shadow = True  # the change that removes it ...
    assert _f12(tmp_path, capfd) == 0
    assert not any(WARNING in text for _, text in _state().messages)
    lamp.use_shadow = False  # ... and brings it back: reported again
    assert _f12(tmp_path, capfd) == 1
