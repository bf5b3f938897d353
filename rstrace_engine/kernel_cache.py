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

Content keys (:class:`ContentKeyedLocator`). numba names a kernel's cache folder after the
*absolute* path of its source folder (``UserProvidedCacheLocator``: ``<dir>_<sha1 of the
path>``) and stamps its index with a hash of the kernel's *own* source file only. So a cache
compiled on one machine is never found after installing on another (other paths), and a
kernel that inlines a constant or an ``@njit`` helper from another module (``tolerances``)
is loaded stale after that module changes. Our locator keys every kernel of a module on
:func:`module_key`: the contents of that module and of every module of the package it
imports, transitively (deferred imports too), of the package ``__init__`` files on the way
and the package's version; the index stamp adds numba's and llvmlite's versions. The cache
folder is the module's path *relative to the package* under ``NUMBA_CACHE_DIR`` (or
``__pycache__`` beside the source, numba's in-tree default). The key is also in the file
names (numba's "disambiguator"), so two checkouts sharing one cache folder keep apart.

numba internals this module relies on (numba 0.59-0.68; ``tests/test_kernel_cache.py``
``test_numba_internals_we_rely_on`` fails loudly when one of them changes):

* ``numba.core.caching._CacheLocator`` (methods ``get_cache_path``, ``get_source_stamp``,
  ``get_disambiguator``, ``from_function``, ``ensure_cache_path``) and the list
  ``CacheImpl._locator_classes`` (``_CacheImpl`` before 0.60), tried in order: the
  extension point numba documents for cache locators (``NUMBA_CACHE_LOCATOR_CLASSES``
  replaces the whole list; when a user sets it, their locators win and ours is unused);
* ``IndexDataCacheFile`` (``_load_index``, ``_save_index``, ``_load_data``, ``_save_data``,
  ``_data_name``, ``_index_path``, ``_index_name``, ``_cache_path``, ``_source_stamp``;
  ``load(key)``, the dispatcher's one look into the disk cache before it compiles, and
  ``save(key, data)`` after a compile: the compile claims hang on these two) and its index
  file format: a pickled ``numba.__version__``, then a pickled ``(stamp, {key: data name})``;
* a dispatcher's ``_cache._cache_file``; the events ``numba:compile`` (data:
  ``dispatcher``, ``args``; ``Event._exc_details`` at its end) and ``numba:compiler_lock``
  (entered before a dispatcher looks in its disk cache);
* the index key's second item is ``codegen.magic_tuple()`` = (triple, CPU name, CPU
  features): a portable build (``NUMBA_CPU_NAME=generic``) and a host build of the same
  kernel are two entries of one index; its first is the argument types, and the whole key
  is ``Cache._index_key(sig, codegen)`` (:func:`load_cached` loads the entries whose key
  is this process's; ``Dispatcher.compile(sig)`` loads a cached signature before it
  would compile one).

Compile claims: before a process compiles a signature that is not in the cache, it takes a
file lock named after the kernel and the signature (``<index>.<digest>.claim`` beside the
index) and holds it until the kernel is saved. A process that finds the claim taken waits
for it (``CLAIMS["wait_s"]`` at most) and then loads what the other saved, instead of
compiling the same kernel at the same time (the warm-up's processes, the first image's
helper, two Blender processes starting at once, ``make demo``). A failed compile or a
process that ends lets the claim go (the OS drops the lock): the waiting process compiles.

Bad files: a truncated or corrupt index or data file is treated as missing (logged once per
file), so the kernel is compiled again and the file rewritten; a cache folder that cannot
be written is numba's own case (the locator declines, numba's next locator is tried).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import re
import sys
import threading
import time
import weakref
from collections import Counter

import numba
from numba.core import caching, config, event
from numba.core.registry import CPUDispatcher

from . import numba_inline

log = logging.getLogger(__name__)

LOCK_NAME = ".rstrace-cache.lock"

#: Modules (name prefixes) whose kernels get the locked cache and are counted.
_PREFIXES: set[str] = {"rstrace_engine"}
_COMPILED: Counter = Counter()  # (module, qualname) -> compilations in this process
_SIGNATURES: dict = {}  # (module, qualname) -> argument types of those compilations
_STATE = {"installed": False, "warned": False}
_THREAD_LOCK = threading.Lock()
_BAD_FILES: set[str] = set()  # corrupt cache files reported (once each)
#: py_funcs our locator placed whose dispatcher is not yet guarded (see _protect_pending)
_PENDING: dict = {}  # module name -> {id(py_func): weakref}

#: The stamp's first item: an index written by another locator never matches ours.
STAMP_TAG = "rstrace-content-1"

