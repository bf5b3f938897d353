"""numba's on-disk kernel cache, safe to share between processes, and counted.

Render-farm workers often start at the same moment on one machine (or share a network
folder through ``NUMBA_CACHE_DIR``), each compiling the kernels the cache lacks. numba
writes every file of its cache atomically (a temporary file, then ``os.replace``), but
saving a new signature of a kernel is a read-modify-write of that kernel's index file that
also *chooses the name of the data file* from the index it read. Two processes that compile
two different signatures of one kernel at once both pick ``<kernel>.1.nbc``: one index
entry is lost, and the surviving entry may name the data file the *other* process wrote,
i.e. machine code compiled for other argument types, which a later process loads without
any check (a crash or a silently wrong image).

:func:`install` (run by ``rstrace_engine/__init__.py``, before any kernel is defined)
registers a listener on numba's ``numba:compile`` event. The first time one of our kernels
is compiled in a process, the listener swaps its cache file for :class:`_LockedCacheFile`,
which does the read-modify-write under an exclusive lock on ``.rstrace-cache.lock`` in the
cache folder and writes the data file *before* the index that names it, so a reader never
finds an index entry whose data is missing or stale. Loading needs no lock (both files are
replaced atomically). The lock is ``fcntl.flock`` (POSIX, also over NFSv4) or
``msvcrt.locking`` (Windows); where neither works, numba's own behaviour is kept and a
warning is logged once.

The same listener counts compilations; loads from the cache are numba's own per-kernel
``cache_hits`` counter. :func:`counts` reports both, which is how the tests and the farm
benchmark check that a warm cache compiles nothing and a cold shared cache compiles each
kernel a bounded number of times.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
from collections import Counter

from numba.core import caching, event
from numba.core.registry import CPUDispatcher

log = logging.getLogger(__name__)

LOCK_NAME = ".rstrace-cache.lock"

#: Modules (name prefixes) whose kernels get the locked cache and are counted.
_PREFIXES: set[str] = {"rstrace_engine"}
_COMPILED: Counter = Counter()  # (module, qualname) -> compilations in this process
_SIGNATURES: dict = {}  # (module, qualname) -> argument types of those compilations
_STATE = {"installed": False, "warned": False}
_THREAD_LOCK = threading.Lock()


class _LockedCacheFile(caching.IndexDataCacheFile):
    """numba's index/data cache file with an inter-process lock around ``save``."""

    def save(self, key, data):
        with _file_lock(self._cache_path):
            overloads = self._load_index()
            data_name = overloads.get(key)
            if data_name is None:
                existing = set(overloads.values())
                number = 1
                while self._data_name(number) in existing:
                    number += 1
                data_name = self._data_name(number)
            self._save_data(data_name, data)  # data first: an index never names a missing file
            if overloads.get(key) != data_name:
                overloads[key] = data_name
                self._save_index(overloads)


@contextlib.contextmanager
def _file_lock(folder: str):
    """An exclusive lock between processes on ``folder/LOCK_NAME`` (and between threads)."""
    with _THREAD_LOCK:
        path = os.path.join(folder, LOCK_NAME)
        try:
            fh = open(path, "a+b")  # noqa: SIM115 (closed below, after unlocking)
        except OSError as exc:
            _warn_once(f"cannot open the kernel cache lock {path}: {exc}")
            yield
            return
        try:
            locked = _lock(fh)
            try:
                yield
            finally:
                if locked:
                    _unlock(fh)
        finally:
            fh.close()


def _lock(fh) -> bool:
    try:
        if sys.platform == "win32":
            import msvcrt

            fh.seek(0)
            while True:
                try:
                    msvcrt.locking(fh.fileno(), msvcrt.LK_LOCK, 1)
                    return True
                except OSError:  # LK_LOCK gives up after 10 s; keep waiting
                    continue
        import fcntl

        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        return True
    except OSError as exc:
        _warn_once(f"cannot lock the kernel cache ({exc}); concurrent compiles are unguarded")
        return False


def _unlock(fh) -> None:
    if sys.platform == "win32":
        import msvcrt

        fh.seek(0)
        msvcrt.locking(fh.fileno(), msvcrt.LK_UNLCK, 1)
    else:
        import fcntl

        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _warn_once(message: str) -> None:
    if not _STATE["warned"]:
        _STATE["warned"] = True
        log.warning(message)


def _ours(dispatcher) -> bool:
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return any(module == p or module.startswith(p + ".") for p in _PREFIXES)


def protect(dispatcher) -> None:
    """Give one cached numba dispatcher the locked cache file (idempotent)."""
    cache = getattr(dispatcher, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    if cache_file is not None and type(cache_file) is caching.IndexDataCacheFile:
        cache_file.__class__ = _LockedCacheFile


class _CompileListener(event.Listener):
    def on_start(self, ev):
        dispatcher = (ev.data or {}).get("dispatcher")
        if dispatcher is not None and _ours(dispatcher):
            protect(dispatcher)  # before numba saves what it is about to compile
            _COMPILED[_name(dispatcher)] += 1  # a compilation starts (not a cache load)
            _SIGNATURES.setdefault(_name(dispatcher), []).append(
                ", ".join(str(a) for a in ev.data.get("args") or ()))

    def on_end(self, ev):
        pass


def install(prefix: str | None = None) -> None:
    """Register the compile listener (once per process); also guard modules ``prefix``.

    ``prefix`` lets a module outside ``rstrace_engine`` (a test's kernel module) opt in.
    """
    if prefix:
        _PREFIXES.add(prefix)
    if not _STATE["installed"]:
        event.register("numba:compile", _CompileListener())
        _STATE["installed"] = True


def _name(dispatcher) -> tuple[str, str]:
    f = dispatcher.py_func
    return f.__module__, f.__qualname__


def dispatchers(prefix: str = "rstrace_engine") -> list:
    """Every numba dispatcher defined in the imported modules under ``prefix``."""
    seen, out = set(), []
    for name, module in list(sys.modules.items()):
        if module is None or not (name == prefix or name.startswith(prefix + ".")):
            continue
        for value in list(vars(module).values()):
            if isinstance(value, CPUDispatcher) and id(value) not in seen:
                if getattr(value.py_func, "__module__", None) == name:
                    seen.add(id(value))
                    out.append(value)
    return sorted(out, key=lambda d: _name(d))


def cached_signatures(dispatcher) -> int:
    """How many compiled signatures of ``dispatcher`` the disk cache holds (fresh ones)."""
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    if cache_file is None:
        return 0
    try:
        return len(cache_file._load_index())
    except (OSError, EOFError, ValueError, TypeError):
        return 0


def counts(prefix: str = "rstrace_engine") -> dict:
    """Kernels of ``prefix`` compiled and loaded from the disk cache in this process.

    ``compiled`` counts compilations (signatures), ``loaded`` signatures read from the
    cache; ``kernels`` is the number of dispatchers, ``used`` those with any signature;
    ``compiled_kernels`` maps each compiled kernel to the argument types it was compiled for.
    """
    ds = dispatchers(prefix)
    compiled = sum(n for (mod, _), n in _COMPILED.items()
                   if mod == prefix or mod.startswith(prefix + "."))
    loaded = sum(sum(d.stats.cache_hits.values()) for d in ds)
    used = sum(1 for d in ds if d.signatures)
    return {"kernels": len(ds), "used": used, "compiled": compiled, "loaded": loaded,
            "compiled_kernels": {f"{m}.{q}": _SIGNATURES.get((m, q), [])
                                 for (m, q), n in sorted(_COMPILED.items())
                                 if n and (m == prefix or m.startswith(prefix + "."))}}
