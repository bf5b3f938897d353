"""The cut first pass's tail (``frame_parts.trace_tail``,
``fallback.Budget.spent_for_good``): the proof that the ledger never walks again credits
the later passes' reprojections of the pixels interpolated so far -- but while the world
lights (``render._Run.world``) or in an incremental frame (``pixels``: no ``Remember``),
no later pass reprojects anything (``candidates`` is never asked), so that credit can
never be earned: it only keeps the tail from being taken where it could be (speed)."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants import fallback, interpolant_cache
from rstrace_engine.interpolants import render as render_mod
from rstrace_engine.interpolants.fallback import Budget
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.soft_lights import world_lights

WALK = 1500  # rays the first pass walks before the ledger cuts it


@pytest.fixture
def cut_after_walk(monkeypatch):
    """Cells built wherever asked, WALK rays walked, then a cut; the proof's arguments and
    the later passes' reprojection candidates recorded."""
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    monkeypatch.setattr(Budget, "batch", lambda self, step, i: step)
    monkeypatch.setattr(Budget, "may_build", lambda self, i: True)
    monkeypatch.setattr(Budget, "chunk", lambda self, rest:
                        0 if self.walked >= WALK else min(rest, WALK - self.walked))
    monkeypatch.setattr(fallback, "owed_at_once", lambda *a: (0.0, 0.0))
    seen = dict(credit=[], candidates=[])
    monkeypatch.setattr(Budget, "spent_for_good",
                        lambda self, r: seen["credit"].append(r) or False)
    cand = render_mod.candidates
    monkeypatch.setattr(render_mod, "candidates", lambda *a: seen["candidates"].append(
        a[0] is not None) or cand(*a))
    return seen


def _renderer(sc, st, accel):
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, accel)
    r.cache.fallback.ray_s = 1e-6  # priced: no first chunk traced to price a ray
    return r


def test_a_world_lit_frame_credits_no_reprojection_to_the_proof(cut_after_walk):
    sc = scenes.build("museum_soft", 64, 48)
    assert world_lights(sc.arrays())  # (its world lights: later passes never reproject)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.01, max_depth=3, samples=4)
    f = _renderer(sc, st, accel).render(sc, st, accel)
    assert f.stats["interpolated_fraction"] > 0  # pixels were interpolated before the cut
    assert cut_after_walk["candidates"] == []  # nothing can reproject in any pass
    assert f.stats["reprojected_fraction"] == 0.0
    assert cut_after_walk["credit"], "the cut first pass asked the proof"
    assert cut_after_walk["credit"] == [0] * len(cut_after_walk["credit"])


def test_an_incremental_frame_credits_no_reprojection_to_the_proof(cut_after_walk):
    sc = scenes.build("studio", 64, 48)
    sc.set_world_color(tuple(sc.world_color), lights=False)  # (reprojection on)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.05, max_depth=3, samples=4)
    r = _renderer(sc, st, accel)
    full = r.render(sc, st, accel)
    cut_after_walk["credit"].clear()
    cut_after_walk["candidates"].clear()
    pixels = np.ones(64 * 48, np.bool_)  # every pixel dirty: an edit's frame
    f = r.render(sc, st, accel, pixels=pixels, base=full)
    assert f.stats["interpolated_fraction"] > 0
    assert not any(cut_after_walk["candidates"])  # no pass had a view to reproject from
    assert cut_after_walk["credit"], "the cut first pass asked the proof"
    assert cut_after_walk["credit"] == [0] * len(cut_after_walk["credit"])
