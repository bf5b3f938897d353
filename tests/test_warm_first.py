"""First use (rstrace_engine.warm_first): the first image's kernels compiled first, the BVH
traversal in a helper process, with exactly the argument types a render uses, and the rest
of the warm-up leaving the render lock to a waiting viewport between steps."""

from __future__ import annotations

import threading

import numba
import numpy as np

from rstrace_engine import warm_first
from rstrace_engine.accel import bvh, bvh_occlusion
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interactive import coarse_camera, trace_view
from rstrace_engine.session import Session
from rstrace_engine.tracing import batches, whitted
from rstrace_engine.warm_kernels import warm_scene


def test_first_image_kernels_exist():
    for name in warm_first.FIRST_IMAGE_KERNELS:
        assert hasattr(warm_first._kernel(name), "signatures"), name
    assert set(warm_first.HELPER_KERNELS) <= set(warm_first.FIRST_IMAGE_KERNELS)


def test_stand_ins_compile_the_signatures_a_render_uses():
    """The helper's zero-ray queries and the tracer's stand-in hits give the kernels the
    argument types of real queries and frames: a render afterwards compiles nothing new
    (each of these kernels has one signature, whatever the query: closest or any hit,
    scalar or per-ray bounds, one instance)."""
    warm_first.compile_traversal()
    scene = warm_scene()
    warm_first._compile_tracer(scene)
    session = Session(scene, RenderSettings(max_depth=2))
    trace_view(session, coarse_camera(scene.camera, 4), session.settings)
    session.render()
    a = session.accel
    o = np.array([[0.0, -6.0, 1.0]])
    d = np.array([[0.0, 1.0, 0.0]])
    a.closest_hit(o, d, 0.0, np.inf)
    a.any_hit(o, d, np.zeros(1), 10.0)
    a.intersect_object(0, o, d, 0.0, np.inf)
    for k in (bvh.trace_kernel, whitted._surface_kernel, whitted._shadow_kernel,
              whitted._shade_kernel, batches.accumulate, batches.scatter_add,
              whitted.dielectric_albedos, bvh_occlusion.occluded_kernel):
        assert len(k.signatures) == 1, (k.py_func.__name__, k.signatures)


def test_helper_process_fills_the_cache(tmp_path, monkeypatch):
    """The helper (sys.executable, the package on its path) compiles the traversal into
    the cache folder this process uses."""
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    helper = warm_first.start_helper()
    assert helper is not None
    assert warm_first._wait_helper(helper, None)
    helper.stderr.close()
    assert list(tmp_path.rglob("bvh.trace_kernel-*.nbi"))
    assert list(tmp_path.rglob("bvh.trace_kernel-*.nbc"))
    assert list(tmp_path.rglob("bvh_occlusion.occluded_kernel-*.nbc"))


def test_viewport_gets_the_lock_after_the_first_image(monkeypatch):
    """After the first image's kernels, a viewport waiting on the render lock gets it while
    the rest of the warm-up is still to come (the warm-up takes it a step at a time)."""
    monkeypatch.setattr(warm_first, "first_image",
                        lambda processes, cancel: dict(seconds=0.0, helper=False,
                                                       cancelled=False))
    lock = threading.Lock()
    first = threading.Event()
    result = {}

    def run():
        result.update(warm_first.warm_viewport("BASE", lock=lock, processes=1,
                                               on_first_image=first.set))

    t = threading.Thread(target=run)
    t.start()
    try:
        assert first.wait(300)
        assert lock.acquire(timeout=300)
        still_warming = t.is_alive()
        lock.release()
    finally:
        t.join(600)
    assert still_warming  # the viewport did not wait for the whole warm-up
    assert not result["cancelled"] and "first_image_s" in result


def test_cancelled_warmup_stops_between_steps():
    first = warm_first.first_image(processes=1, cancel=lambda: True)
    assert first["cancelled"] and not first["helper"]
    result = warm_first.warm_viewport("BASE", processes=1, cancel=lambda: True)
    assert result["cancelled"]


