"""numba's own ``@overload`` implementations (``np.empty``, ``np.zeros``, ``arr.copy`` ...)
cached on disk like our kernels, so that each process does not compile them again.

Why: when one of our kernels is compiled, every numba function it calls that numba
implements with ``@overload`` (``np.empty(n, np.float64)``, ``np.argsort``, ``arr.sum()``
...) is compiled too, as a dispatcher of its own (typing, lowering, LLVM module passes and
machine code), then linked into the kernel. numba makes those dispatchers without
``cache=True``, so every process compiles its own: 21-31 s of CPU per cold ``make demo``
over its three compiling processes (docs/first-render.md, sessions 33-35).

What: :func:`install` (called by ``rstrace_engine/__init__.py`` after
``kernel_cache.install()``) wraps the jit decorator numba's overload templates build their
implementation with (``_OverloadFunctionTemplate._get_jit_decorator``, used by
``_build_impl`` only): an implementation defined in a ``numba`` module gets a disk cache,
numba's own ``FunctionCache`` (numba's own locators: ``NUMBA_CACHE_DIR``, or beside numba,
or the user-wide folder; stamped with numba's source file; the index key hashes the
implementation's bytecode and its closure's values, which is how one overload's
specialisations keep apart), with two changes:

* the index key also holds the compile flags the implementation *inherits* from the
  kernel that calls it (``nrt``, ``fastmath``, ``error_model``, ``forceinline``: what
  ``CPUTargetOptions.finalize`` inherits from numba's ``ConfigStack``). numba's disk cache
  does not key on them: without this, a ``np.empty`` compiled inside an
  ``error_model="numpy"`` kernel would be loaded into a ``"python"`` one;
* the index key also holds numpy's version: implementations branch on it in their bodies
  (``bool(empty array)`` raises from numpy 2.2), and numba stamps only its own;
* the cache file is :class:`kernel_cache._LockedCacheFile` (the index written under a lock,
  compile claims), as for our kernels: three processes compile at once in ``make demo``.

A key that cannot be computed (a closure value that does not pickle), one that holds an
object pickled under a per-process uuid (a jitted ``key=`` function, an ``@intrinsic``: it
would never load again, and every process would add entries), or a cache folder
that cannot be made leaves that implementation compiled in memory as numba does. The
compiled code is numba's: a cached implementation's library is its object code and bitcode,
which the calling kernel links as it links one compiled in the process (our own callees
are loaded the same way), so no kernel's code changes (``tests/test_numba_overloads_cached``
compares the LLVM IR of a kernel compiled with a loaded and with a fresh ``np.empty``).

Only implementations made while this thread compiles one of our kernels are cached
(:class:`_OursListener`): another add-on's numba code in Blender's process keeps numba's own
behaviour, and nothing of it is written to the cache folder the add-on sets for the process.
Where ``NUMBA_CACHE_DIR`` is unset (a checkout's CLI or ``make demo`` without it) numba's
locators put these files beside numba's own sources if that folder is writable (a virtual
environment's), else in the user-wide folder.

``RSTRACE_NUMBA_OVERLOAD_CACHE=0`` in the environment leaves numba alone (to compare).
numba internals relied on (0.59-0.68): ``_OverloadFunctionTemplate._get_jit_decorator``
(returns the jit decorator ``_build_impl`` calls with ``**self._jit_options``),
``_overload_func``, ``targetconfig.ConfigStack``, ``caching.FunctionCache`` (``_index_key``,
``load_overload``, ``save_overload``, ``_cache_file``) and a dispatcher's ``_cache``.
"""

from __future__ import annotations

import functools
import io
import logging
import os
import threading

import numpy
from numba.core import caching, event, serialize, targetconfig
from numba.core.typing import templates

log = logging.getLogger(__name__)

#: the flags ``CPUTargetOptions.finalize`` inherits from the calling kernel's compile
INHERITED = ("nrt", "fastmath", "error_model", "forceinline")

_STATE = {"installed": False, "original": None, "failed": 0}


def _flag_value(value):
    flags = getattr(value, "flags", None)  # FastMathOptions: a set (order varies by process)
    if isinstance(flags, (set, frozenset)):
        return tuple(sorted(str(f) for f in flags))
    return repr(value)


def inherited_flags() -> tuple | None:
    """The flags a dispatcher compiled now would inherit (None: compiled on its own)."""
    stack = targetconfig.ConfigStack()
    if not stack:
        return None
    top = stack.top()
    return tuple((name, _flag_value(getattr(top, name))) for name in INHERITED)


class PerProcessKey(Exception):
    """An index key that holds an object named by a per-process uuid."""


