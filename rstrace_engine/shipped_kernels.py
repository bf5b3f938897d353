"""Compiled kernels that ship with the extension: numba's portable CPU target, the manifest
that says what a shipped cache was built with, and seeding numba's cache from it.

``scripts/build_extension.py`` compiles every kernel for numba's generic CPU
(:func:`use_portable_target`), writes :data:`MANIFEST` (:func:`build_manifest`) and packs
the cache into the platform's zip; the installed add-on (``addon/runtime.py``) checks it
(:func:`shipped_status`) and copies what is current into its own cache (:func:`seed`).
What keeps a shipped kernel from being loaded stale is :mod:`.kernel_cache`'s content key:
an index is taken only when its stamp names this checkout's key.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections import Counter

import numba
from numba.core import caching, config

from .kernel_cache import (
    _bad_file,
    _base_folder,
    _file_lock,
    _module_file,
    _version,
    module_key,
    source_stamp,
)

log = logging.getLogger(__name__)

#: The file that describes a shipped cache (``scripts/build_extension.py`` writes it).
MANIFEST = "rstrace-kernels.json"
#: numba's portable CPU: code every x86-64 (or arm64) machine runs.
PORTABLE_CPU = "generic"


def target_initialised() -> bool:
    """True once numba's CPU target (and its code generator) exists in this process: its CPU
    name and features are fixed from then on."""
    from numba.core.registry import cpu_target

    return "_toplevel_target_context" in vars(cpu_target)


def cpu_name() -> str:
    """The CPU this process compiles for and looks up in the cache (``generic`` or the
    host's name)."""
    import llvmlite.binding as ll

    return config.CPU_NAME or ll.get_host_cpu_name()


def use_portable_target() -> bool:
    """Compile for (and load kernels compiled for) numba's generic CPU from now on, as a
    shipped cache was built. Only possible before numba's CPU target is initialised (another
    add-on may have compiled first): returns whether this process now uses it.

    Only numba's config is set, not the environment: ``config.reload_config()`` (which numba
    runs before each compile) re-reads every setting from the environment when a
    ``NUMBA_*`` variable changed, which would also drop a ``config.CACHE_DIR`` set in code
    (the add-on's): the first measured install compiled every kernel into
    ``site-packages`` that way. Helper processes get ``NUMBA_CPU_NAME`` from
    ``config.CPU_NAME`` (``warm_first``, ``warm_kernels.warm_parallel``)."""
    if config.CPU_NAME == PORTABLE_CPU:
        return True
    if target_initialised():
        log.info("numba's CPU target is initialised already (%s): shipped kernels for the "
                 "generic CPU are not used", cpu_name())
        return False
    config.CPU_NAME, config.CPU_FEATURES = PORTABLE_CPU, ""
    return True


def build_manifest(platform: str, shipped: bool, reason: str = "") -> dict:
    """What a shipped cache was built with (checked by :func:`shipped_status`)."""
    import platform as _platform

    import llvmlite

    return {"platform": platform, "shipped": shipped, "reason": reason,
            "cpu": cpu_name() if shipped else None, "version": _version("rstrace_engine"),
            "numba": numba.__version__, "llvmlite": llvmlite.__version__,
            "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
            "machine": _platform.machine() if shipped else None}


def shipped_status(folder: str) -> tuple[dict | None, str]:
    """(manifest, why not) for the shipped cache in ``folder``: why not is "" when this
    process can load it (same numba, llvmlite, Python and package version)."""
    import json

    import llvmlite

    try:
        with open(os.path.join(folder, MANIFEST)) as f:
            m = json.load(f)
    except FileNotFoundError:
        return None, "no compiled kernels ship with this build"
    except (OSError, ValueError) as exc:
        return None, f"the shipped kernels' manifest is unreadable ({exc})"
    if not m.get("shipped"):
        return m, m.get("reason") or "no compiled kernels ship for this platform"
    want = {"numba": numba.__version__, "llvmlite": llvmlite.__version__,
            "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
            "version": _version("rstrace_engine")}
    other = [f"{k} {m.get(k)} (this is {v})" for k, v in want.items() if m.get(k) != v]
    if other:
        return m, "the shipped kernels were built for another " + ", ".join(other)
    return m, ""


def _read_index(path: str):
    """(numba version, stamp, overloads) of an index file; None when unreadable."""
    import pickle

    try:
        with open(path, "rb") as f:
            version = pickle.load(f)
            stamp, overloads = pickle.loads(f.read())
        return version, stamp, dict(overloads)
    except FileNotFoundError:
        return None
    except Exception as exc:  # noqa: BLE001  (truncated or corrupt)
        _bad_file(path, exc)
        return None


def _copy_atomic(src: str, dst: str) -> None:
    import shutil
    import uuid

    tmp = f"{dst}.tmp.{uuid.uuid4().hex[:16]}"
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def seed(shipped: str, cache_dir: str, package: str = "rstrace_engine") -> dict:
    """Copy the compiled kernels shipped in ``shipped`` into numba's cache ``cache_dir``.

    An index is taken only when it is readable, of this numba version and current: its
    stamp names the content key this checkout's module has (:func:`module_key`), so a cache
    of other sources is never loaded. Its entries go into ``cache_dir``'s index of the same
    kernel (added to the entries there when those are current too, under the cache lock,
    data files before the index). Returns counts: ``copied`` (signatures), ``kernels``,
    ``current`` (already there), ``stale``, ``bad``."""
    import pickle

    top = sys.modules.get(package)
    base = _base_folder(package, top.__file__) if top is not None else None
    out = Counter(copied=0, kernels=0, current=0, stale=0, bad=0)
    for folder, _, files in os.walk(shipped):
        rel = os.path.relpath(folder, shipped)
        if rel.split(os.sep)[0] != package.split(".")[0]:
            continue  # not ours: numba's own overloads (numba_overloads_cached) are not shipped
        for index_name in sorted(f for f in files if f.endswith(".nbi")):
            src = _read_index(os.path.join(folder, index_name))
            if src is None:
                out["bad"] += 1
                continue
            version, stamp, overloads = src
            parts = [p for p in rel.split(os.sep) if p not in (".", "")]
            parts.append(index_name.split(".", 1)[0])
            module = ".".join(parts).removesuffix(".__init__")
            py_file = _module_file(base, module) if base else None
            if (version != numba.__version__ or py_file is None
                    or stamp != source_stamp(module_key(module, py_file))):
                out["stale"] += 1
                continue
            dest = os.path.join(cache_dir, rel)
            os.makedirs(dest, exist_ok=True)
            dest_index = os.path.join(dest, index_name)
            with _file_lock(dest):
                there = _read_index(dest_index)
                have = there[2] if there is not None and there[:2] == (version, stamp) else {}
                todo = {k: v for k, v in overloads.items() if k not in have}
                if not todo:
                    out["current"] += 1
                    continue
                used, merged = set(have.values()), dict(have)
                pattern = index_name[:-len(".nbi")] + ".{}.nbc"
                number = 1
                for key, data_name in todo.items():
                    while pattern.format(number) in used:
                        number += 1
                    new_name = pattern.format(number)
                    used.add(new_name)
                    _copy_atomic(os.path.join(folder, data_name), os.path.join(dest, new_name))
                    merged[key] = new_name
                    out["copied"] += 1
                tmp = f"{dest_index}.tmp.{os.getpid()}"
                with open(tmp, "wb") as f:
                    pickle.dump(version, f, protocol=-1)
                    f.write(caching.dumps((stamp, merged)))
                os.replace(tmp, dest_index)
                out["kernels"] += 1
    log.info("shipped kernels from %s: %s", shipped, dict(out))
    return dict(out)
