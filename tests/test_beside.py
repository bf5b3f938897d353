"""``rstrace_engine.beside``: one call run on a pool thread beside the caller, joined."""

from __future__ import annotations

import threading

import numba
import pytest

from rstrace_engine import beside
from rstrace_engine.beside import Beside


def _thread() -> int:
    return threading.get_ident()


@pytest.fixture
def two_threads():
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    if numba.get_num_threads() < 2:
        pytest.skip("one thread only here")
    yield
    numba.set_num_threads(before)


def test_the_call_runs_on_another_thread_and_its_value_comes_back(two_threads):
    began = threading.Event()

    def call():
        began.set()
        return _thread()

    job = Beside(call)
    assert job.started
    assert began.wait(5)  # (else result() would take it back: run here)
    assert job.result() != threading.get_ident()
    assert job.result() == job.result()  # (joined once; the value kept)
    assert job.started  # (still says where it went)


def test_one_thread_or_a_small_call_runs_here():
    job = Beside(_thread, when=False)
    assert not job.started
    assert job.result() == threading.get_ident()
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        job = Beside(_thread)
        assert not job.started and job.result() == threading.get_ident()
    finally:
        numba.set_num_threads(before)


def test_its_exception_is_raised_by_result_and_dropped_by_drop(two_threads):
    def fail():
        raise ValueError("inside")

    with pytest.raises(ValueError, match="inside"):
        Beside(fail).result()
    with pytest.raises(ValueError, match="inside"):
        Beside(fail, when=False).result()  # (run here: the same exception)
    Beside(fail).drop()  # (the caller is raising something else already)


def test_drop_joins_a_running_call_and_never_runs_one_not_started(two_threads):
    ran, began, release = [], threading.Event(), threading.Event()

    def slow():
        began.set()
        release.wait(5)
        ran.append("slow")

    job = Beside(slow)
    assert began.wait(5)
    queued = Beside(ran.append, "queued")  # (behind ``slow`` on the one pool thread)
    here = Beside(ran.append, "here", when=False)
    queued.drop()
    here.drop()
    threading.Timer(0.05, release.set).start()
    job.drop()  # (waits for ``slow`` to end)
    assert ran == ["slow"]


def test_a_call_queued_behind_a_busy_pool_thread_is_taken_back_and_run_here(two_threads):
    """Nested or concurrent calls never wait on the queue: the one pool thread is busy with
    the outer call, so the inner one runs on the outer call's own thread."""
    began, release = threading.Event(), threading.Event()

    def outer():
        began.set()
        inner = Beside(_thread)
        got = inner.result()
        release.wait(5)
        return got, threading.get_ident()

    job = Beside(outer)
    assert began.wait(5)
    blocked = Beside(_thread)  # (queued behind ``outer``, taken back by this thread)
    assert blocked.result() == threading.get_ident()
    release.set()
    inner, outer_thread = job.result()
    assert inner == outer_thread != threading.get_ident()


def test_the_pool_is_one_thread_made_once(two_threads):
    Beside(_thread).result()
    pool = beside._POOL["pool"]
    assert pool is not None
    Beside(_thread).result()
    assert beside._POOL["pool"] is pool and pool._max_workers == 1


def test_the_kernels_run_beside_launch_no_parallel_region():
    """What the sync runs on the pool thread (the content hash's NH blocks, the scene
    model's vertex pass and area test) must be serial ``nogil`` kernels: a ``parallel=True``
    one there could launch a parallel region while another thread launches one, which
    numba's ``workqueue`` layer does not survive (``addon/runtime.py``); ``nogil``, else
    the two threads take turns. A guard for a later edit of these kernels."""
    from rstrace_engine.accel import content_hash
    from rstrace_engine.geometry import mesh_check, mesh_math

    for kernel in (content_hash._nh_blocks, mesh_math._proper_kernel,
                   mesh_check._vertex_stats):
        opts = kernel.targetoptions
        assert opts.get("nogil") and not opts.get("parallel"), kernel.py_func.__name__