class _Probe(serialize.NumbaPickler):
    """numba's pickler that refuses what pickles under a uuid drawn in this process: a
    dispatcher (a jitted function passed as an argument: ``list.sort(key=f)``,
    ``sorted(a, key=f)``) or an ``@intrinsic``. A key holding one differs in every
    process: it is never loaded again, and each process would add an entry and a data
    file to the index (which every later load unpickles, rebuilding those dispatchers)."""

    def reducer_override(self, obj):
        if isinstance(getattr(type(obj), "_uuid", None), property):
            raise PerProcessKey(type(obj).__name__)
        return super().reducer_override(obj)


def _per_process(obj) -> bool:
    try:
        _Probe(io.BytesIO()).dump(obj)
    except PerProcessKey:
        return True
    return False


class FlagKeyedCache(caching.FunctionCache):
    """numba's function cache, its index key extended with the inherited flags."""

    def __init__(self, py_func, flags):
        self._inherited = flags
        super().__init__(py_func)

    def _index_key(self, sig, codegen):
        closure = self._py_func.__closure__ or ()
        if _per_process((sig, tuple(c.cell_contents for c in closure))):
            raise PerProcessKey(f"{self._py_func.__qualname__}{sig}")  # compiled in memory
        # numpy's version: numba's implementations read it (``numpy_version`` in
        # ``bool(array)``, ``np.geomspace`` ...); the index is stamped with numba's only
        return super()._index_key(sig, codegen) + (self._inherited, numpy.__version__)

    def load_overload(self, sig, target_context):
        try:
            return super().load_overload(sig, target_context)
        except Exception as exc:  # noqa: BLE001  (an unkeyable closure: compile it)
            _failed(exc)
            return None

    def save_overload(self, sig, data):
        try:
            super().save_overload(sig, data)
        except Exception as exc:  # noqa: BLE001
            _failed(exc)


def _failed(exc: Exception) -> None:
    _STATE["failed"] += 1
    if _STATE["failed"] == 1:
        log.info("a numba overload is not cached on disk (compiled in memory): %s", exc)


def _numbas(pyfunc) -> bool:
    module = getattr(pyfunc, "__module__", "") or ""
    return module == "numba" or module.startswith("numba.")


def cache(dispatcher) -> bool:
    """Give one numba-implementation dispatcher the flag-keyed, locked disk cache."""
    from . import kernel_cache

    try:
        dispatcher._cache = FlagKeyedCache(dispatcher.py_func, inherited_flags())
    except Exception as exc:  # noqa: BLE001  (no locator can write: numba's NullCache stays)
        _failed(exc)
        return False
    kernel_cache.protect(dispatcher)
    return True


#: this thread's compiles of our kernels in progress (:class:`_OursListener`)
_DEPTH = threading.local()


class _OursListener(event.Listener):
    """Counts this thread's compiles of our own kernels in progress
    (``kernel_cache._ours``: ``rstrace_engine`` and the prefixes opted in): only numba's
    implementations made while one of ours compiles are cached, so that another add-on's
    numba code in Blender's process keeps numba's behaviour (compiled in memory)."""

    def on_start(self, ev):
        if _ours_event(ev):
            _DEPTH.n = getattr(_DEPTH, "n", 0) + 1

    def on_end(self, ev):
        if _ours_event(ev):
            _DEPTH.n = max(0, getattr(_DEPTH, "n", 0) - 1)


def _ours_event(ev) -> bool:
    from . import kernel_cache

    dispatcher = (ev.data or {}).get("dispatcher")
    return dispatcher is not None and kernel_cache._ours(dispatcher)


def compiling_ours() -> bool:
    """Whether this thread is compiling one of our kernels now."""
    return getattr(_DEPTH, "n", 0) > 0


def _cached_jitter(jitter):
    @functools.wraps(jitter)
    def decorator_maker(*args, **options):
        decorate = jitter(*args, **options)
        if options.get("cache"):
            return decorate

        def decorate_and_cache(pyfunc):
            disp = decorate(pyfunc)
            if _numbas(pyfunc) and hasattr(disp, "_cache") and compiling_ours():
                cache(disp)
            return disp

        return decorate_and_cache

    return decorator_maker


def _get_jit_decorator(self):
    return _cached_jitter(_STATE["original"](self))


def installed() -> bool:
    return _STATE["installed"]


def install() -> bool:
    """Cache numba's overload implementations on disk (module doc); idempotent. False where
    ``RSTRACE_NUMBA_OVERLOAD_CACHE=0`` or numba lacks the hook."""
    if _STATE["installed"]:
        return True
    if os.environ.get("RSTRACE_NUMBA_OVERLOAD_CACHE", "1") == "0":
        return False
    cls = templates._OverloadFunctionTemplate
    original = getattr(cls, "_get_jit_decorator", None)
    if original is None or not hasattr(caching.FunctionCache, "_index_key"):
        log.info("numba's overload templates have no _get_jit_decorator: not cached")
        return False
    _STATE["original"] = original
    event.register("numba:compile", _OursListener())
    cls._get_jit_decorator = _get_jit_decorator
    _STATE["installed"] = True
    return True