#: Modules left out of every content key: this one (the cache machinery, no kernel code;
#: a change of its file format bumps :data:`STAMP_TAG`).
NOT_KEYED = frozenset({__name__})

#: numba's locator list (``_CacheImpl`` before numba 0.60).
_CACHE_IMPL = getattr(caching, "CacheImpl", None) or caching._CacheImpl


# --- content keys -------------------------------------------------------------------

def usable_cores() -> int:
    """The CPUs this process may run on: its affinity (``taskset``, a container's cpuset),
    which ``os.cpu_count()`` ignores; the machine's count where there is no affinity call
    (macOS, Windows). At least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _top_packages() -> set[str]:
    return {p.split(".")[0] for p in _PREFIXES}


@functools.cache
def _file_bytes(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def _module_file(base: str, name: str) -> str | None:
    """The source file of module ``name`` below folder ``base`` (a package: its
    ``__init__.py``), or None."""
    parts = name.split(".")
    stem = os.path.join(base, *parts)
    for candidate in (stem + ".py", os.path.join(stem, "__init__.py")):
        if os.path.isfile(candidate):
            return candidate
    return None


#: ``import a.b, c as d`` and ``from .p import (x, y)`` statements, found by a scan of the
#: source text (not a parse: :func:`_imports` runs for every module a kernel module imports,
#: in every process that imports a kernel; ``ast.parse`` of them all took 0.6 s of CPU, more
#: than half of a warm process's first render). The scan may find more than the statements
#: (an import in a string or a comment): a superset only makes a key depend on one more file.
_IMPORT_RE = re.compile(r"^[ \t]*import[ \t]+([^\n#;]+)", re.M)
_FROM_RE = re.compile(
    r"^[ \t]*from[ \t]+(\.*)[ \t]*([\w.]*)[ \t]+import[ \t]*(\([^)]*\)|[^\n#;]*)", re.M)
_NAME_RE = re.compile(r"[A-Za-z_][\w.]*")


@functools.cache
def _imports(path: str, name: str, tops: frozenset) -> tuple[str, ...]:
    """Names of the modules of ``tops`` that module ``name`` (file ``path``) imports, at
    module level or inside a function, absolute or relative (``from p import x``: ``p.x``
    and ``p``), plus its parent packages."""
    text = re.sub(r"#[^\n]*", "", _file_bytes(path).decode("utf-8", errors="replace"))
    text = text.replace("\\\n", " ")
    is_package = os.path.basename(path) == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    out = set()
    for m in _IMPORT_RE.finditer(text):
        for alias in m.group(1).split(","):
            words = alias.split()
            if words and _NAME_RE.fullmatch(words[0]):
                out.add(words[0])
    for m in _FROM_RE.finditer(text):
        dots, module, names = m.group(1), m.group(2), m.group(3)
        if dots:
            base = package.split(".")
            base = base[:len(base) - (len(dots) - 1)]
            prefix = ".".join(base + ([module] if module else []))
        else:
            prefix = module
        out.add(prefix)
        for alias in names.strip("()").split(","):
            words = alias.split()
            if words and _NAME_RE.fullmatch(words[0]):
                out.add(f"{prefix}.{words[0]}")
    parts = name.split(".")
    out.update(".".join(parts[:i]) for i in range(1, len(parts)))
    return tuple(sorted(n for n in out if n and n.split(".")[0] in tops))


def _base_folder(name: str, path: str) -> str:
    """The folder that holds module ``name``'s top-level package (or the module itself)."""
    depth = name.count(".") + (1 if os.path.basename(path) == "__init__.py" else 0)
    base = os.path.dirname(os.path.abspath(path))
    for _ in range(depth):
        base = os.path.dirname(base)
    return base


def module_sources(name: str, path: str) -> dict[str, str]:
    """Module name -> source file of ``name`` and every module of our packages it imports,
    transitively (the files :func:`module_key` hashes)."""
    base, tops = _base_folder(name, path), frozenset(_top_packages())
    found, todo = {}, [(name, os.path.abspath(path))]
    while todo:
        mod, file = todo.pop()
        if mod in found:
            continue
        found[mod] = file
        for other in _imports(file, mod, tops):
            if other not in found:
                other_file = None if other in NOT_KEYED else _module_file(base, other)
                if other_file is not None:  # a name imported from a module, not a module
                    todo.append((other, other_file))
    return found


def _version(name: str) -> str:
    top = sys.modules.get(name.split(".")[0])
    return str(getattr(top, "__version__", ""))


