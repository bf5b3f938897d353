"""Small matrix inverses without waking OpenBLAS's idle threads.

``np.linalg.inv`` of a 4x4 matrix (LAPACK ``dgesv`` with the identity on the right: its
``dtrsm``) wakes the worker threads of numpy's OpenBLAS, which then spin waiting for more
work: on the 2-core machine of ``docs/bench-scale-bpy.md`` (session 35, f12one) about
0.06-0.13 s of process CPU per call (or per burst of calls), for a result that takes 0.2 ms
(``np.linalg.solve`` with one right-hand side, ``det``, ``svd`` and small ``matmul``s do
not wake them). A first F12 inverts every object's matrix (:meth:`.geometry.scene.Scene`'s
placement), so it paid that spin once, whatever the scene's size.

:func:`inv` is ``np.linalg.inv``, the same LAPACK call and the same bits, run with OpenBLAS
set to one thread for the call and set back after (OpenBLAS's own
``openblas_set_num_threads``, found in the library the process loaded; where numpy's BLAS
is another one, or the controls are not found, it is ``np.linalg.inv`` as it is). For a
4x4 matrix OpenBLAS computes the same values on one thread as on several (30,000 random
4x4 matrices -- affine, general, rotation and scale -- compared bit for bit, session 35).
While the one-thread setting holds (the inverse's 0.2 ms), a BLAS call another thread
starts runs on one thread too (the same values for a matrix product; a threaded reduction,
such as a long dot product, may round differently on one thread).
"""

from __future__ import annotations

import ctypes
import threading

import numpy as np

#: (get, set) symbol names of OpenBLAS's thread-count controls, per OpenBLAS build
#: (numpy 1.x wheels: 64-bit ints with a ``64_`` suffix; numpy 2.x: scipy-openblas's).
_SYMBOLS = (("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
            ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
            ("openblas_get_num_threads", "openblas_set_num_threads"))

_lock = threading.Lock()
_found: list = []  # [(get, set) or None] once looked up


def _openblas_paths() -> list[str]:
    """Paths of the OpenBLAS libraries this process has loaded (Linux's memory map)."""
    try:
        with open("/proc/self/maps") as fh:
            paths = {line.split(None, 5)[-1].strip() for line in fh if "openblas" in line}
    except OSError:
        return []
    return sorted(p for p in paths if p.startswith("/"))


def controls():
    """OpenBLAS's ``(get_num_threads, set_num_threads)`` as ctypes functions, or None
    where numpy's BLAS is not an OpenBLAS this module can find."""
    if not _found:
        found = None
        for path in _openblas_paths():
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            for get_name, set_name in _SYMBOLS:
                get, set_ = getattr(lib, get_name, None), getattr(lib, set_name, None)
                if get is not None and set_ is not None:
                    get.restype, get.argtypes = ctypes.c_int, []
                    set_.restype, set_.argtypes = None, [ctypes.c_int]
                    found = (get, set_)
                    break
            if found is not None:
                break
        _found.append(found)
    return _found[0]


def inv(m: np.ndarray) -> np.ndarray:
    """``np.linalg.inv(m)``, bit for bit, with OpenBLAS on one thread for the call (module
    docstring: its idle threads are not woken)."""
    c = controls()
    if c is None:
        return np.linalg.inv(m)
    get, set_ = c
    with _lock:
        n = get()
        if n <= 1:
            return np.linalg.inv(m)
        set_(1)
        try:
            return np.linalg.inv(m)
        finally:
            set_(n)
