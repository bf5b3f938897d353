"""``make demo``'s background warm-up (``examples/demo.py --warm-cache``): it runs this
checkout's ``warm-cache`` for the demo's kernels in its own process group, and stopping it
when the demo is done stops its parts too (no compile left running after ``make demo``)."""

from __future__ import annotations

import os
import sys
import time

import pytest
from repo_files import load_module


def _demo_module():
    return load_module("examples/demo.py", "rstrace_demo")


def _group(pgid: int) -> list[int]:
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            pids.append(int(entry))
    return pids


def test_demo_warm_cache_is_the_demo_kernels_warm_up():
    demo = _demo_module()
    args = demo.WARM_CACHE_ARGS
    assert args[0] == "warm-cache" and "--no-soft-light" in args
    assert "--no-textures" in args  # the demo's scene has none (session 36: 7-12 s of CPU)
    modes = args[args.index("--modes") + 1:args.index("--accelerators")]
    # the demo renders in both, but INTERPOLANT's cell build compiles beside its frames on a
    # cold cache (interpolants.build_beside): its frame there is the base tracer's
    assert set(modes) == {"BASE"}
    from rstrace_engine.__main__ import _parser

    parsed = _parser().parse_args(list(args))
    assert parsed.accelerators == ["BVH"] and not parsed.soft and parsed.jobs == 0


def test_no_textures_reaches_the_parts_and_the_warm_scene(monkeypatch):
    """``warm-cache --no-textures`` hands the flag to each part it starts, and its steps'
    scene has no textured material (the kernels that texture interpolated rays and split a
    sample's radiance by its texel are never called: ``make demo``'s scene has no
    texture)."""
    import subprocess

    from rstrace_engine import warm_kernels

    started = []

    class FakePart:
        returncode = 0

        def __init__(self, args, stdout=None, **kw):
            started.append(list(args))
            stdout.write('{"compiled": 0, "loaded": 0, "compiled_kernels": {}}')

        def poll(self):
            return 0

        def wait(self):
            return 0

    monkeypatch.setattr(subprocess, "Popen", FakePart)
    warm_kernels.warm_parallel(2, ("BASE", "INTERPOLANT"), ("BVH",), report_unreached=False,
                               soft=False, textures=False)
    assert len(started) == 2 and all("--no-textures" in a for a in started)
    started.clear()
    warm_kernels.warm_parallel(2, ("BASE",), ("BVH",), report_unreached=False)
    assert started and not any("--no-textures" in a for a in started)
    # BASE alone has one unit but two part heads (warm_kernels.BASE_PART_HEADS: make demo's
    # warm-up): two processes, the second compiling the traversal
    assert [a[a.index("--part") + 1] for a in started] == ["0/2", "1/2"]
    # ... but not for another accelerator: those heads compile the BVH's kernels
    started.clear()
    out = warm_kernels.warm_parallel(2, ("BASE",), ("VISIBILITY_FIELD",), report_unreached=False,
                                     soft=False)
    assert out["jobs"] == 1 and len(started) == 1
    plain = warm_kernels.warm_scene(textured=False)
    assert all(m.texture is None for m in plain.materials)
    assert any(m.texture is not None for m in warm_kernels.warm_scene().materials)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_demo_warm_cache_stops_with_its_parts(tmp_path):
    demo = _demo_module()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    proc = demo.start_warm_cache(env)
    try:
        deadline = time.monotonic() + 120.0
        while len(_group(proc.pid)) < 2 and proc.poll() is None:  # the parts started
            assert time.monotonic() < deadline, "warm-cache started no part"
            time.sleep(0.2)
        assert proc.poll() is None
        assert demo.stop_warm_cache(proc)
        deadline = time.monotonic() + 30.0
        while _group(proc.pid):
            assert time.monotonic() < deadline, f"still running: {_group(proc.pid)}"
            time.sleep(0.2)
        assert not demo.stop_warm_cache(proc)  # stopped already
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
            proc.wait()


def test_warm_up_reaches_the_reprojection_of_the_demos_interpolated_frame(monkeypatch):
    """The demo's interpolated frame (4 samples) reprojects the later samples of a pixel
    from its first (``reproject._reproject_rays``); the warm-up's interpolants that pass
    must reach that kernel too, with rays to reproject (before, at one sample, it never
    called it: a fresh ``make demo`` compiled it in the middle of its interpolated frame);
    and a camera step's splat (``reproject._splat``), which no warm-up step reached."""
    from rstrace_engine import warm_kernels
    from rstrace_engine.interpolants import reproject

    calls = []
    kernel = reproject._reproject_rays

    def counted(*args):
        m = kernel(*args)
        calls.append((len(args[11]), int(m)))  # (rays, reprojected)
        return m

    splats = []
    splat = reproject._splat

    def splat_counted(*args):
        splats.append(len(args[2]))  # the interpolants splatted
        return splat(*args)

    monkeypatch.setattr(reproject, "_reproject_rays", counted)
    monkeypatch.setattr(reproject, "_splat", splat_counted)
    warm_kernels._warm_edited_interpolants()
    assert calls and sum(m for _, m in calls) > 0, calls
    # and a camera step splats the frame's interpolants into the next (a camera move)
    assert splats and max(splats) > 0, splats
    assert len(kernel.signatures) == 1  # one signature, the one a render at 4 samples uses


def test_demo_warm_up_reaches_the_glossy_kernels_of_the_demo(monkeypatch):
    """``make demo``'s warm-up leaves the orthographic steps out (``soft=False``), and with
    them the warm scene's rough metal: seven kernels its rough spheres' glossy rays call
    (the strata, the roulette, the own-instance skip of a convex ball and its reflected
    rays, a mesh's convexity) were compiled by the demo itself, on its own path (session
    36). The perspective steps carry the rough metal now; on main none is called. (The
    glossy fronts' tags: ``_next_paths`` since session 41, ``_child_tags`` before.)"""
    from rstrace_engine import warm_kernels
    from rstrace_engine.tracing import glossy_rays, glossy_strata, object_rays, shaft_skip

    kernels = [(shaft_skip, "_own_kernel"), (shaft_skip, "_own_reflections"),
               (object_rays, "_plane_excess"), (glossy_rays, "_roulette"),
               (glossy_strata, "_next_paths"), (glossy_strata, "_lattices"),
               (glossy_strata, "_pixel_seeds")]
    calls = {}

    def counting(kernel, name):
        def counted(*args):
            calls[name] = calls.get(name, 0) + 1
            return kernel(*args)
        return counted

    for module, name in kernels:
        monkeypatch.setattr(module, name, counting(getattr(module, name), name))
    warm_kernels.warm(("BASE",), ("BVH",), report_unreached=False, soft=False,
                      textures=False)
    assert sorted(calls) == sorted(name for _, name in kernels), calls
    # the add-on's full warm-up keeps the perspective scene as it was (hard light, no metal)
    assert len(warm_kernels.warm_scene().materials) + 1 == len(
        warm_kernels.warm_scene(rough=True).materials)