@functools.cache
def module_key(name: str, path: str) -> str:
    """The content key of every kernel of module ``name`` (source file ``path``): a hash of
    the package version and of the module's and its in-package imports' sources (read
    once per process)."""
    h = hashlib.sha256(f"{STAMP_TAG}\0{_version(name)}\0".encode())
    for mod, file in sorted(module_sources(name, path).items()):
        h.update(mod.encode() + b"\0" + hashlib.sha256(_file_bytes(file)).digest())
    return h.hexdigest()


def source_stamp(key: str) -> tuple:
    """The stamp numba writes into (and compares with) an index of our kernels."""
    import llvmlite

    return (STAMP_TAG, key, numba.__version__, llvmlite.__version__)


class ContentKeyedLocator(caching._CacheLocator):
    """Caches our kernels under a folder relative to their package, keyed on content."""

    def __init__(self, py_func, py_file, name: str):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._key = module_key(name, py_file)
        rel = os.path.relpath(os.path.dirname(os.path.abspath(py_file)),
                              _base_folder(name, py_file))
        if config.CACHE_DIR:
            self._cache_path = os.path.join(config.CACHE_DIR, rel)
        else:  # numba's in-tree default
            self._cache_path = os.path.join(os.path.dirname(py_file), "__pycache__")

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return source_stamp(self._key)

    def get_disambiguator(self):
        return f"{self._lineno}-{self._key[:12]}"

    @classmethod
    def from_function(cls, py_func, py_file):
        name = getattr(py_func, "__module__", "") or ""
        if not _ours_by_name(name) or not os.path.isfile(py_file):
            return None
        try:
            self = cls(py_func, py_file, name)
            self.ensure_cache_path()
        except (OSError, SyntaxError, ValueError):
            return None  # numba's own locators are tried next
        _PENDING.setdefault(name, {})[id(py_func)] = weakref.ref(py_func)
        return self


def _ours_by_name(module: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in _PREFIXES)


class _LockedCacheFile(caching.IndexDataCacheFile):
    """numba's index/data cache file with an inter-process lock around ``save``; a corrupt
    or truncated file reads as missing, a save that cannot write is logged, not raised."""

    def _load_index(self):
        try:
            return super()._load_index()
        except Exception as exc:  # noqa: BLE001  (any unpickling error: a bad file)
            _bad_file(self._index_path, exc)
            return {}

    def _load_unclaimed(self, key):
        try:
            return super().load(key)
        except Exception as exc:  # noqa: BLE001
            _bad_file(os.path.join(self._cache_path, self._load_index().get(key, "?")), exc)
            return None

    def load(self, key):
        """The cached kernel, or None: then this process compiles it, under a claim (see
        :func:`_claim`): while another process compiles the same signature, wait for it and
        load what it saved."""
        data = self._load_unclaimed(key)
        if data is not None or not CLAIMS["on"]:
            return data
        _claim(self._cache_path, self._index_name, key)
        # again: another process saved it meanwhile (it waited for us, or finished between
        # our first look and our claim)
        data = self._load_unclaimed(key)
        if data is not None:
            _release(self._cache_path, self._index_name, key)
        return data

    def save(self, key, data):
        try:
            self._save_locked(key, data)
        except OSError as exc:  # a read-only or full cache folder: the kernel stays in memory
            _warn_once(f"cannot write the kernel cache in {self._cache_path}: {exc}")
        finally:
            _release(self._cache_path, self._index_name, key)

    def _save_locked(self, key, data):
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


# --- compile claims: one process compiles a signature, the others wait and load it -------

#: ``on``: claims are taken (``RSTRACE_COMPILE_CLAIMS=0`` turns them off); ``wait_s``: the
#: longest wait for another process's compile before compiling here anyway.
CLAIMS = {"on": os.environ.get("RSTRACE_COMPILE_CLAIMS", "1") != "0", "wait_s": 900.0,
          "poll_s": 0.05}
_CLAIMED: dict = {}  # (cache folder, index name, key digest) -> open claim file
_CLAIM_STATS = Counter()  # "claimed", "waited", "wait_s" (this process)
CLAIM_WAITS: list = []  # this process's waits: (index name, time.time() at start, s)


def _claim_path(folder: str, index_name: str, key) -> tuple[tuple, str]:
    digest = hashlib.sha256(repr(key).encode()).hexdigest()[:20]
    stem = index_name[:-len(".nbi")] if index_name.endswith(".nbi") else index_name
    return (folder, index_name, digest), os.path.join(folder, f"{stem}.{digest}.claim")


def _try_lock(fh) -> bool:
    """Lock ``fh`` without waiting: True when this process now holds it."""
    if sys.platform == "win32":
        import msvcrt

        fh.seek(0)
        try:
            msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False
    import fcntl

    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


