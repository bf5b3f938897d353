"""Striped kernels (rstrace_engine/stripes.py): every item once, the same result on any
number of threads, errors raised, and the costliest kernels to compile are not ``prange``."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numba import njit

from rstrace_engine import stripes


@njit(nogil=True)
def _mark(out, first, step):
    n = out.shape[0]
    for q in range(stripes.stripe_len(n, first, step)):
        i = stripes.stripe_item(q, first, step)
        if i >= n:
            break
        out[i] += 1 + first


@pytest.mark.parametrize("n", [0, 1, 63, 64, 65, 200, 1000])
@pytest.mark.parametrize("step", [1, 2, 3, 5])
def test_stripes_cover_every_item_once(n, step):
    out = np.zeros(n, np.int64)
    for first in range(step):
        _mark(out, first, step)
    assert np.all(out >= 1)
    # item i belongs to the stripe of its block: block (i // BLOCK) % step
    owner = (np.arange(n) // stripes.BLOCK) % step
    assert np.array_equal(out, 1 + owner)


def test_run_uses_the_numba_thread_count():
    seen = []

    def kernel(x, first, step):
        seen.append((first, step))

    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        stripes.run(kernel, 10, None)
        assert seen == [(0, 1)]
        if numba.config.NUMBA_NUM_THREADS >= 2:
            seen.clear()
            numba.set_num_threads(2)
            stripes.run(kernel, 10, None)
            assert sorted(seen) == [(0, 2), (1, 2)]
            seen.clear()
            stripes.run(kernel, 1, None)  # one block: one thread
            assert seen == [(0, 1)]
    finally:
        numba.set_num_threads(old)


def test_run_raises_a_stripe_error():
    def kernel(first, step):
        if first == step - 1:
            raise ValueError(f"stripe {first}")

    old = numba.get_num_threads()
    try:
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        with pytest.raises(ValueError, match="stripe"):
            stripes.run(kernel, 10)
    finally:
        numba.set_num_threads(old)


def test_costliest_kernels_compile_serially_without_reference_counting():
    """The kernels whose ``parallel=True`` compile was most of a cold start (the NamedTuple
    fields each a parameter of the parfor) are serial and striped, and count no references
    (``_nrt=False``: with numba's reference counting a serial loop was 30-60 % slower than
    the parfor, docs/KERNELS.md)."""
    from rstrace_engine.accel import bvh
    from rstrace_engine.interpolants import predicate
    from rstrace_engine.tracing import shader

    for k in (bvh.trace_kernel, shader._surface_kernel, shader._shade_kernel,
              predicate._check_cells):
        assert not k.targetoptions.get("parallel"), k.py_func.__name__
        assert k.targetoptions.get("nogil"), k.py_func.__name__
        # (the predicate's cells call _check_one, which allocates: one call per cell)
        assert k.targetoptions.get("_nrt") is False or k is predicate._check_cells, k
        # what numba compiles a prange body with: inf / nan on a division by zero, no check
        assert k.targetoptions.get("error_model") == "numpy", k.py_func.__name__

