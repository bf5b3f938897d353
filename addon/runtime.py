"""Numba inside Blender: where compiled kernels are cached, and one render at a time.

:func:`configure` must run before any ``rstrace_engine`` module that defines kernels is
imported: numba binds a kernel to its cache directory when the kernel is decorated. The
add-on's ``__init__`` calls it first thing.

* Installed as an extension, kernels are cached in the extension's user directory
  (``bpy.utils.extension_path_user(__package__, path="numba_cache")``), which is writable
  and survives Blender restarts; a new version of the extension recompiles once.
* Imported as a plain package (``import addon`` from a checkout, as the tests and the demo
  do), numba's own default applies: ``__pycache__`` beside the ``rstrace_engine`` sources,
  or numba's per-user cache where that is not writable. This shares the cache with plain
  Python use of ``rstrace_engine``.
* ``NUMBA_CACHE_DIR`` in the environment always wins.
* Compiled kernels shipped in the extension (``kernel_cache/`` beside this file, written by
  ``scripts/build_extension.py`` for numba's portable ``generic`` CPU) are copied into that
  cache on first use (``rstrace_engine.shipped_kernels.seed``: only the kernels whose content
  key matches the installed sources, of this numba version), and this process then compiles
  and loads for the generic CPU. When they cannot be used (another platform, another numba,
  numba already initialised by another add-on) :func:`shipped_status` says why, and the
  kernels compile on first use.

Threads: Blender may render the viewport and an F12 render at the same time, from different
threads. Numba's ``workqueue`` threading layer (the fallback where neither TBB nor OpenMP is
available) aborts the process when two threads launch parallel kernels at once, and TBB
inside Blender is whatever version Blender ships. :data:`RENDER_LOCK` serialises every call
into the renderer, which is safe under every layer; renders are parallel inside.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

log = logging.getLogger(__name__)

#: Held around every call into rstrace_engine that may run numba kernels.
RENDER_LOCK = threading.Lock()

_state = {"cache_dir": None, "configured": False, "kernels_ready": False,
          "shipped": "not looked for", "seeded": None, "target": None, "host_job": None,
          "manifest_stamp": ""}

#: The compiled kernels the extension zip ships (absent in a checkout).
SHIPPED_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "kernel_cache")


def configure(package: str) -> str | None:
    """Point numba's cache at the extension's user directory; return the directory used.

    ``package`` is the add-on's ``__package__``: ``bl_ext.<repo>.rstrace`` when installed
    as an extension, ``addon`` when imported from a checkout.
    """
    import numba

    if os.environ.get("NUMBA_CACHE_DIR"):
        path = os.environ["NUMBA_CACHE_DIR"]
    elif package.startswith("bl_ext."):
        import bpy

        path = bpy.utils.extension_path_user(package, path="numba_cache", create=True)
        numba.config.CACHE_DIR = path
    else:
        path = None  # numba's default: beside the sources
    _state.update(cache_dir=path, configured=True)
    if path:
        _state["shipped"] = _use_shipped(SHIPPED_DIR, path)
    log.debug("numba cache directory: %s", path or "numba default")
    return path


def _use_shipped(shipped: str, path: str) -> str:
    """Seed the cache ``path`` from the shipped kernels; returns "" when they are used, or
    why not. Never raises: without them the kernels compile on first use.

    Portable code is a few percent slower than code for the host CPU on the BVH traversal
    (``docs/KERNELS.md``), so after the first render :func:`start_host_compile` compiles the
    host's kernels into the same cache in a background process; once it has finished, the
    next Blender process uses them (a running process keeps the kernels it has)."""
    import json

    if not os.path.isdir(shipped):
        return "no compiled kernels ship with this build"
    try:
        from rstrace_engine import shipped_kernels

        manifest, why = shipped_kernels.shipped_status(shipped)
        stamp = json.dumps(manifest, sort_keys=True)
        _state["manifest_stamp"] = stamp
        if not why and host_kernels_ready(path, stamp):
            _state["target"] = "host"
            log.info("RSTrace: kernels compiled for this CPU (%s) are used", _host_cpu())
            return "kernels compiled for this CPU are used"
        if not why and not shipped_kernels.use_portable_target():
            why = "numba was initialised by another add-on before RSTrace"
        if why:
            log.info("RSTrace: %s; kernels compile on first use", why)
            return why
        _state["target"] = "generic"
        marker = os.path.join(path, ".rstrace-seeded")
        try:
            with open(marker) as f:
                if f.read() == stamp:
                    return ""
        except OSError:
            pass
        _state["seeded"] = shipped_kernels.seed(shipped, path)
        with open(marker, "w") as f:
            f.write(stamp)
        return ""
    except Exception as exc:  # a broken shipped cache must not stop the add-on
        log.warning("RSTrace: the shipped kernels cannot be used (%s: %s); kernels compile "
                    "on first use", type(exc).__name__, exc)
        return f"{type(exc).__name__}: {exc}"


HOST_MARKER = ".rstrace-host-kernels"
#: Below this many cores the portable kernels stay (a few percent slower on the traversal
#: only; a background compile takes minutes of one core).
MIN_CORES_FOR_HOST_COMPILE = 4
_HOST_CODE = """
import contextlib, io, json, os, sys
if hasattr(os, "nice"):
    os.nice(10)
from rstrace_engine.__main__ import main
import llvmlite.binding as ll
out = io.StringIO()
with contextlib.redirect_stdout(out):
    rc = main(["warm-cache", "--jobs", "1", "--json"])
