"""First use: compile (or load from numba's cache) the kernels in the background.

On a fresh install the first render compiles every kernel it touches, which takes a minute
or more on two cores. :func:`start_warmup` starts that work on a background thread as soon
as the add-on is enabled with RSTrace as a scene's engine, the engine is selected, or a
viewport starts: it renders a tiny built-in scene in the chosen mode only (BASE touches the
tracer's kernels; INTERPOLANT adds the interpolant kernels), with the render lock held, so
the kernels are compiled (or loaded) once and a real render afterwards only runs them.
:func:`progress_text` ("compiling kernels 12/40") is shown in the viewport and the status
bar; it counts the numba dispatchers of the packages that mode uses that have a compiled
signature.

The thread never touches ``bpy``; :func:`stop` asks it to stop between kernels and joins it
(unregister).

Layer: imports ``runtime`` (and ``rstrace_engine``); imported by ``viewport``, ``engine``
and the package ``__init__``.
"""

from __future__ import annotations

import importlib
import logging
import pkgutil
import threading
import time

from . import runtime

log = logging.getLogger(__name__)

#: Packages of rstrace_engine whose kernels each mode runs.
MODE_PACKAGES = {
    "BASE": ("geometry", "accel", "tracing"),
    "INTERPOLANT": ("geometry", "accel", "tracing", "interpolants"),
}

_state = {"thread": None, "modes_done": set(), "mode": None, "stop": False,
          "started_at": None, "seconds": {}, "error": None}
_lock = threading.Lock()


def dispatchers(packages) -> list:
    """The numba dispatchers (``@njit`` functions) defined in ``rstrace_engine.<package>``."""
    from numba.core.registry import CPUDispatcher

    found = []
    for pkg_name in packages:
        pkg = importlib.import_module(f"rstrace_engine.{pkg_name}")
        for info in pkgutil.iter_modules(pkg.__path__):
            mod = importlib.import_module(f"{pkg.__name__}.{info.name}")
            for value in vars(mod).values():
                if isinstance(value, CPUDispatcher) and value.py_func.__module__ == mod.__name__:
                    found.append(value)
    return found


def counts(mode: str = "BASE") -> tuple[int, int]:
    """(kernels compiled or loaded in this process, kernels in the packages ``mode`` uses)."""
    ds = dispatchers(MODE_PACKAGES.get(mode, MODE_PACKAGES["INTERPOLANT"]))
    return sum(1 for d in ds if d.signatures), len(ds)


def ready(mode: str = "BASE") -> bool:
    return mode in _state["modes_done"]


def progress_text() -> str | None:
    """"compiling kernels 12/40" while a warm-up runs; None when none is running."""
    t = _state["thread"]
    if t is None or not t.is_alive():
        return None
    done, total = counts(_state["mode"])
    verb = "compiling" if runtime.kernel_status() and "compiling" in runtime.kernel_status() \
        else "loading"
    return f"{verb} kernels {done}/{total}"


def _warm(mode: str) -> None:
    """Render a tiny scene in ``mode``: every kernel that mode's frames use is compiled."""
    from rstrace_engine import scenes
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.interactive import coarse_camera, trace_view
    from rstrace_engine.session import Session

    t0 = time.perf_counter()
    scene = scenes.three_spheres(16, 12, subdivisions=1)
    settings = RenderSettings(mode=mode)
    with runtime.RENDER_LOCK:
        if _state["stop"]:
            return
        session = Session(scene, settings)
        session.render(cancel=lambda: _state["stop"])
        trace_view(session, coarse_camera(scene.camera, 4), settings,
                   cancel=lambda: _state["stop"])
    if not _state["stop"]:
        _state["modes_done"].add(mode)
        runtime.mark_kernels_ready()
        _state["seconds"][mode] = time.perf_counter() - t0
        log.info("RSTrace: %s kernels ready in %.1f s", mode, _state["seconds"][mode])


def _run(modes: list[str]) -> None:
    for mode in modes:
        if _state["stop"]:
            return
        _state["mode"] = mode
        try:
            _warm(mode)
        except Exception as exc:  # the real render will report it properly
            _state["error"] = f"{type(exc).__name__}: {exc}"
            log.exception("RSTrace kernel warm-up failed")
            return


def start_warmup(mode: str = "BASE") -> bool:
    """Start compiling/loading the kernels ``mode`` uses (BASE first), unless done or
    running. Returns True when a thread was started."""
    modes = ["BASE"] + (["INTERPOLANT"] if mode == "INTERPOLANT" else [])
    todo = [m for m in modes if m not in _state["modes_done"]]
    with _lock:
        t = _state["thread"]
        if not todo or (t is not None and t.is_alive()):
            return False
        _state["stop"] = False
        _state["started_at"] = time.perf_counter()
        t = threading.Thread(target=_run, args=(todo,), name="rstrace-kernels", daemon=True)
        _state["thread"] = t
        t.start()
    return True


def wait(timeout: float | None = None) -> bool:
    """Block until the warm-up thread is done; True when it is."""
    t = _state["thread"]
    if t is not None:
        t.join(timeout)
        return not t.is_alive()
    return True


def stop(timeout: float = 60.0) -> bool:
    """Ask the warm-up to stop (it finishes the kernel being compiled) and join it."""
    _state["stop"] = True
    return wait(timeout)
