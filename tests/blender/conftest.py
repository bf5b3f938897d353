"""bpy test harness: the add-on imported from the repository root as the package ``addon``
and registered once; a fresh empty factory scene for every test; handlers added by a test
removed after it; frames compile the cell build's kernels themselves (:func:`_build_in_frame`)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

_HANDLER_LISTS = ("load_pre", "load_post", "render_pre", "render_post", "render_complete",
                  "render_cancel", "render_init", "render_write", "render_stats",
                  "frame_change_pre", "frame_change_post", "depsgraph_update_pre",
                  "depsgraph_update_post", "save_pre", "save_post")


@pytest.fixture(scope="session")
def rstrace_addon():
    """The add-on, registered for the whole session and unregistered at its end."""
    import addon

    addon.register()
    yield addon
    addon.unregister()


def _handlers() -> dict[str, list]:
    return {name: list(getattr(bpy.app.handlers, name)) for name in _HANDLER_LISTS}


@pytest.fixture(autouse=True)
def _build_in_frame(monkeypatch):
    """A frame compiles the cell build's kernels itself, as the core tests' frames do
    (``rstrace_engine.interpolants.build_beside``: off; on a cold kernel cache a frame
    with the fallback would otherwise be the base tracer's while a background process
    compiles them, and what a test sees would depend on the cache it runs on); the tests
    of that path turn it on."""
    from rstrace_engine.interpolants import build_beside

    monkeypatch.setattr(build_beside, "BESIDE", False)


@pytest.fixture(autouse=True)
def fresh_scene(rstrace_addon, tmp_path):
    """An empty factory file; handlers a test adds are removed afterwards."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    before = _handlers()
    yield bpy.context.scene
    for name, old in before.items():
        current = getattr(bpy.app.handlers, name)
        for h in list(current):
            if h not in old:
                current.remove(h)
    rstrace_addon.session.forget_all()
