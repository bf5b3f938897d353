"""The cell build's kernels compile beside the frames, never inside one (issue 25,
:mod:`rstrace_engine.interpolants.build_beside`): a frame whose cache keeps no cell while the
error predicate's chain is not compiled is the base tracer's (exact) and one background
process compiles the chain; once it is in the cache, frames build cells. The core tests turn
it off (``conftest.py``); these turn it on, with a stand-in for the compile (a process that
sleeps, or ends at once) and a stand-in for "compiled" (:func:`build_beside.ready`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba import njit

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants import build_beside, fallback
from rstrace_engine.session import Session

SLEEP = "import time; time.sleep(120)"


@pytest.fixture(autouse=True)
def _beside(monkeypatch):
    monkeypatch.setattr(build_beside, "BESIDE", True)
    # the ledger never cuts (cells would not pay on this small scene: the frames that may
    # build must build, whatever this machine's timings)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e6)
    monkeypatch.setattr(build_beside, "_STATE", {"proc": None, "since": None, "failed": False})
    yield
    build_beside.stop()


def _session(mode: str = "INTERPOLANT", fallback: bool = True) -> Session:
    s = Session(scenes.three_spheres(128, 96, subdivisions=2),
                RenderSettings(mode=mode, max_depth=2, epsilon=0.05, samples=1))
    s.interpolants.auto_fallback = fallback
    return s


def _cold(monkeypatch, code: str = SLEEP) -> list:
    """The chain not compiled (until ``state[0]`` is set); the compile a process running
    ``code``."""
    state = [False]
    monkeypatch.setattr(build_beside, "ready", lambda: state[0])
    monkeypatch.setattr(build_beside, "_CODE", code)
    return state


def test_a_cold_chain_is_compiled_beside_and_the_frame_is_the_base_tracers(monkeypatch,
                                                                          tmp_path):
    done = tmp_path / "done"  # the stand-in compile ends when this file is there
    ready = _cold(monkeypatch, code=f"import os, time\nwhile not os.path.exists({str(done)!r}):"
                                    f"\n    time.sleep(0.02)")
    base = _session("BASE").render()
    s = _session()
    frame = s.render()
    proc = build_beside._STATE["proc"]
    assert proc is not None and proc.poll() is None  # the compile runs beside
    fb = frame.stats["fallback"]
    assert fb["build_compiling"] and frame.stats["cells_built"] == 0
    assert frame.stats["interpolated_fraction"] == 0.0
    assert any("compiling in the background" in n for n in frame.stats["fallback_notes"])
    np.testing.assert_array_equal(frame.radiance, base.radiance)  # exact: the base tracer's
    # a second frame while it compiles: the same process, the base tracer again
    s.settings.seed += 1
    assert s.render().stats["fallback"]["build_compiling"]
    assert build_beside._STATE["proc"] is proc
    # the chain in the cache but the process still at the rest of the build's kernels: the
    # frames wait for it (the first frame with cells then only loads them)
    ready[0] = True
    s.settings.seed += 1
    assert s.render().stats["fallback"]["build_compiling"]
    done.write_text("")
    proc.wait(60)
    # done: the next frame builds cells and walks them; the process collected (no zombie)
    s.settings.seed += 1
    frame = s.render()
    assert not frame.stats["fallback"]["build_compiling"]
    assert s.interpolants.cache.totals["cells_built"] > 0
    assert build_beside._STATE["proc"] is None and not build_beside._STATE["failed"]


def test_stop_ends_the_compile(monkeypatch):
    _cold(monkeypatch)
    assert build_beside.compiling()
    proc = build_beside._STATE["proc"]
    build_beside.stop()
    assert proc.poll() is not None and build_beside._STATE["proc"] is None  # none outlives


def test_a_compile_that_leaves_no_kernel_leaves_the_build_to_the_frames(monkeypatch):
    """A background process that ends with the chain still not in the cache (failed, or a
    cache that cannot be written): the frames compile it themselves from then on."""
    _cold(monkeypatch, code="pass")
    s = _session()
    assert s.render().stats["fallback"]["build_compiling"]
    build_beside._STATE["proc"].wait(60)
    s.settings.seed += 1
    frame = s.render()
    assert not frame.stats["fallback"]["build_compiling"]
    assert build_beside._STATE["failed"] and build_beside._STATE["proc"] is None
    assert s.interpolants.cache.totals["cells_built"] > 0
    assert not build_beside.compiling()  # and no process is started again


def test_no_process_to_start_leaves_the_build_to_the_frame(monkeypatch):
    from rstrace_engine import child_python

    _cold(monkeypatch)
    monkeypatch.setattr(child_python, "python", lambda: None)  # an embedding host
    s = _session()
    frame = s.render()
    assert not frame.stats["fallback"]["build_compiling"]
    assert s.interpolants.cache.totals["cells_built"] > 0


def test_without_the_fallback_cells_are_built_wherever_the_rays_need_them(monkeypatch):
    _cold(monkeypatch)
    s = _session(fallback=False)
    frame = s.render()
    assert "build_compiling" not in frame.stats.get("fallback", {})
    assert s.interpolants.cache.totals["cells_built"] > 0
    assert build_beside._STATE["proc"] is None  # nothing started


def test_a_cache_with_cells_keeps_walking_them(monkeypatch):
    """Only a cache with no cell leaves its frame to the base tracer: one that keeps cells
    (the chain was compiled when they were built) walks them."""
    ready = _cold(monkeypatch)
    ready[0] = True
    s = _session()
    s.interpolants.auto_fallback = False  # cells built whatever they cost (this scene)
    s.render()
    assert s.interpolants.cache.pool.n_live > 0
    ready[0] = False
    s.interpolants.auto_fallback = True
    s.settings.seed += 1
    frame = s.render()
    assert not frame.stats["fallback"]["build_compiling"]
    assert build_beside._STATE["proc"] is None


def test_ready_is_in_memory_or_in_the_kernel_cache(monkeypatch):
    """:func:`build_beside.ready` of a kernel neither compiled nor cached, then compiled."""

    @njit(cache=False)
    def kernel(x):
        return x + 1

    monkeypatch.setattr(build_beside, "_kernel", lambda: kernel)
    assert not build_beside.ready()
    kernel(1)
    assert build_beside.ready()


def test_a_compile_that_is_done_leaves_no_zombie(monkeypatch):
    """Once the chain is ready, the ended background process is collected (before: it
    stayed a zombie in ``_STATE`` until :func:`build_beside.stop`, e.g. a Blender session's
    whole life)."""
    import os

    ready = _cold(monkeypatch, code="pass")
    assert build_beside.compiling()
    proc = build_beside._STATE["proc"]
    os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOWAIT)  # ended, not collected
    ready[0] = True
    assert not build_beside.compiling()
    assert proc.returncode == 0 and build_beside._STATE["proc"] is None


def test_the_compile_ends_with_the_process_that_started_it(tmp_path):
    """A script (no add-on, no unregister) that ends while the chain compiles beside its
    frames leaves no orphan process compiling on (before: it ran on, reparented)."""
    import os
    import subprocess
    import sys
    import time

    code = ("from rstrace_engine.interpolants import build_beside as b; "
            "b.ready = lambda: False; b._CODE = 'import time; time.sleep(120)'; "
            "assert b.compiling(); print(b._STATE['proc'].pid)")
    root = str(Path(__file__).parent.parent)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root] + sys.path))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=120, check=True).stdout
    pid = int(out.split()[-1])
    try:
        time.sleep(0.2)
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    finally:
        try:
            os.kill(pid, 9)
        except ProcessLookupError:
            pass


def _plus_one(x):
    return x + 1


def test_ready_wants_a_kernel_compiled_for_this_process(monkeypatch):
    """An index entry this process would not load (compiled for another CPU or target:
    the portable kernels a shipped cache seeded, in a process that compiles for its host)
    is not :func:`build_beside.ready` (before: counted, and the frame compiled the chain
    after all)."""
    njit(cache=True)(_plus_one)(1)  # in the disk cache
    kernel = njit(cache=True)(_plus_one)  # not in memory
    monkeypatch.setattr(build_beside, "_kernel", lambda: kernel)
    assert build_beside.ready()
    index_key = kernel._cache._index_key

    def other_cpu(sig, codegen):
        key = index_key(sig, codegen)
        return (key[0], (key[1][0], "another-cpu", ""), *key[2:])

    monkeypatch.setattr(kernel._cache, "_index_key", other_cpu)
    assert not build_beside.ready()


def test_the_background_code_compiles_the_chain():
    """The process's own code (not a stand-in: the chain, then interpolants built, walked and
    edited) runs and leaves the chain where :func:`build_beside.ready` finds it (a renamed
    import would fail silently there: its output is not read, and every frame would compile
    the chain itself)."""
    from rstrace_engine import child_python

    proc = child_python.start(build_beside._CODE)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err.decode()[-2000:]
    assert build_beside.ready()
