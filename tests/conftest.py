"""Core tests decide by given costs, not timings: the interpolants' learned cost of a
scene's structures (:data:`~rstrace_engine.interpolants.fallback.STRUCTURE_RATE`, learned
from the builds of earlier tests in the process) is not learned, so no test's frames depend
on which tests ran before it, and a cache's first walk is not priced before it is walked
(:data:`~rstrace_engine.interpolants.fallback.PRICE_FIRST_WALK` off: a price learned in
one frame would decline a test's later frames; its tests turn it on), and a frame that
compiled or loaded a kernel is judged as any other (:data:`~rstrace_engine.interpolants.
fallback.SKIP_COMPILED` off: whether one does depends on the tests before it; its tests turn
it on), and a frame compiles the cell build's kernels itself (:data:`~rstrace_engine.
interpolants.build_beside.BESIDE` off: not in a background process; its tests turn it on).
The bpy tests under
``blender/`` run the add-on as it is."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _no_learned_structure_rate(request, monkeypatch):
    if (Path(__file__).parent / "blender") in Path(str(request.node.fspath)).parents:
        yield
        return
    from rstrace_engine.interpolants import build_beside, fallback

    monkeypatch.setattr(build_beside, "BESIDE", False)
    monkeypatch.setattr(fallback, "LEARN_STRUCTURES", False)
    monkeypatch.setattr(fallback, "STRUCTURE_RATE", {"topo": None, "qs": None})
    monkeypatch.setattr(fallback, "PRICE_FIRST_WALK", False)
    monkeypatch.setattr(fallback, "SKIP_COMPILED", False)
    yield
