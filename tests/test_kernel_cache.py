"""A cold numba cache shared by workers that compile at the same moment (render farms).

The full kernel set takes minutes to compile, so these tests use a tiny kernel module
written into a temporary folder (several signatures per kernel, a parallel kernel, a kernel
calling another), guarded like ``rstrace_engine``'s own kernels through
``kernel_cache.install(prefix)``. Worker processes start together on one empty
``NUMBA_CACHE_DIR`` and compile the signatures in *opposite orders*: that is the case where
numba alone may pair an index entry with another signature's machine code. A last process
must then load every signature from the cache (nothing compiled) and compute exact results.
The full-size measurement (every kernel, cold, 2 workers) is ``scripts/farm_bench.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

KERNELS = textwrap.dedent('''
    import numpy as np
    from numba import njit, prange

    from rstrace_engine import kernel_cache

    kernel_cache.install(__name__)


    @njit(cache=True, nogil=True)
    def axpy(a, x, y):
        return a * x + y


    @njit(cache=True, nogil=True, parallel=True)
    def scaled(x, s):
        out = np.empty_like(x)
        for i in prange(x.shape[0]):
            out[i] = x[i] * s
        return out


    @njit(cache=True, nogil=True)
    def inner(v):
        return v * 3 + 1


    @njit(cache=True, nogil=True)
    def total(x):
        t = x.dtype.type(0)
        for v in x:
            t += inner(v)
        return t
''')

WORKER = textwrap.dedent('''
    import json, os, sys, time
    import numpy as np

    folder, name, order = sys.argv[1], sys.argv[2], sys.argv[3]
    sys.path.insert(0, folder)
    import tinykernels as k
    from rstrace_engine import kernel_cache

    calls = [
        ("axpy i8", lambda: k.axpy(np.int64(3), np.int64(4), np.int64(5)), 17),
        ("axpy f8", lambda: k.axpy(1.5, 2.0, 0.25), 3.25),
        ("axpy c16", lambda: k.axpy(1j, 1j, 1.0 + 0j), 0j),
        ("scaled f4", lambda: float(k.scaled(np.arange(4, dtype=np.float32), 0.5).sum()), 3.0),
        ("scaled i8", lambda: int(k.scaled(np.arange(4, dtype=np.int64), 3).sum()), 18),
        ("total i4", lambda: int(k.total(np.arange(5, dtype=np.int32))), 35),
        ("total f8", lambda: float(k.total(np.arange(5, dtype=np.float64) / 2)), 20.0),
    ]
    if order == "reverse":
        calls.reverse()
    open(os.path.join(folder, f"ready-{name}"), "w").close()
    while not os.path.exists(os.path.join(folder, "go")):
        time.sleep(0.005)
    wrong = []
    for label, call, expected in calls:
        got = call()
        if got != expected or type(got) is not type(expected):
            wrong.append(f"{label}: {got!r} != {expected!r}")
    c = kernel_cache.counts("tinykernels")
    print("RESULT " + json.dumps(dict(name=name, wrong=wrong, compiled=c["compiled"],
                                      loaded=c["loaded"], signatures=len(calls),
                                      which=c["compiled_kernels"])))
''')


def _start(folder: Path, cache: Path, name: str, order: str) -> subprocess.Popen:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, str(folder / "worker.py"), str(folder), name,
                             order], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _result(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=300)
    lines = [ln for ln in out.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, out[-2000:] + err[-3000:]
    return json.loads(lines[-1][len("RESULT "):])


def _run_together(folder: Path, cache: Path, names_orders) -> list[dict]:
    (folder / "go").unlink(missing_ok=True)
    procs = [_start(folder, cache, n, o) for n, o in names_orders]
    deadline = time.monotonic() + 120
    while not all((folder / f"ready-{n}").exists() for n, _ in names_orders):
        if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
            break
        time.sleep(0.01)
    (folder / "go").touch()  # every worker starts compiling at the same moment
    return [_result(p) for p in procs]


@pytest.fixture
def kernel_folder(tmp_path) -> Path:
    folder = tmp_path / "kernels"
    folder.mkdir()
    (folder / "tinykernels.py").write_text(KERNELS)
    (folder / "worker.py").write_text(WORKER)
    return folder


def test_cold_cache_compiled_by_concurrent_workers_in_opposite_orders(kernel_folder, tmp_path):
    cache = tmp_path / "shared_cache"
    workers = [("w0", "forward"), ("w1", "reverse"), ("w2", "forward")]
    results = _run_together(kernel_folder, cache, workers)
    for r in results:
        assert r["wrong"] == [], r
        # every signature compiled or loaded once per worker: bounded by the worker count
        assert r["compiled"] + r["loaded"] >= r["signatures"]
        assert r["compiled"] <= r["signatures"] + 1  # +1: inner, compiled inside total
    total_compiled = sum(r["compiled"] for r in results)
    print("compiled per worker:", [(r["compiled"], r["which"]) for r in results],
          "loaded:", [r["loaded"] for r in results])
    assert total_compiled <= len(workers) * (results[0]["signatures"] + 1)
    # compile claims: each signature compiled by one worker (inner for two of them), the
    # others waited for it and loaded it
    assert total_compiled == results[0]["signatures"] + 2

    # nothing half-written is left, and a new worker finds every signature, correct
    leftovers = [p.name for p in cache.rglob("*") if ".tmp." in p.name]
    assert leftovers == []
    (after,) = _run_together(kernel_folder, cache, [("after", "reverse")])
    assert after["wrong"] == [] and after["compiled"] == 0
    assert after["loaded"] == after["signatures"]


CLAIMANT = textwrap.dedent('''
    import os, sys, time
    folder = sys.argv[1]
    sys.path.insert(0, folder)
    import tinykernels as k
    from rstrace_engine import kernel_cache

    def die(self, key, data):  # compiled, then killed before saving: the claim goes with it
        open(os.path.join(folder, "claimed"), "w").close()
        while not os.path.exists(os.path.join(folder, "waiting")):
            time.sleep(0.01)
        time.sleep(float(sys.argv[2]))  # the other process waits for the claim meanwhile
        os._exit(3)

    kernel_cache._LockedCacheFile.save = die
    k.axpy(1.5, 2.0, 0.25)
''')

WAITER = textwrap.dedent('''
    import json, os, sys
    folder = sys.argv[1]
    sys.path.insert(0, folder)
    import tinykernels as k
    from rstrace_engine import kernel_cache

    k.inner(1)  # numba's first-compile set-up (seconds on a busy machine) done here
    open(os.path.join(folder, "waiting"), "w").close()
    got = k.axpy(1.5, 2.0, 0.25)
    print("RESULT " + json.dumps(dict(got=got, compiled=kernel_cache.counts("tinykernels")[
        "compiled"], **kernel_cache.claim_stats())))
''')


def test_a_process_killed_while_claiming_a_compile_lets_the_waiting_one_compile(
        kernel_folder, tmp_path):
    """Compile claims: a process waits for another's compile of the same signature; when
    that one dies before saving (the OS drops its lock) the waiting one compiles it."""
    (kernel_folder / "claimant.py").write_text(CLAIMANT)
    (kernel_folder / "waiter.py").write_text(WAITER)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))
    run = dict(cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    claimant = subprocess.Popen([sys.executable, str(kernel_folder / "claimant.py"),
                                 str(kernel_folder), "3"], **run)
    deadline = time.monotonic() + 240
    while not (kernel_folder / "claimed").exists():
        assert claimant.poll() is None and time.monotonic() < deadline, claimant.stderr.read()
        time.sleep(0.01)
    waiter = subprocess.Popen([sys.executable, str(kernel_folder / "waiter.py"),
                               str(kernel_folder)], **run)
    assert claimant.wait(timeout=240) == 3
    r = _result(waiter)
    assert r["got"] == 3.25 and r["compiled"] == 2  # inner, then axpy after the wait
    assert r["claimed"] == 2 and r["waited"] == 1 and r["wait_s"] > 0.3


SAVER = textwrap.dedent('''
    import sys
    from numba.core import caching
    from rstrace_engine import kernel_cache

    folder = sys.argv[1]
    f = caching.IndexDataCacheFile(cache_path=folder, filename_base="k", source_stamp=(1, 2))
    kernel_cache.protect(type("D", (), {"_cache": type("C", (), {"_cache_file": f})()})())
    assert type(f).__name__ == "_LockedCacheFile"
    f.save("sig-b", b"code for b")
    print("SAVED", f._load_index())
''')


@pytest.mark.skipif(sys.platform == "win32", reason="the test holds the lock with fcntl")
def test_a_save_waits_for_the_shared_lock_and_writes_data_before_its_index(tmp_path):
    import fcntl

    from numba.core import caching

    from rstrace_engine import kernel_cache

    mine = caching.IndexDataCacheFile(cache_path=str(tmp_path), filename_base="k",
                                      source_stamp=(1, 2))
    order = []
    mine.__class__ = type("Recording", (kernel_cache._LockedCacheFile,), {
        "_save_data": lambda self, n, d: (order.append("data"),
                                          kernel_cache._LockedCacheFile._save_data(self, n, d)),
        "_save_index": lambda self, o: (order.append("index"),
                                        kernel_cache._LockedCacheFile._save_index(self, o))})
    mine.save("sig-a", b"code for a")
    assert order == ["data", "index"]

    script = tmp_path / "saver.py"
    script.write_text(SAVER)
    with open(tmp_path / kernel_cache.LOCK_NAME, "a+b") as lock:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX)  # another process is saving
        proc = subprocess.Popen([sys.executable, str(script), str(tmp_path)], cwd=ROOT,
                                env=dict(os.environ, PYTHONPATH=str(ROOT)),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(3.0)
        assert proc.poll() is None, proc.communicate()  # blocked on the lock
        assert mine._load_index() == {"sig-a": "k.1.nbc"}
        fcntl.flock(lock.fileno(), fcntl.LOCK_UN)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    # both signatures kept, each with its own data file and the right contents
    assert mine._load_index() == {"sig-a": "k.1.nbc", "sig-b": "k.2.nbc"}
    assert mine.load("sig-a") == b"code for a" and mine.load("sig-b") == b"code for b"


def test_column_major_host_matrices_reach_the_kernels_c_ordered():
    """Blender hands matrices over column-major; numba compiles one kernel per array layout,
    so the packed scene and the camera must be C-ordered whatever the host gave (else a
    Blender scene compiles, and caches, a second copy of every kernel)."""
    import numpy as np

    from rstrace_engine import scenes
    from rstrace_engine.geometry.cameras import camera_params

    scene = scenes.three_spheres(32, 24, subdivisions=1)
    for i, inst in enumerate(scene.instances):
        scene.set_instance_matrix(i, np.asfortranarray(inst["matrix"]))
    scene.camera.matrix = np.asfortranarray(scene.camera.matrix)
    sa = scene.arrays()
    bad = [name for name, a in zip(sa._fields, sa, strict=True)
           if isinstance(a, np.ndarray) and not a.flags.c_contiguous]
    assert bad == []
    assert camera_params(scene.camera).xform.flags.c_contiguous


# --- content-keyed cache (issue 25) -----------------------------------------------------

PACKAGE = {
    "__init__.py": '__version__ = "1.0"\nfrom rstrace_engine import kernel_cache\n'
                   'kernel_cache.install(__name__)\n',
    "consts.py": "SCALE = 2.0\n",
    "kern.py": textwrap.dedent('''
        import numpy as np
        from numba import njit

        from .consts import SCALE


        @njit(cache=True, nogil=True)
        def scaled(x):
            return x * SCALE


        @njit(cache=True, nogil=True)
        def total(x):
            t = 0.0
            for v in x:
                t += scaled(v)
            return t
    '''),
}

PKG_WORKER = textwrap.dedent('''
    import json, sys
    import numpy as np

    sys.path.insert(0, sys.argv[1])
    from tinypkg import kern
    from rstrace_engine import kernel_cache

    values = [kern.scaled(1.5), kern.total(np.arange(4.0))]
    c = kernel_cache.counts("tinypkg")
    guarded = all(type(d._cache._cache_file).__name__ == "_LockedCacheFile"
                  for d in kernel_cache.dispatchers("tinypkg"))
    print("RESULT " + json.dumps(dict(values=values, compiled=c["compiled"],
                                      loaded=c["loaded"], guarded=guarded,
                                      bad=kernel_cache.bad_files())))
''')


def _package(folder: Path, **changes) -> Path:
    pkg = folder / "tinypkg"
    pkg.mkdir(parents=True, exist_ok=True)
    for name, text in {**PACKAGE, **changes}.items():
        (pkg / name).write_text(text)
    return folder


def _run_pkg(folder: Path, cache: Path, **env) -> dict:
    (folder / "worker.py").write_text(PKG_WORKER)
    full = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    full.update(NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT), **env)
    proc = subprocess.run([sys.executable, str(folder / "worker.py"), str(folder)], cwd=ROOT,
                          env=full, capture_output=True, text=True, timeout=300)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stdout[-2000:] + proc.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT "):])


def test_cache_follows_the_package_anywhere_and_the_constants_it_imports(tmp_path):
    """The key is the sources' contents, not their path or time stamps: a copy of the
    package elsewhere (an install from a zip) loads what the first compiled; a change of an
    imported module's constant (tolerances.py's case) compiles again, never loads stale code;
    the cache files sit under the package-relative path."""
    cache = tmp_path / "cache"
    first = _run_pkg(_package(tmp_path / "a"), cache)
    assert first["values"] == [3.0, 12.0] and first["compiled"] == 2 and first["guarded"]
    assert sorted(p.parent.name for p in cache.rglob("*.nbi")) == ["tinypkg", "tinypkg"]

    moved = _run_pkg(_package(tmp_path / "b"), cache)  # other path, new time stamps
    assert moved["values"] == [3.0, 12.0]
    assert (moved["compiled"], moved["loaded"]) == (0, 2) and moved["guarded"]

    changed = _run_pkg(_package(tmp_path / "b", **{"consts.py": "SCALE = 3.0\n"}), cache)
    assert changed["values"] == [4.5, 18.0] and changed["compiled"] == 2
    back = _run_pkg(_package(tmp_path / "b"), cache)  # the first contents' entries remain
    assert back["values"] == [3.0, 12.0] and back["compiled"] == 0

    version = _run_pkg(_package(tmp_path / "b", **{"__init__.py": PACKAGE["__init__.py"].replace(
        "1.0", "1.1")}), cache)
    assert version["compiled"] == 2  # another version of the package compiles its own


@pytest.mark.parametrize("damage", ["truncated_data", "garbage_index", "truncated_index",
                                    "missing_data"])
def test_corrupt_cache_files_compile_again(tmp_path, damage):
    cache = tmp_path / "cache"
    folder = _package(tmp_path / "a")
    assert _run_pkg(folder, cache)["compiled"] == 2
    index = sorted(cache.rglob("kern.scaled-*.nbi"))[0]
    data = sorted(cache.rglob("kern.scaled-*.nbc"))[0]
    if damage == "truncated_data":
        data.write_bytes(data.read_bytes()[:100])
    elif damage == "garbage_index":
        index.write_bytes(b"\x80\x04not a pickle at all")
    elif damage == "truncated_index":
        index.write_bytes(index.read_bytes()[:40])
    else:
        data.unlink()
    r = _run_pkg(folder, cache)
    assert r["values"] == [3.0, 12.0]
    # scaled compiles again (total, which inlines nothing of it, still loads) ...
    assert r["compiled"] >= 1
    assert damage == "missing_data" or r["bad"], r
    again = _run_pkg(folder, cache)  # ... and is written back whole
    assert again["compiled"] == 0 and again["bad"] == [] and again["values"] == [3.0, 12.0]


def test_unwritable_cache_still_renders(tmp_path):
    """A cache folder that cannot be created (a file in its way; root ignores chmod):
    numba's next locator is used, the kernels are correct."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    r = _run_pkg(_package(tmp_path / "a"), blocker / "cache")
    assert r["values"] == [3.0, 12.0]


