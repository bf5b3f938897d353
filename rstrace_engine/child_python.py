"""A Python process that shares this process's kernel cache: the warm-up's parts
(:func:`.warm_kernels.warm_parallel`), the first image's helper (:mod:`.warm_first`) and
the cell build's background compile (:mod:`.interpolants.build_beside`) run in one.

It gets this process's numba cache folder and CPU target (the portable target of shipped
kernels, ``kernel_cache``), so that what it compiles is what this process loads, and this
package first on its ``PYTHONPATH``. None where this process's executable is not a Python
(an embedding host): the callers then do the work themselves.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

log = logging.getLogger(__name__)


def python() -> str | None:
    """This process's Python executable (None: an embedding host's, not a Python)."""
    exe = sys.executable
    if not exe or not os.path.basename(exe).lower().startswith("python"):
        return None
    return exe


def environment() -> dict:
    """The environment of a child that shares this process's kernel cache and target."""
    import numba

    env = dict(os.environ)
    if numba.config.CACHE_DIR:
        env["NUMBA_CACHE_DIR"] = numba.config.CACHE_DIR
    if numba.config.CPU_NAME:  # the portable target of shipped kernels (kernel_cache)
        env["NUMBA_CPU_NAME"] = numba.config.CPU_NAME
        env["NUMBA_CPU_FEATURES"] = numba.config.CPU_FEATURES or ""
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = os.pathsep.join([package_root] + [p for p in sys.path if p])
    return env


def start(code: str, stderr=subprocess.PIPE) -> subprocess.Popen | None:
    """``python -c code`` with :func:`environment` (None when no Python can be started)."""
    exe = python()
    if exe is None:
        return None
    try:
        return subprocess.Popen([exe, "-c", code], env=environment(),
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=stderr)
    except OSError as exc:
        log.info("rstrace: no child process (%s)", exc)
        return None