def _claim(folder: str, index_name: str, key) -> bool:
    """Claim the compile of ``key`` (a signature of the kernel whose index is
    ``index_name``) for this process: a file lock beside the index, held until the kernel is
    saved (:func:`_release`; or the compile failed, or the process ended: the OS lets the
    lock go). While another process holds it, wait (at most ``CLAIMS["wait_s"]``) and take
    it. Returns True when this process waited (the caller loads again: the other process
    saved it, or failed and this one compiles). Without a claim file (a read-only cache)
    nothing is claimed: compiling here is what happened before claims."""
    name, path = _claim_path(folder, index_name, key)
    if name in _CLAIMED:  # this process is compiling it already (another thread, nested)
        return False
    try:
        fh = open(path, "a+b")  # noqa: SIM115  (kept open while claimed)
    except OSError:
        return False
    waited, t0, told = False, time.perf_counter(), False
    try:
        while not _try_lock(fh):
            waited = True
            if not told:
                told = True
                log.info("kernel %s: another process is compiling it, waiting", index_name)
            if time.perf_counter() - t0 > CLAIMS["wait_s"]:
                log.warning("kernel %s: waited %.0f s for another process's compile; "
                            "compiling here", index_name, CLAIMS["wait_s"])
                fh.close()
                return True
            time.sleep(CLAIMS["poll_s"])
    except OSError as exc:  # no locks on this file system: compile, unclaimed
        _warn_once(f"cannot lock {path} ({exc}); processes may compile a kernel twice")
        fh.close()
        return waited
    _CLAIMED[name] = fh
    _CLAIM_STATS["claimed"] += 1
    if waited:
        _CLAIM_STATS["waited"] += 1
        _CLAIM_STATS["wait_s"] += time.perf_counter() - t0
        CLAIM_WAITS.append((index_name, time.time() - time.perf_counter() + t0,
                            time.perf_counter() - t0))
    return waited


def _release(folder: str, index_name: str, key) -> None:
    """Let a claim go (the kernel was saved, or found in the cache after waiting)."""
    name, path = _claim_path(folder, index_name, key)
    fh = _CLAIMED.pop(name, None)
    if fh is None:
        return
    try:  # remove the file first: a process that opened it meanwhile takes a lock on a
        os.remove(path)  # file gone, finds the kernel saved and loads it
    except OSError:
        pass
    fh.close()  # closing unlocks


def _release_all(folder: str) -> None:
    """Let go every claim on the kernels of index files in ``folder`` (a compile failed)."""
    for name in [n for n in _CLAIMED if n[0] == folder]:
        fh = _CLAIMED.pop(name)
        fh.close()


def claim_stats() -> dict:
    """This process's compile claims: ``claimed``, ``waited`` (for another process's
    compile, then loaded or compiled here), ``wait_s``."""
    return {"claimed": _CLAIM_STATS["claimed"], "waited": _CLAIM_STATS["waited"],
            "wait_s": round(_CLAIM_STATS["wait_s"], 3)}


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


def _bad_file(path: str, exc: Exception) -> None:
    if path not in _BAD_FILES:
        _BAD_FILES.add(path)
        log.warning("kernel cache file %s is unreadable (%s: %s): compiling again", path,
                    type(exc).__name__, exc)


def bad_files() -> list[str]:
    """The cache files found corrupt or truncated in this process."""
    return sorted(_BAD_FILES)


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
        # the compile raised: nothing will be saved, let the waiting processes compile it
        # (``Event.is_failed`` says the opposite in numba 0.68: ``_exc_details`` is read)
        if _CLAIMED and getattr(ev, "_exc_details", None) is not None:
            dispatcher = (ev.data or {}).get("dispatcher")
            cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
            folder = getattr(cache_file, "_cache_path", None)
            if folder is not None:
                _release_all(folder)


class _LockListener(event.Listener):
    """Guards our dispatchers' cache files before they first read the disk cache."""

    def on_start(self, ev):
        if _PENDING:
            _protect_pending()

    def on_end(self, ev):
        pass


def _protect_pending() -> None:
    """Swap in :class:`_LockedCacheFile` for the dispatchers our locator placed since the
    last call (module-level kernels; a kernel made inside a function is guarded when it
    first compiles, by the compile listener)."""
    for name in list(_PENDING):
        module = sys.modules.get(name)
        funcs = _PENDING.get(name)
        if module is None or not funcs:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, CPUDispatcher) and id(value.py_func) in funcs:
                protect(value)
                funcs.pop(id(value.py_func), None)
        for key, ref in list(funcs.items()):
            if ref() is None:
                funcs.pop(key, None)
        if not funcs:
            _PENDING.pop(name, None)