def test_a_save_that_cannot_write_is_logged_not_raised(tmp_path, caplog):
    from numba.core import caching

    from rstrace_engine import kernel_cache

    blocker = tmp_path / "file"
    blocker.write_text("")
    f = caching.IndexDataCacheFile(cache_path=str(blocker), filename_base="k",
                                   source_stamp=(1, 2))
    f.__class__ = kernel_cache._LockedCacheFile
    monkey = kernel_cache._STATE["warned"]
    kernel_cache._STATE["warned"] = False
    try:
        f.save("sig", b"code")  # no exception: the kernel stays in memory
    finally:
        kernel_cache._STATE["warned"] = monkey
    assert f._load_index() == {}


def _shipped(tmp_path) -> Path:
    """A shipped cache of the tiny package, built as build_extension does it."""
    build = tmp_path / "build_cache"
    folder = _package(tmp_path / "src")
    assert _run_pkg(folder, build, NUMBA_CPU_NAME="generic")["compiled"] == 2
    return build


SEEDER = textwrap.dedent('''
    import json, sys
    sys.path.insert(0, sys.argv[1])
    import tinypkg
    from rstrace_engine import shipped_kernels
    print("RESULT " + json.dumps(shipped_kernels.seed(sys.argv[2], sys.argv[3], "tinypkg")))
''')


