"""The scene's structures (surface topology, the predicate's query structures) are owed
at once by a frame's first walk (issue 20: a user who picks interpolants never loses): a
frame whose allowance cannot pay them walks nothing and is the base tracer's; a later frame
that can builds them, and its frame keeps the bound. Decided by given rates, not timings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry import mesh_topology
from rstrace_engine.interpolants import fallback, interpolant_cache
from rstrace_engine.interpolants.fallback import Budget, structures_owed
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.whitted import render

EPS = 0.05
FLOAT_TOL = 1e-6


@pytest.fixture(autouse=True)
def fresh_structures(monkeypatch):
    """No structures kept from other tests' scenes; small cells (6 rays on)."""
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    monkeypatch.setattr(interpolant_cache, "_QS_LAST", [None])
    monkeypatch.setattr(mesh_topology, "_LAST", [None])
    monkeypatch.setattr(fallback, "STRUCTURE_RATE", {"topo": None, "qs": None})
    monkeypatch.setattr(fallback, "LEARN_STRUCTURES", True)  # (conftest turns it off)


def test_a_walk_owes_the_structures_not_built():
    b = Budget(100_000, ray_s=1e-5)  # an allowance of ALLOWANCE * 1 s
    assert b.owed == 0.0 and b.chunk(50_000) == fallback.CHUNK_MIN
    b.owed = 0.5 * b.limit  # affordable: the walk goes on
    assert b.chunk(50_000) == fallback.CHUNK_MIN and not b.cut
    b.owed = 2.0 * b.limit  # not: nothing walks, the rest is traced
    assert b.chunk(50_000) == 0 and b.cut
    # a build owes the query structures where the walk did not (cells kept to find)
    b = Budget(100_000, ray_s=1e-5)
    assert b.may_build(0)
    b.owed_build = 2.0 * b.limit
    assert not b.may_build(0) and b.batch(64, 0) == 0
    fallback.STRUCTURE_RATE.update(topo=1e-6, qs=3e-6)
    assert fallback.owed_at_once(["topo", "qs"], 1000, cells_kept=False) == pytest.approx(
        (4e-3, 0.0))
    assert fallback.owed_at_once(["topo", "qs"], 1000, cells_kept=True) == pytest.approx(
        (1e-3, 3e-3))
    assert fallback.owed_at_once(["qs"], 1000, cells_kept=True) == pytest.approx((0.0, 3e-3))
    # the rates: learned per kind from the last build, none foreseen before one
    fallback.STRUCTURE_RATE.update(topo=2e-6, qs=None)
    assert structures_owed(["topo", "qs"], 1000) == pytest.approx(2e-3)
    assert fallback.timed_structure("qs", 1000, lambda: "built") == "built"
    assert fallback.STRUCTURE_RATE["qs"] >= 0.0
    assert structures_owed([], 1000) == 0.0


def test_a_build_that_loads_or_compiles_a_kernel_is_not_learned(monkeypatch):
    """A process's first build times numba (270-1300x the steady rate, measured), and a
    rate that high would never be corrected: frames that cannot pay it build nothing."""
    from rstrace_engine import kernel_cache

    seen = {"compiled": 0, "loaded": 1}
    monkeypatch.setattr(kernel_cache, "counts", lambda since=None, **kw: dict(seen))
    fallback.timed_structure("topo", 1000, lambda: None)
    assert fallback.STRUCTURE_RATE["topo"] is None  # a kernel loaded: not learned
    seen.update(loaded=0, compiled=2)
    fallback.timed_structure("topo", 1000, lambda: None)
    assert fallback.STRUCTURE_RATE["topo"] is None  # compiled: not learned
    seen.update(compiled=0)
    fallback.timed_structure("topo", 1000, lambda: None)
    assert fallback.STRUCTURE_RATE["topo"] is not None  # a steady build: learned


def _error(f, base) -> float:
    return float(np.abs(image.to_display(f.radiance) - image.to_display(base.radiance)).max())


def test_a_frame_that_cannot_pay_the_structures_is_the_base_frame_and_a_later_one_builds(
        monkeypatch):
    sc = scenes.three_spheres(96, 72, subdivisions=3)
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    r = InterpolantRenderer()
    r.prepare(sa, st, accel)
    r.cache.fallback.ray_s = 1.0  # a dear ray: a large allowance (4% of the frame's rays)
    # ... and dearer structures (a second per triangle): nothing walks, nothing is built
    fallback.STRUCTURE_RATE.update(topo=1.0, qs=1.0)
    assert r.cache.structures_missing() == ["topo", "qs"]
    f0 = r.render(sc, st, accel)
    s0 = f0.stats["fallback"]
    assert s0["walked_rays"] == 0 and f0.stats["cells_built"] == 0
    assert r.cache.structures_missing() == ["topo", "qs"]
    assert not mesh_topology.topology_kept(sa)
    base0 = render(sc, replace(st, mode="BASE"), accel=accel)
    np.testing.assert_array_equal(f0.radiance, base0.radiance)
    # a renderer's first frame (no price yet) prices a ray with its first chunk, then
    # walks nothing either: the rest traced, the base frame's
    first = InterpolantRenderer()
    f_first = first.render(sc, st, accel)
    assert f_first.stats["fallback"]["probe_rays"] > 0
    assert f_first.stats["fallback"]["walked_rays"] == 0
    assert first.cache.structures_missing() == ["topo", "qs"]
    np.testing.assert_array_equal(f_first.radiance, base0.radiance)
    # cheap structures: the next frame (a camera step) builds them and its cells
    fallback.STRUCTURE_RATE.update(topo=0.0, qs=0.0)
    cam = sc.camera
    step = cam.matrix.copy()
    step[:3, 3] += 0.05 * step[:3, 0]
    sc.set_camera(replace(cam, matrix=step))
    r.cache.fallback.ray_s = 1.0
    f1 = r.render(sc, st, accel)
    assert f1.stats["fallback"]["walked_rays"] > 0 and f1.stats["cells_built"] > 0
    assert r.cache.structures_missing() == []
    # (the rate is learned from a build that loaded no kernel: the test above)
    base1 = render(sc, replace(st, mode="BASE"), accel=accel)
    assert (f1.pixel_class == CLASS_INTERPOLATED).any()
    assert _error(f1, base1) <= EPS + FLOAT_TOL
    traced = f1.pixel_class != CLASS_INTERPOLATED
    np.testing.assert_array_equal(f1.radiance[traced], base1.radiance[traced])
    # a renderer that built them in its first frame gives a frame within the same bound
    fresh = InterpolantRenderer()
    fresh.prepare(sa, st, accel)
    fresh.cache.fallback.ray_s = 1.0
    f2 = fresh.render(sc, st, accel)
    assert f2.stats["cells_built"] > 0 and _error(f2, base1) <= EPS + FLOAT_TOL
