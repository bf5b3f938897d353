"""The kernel loaders of a session's first edits (``tracing/edit_kernels.py``): one
mechanism, each loader run once per process at the end of the first frame that keeps
light terms and meets its condition -- the recombination's and the edits' with the first
frame, the soft lights' re-shade with a BASE frame under soft light, the interpolants' term
kernel with an INTERPOLANT frame (a BASE frame first, before: never, its flag shared)."""

from __future__ import annotations

from bound_scenes import soft_penumbra
from test_relight_interpolants import edit

from rstrace_engine.frame import RenderSettings
from rstrace_engine.session import Session
from rstrace_engine.tracing import edit_kernels


def test_each_loader_runs_once_with_the_first_frame_it_needs(monkeypatch):
    calls: list = []

    def wrap(name, fn):
        def run(records, sa, camera):
            calls.append(name)
            fn(records, sa, camera)
        return run

    monkeypatch.setattr(edit_kernels, "_loaded", set())
    monkeypatch.setattr(edit_kernels, "LOADERS",
                        [(n, wrap(n, fn), when) for n, fn, when in edit_kernels.LOADERS])
    assert {n for n, _, _ in edit_kernels.LOADERS} == {"recombine", "edit", "reshade",
                                                      "term_pixels", "recombine_pixels"}
    scene = soft_penumbra("PERSP")
    base = Session(scene.copy(), RenderSettings(mode="BASE", max_depth=3))
    base.light_terms = True
    base.render()
    assert sorted(calls) == ["edit", "recombine", "recombine_pixels", "reshade"]  # (at its end)
    base.apply(edit(base, "Area", power=0.5))
    base.render()
    assert len(calls) == 4
    interp = Session(scene.copy(), RenderSettings(mode="INTERPOLANT", max_depth=3))
    interp.light_terms = True
    interp.render()
    assert sorted(calls) == ["edit", "recombine", "recombine_pixels", "reshade",
                           "term_pixels"]
    interp.render()
    Session(scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
    assert len(calls) == 5
