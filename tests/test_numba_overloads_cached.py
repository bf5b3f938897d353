"""numba's own overload implementations cached on disk (rstrace_engine/numba_overloads_cached):
a second process loads them instead of compiling them, the kernel's code is the same as with
numba's in-memory ones, and an implementation compiled under other inherited flags is not
loaded in their place."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import rstrace_engine  # noqa: F401  (installs it)
from rstrace_engine import numba_overloads_cached

ROOT = Path(__file__).resolve().parents[1]

# a kernel (not cached itself: compiled in every process) calling numba's overloads
SCRIPT = '''
import json, re, sys
import numpy as np
from numba import njit
from numba.core import event
import rstrace_engine
from rstrace_engine import kernel_cache
kernel_cache.install(prefix='__main__')  # this script's kernels are ours
from rstrace_engine import numba_overloads_cached

compiled = []


class Listener(event.Listener):
    def on_start(self, ev):
        f = ev.data["dispatcher"].py_func
        compiled.append(f.__module__ + "." + f.__qualname__)

    def on_end(self, ev):
        pass


event.register("numba:compile", Listener())


@njit(error_model=sys.argv[1])
def kernel(n):
    a = np.empty(n, np.float64)
    for i in range(n):
        a[i] = (i * 7919) % 13 + 0.5 / (i + 1)
    b = np.zeros((n, 3), np.int32)
    order = np.argsort(a)
    c = a.copy()
    return c[order[0]] + a.sum() + b.sum()


value = kernel(17)
print(json.dumps({"installed": numba_overloads_cached.installed(), "value": value,
                  "numba": sorted(c for c in compiled if c.startswith("numba.")),
                  "llvm": kernel.inspect_llvm(kernel.signatures[0])}))
'''


def _run(cache_dir, error_model="python", on="1") -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), RSTRACE_NUMBA_OVERLOAD_CACHE=on,
               PYTHONHASHSEED="0", PYTHONPATH=os.pathsep.join([str(ROOT)] + sys.path))
    out = subprocess.run([sys.executable, "-c", SCRIPT, error_model], env=env,
                         capture_output=True, text=True, check=True, timeout=600).stdout
    result = json.loads(out.strip().splitlines()[-1])
    assert result["installed"] == (on == "1")
    # (names that hold a memory address differ between any two processes, and so do the
    # numbers numba gives each function it compiles, in the order it meets them: ``B3v14``)
    result["llvm"] = re.sub(r"B\d+v\d+", "Bv", re.sub(r"0x[0-9a-f]+", "", result["llvm"]))
    return result


def test_installed_on_this_numba():
    assert numba_overloads_cached.installed()


def test_a_second_process_loads_numbas_overloads_and_links_the_same_code(tmp_path):
    fresh = _run(tmp_path / "off", on="0")  # numba as it is: compiled in memory
    first = _run(tmp_path / "on")
    second = _run(tmp_path / "on")
    assert fresh["numba"] and first["numba"], "the kernel compiles numba's overloads"
    assert second["numba"] == [], second["numba"]  # all loaded from the disk cache
    assert fresh["value"] == first["value"] == second["value"]
    assert second["llvm"] == first["llvm"] == fresh["llvm"]


def test_an_overload_compiled_under_other_inherited_flags_is_not_loaded(tmp_path):
    """numba's disk cache keys a function on its types and code, not on the flags it
    inherits from its caller: the same ``np.empty`` compiled in an ``error_model="numpy"``
    kernel must not be loaded into a ``"python"`` one."""
    numpy_model = _run(tmp_path, error_model="numpy")
    python_model = _run(tmp_path, error_model="python")
    again = _run(tmp_path, error_model="numpy")
    assert numpy_model["numba"]
    assert python_model["numba"], "loaded what was compiled under error_model='numpy'"
    assert again["numba"] == []


def test_the_inherited_flags_are_in_the_key():
    assert numba_overloads_cached.inherited_flags() is None  # outside any compile
    assert set(numba_overloads_cached.INHERITED) >= {"nrt", "error_model", "fastmath"}


# numba's list.sort / sorted with a jitted key: the key's dispatcher is in the overloads'
# signatures, and it pickles under a uuid drawn in each process
KEYED = '''
import numpy as np
from numba import njit
import rstrace_engine
from rstrace_engine import kernel_cache
kernel_cache.install(prefix='__main__')  # this script's kernels are ours


@njit
def key(x):
    return -x


@njit
def kernel(n):
    values = [float(i) for i in range(n)]
    values.sort(key=key)
    return sorted(values, key=key)[0]


print(kernel(5))
'''


def test_an_overload_keyed_on_a_per_process_uuid_does_not_grow_the_cache(tmp_path):
    """An implementation whose key holds a jitted function (a uuid drawn per process) is
    compiled in memory: on s35-int every process added three index entries and data files
    that no later process can load (15, 18, 21 ... files: the cache grew without end)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), RSTRACE_NUMBA_OVERLOAD_CACHE="1",
               PYTHONPATH=os.pathsep.join([str(ROOT)] + sys.path))
    counts = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", KEYED], env=env, capture_output=True,
                             text=True, check=True, timeout=600).stdout
        assert out.split()[-1] == "4.0"
        counts.append(len(list(tmp_path.rglob("*.nbc"))))
    assert counts[0] > 0  # the key-less implementations are still cached
    assert counts[1] == counts[0]


