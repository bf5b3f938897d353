"""First use: the kernels are compiled (or loaded) in the background with a progress count,
only for the chosen mode, and the warm-up thread is joined on stop."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_warmup_runs_in_the_background_with_progress(monkeypatch):
    import addon
    from addon import kernels, runtime

    kernels.wait(600)  # a warm-up started by an earlier test (engine selected)
    monkeypatch.setitem(kernels._state, "modes_done", set())
    monkeypatch.setitem(kernels._state, "thread", None)
    counts = kernels.counts
    # as on a fresh install (else, every kernel cached, no warm-up would run: test below);
    # patched while the lock is held: the thread looks once, before it waits for the lock
    monkeypatch.setattr(kernels, "counts", lambda mode="BASE": (3, 15))
    with runtime.RENDER_LOCK:  # a render in progress: the warm-up waits its turn
        assert kernels.start_warmup("BASE")
        assert not kernels.start_warmup("BASE")  # one at a time
        text = kernels.progress_text()
        assert text is not None and re.fullmatch(r"(compiling|loading) kernels 3/15", text)
        monkeypatch.setattr(kernels, "counts", counts)
    assert kernels.wait(600) and kernels.ready("BASE") and not kernels.ready("INTERPOLANT")
    assert kernels.progress_text() is None
    done, total = kernels.counts("BASE")
    assert done == total == len(kernels.MODE_KERNELS["BASE"])  # every listed name exists
    # BASE compiles no interpolant kernel: INTERPOLANT lists more
    assert kernels.counts("INTERPOLANT")[1] == len(kernels.MODE_KERNELS["INTERPOLANT"]) > total
    assert addon.kernels is kernels


def test_stop_joins_the_warmup(monkeypatch):
    from addon import kernels

    kernels.wait(600)
    monkeypatch.setitem(kernels._state, "modes_done", set())
    monkeypatch.setitem(kernels._state, "thread", None)
    assert kernels.start_warmup("INTERPOLANT")
    thread = kernels._state["thread"]
    assert kernels.stop(600) and not thread.is_alive()
    monkeypatch.setitem(kernels._state, "stop", False)


def test_no_warmup_when_every_kernel_of_the_mode_is_cached(monkeypatch):
    """A second process (or the shipped kernels): nothing to compile, so no warm-up loads
    every kernel and renders its scenes while the user's render waits for the lock."""
    from addon import kernels, runtime

    kernels.wait(600)
    monkeypatch.setitem(kernels._state, "modes_done", set())
    monkeypatch.setitem(kernels._state, "thread", None)
    done, total = kernels.counts("BASE")
    assert done == total  # the warm-up of the test above cached them
    with runtime.RENDER_LOCK:  # a render holds the lock: this warm-up does not wait for it
        assert kernels.start_warmup("BASE")
        assert kernels.wait(120) and kernels.ready("BASE")
    assert kernels.progress_text() is None


FIRST_F12 = textwrap.dedent('''
    import json, os, sys
    sys.path.insert(0, sys.argv[1])
    import bpy
    import addon
    from addon import kernels
    from rstrace_engine import kernel_cache
    from tests.blender import builders as b

    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    b.setup_render(32, 24, samples=1, max_depth=int(sys.argv[2]))
    b.set_world((0.05, 0.05, 0.06), lights=False)
    grey = b.principled("Grey", (0.6, 0.6, 0.6), roughness=0.6)
    b.add_object("Floor", b.grid("Floor", 40.0), material=grey)
    # past bvh_build.PARALLEL_MIN triangles: a large mesh's build kernels too
    ball = b.add_object("Ball", b.uv_sphere("BallMesh", 1.0, 256, 160), (0, 0, 1), grey)
    b.point_light("Key", (-3.0, -4.0, 6.0), 2500.0)
    b.camera((0.0, -6.0, 2.5), (0.0, 0.0, 1.0))
    bpy.context.view_layer.update()  # (the engine is RSTrace: the background load starts)
    started = not kernels.wait(0) or kernels.ready("BASE")
    assert kernels.wait(600)
    before = kernel_cache.mark()
    bpy.ops.render.render()
    st = addon.last_render_stats(bpy.context.scene)
    counts = kernel_cache.counts(since=before)
    print("RESULT " + json.dumps(dict(started=started, triangles=st.get("triangles"),
                                      loaded=counts["loaded"], compiled=counts["compiled"],
                                      kernels=sorted(counts["compiled_kernels"]) + [
                                          f"{d.py_func.__module__}.{d.__name__}"
                                          for d in kernel_cache.dispatchers("rstrace_engine")
                                          if sum(d.stats.cache_hits.values())
                                          > before["hits"].get(id(d), 0)])))
    addon.unregister()
''')


@pytest.mark.parametrize("depth", [0, 5])
def test_a_warm_process_loads_the_first_f12s_kernels_before_it(depth):
    """A second process on a warm cache: once a scene renders with RSTrace, the add-on loads
    the kernels an F12 runs from the cache in the background (nothing compiled, nothing
    rendered), so the first F12 that comes after it loads none (it loaded ~25 itself, about
    1 s of CPU at 1M triangles, docs/bench-scale-bpy.md). Its own process: the test process
    has loaded them already."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", FIRST_F12, str(ROOT), str(depth)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=900)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stdout[-2000:] + proc.stderr[-3000:]
    result = json.loads(lines[-1][len("RESULT "):])
    assert result["started"] and result["triangles"] > (1 << 16)
    assert result["loaded"] == 0 and result["compiled"] == 0, result