def install(prefix: str | None = None) -> None:
    """Register the compile listener (once per process); also guard modules ``prefix``.

    ``prefix`` lets a module outside ``rstrace_engine`` (a test's kernel module) opt in.
    """
    if prefix:
        _PREFIXES.add(prefix)
    if not _STATE["installed"]:
        numba_inline.install()  # inlining without numba's per-block copies (same code)
        event.register("numba:compile", _CompileListener())
        event.register("numba:compiler_lock", _LockListener())
        if ContentKeyedLocator not in _CACHE_IMPL._locator_classes:
            _CACHE_IMPL._locator_classes.insert(0, ContentKeyedLocator)
        if config.CACHE_LOCATOR_CLASSES if hasattr(config, "CACHE_LOCATOR_CLASSES") else None:
            log.info("NUMBA_CACHE_LOCATOR_CLASSES is set: rstrace's content-keyed kernel "
                     "cache is not used")
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


def _index(dispatcher, ours: bool) -> list:
    """The signatures in ``dispatcher``'s disk cache index (fresh ones); ``ours``: only
    those this process would load (this CPU or target, the kernel's current code)."""
    cache = getattr(dispatcher, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    if cache_file is None or ours and not hasattr(cache, "_index_key"):
        return []
    try:
        keys = list(cache_file._load_index())
    except Exception:  # noqa: BLE001  (a corrupt index holds nothing)
        return []
    codegen, out = dispatcher.targetctx.codegen() if ours else None, []
    for key in keys:
        sig = key[0] if isinstance(key, tuple) and key else None
        with contextlib.suppress(Exception):  # (an entry of another numba: not ours)
            if not ours or isinstance(sig, tuple) and cache._index_key(sig, codegen) == key:
                out.append(sig)
    return out


def cached_signatures(dispatcher, ours: bool = False) -> int:
    """How many compiled signatures of ``dispatcher`` the disk cache holds (fresh ones);
    ``ours``: only those this process would load (:func:`load_cached`; an index also lists
    another CPU's, e.g. the portable kernels a shipped cache seeded)."""
    return len(_index(dispatcher, ours))


def load_cached(dispatcher, stop=None) -> int:
    """Load into memory every signature of ``dispatcher`` that the disk cache holds for
    this process (this CPU or target, the kernel's current code), rendering and compiling
    nothing: what its first call would load (a second process's first render loads each
    kernel it runs this way, about 30 ms each). ``stop`` () -> bool is asked between
    signatures. Returns how many were loaded (0: none cached, or all in memory already).

    A signature whose data file turns out unreadable is compiled (what the first call
    would do too; the file is rewritten)."""
    loaded = 0
    for sig in _index(dispatcher, True):
        if stop is not None and stop():
            break
        if tuple(sig) not in dispatcher.overloads:
            dispatcher.compile(sig)
            loaded += 1
    return loaded


def mark(prefix: str = "rstrace_engine") -> dict:
    """This process's compile and cache-load counts so far, for ``counts(since=...)``."""
    return {"compiled": Counter(_COMPILED),
            "signatures": {k: len(v) for k, v in _SIGNATURES.items()},
            "hits": {id(d): sum(d.stats.cache_hits.values()) for d in dispatchers(prefix)}}


def counts(prefix: str = "rstrace_engine", since: dict | None = None) -> dict:
    """Kernels of ``prefix`` compiled and loaded from the disk cache in this process (since
    :func:`mark` returned ``since``: what one warm-up did, whatever ran before it in the
    process; without it a test's earlier compiles on a partly warm cache counted too).

    ``compiled`` counts compilations (signatures), ``loaded`` signatures read from the
    cache; ``kernels`` is the number of dispatchers, ``used`` those with any signature;
    ``compiled_kernels`` maps each compiled kernel to the argument types it was compiled for.
    """
    ds = dispatchers(prefix)
    before = since or {"compiled": Counter(), "signatures": {}, "hits": {}}
    new = {k: n - before["compiled"].get(k, 0) for k, n in _COMPILED.items()
           if k[0] == prefix or k[0].startswith(prefix + ".")}
    loaded = sum(sum(d.stats.cache_hits.values()) - before["hits"].get(id(d), 0) for d in ds)
    used = sum(1 for d in ds if d.signatures)
    return {"kernels": len(ds), "used": used, "compiled": sum(new.values()),
            "loaded": loaded,
            "compiled_kernels": {f"{m}.{q}": _SIGNATURES.get((m, q), [])[
                before["signatures"].get((m, q), 0):]
                for (m, q), n in sorted(new.items()) if n}}
