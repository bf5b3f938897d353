"""Views of a struct of arrays for parallel kernels (rstrace_engine.views), and kernels that
compile one signature where they used to compile two (issue 25: the cold compile)."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit, prange
from numba.core.errors import TypingError

from rstrace_engine.views import fields, view_type

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class _Struct(NamedTuple):
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    scale: float


_AB = view_type("_AB", _Struct, ("b", "scale", "a"), __name__)
_A = view_type("_A", _Struct, ("a",), __name__)


@njit(inline="always")
def _combine(s, i):
    return s.a[i] * s.scale + s.b[i]


@njit(parallel=True)
def _from_struct(s, out):
    for i in prange(out.shape[0]):
        out[i] = _combine(s, i)


@njit(parallel=True)
def _from_view(s, out):
    s = _AB(*fields(s, _AB))
    for i in prange(out.shape[0]):
        out[i] = _combine(s, i)


@njit
def _view_fields(s):
    return fields(s, _AB)


@njit(parallel=True)
def _from_short_view(s, out):
    s = _A(*fields(s, _A))
    for i in prange(out.shape[0]):
        out[i] = _combine(s, i)


def _struct(n=1000):
    rng = np.random.default_rng(3)
    return _Struct(rng.random(n), rng.random(n), rng.random(n), 0.7)


def test_a_view_holds_the_struct_fields_in_its_order_shared():
    assert _AB._fields == ("a", "b", "scale")
    assert _AB.__module__ == __name__
    s = _struct()
    want = np.empty(len(s.a))
    _from_struct(s, want)
    got = np.empty(len(s.a))
    _from_view(s, got)
    assert np.array_equal(got, want)  # bit for bit
    assert np.array_equal(got, s.a * 0.7 + s.b)
    a, b, scale = _view_fields(s)  # the struct's own arrays, not copies
    assert a.ctypes.data == s.a.ctypes.data and b.ctypes.data == s.b.ctypes.data
    assert scale == s.scale


def test_a_view_holds_its_own_references():
    """The view's arrays are new references (taken in ``fields``, let go with the view):
    a thousand calls leave every reference count and numba's allocation balance as they
    were (without the reference the view's end freed the struct's arrays: a crash)."""
    from numba.core.runtime import _nrt_python, rtsys

    s = _struct(100)
    out = np.empty(100)
    _from_view(s, out)
    refs = [sys.getrefcount(x) for x in s[:3]]
    was = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        before = rtsys.get_allocation_stats()
        for _ in range(1000):
            _from_view(s, out)
            _view_fields(s)
        after = rtsys.get_allocation_stats()
    finally:
        if not was:
            _nrt_python.memsys_disable_stats()
    assert [sys.getrefcount(x) for x in s[:3]] == refs
    assert after.mi_alloc - before.mi_alloc == after.mi_free - before.mi_free


def test_a_view_of_fields_the_struct_lacks_is_refused():
    with pytest.raises(ValueError, match="_Struct has no field d"):
        view_type("_Bad", _Struct, ("a", "d"))


def test_a_loop_reading_a_field_its_view_lacks_does_not_compile():
    with pytest.raises(TypingError, match="b"):
        _from_short_view(_struct(10), np.empty(10))


def test_the_scene_views_name_fields_of_the_scene():
    """Every view of SceneArrays that a kernel module makes is bound to its own name (the
    parfor lowering looks the class up by it)."""
    import importlib

    from rstrace_engine.geometry.scene import SceneArrays

    found = 0
    for name in ("tracing.shader", "tracing.light_reshade", "tracing.soft_lights",
                 "tracing.seen_lights", "tracing.shaft_skip", "tracing.sample_rays",
                 "ri_tree.sampling", "ri_tree.tree_cache", "ri_tree.surfaces"):
        module = importlib.import_module(f"rstrace_engine.{name}")
        for attr, value in vars(module).items():
            if isinstance(value, type) and issubclass(value, tuple) and attr.endswith(
                    "Scene") and value is not SceneArrays and hasattr(value, "_fields"):
                assert value.__name__ == attr and value.__module__ == module.__name__
                assert set(value._fields) < set(SceneArrays._fields)
                found += 1
    assert found >= 13


_ONE_SIGNATURE = textwrap.dedent('''
    from numba.core.caching import NullCache
    from numba.core.dispatcher import Dispatcher

    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.geometry import shaft_geometry
    from rstrace_engine.interpolants import occluders, predicate, shafts
    from rstrace_engine.session import Session
    from rstrace_engine.tracing import glossy_rays, whitted
    from rstrace_engine.warm_kernels import _warm_edited_interpolants, warm_scene

    kernels = (predicate._check_cells, predicate._light_shafts, occluders.occluder_covers,
               occluders.cone_umbra, shafts.other_geometry, shafts.shaft_instances,
               shafts.mesh_candidates, shafts.boundary_edge_in, shaft_geometry.to_object,
               glossy_rays._glossy_rays)
    # these and their callers compile here (a kernel loaded from the disk cache has its
    # callees linked in: it leaves them untyped in this process)
    for module in (predicate, occluders, shafts, shaft_geometry):
        for k in vars(module).values():
            if isinstance(k, Dispatcher):
                k._cache = NullCache()
    for k in (glossy_rays._glossy_rays, whitted._shade_kernel):
        k._cache = NullCache()
    _warm_edited_interpolants()
    Session(warm_scene(16, 12), RenderSettings(max_depth=2)).render()
    print({k.py_func.__name__: [str(s) for s in k.signatures] for k in kernels})
''')


def test_kernels_called_with_constants_or_loop_indices_compile_once():
    """A constant argument (``6``, ``True``) gives a callee a literal type, and a parallel
    loop's index is unsigned in the loop's own function but signed where numba types the
    kernel first: each compiled the callee once more (the error predicate's kernels twice
    or three times: ~25 s of the demo's cold compile). Every call site passes the same
    types now: one signature each after interpolants pass the predicate and an edit
    queries them, and a glossy frame (in a fresh process, the callers compiled)."""
    proc = subprocess.run([sys.executable, "-c", _ONE_SIGNATURE], capture_output=True,
                          text=True, timeout=900, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=ROOT))
    assert proc.returncode == 0, proc.stderr[-3000:]
    signatures = ast.literal_eval(proc.stdout.strip().splitlines()[-1])
    for name, sigs in signatures.items():
        assert len(sigs) == 1, (name, sigs)
