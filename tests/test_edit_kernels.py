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
                                                      "samples", "term_pixels",
                                                      "recombine_pixels"}
    scene = soft_penumbra("PERSP")
    base = Session(scene.copy(), RenderSettings(mode="BASE", max_depth=3))
    base.light_terms = True
    base.render()
    assert sorted(calls) == ["edit", "recombine", "recombine_pixels", "reshade",
                             "samples"]  # (at its end)
    base.apply(edit(base, "Area", power=0.5))
    base.render()
    assert len(calls) == 5
    interp = Session(scene.copy(), RenderSettings(mode="INTERPOLANT", max_depth=3))
    interp.light_terms = True
    interp.render()
    assert sorted(calls) == ["edit", "recombine", "recombine_pixels", "reshade", "samples",
                             "term_pixels"]
    interp.render()
    Session(scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
    assert len(calls) == 6


_FIRST_EDIT = """
import numba
import numpy as np
from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry.edits import ObjectTransform
from rstrace_engine.session import Session


def signatures():
    import sys
    out = set()
    for name, mod in list(sys.modules.items()):
        if name.startswith("rstrace_engine"):
            for attr, d in list(vars(mod).items()):
                if isinstance(d, numba.core.registry.CPUDispatcher):
                    out |= {(name, attr, str(s)) for s in d.signatures}
    return out


scene = scenes.studio(80, 60)
session = Session(scene, RenderSettings(mode="BASE", max_depth=3, light_samples=4))
session.light_terms = True
session.render()
m = scene.instances[scene.instance_slot("MirrorBall")]["matrix"].copy()
m[0, 3] += 0.1
before = signatures()
session.apply([ObjectTransform("MirrorBall", m)])
frame = session.render()
assert frame.stats["incremental"] and frame.stats["reshaded_pixels"] > 0
for name, attr, sig in sorted(signatures() - before):
    print(name, attr, sig[:60])
"""


def test_first_object_edit_loads_no_kernel():
    """The first object move under soft light (BASE), its edit and its incremental frame
    (the records' sampled-ray queries and proofs, pixels traced, others re-shaded, the
    records compacted) run kernels the first frame's loaders loaded -- none is loaded (5-20
    ms each) in them: the records' compaction counts their 16-bit codes there
    (``_mark_used``), where the first frame counted 32-bit ones. In a process of its own
    (other tests load kernels)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", _FIRST_EDIT], env=env, capture_output=True,
                         text=True, check=True, cwd=root)
    assert out.stdout.strip() == "", out.stdout