def test_demo_warm_up_parts_share_the_interpolant_kernels():
    """``make demo``'s two warm-up processes: the first (the tracer's stages) renders the
    INTERPOLANT step, then BASE; the second (the traversal, the BVH build) the interpolants
    that pass. Before, the first had BASE and the interpolants (229 s of the 287 s of CPU)
    and the second only the INTERPOLANT step, waiting for the first's kernels."""
    from rstrace_engine.warm_kernels import units

    u = units(("BASE", "INTERPOLANT"), ("BVH",), soft=False)
    assert u[0::2] == [("step", "INTERPOLANT", "BVH", False), ("step", "BASE", "BVH", False)]
    assert u[1::2] == [("interpolants",)]
    full = units(("BASE", "INTERPOLANT", "RI_TREE"), ("BVH", "VISIBILITY_FIELD"))
    assert sorted(full) == sorted(set(full)) and len(full) == 2 * 3 * 2 + 3  # each once


def test_predicate_head_compiles_the_signature_a_render_uses():
    """``warm-cache``'s second part compiles the error predicate's chain with no cells
    (``compile_predicate``) before the interpolants' own kernels: with the argument types
    of a render's call, so an INTERPOLANT render afterwards compiles no second signature
    (fails on main: no ``compile_predicate``; the chain was reached last there)."""
    from rstrace_engine import scenes
    from rstrace_engine.interpolants import predicate

    warm_first.compile_predicate(warm_scene())
    assert len(predicate._check_cells.signatures) == 1
    session = Session(scenes.three_spheres(128, 96, subdivisions=2),
                      RenderSettings(mode="INTERPOLANT", max_depth=3, epsilon=0.02,
                                     depth_cap=5, samples=2))
    session.interpolants.auto_fallback = False
    session.render()
    assert session.interpolants.cache.totals["cells_built"] > 0  # the predicate ran
    assert len(predicate._check_cells.signatures) == 1, predicate._check_cells.signatures


def test_part_heads_start_the_predicate_at_once(monkeypatch):
    """The first part's head: the first image's kernels (the tracer's stages first: make
    demo's first frame compiles the build meanwhile, then needs them); the second part's:
    the predicate's chain (the
    longest compile) from the start; a warm-up without INTERPOLANT (``make demo``) leaves
    it out and compiles the traversal in the second part instead; one process has no
    head."""
    calls = []
    monkeypatch.setattr(warm_first, "_compile_tracer", lambda *a, **k: calls.append("tracer"))
    for name in ("traversal", "predicate", "build"):
        monkeypatch.setattr(warm_first, f"compile_{name}",
                            lambda *a, _n=name: calls.append(_n))
    assert warm_first.part_head(1, 2, ("BASE", "INTERPOLANT")) == ["predicate"]
    assert warm_first.part_head(0, 2, ("BASE", "INTERPOLANT")) == [
        "tracer", "traversal", "build"]
    assert calls == ["predicate", "tracer", "traversal", "build"]
    calls.clear()
    # without INTERPOLANT (make demo): the traversal in the second part, from the start
    assert warm_first.part_head(1, 2, ("BASE",)) == ["traversal"]
    assert warm_first.part_head(0, 2, ("BASE",)) == ["tracer", "build"]
    assert warm_first.part_head(0, 2, None) == ["tracer", "traversal", "build"]
    assert warm_first.part_head(1, 2, None) == ["predicate"]
    assert warm_first.part_head(0, 1, None) == []


def test_predicate_head_builds_no_bvh(monkeypatch):
    """The predicate's head compiles no BVH build (it would wait for ``make demo``'s own
    first frame compiling it): its query structures take :func:`warm_first._no_bvh`."""
    from rstrace_engine.accel import bvh_build

    def no_build(*a, **k):
        raise AssertionError("built a BVH")

    monkeypatch.setattr(bvh_build, "build_flat", no_build)
    warm_first.compile_predicate(warm_scene())