def test_a_per_process_object_in_a_key_is_found():
    from numba import njit

    @njit
    def f(x):
        return x

    assert numba_overloads_cached._per_process((1, (f,)))
    assert not numba_overloads_cached._per_process((1.0, ("float64", None)))


# ``bool(array)``'s implementation reads numba's ``numpy_version`` in its body: an empty
# array is False before numpy 2.2 and raises from 2.2 on
NUMPY = '''
import sys
import numpy as np
if sys.argv[1] == "other":  # this process plays another numpy (2.2), same numba
    import numba.np.arrayobj as arrayobj
    arrayobj.numpy_version = (2, 2)
    np.__version__ = "2.2.0"
import rstrace_engine
from rstrace_engine import kernel_cache
kernel_cache.install(prefix='__main__')  # this script's kernels are ours
from numba import njit


@njit
def truth(a):
    return bool(a)


try:
    print(truth(np.empty(0)))
except ValueError:
    print("raises")
'''


def test_an_overload_compiled_under_another_numpy_is_not_loaded(tmp_path):
    """On s35-int the index key had numba's version but not numpy's: the implementation
    compiled under numpy 2.2 (raises) was loaded under this numpy."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), RSTRACE_NUMBA_OVERLOAD_CACHE="1",
               PYTHONPATH=os.pathsep.join([str(ROOT)] + sys.path))

    def run(which):
        return subprocess.run([sys.executable, "-c", NUMPY, which], env=env,
                              capture_output=True, text=True, check=True,
                              timeout=600).stdout.split()[-1]

    here = run("this")  # what this numpy compiles, before any other numpy's cache
    for other in tmp_path.rglob("*.nb[ic]"):
        other.unlink()
    assert run("other") == "raises"
    assert run("this") == here


# another add-on's numba code in Blender's process: not ours (no prefix opted in)
OTHERS = '''
import numpy as np
from numba import njit
import rstrace_engine


@njit
def kernel(n):
    a = np.empty(n, np.float64)
    a[:] = 2.0
    return np.argsort(a)[0] + a.copy().sum()


print(kernel(9))
'''


def test_numbas_implementations_are_cached_only_for_our_kernels(tmp_path):
    """A kernel outside rstrace (another add-on's, in Blender's process) keeps numba's
    behaviour: its np.empty & co are compiled in memory, nothing is written to the cache
    (the cache dir is the process's: the add-on sets it for every add-on)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), RSTRACE_NUMBA_OVERLOAD_CACHE="1",
               PYTHONPATH=os.pathsep.join([str(ROOT)] + sys.path))
    out = subprocess.run([sys.executable, "-c", OTHERS], env=env, capture_output=True,
                         text=True, check=True, timeout=600).stdout
    assert out.split()[-1] == "18.0"
    assert not list(tmp_path.rglob("*.nb[ic]"))
