"""The cell build's kernels compile beside the frames, never inside one (issue 25).

The error predicate's chain (:func:`.predicate._check_cells` and its callees: the occluder,
shaft and soft-light tests) is INTERPOLANT mode's longest compile, ~37 s of CPU on the
project's 2-core machine, and a cache with no cell reaches it in its first frame. A frame
that compiled it took ~40 s where the base tracer's took ~0.1 s, to build cells that a
fallback frame (:mod:`.fallback`) may then not even use.

So, where the measured fallback decides (:attr:`.render.InterpolantRenderer.auto_fallback`,
the default): a frame whose cache keeps no cell, while the chain is neither in memory nor in
the kernel cache (:func:`ready`), is the base tracer's frame (exact; ``stats["fallback"]
["build_compiling"]`` and a note say why) and one background Python process compiles the
build's kernels into the kernel cache (:func:`.warm_first.compile_cell_build`: the chain for
the argument types of a render's build, then cells built, walked and edited for real;
:mod:`..child_python`). Until it ends, such frames stay the base tracer's; the first frame
after it loads the kernels from the cache and builds cells. Where no process can be started,
or it ended without the chain in the cache (it failed, or a cache that cannot be written),
the frames compile the chain themselves, as before. With the fallback off, cells are built
wherever the rays need them, compile included (what the cache's tests count).

:func:`stop` ends the process (the add-on's unregister, and this process's exit: a compile
must not outlive the Blender session or the script that started it; a stopped compile is
started again by the next frame that needs it). What this relies on: numba's cache index
(``kernel_cache.cached_signatures``, the entries this process would load) lists the chain
once a process has written it, and concurrent compiles of one signature are claimed by one
process (``kernel_cache``: the add-on's own warm-up may be compiling it too).
"""

from __future__ import annotations

import atexit
import logging
import subprocess
import time

from .. import child_python, kernel_cache

log = logging.getLogger(__name__)

#: off: a frame that needs the chain compiles it (the tests turn it off, tests/conftest.py:
#: what they count must not depend on a background process's timing)
BESIDE = True
_CODE = "from rstrace_engine.warm_first import compile_cell_build; compile_cell_build()"
#: the compiling process while it runs; when it started; whether one failed (then frames
#: compile the chain themselves for the rest of the process)
_STATE: dict = {"proc": None, "since": None, "failed": False}


def _kernel():
    from .predicate import _check_cells

    return _check_cells


def ready() -> bool:
    """Whether the chain is in memory or in the kernel cache for this process (a build only
    loads it; an entry for another CPU or target, e.g. the portable kernels a shipped cache
    seeded in a process that compiles for its host, would be compiled in the frame)."""
    k = _kernel()
    return bool(k.signatures) or kernel_cache.cached_signatures(k, ours=True) > 0


def compiling() -> bool:
    """Whether a frame should leave the build to the background process: :data:`BESIDE`
    and the process running (it compiles the chain, then the rest of the build's kernels:
    :func:`.warm_first.compile_cell_build`), or the chain not :func:`ready` (the process
    is started here). False once it has ended with the chain ready (its exit status
    collected: no zombie), or where it cannot run or failed (the frames then compile what
    they need themselves)."""
    if not BESIDE or _STATE["failed"]:
        return False
    proc = _STATE["proc"]
    if proc is not None:
        if proc.poll() is None:
            return True
        _STATE["proc"] = None
        if proc.returncode != 0 or not ready():
            # failed, stopped from outside, or a cache that cannot be written: the frames
            # compile it themselves from now on
            log.warning("RSTrace: the cell build's background compile ended (rc %s) without "
                        "the chain in the cache; frames compile it themselves",
                        proc.returncode)
            _STATE["failed"] = True
        return False
    if ready():
        return False
    proc = child_python.start(_CODE, stderr=subprocess.DEVNULL)
    if proc is None:
        _STATE["failed"] = True
        return False
    _STATE["proc"], _STATE["since"] = proc, time.perf_counter()
    log.info("RSTrace: compiling the cell build's kernels in the background")
    return True


def seconds() -> float:
    """How long the background compile has run (0: none running)."""
    return 0.0 if _STATE["proc"] is None else time.perf_counter() - _STATE["since"]


def note() -> str:
    """The frame's note while the chain compiles beside it."""
    return (f"Interpolants: the cell build's kernels are compiling in the background (first "
            f"use, {seconds():.0f} s so far): this frame is the base tracer's, exact; cells "
            f"are built once they are ready")


def stop() -> None:
    """End the background compile if it runs (the next frame that needs it starts it again)."""
    proc, _STATE["proc"] = _STATE["proc"], None
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


# a process that ends mid-compile (a script: no add-on unregister) leaves no orphan
atexit.register(stop)