if rc == 0 and not json.loads(out.getvalue())["cancelled"]:
    path = os.path.join(sys.argv[1], sys.argv[3])
    with open(path + ".tmp", "w") as f:
        f.write(ll.get_host_cpu_name() + "\\n" + sys.argv[2])
    os.replace(path + ".tmp", path)
"""


def _host_cpu() -> str:
    import llvmlite.binding as ll

    return ll.get_host_cpu_name()


def host_kernels_ready(path: str, stamp: str) -> bool:
    """True when a background compile finished this CPU's kernels for this build."""
    try:
        with open(os.path.join(path, HOST_MARKER)) as f:
            return f.read() == f"{_host_cpu()}\n{stamp}"
    except OSError:
        return False


def start_host_compile() -> bool:
    """After the first render with the shipped (portable) kernels: compile every kernel for
    this CPU into the cache in a background process (low priority, one core; on machines
    with :data:`MIN_CORES_FOR_HOST_COMPILE` cores or more); the next Blender process uses
    them. Returns True when one was started."""
    import subprocess
    import sys

    path = _state["cache_dir"]
    if _state.get("target") != "generic" or _state.get("host_job") is not None or not path:
        return False
    if (os.cpu_count() or 1) < MIN_CORES_FOR_HOST_COMPILE:
        return False  # minutes of compiling would slow the user's own work more
    exe = sys.executable
    if not exe or not os.path.basename(exe).lower().startswith("python"):
        return False
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    env["NUMBA_CACHE_DIR"] = path
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    try:
        _state["host_job"] = subprocess.Popen(
            [exe, "-c", _HOST_CODE, path, _state["manifest_stamp"], HOST_MARKER], env=env,
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError as exc:
        log.info("RSTrace: no background compile for this CPU (%s)", exc)
        return False
    log.info("RSTrace: compiling kernels for this CPU (%s) in the background", _host_cpu())
    return True


def stop_host_compile() -> None:
    job = _state.get("host_job")
    if job is not None and job.poll() is None:
        job.terminate()
    _state["host_job"] = None


def shipped_status() -> str:
    """"" when the extension's shipped kernels are in use, else why not."""
    return _state["shipped"]


def kernel_target() -> str | None:
    """"generic" (the shipped portable kernels), "host" (this CPU's, compiled here in the
    background after an earlier first render) or None (compiled on first use)."""
    return _state.get("target")


def cache_dir() -> str | None:
    return _state["cache_dir"]


def _cache_is_cold() -> bool:
    """True when no compiled kernel of rstrace_engine is cached yet (first render)."""
    if _state["cache_dir"]:
        root = Path(_state["cache_dir"])
    else:
        import importlib.util

        spec = importlib.util.find_spec("rstrace_engine")
        if spec is None or spec.origin is None:
            return True
        root = Path(spec.origin).parent
    try:
        return next(root.rglob("*.nbi"), None) is None
    except OSError:
        return True


def kernel_status() -> str | None:
    """A status-line message while kernels still have to be compiled or loaded.

    None once a render has completed in this process (kernels are in memory).
    """
    if _state["kernels_ready"]:
        return None
    if _cache_is_cold():
        why = _state["shipped"]
        detail = f"{why}: " if why and why != "not looked for" else ""
        return f"compiling kernels ({detail}first render after install, a few minutes)"
    return "loading compiled kernels"


def mark_kernels_ready() -> None:
    _state["kernels_ready"] = True


def warm_cache(progress=None, **options) -> dict:
    """Compile every render kernel into this add-on's numba cache, rendering nothing.

    The "warm the cache once" step of a render farm (``docs/FARM.md``), also the
    ``rstrace.warm_cache`` operator: afterwards no Blender process using the same cache
    compiles a kernel. Returns ``rstrace_engine.warm_kernels.warm``'s counts (``compiled``,
    ``loaded``, ``seconds``, ``unreached``) plus ``cache_dir``. Holds :data:`RENDER_LOCK`.
    ``options`` go to ``warm`` (``modes``, ``accelerators``, ``cancel``: the background
    warm-up of ``kernels`` warms one mode this way).
    """
    if not _state["configured"]:
        raise RuntimeError("runtime.configure() must run before kernels are compiled")
    from rstrace_engine import warm_kernels as warm

    with RENDER_LOCK:
        result = warm.warm(progress=progress, **options)
    if not result.get("cancelled"):
        mark_kernels_ready()
    result["cache_dir"] = _state["cache_dir"] or "numba default (beside rstrace_engine)"
    return result


def warm_viewport(mode: str, cancel=None, progress=None) -> dict:
    """The background warm-up for ``mode`` (``rstrace_engine.warm_first.warm_viewport``):
    the kernels of the viewport's first image first (the BVH traversal in a helper process
    meanwhile), then the rest of the mode's, holding :data:`RENDER_LOCK` one step at a time
    so a viewport renders in between."""
    if not _state["configured"]:
        raise RuntimeError("runtime.configure() must run before kernels are compiled")
    from rstrace_engine import warm_first

    result = warm_first.warm_viewport(mode, lock=RENDER_LOCK, cancel=cancel,
                                      progress=progress)
    if not result.get("cancelled"):
        mark_kernels_ready()
    return result


def set_threads(render) -> int:
    """Use Blender's render thread setting (Fixed) for numba's parallel loops."""
    import numba

    n = numba.config.NUMBA_NUM_THREADS
    if render.threads_mode == "FIXED":
        n = max(1, min(int(render.threads), n))
    numba.set_num_threads(n)
    return n
