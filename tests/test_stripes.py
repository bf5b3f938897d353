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
    from rstrace_engine.tracing import light_reshade, record_queries, shader

    for k in (bvh.trace_kernel, shader._surface_kernel, shader._shade_kernel,
              predicate._check_cells, record_queries._query_tiles,
              light_reshade._one_light_states):
        assert not k.targetoptions.get("parallel"), k.py_func.__name__
        assert k.targetoptions.get("nogil"), k.py_func.__name__
        # (the predicate's cells call _check_one, which allocates: one call per cell)
        assert k.targetoptions.get("_nrt") is False or k is predicate._check_cells, k
        # what numba compiles a prange body with: inf / nan on a division by zero, no check
        assert k.targetoptions.get("error_model") == "numpy", k.py_func.__name__



def tile_query_case(rng, width: int, height: int, spp: int, dirty_every_tile: bool):
    """Synthetic per-pixel records for the tile query (misses, a dirty combination, a hard
    light and a sun, a moved object's box and a region): ``(n_rays, head, tail)``, the
    arguments before and after ``width, height, n_pixels`` (scripts/stripe_kernels_ab.py
    times the kernel on them)."""
    from rstrace_engine.geometry.elements import LIGHT_POINT, LIGHT_SUN
    from rstrace_engine.tracing import record_queries as rq
    from rstrace_engine.tracing.pixel_records import PixelRecords

    r = PixelRecords(width, height, spp, np.array([[0.0, 0, 0], [1.0, 1, 1]]))
    n = width * height * spp
    combo_inst = np.array([-1, 0, 1, 2, 3, 0], np.int64)
    combo_traced = np.array([[0], [1], [2], [3], [3], [0]], np.uint64)
    combo_dirty = np.array([False, False, False, False, False, True])
    p_combo = rng.choice(6, n, p=[0.05, 0.3, 0.25, 0.2, 0.19, 0.01]).astype(np.uint32)
    if dirty_every_tile:
        p_combo.reshape(spp, height, width)[:, ::rq.TILE, ::rq.TILE] = 5
    p_code = rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
    cam = np.array([0.5, 0.5, -2.0])
    seg_lo, seg_hi = np.array([[0.2, 0.2, 0.5]]), np.array([[0.3, 0.3, 0.6]])
    seg_c, seg_r = 0.5 * (seg_lo + seg_hi), np.array([0.5 * np.linalg.norm(0.1 * np.ones(3))])
    reg_lo, reg_hi = np.array([[0.6, 0.55, 0.6]]), np.array([[0.7, 0.65, 0.7]])
    kind = np.array([LIGHT_POINT, LIGHT_SUN], np.int32)
    lgeo = np.array([[0.5, 2.0, 0.5, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]])
    ldir = np.array([[0.0, 0.0, 0.0], [0.3, -1.0, 0.2]])
    head = (p_combo, p_code, combo_dirty, combo_inst, combo_traced, cam)
    tail = (r.lo, r.step, r.levels, r.shift, reg_lo, reg_hi, seg_lo, seg_hi, seg_c, seg_r,
            kind, lgeo, ldir)
    return n, head, tail


def test_tile_query_stripes_equal_the_ray_by_ray_query():
    """The records' tile query (``record_queries._query_tiles``, striped): every stripe
    count and thread count marks exactly the rays the unculled ray-by-ray query marks
    (``_query_primary``), on an image whose tiles span several blocks (misses, a dirty
    combination, a hard light and a sun, a moved object's box and a region)."""
    from rstrace_engine.tracing import record_queries as rq

    width, height, spp = 150, 90, 2
    n, args, tail = tile_query_case(np.random.default_rng(7), width, height, spp, True)
    want = np.zeros(n, np.bool_)
    rq._query_primary(*args, np.zeros((0, 3)), *tail, want)
    assert 0 < np.count_nonzero(want) < n // 2  # both kinds of ray, most culled
    n_tiles = 19 * 12 * spp
    assert stripes.blocks_of(n_tiles) > 3
    for n_stripes in (1, 2, 3, 5):
        out = np.zeros(n, np.bool_)
        for first in range(n_stripes):
            rq._query_tiles(*args, width, height, width * height, *tail, out,
                            np.empty((n_stripes, 4, 3)),
                            np.empty((n_stripes, 1), np.uint64), first, n_stripes)
        assert np.array_equal(out, want), n_stripes
    old = numba.get_num_threads()
    try:
        for threads in {1, min(2, numba.config.NUMBA_NUM_THREADS)}:
            numba.set_num_threads(threads)
            out = np.zeros(n, np.bool_)
            rq.query_tiles(*args, width, height, width * height, *tail, out)
            assert np.array_equal(out, want), threads
    finally:
        numba.set_num_threads(old)


def light_state_points(sa, n: int, rng):
    """``n`` random points in ``sa``'s box with random unit normals, materials and
    instances: ``(P, NG, MAT, INST)`` for a light's states (scripts/stripe_kernels_ab.py
    too)."""
    lo, hi = sa.scene_aabb
    P = lo + rng.random((n, 3)) * (hi - lo)
    NG = rng.normal(size=(n, 3))
    NG /= np.linalg.norm(NG, axis=1)[:, None]
    MAT = rng.integers(0, len(sa.mat_model), n).astype(np.int32)
    INST = rng.integers(0, len(sa.inst_mesh), n).astype(np.int32)
    return P, NG, MAT, INST


def test_light_states_shares_cover_every_point_once():
    """``light_reshade._one_light_states`` over 1, 2, 3 and 7 shares of the points (each
    share ``first`` of ``step`` in turn) writes every point, and the same states and
    materials as one share."""
    from rstrace_engine import scenes
    from rstrace_engine.tracing import light_reshade

    sa = scenes.three_spheres(32, 24).arrays()
    n = 1001
    P, NG, MAT, INST = light_state_points(sa, n, np.random.default_rng(3))
    results = []
    for step in (1, 2, 3, 7):
        state, mat = np.full(n, 99, np.int8), np.full(n, -99, np.int32)
        for first in range(step):
            light_reshade._one_light_states(sa, 0, P, NG, NG, P + 1e-6 * NG, MAT, INST,
                                            state, mat, first, step)
        assert not (state == 99).any() and not (mat == -99).any(), step
        results.append((state, mat))
    assert len(np.unique(results[0][0])) > 1  # faced and not faced points both
    for state, mat in results[1:]:
        assert np.array_equal(state, results[0][0]) and np.array_equal(mat, results[0][1])
