"""``scripts/first_f12_split.py``'s render order: the comparison with Cycles is fair only when
each renderer can render first (whichever renders second reuses the pages the first freed)
or alone, in a process of its own (docs/bench-scale-bpy.md, session 35)."""

import pytest
from repo_files import load_module


def _script():  # (stdlib imports only: bpy comes in main)
    return load_module("scripts/first_f12_split.py", "first_f12_split")


def test_either_renderer_renders_first_or_alone():
    s = _script()
    assert s.plan() == ("ours", "cycles")
    assert s.plan("ours-first") == ("ours", "cycles")
    assert s.plan("cycles-first") == ("cycles", "ours")
    assert s.plan("ours-first", "cycles") == ("cycles",)
    assert s.plan("cycles-first", "ours") == ("ours",)
    with pytest.raises(ValueError):
        s.plan("both")
    with pytest.raises(ValueError):
        s.plan("ours-first", "eevee")