def _seed(folder: Path, shipped: Path, cache: Path) -> dict:
    (folder / "seeder.py").write_text(SEEDER)
    proc = subprocess.run([sys.executable, str(folder / "seeder.py"), str(folder),
                           str(shipped), str(cache)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.splitlines()[-1][len("RESULT "):])


def test_shipped_portable_cache_seeds_a_fresh_one(tmp_path):
    """The installed package (elsewhere, other time stamps) seeds its cache from the shipped
    one, read-only, and then loads every kernel for the generic CPU, compiling nothing; a
    host process compiles its own (another CPU, another entry of the same index)."""
    shipped = _shipped(tmp_path)
    for p in shipped.rglob("*"):
        p.chmod(0o444 if p.is_file() else 0o555)
    installed = _package(tmp_path / "installed")
    cache = tmp_path / "user_cache"
    counts = _seed(installed, shipped, cache)
    assert counts["kernels"] == 2 and counts["copied"] == 2 and counts["stale"] == 0
    r = _run_pkg(installed, cache, NUMBA_CPU_NAME="generic")
    assert (r["compiled"], r["loaded"]) == (0, 2) and r["values"] == [3.0, 12.0]
    assert _seed(installed, shipped, cache)["current"] == 2  # seeding again: nothing to do
    host = _run_pkg(installed, cache)
    assert host["compiled"] == 2 and host["values"] == [3.0, 12.0]
    assert _seed(installed, shipped, cache)["current"] == 2  # merged, the host's kept
    assert _run_pkg(installed, cache)["compiled"] == 0


def test_numbas_own_overloads_in_the_build_cache_are_not_shipped(tmp_path):
    """numba's overloads cached beside our kernels (numba_overloads_cached: a folder per
    numba package, stamped with numba's file) are left out of the seed, neither copied nor
    counted stale or bad (on main they counted: a folder outside the package)."""
    shipped = _shipped(tmp_path)
    theirs = shipped / "np_0123abcd"
    theirs.mkdir()
    (theirs / "arrayobj.ol_np_empty.locals.impl-4470.py311.nbi").write_bytes(b"not ours")
    counts = _seed(_package(tmp_path / "installed"), shipped, tmp_path / "cache")
    assert (counts["copied"], counts["stale"], counts["bad"]) == (2, 0, 0)
    assert not (tmp_path / "cache" / "np_0123abcd").exists()


def test_shipped_cache_of_other_sources_or_numba_is_not_used(tmp_path):
    import pickle

    shipped = _shipped(tmp_path)
    other = _package(tmp_path / "other", **{"consts.py": "SCALE = 5.0\n"})
    cache = tmp_path / "user_cache"
    assert _seed(other, shipped, cache)["stale"] == 2
    r = _run_pkg(other, cache, NUMBA_CPU_NAME="generic")
    assert r["compiled"] == 2 and r["values"] == [7.5, 30.0]  # never the shipped SCALE 2

    for index in shipped.rglob("*.nbi"):  # another numba version wrote it
        raw = index.read_bytes()
        with open(index, "rb") as f:
            pickle.load(f)
            rest = f.read()
        index.write_bytes(pickle.dumps("0.0.1") + rest)
        assert raw != index.read_bytes()
    same = _package(tmp_path / "same")
    assert _seed(same, shipped, tmp_path / "cache2")["stale"] == 2


def test_numba_internals_we_rely_on(tmp_path):
    """What kernel_cache relies on of numba (listed in its docstring): fails loudly when a
    numba upgrade changes one of them."""
    import pickle

    import numba
    from numba.core import caching, config, event
    from numba.core.registry import cpu_target

    from rstrace_engine import kernel_cache, shipped_kernels

    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    assert impl._locator_classes[0] is kernel_cache.ContentKeyedLocator
    for name in ("get_cache_path", "get_source_stamp", "get_disambiguator", "from_function",
                 "ensure_cache_path"):
        assert callable(getattr(caching._CacheLocator, name)), name
    assert hasattr(config, "CACHE_DIR") and hasattr(config, "CPU_NAME")
    assert hasattr(config, "CPU_FEATURES")
    assert callable(caching.dumps)
    f = caching.IndexDataCacheFile(cache_path=str(tmp_path), filename_base="k",
                                   source_stamp=("s", 1))
    for name in ("_load_index", "_save_index", "_load_data", "_save_data", "_data_name",
                 "save", "load"):
        assert callable(getattr(f, name)), name
    assert f._index_path == str(tmp_path / "k.nbi") and f._cache_path == str(tmp_path)
    assert f._index_name == "k.nbi"
    ok, failed = event.Event("x", event.EventStatus.END), event.Event(
        "x", event.EventStatus.END, exc_details=(ValueError, ValueError(), None))
    assert ok._exc_details is None and failed._exc_details is not None  # compile claims
    f.save("key", b"data")
    with open(f._index_path, "rb") as fh:  # the index format seed() reads and writes
        assert pickle.load(fh) == numba.__version__
        assert pickle.loads(fh.read()) == (("s", 1), {"key": "k.1.nbc"})
    kinds = getattr(event, "_builtin_kinds", None)
    assert kinds is None or {"numba:compile", "numba:compiler_lock"} <= set(kinds)
    assert "_toplevel_target_context" in type(cpu_target).__dict__  # target_initialised
    codegen = cpu_target.target_context.codegen()
    magic = codegen.magic_tuple()
    assert len(magic) == 3 and magic[1] == shipped_kernels.cpu_name()
    from rstrace_engine.accel import bvh

    d = bvh.trace_kernel
    assert isinstance(d._cache._cache_file, caching.IndexDataCacheFile)
    assert isinstance(d._cache._impl.locator, kernel_cache.ContentKeyedLocator)
    assert d._cache._cache_file._source_stamp[0] == kernel_cache.STAMP_TAG


def test_kernel_keys_cover_imported_modules():
    from rstrace_engine import kernel_cache

    sources = kernel_cache.module_sources("rstrace_engine.accel.bvh",
                                          str(ROOT / "rstrace_engine/accel/bvh.py"))
    assert "rstrace_engine.tolerances" in sources and "rstrace_engine" in sources
    assert "rstrace_engine.kernel_cache" not in sources


def test_counts_since_a_mark_leave_out_earlier_compiles(tmp_path, monkeypatch):
    """test_farm's warm-cache operator test flaked on a partly warm cache: counts() were the
    whole process's, so kernels compiled by earlier tests in that bpy process counted as the
    operator's. A warm-up now counts from its own start (kernel_cache.mark)."""
    import importlib

    import numba
    import numpy as np

    from rstrace_engine import kernel_cache

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.syspath_prepend(str(_package(tmp_path / "a")))
    try:
        kern = importlib.import_module("tinypkg.kern")
        kern.scaled(1.0)  # an earlier test compiled this
        since = kernel_cache.mark("tinypkg")
        kern.scaled(2.0)
        assert kern.total(np.arange(3.0)) == 6.0
        c = kernel_cache.counts("tinypkg", since=since)
        assert c["compiled"] == 1 and list(c["compiled_kernels"]) == ["tinypkg.kern.total"]
        assert kernel_cache.counts("tinypkg")["compiled"] == 2
    finally:
        for name in [n for n in sys.modules if n.split(".")[0] == "tinypkg"]:
            del sys.modules[name]


def test_two_processes_seeding_at_once(tmp_path):
    """Two Blender processes starting together seed the same cache: both finish, the
    index is whole, and a third process loads every kernel."""
    shipped = _shipped(tmp_path)
    installed = _package(tmp_path / "installed")
    cache = tmp_path / "user_cache"
    (installed / "seeder.py").write_text(SEEDER)
    procs = [subprocess.Popen([sys.executable, str(installed / "seeder.py"), str(installed),
                               str(shipped), str(cache)], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True,
                              env=dict(os.environ, PYTHONPATH=str(ROOT))) for _ in range(2)]
    counts = []
    for p in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err[-3000:]
        counts.append(json.loads(out.splitlines()[-1][len("RESULT "):]))
    assert sorted(c["kernels"] + c["current"] for c in counts) == [2, 2]
    r = _run_pkg(installed, cache, NUMBA_CPU_NAME="generic")
    assert (r["compiled"], r["loaded"]) == (0, 2) and r["values"] == [3.0, 12.0]


def test_a_wait_for_another_compile_is_recorded(tmp_path):
    """A claim taken while another holder has it waits, and the wait is recorded
    (``CLAIM_WAITS``: the index, when, how long; ``scripts/compile_profile.py`` reports each
    process's waits). The other holder here is a second open file of the same claim, let go
    after 0.3 s."""
    import threading

    from rstrace_engine import kernel_cache

    key = ("sig", "target")
    _, path = kernel_cache._claim_path(str(tmp_path), "mod.kernel-1.py311.nbi", key)
    other = open(path, "a+b")  # noqa: SIM115
    assert kernel_cache._try_lock(other)
    threading.Timer(0.3, other.close).start()
    before = len(kernel_cache.CLAIM_WAITS)
    t0 = time.time()
    try:
        assert kernel_cache._claim(str(tmp_path), "mod.kernel-1.py311.nbi", key)
    finally:
        kernel_cache._release(str(tmp_path), "mod.kernel-1.py311.nbi", key)
    assert len(kernel_cache.CLAIM_WAITS) == before + 1
    name, start, seconds = kernel_cache.CLAIM_WAITS[-1]
    assert name == "mod.kernel-1.py311.nbi" and seconds >= 0.2
    assert t0 - 1.0 <= start <= t0 + 1.0
