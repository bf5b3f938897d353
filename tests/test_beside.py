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


def test_shared_ranges_are_taken_once_by_both_threads_in_range_order(two_threads):
    """``Shared``: the pool thread starts taking ranges at once, the caller takes the rest
    in ``result()``; every range runs once, the values come back in range order."""
    took: list = []
    pool_began, caller_took = threading.Event(), threading.Event()
    here = threading.get_ident()

    def run(start, stop):
        took.append((start, threading.get_ident()))
        if threading.get_ident() != here:
            pool_began.set()
            caller_took.wait(5)  # (the pool thread's first range lasts until the caller's)
        else:
            caller_took.set()
        return list(range(start, stop))

    job = beside.Shared(run, 103, 10)
    assert job.started
    assert pool_began.wait(5)
    values = job.result()
    assert [x for v in values for x in v] == list(range(103))
    assert sorted(s for s, _ in took) == list(range(0, 103, 10))
    assert len({t for _, t in took}) == 2


def test_shared_does_not_wait_on_a_busy_pool_thread_and_runs_here_on_one_thread(
        two_threads):
    """The pool thread busy with another call: the caller takes every range (the queued
    take is taken back, nothing waits); ``when=False`` or one thread: every range here, in
    order."""
    began, release = threading.Event(), threading.Event()
    busy = Beside(lambda: (began.set(), release.wait(5)))
    assert began.wait(5)
    here = threading.get_ident()
    took: list = []
    values = beside.Shared(lambda a, b: took.append(threading.get_ident()) or a, 50,
                           7).result()
    assert values == list(range(0, 50, 7)) and set(took) == {here}
    release.set()
    assert busy.result() == (None, True)  # (not timed out: the caller never waited on it)
    assert beside.Shared(lambda a, b: threading.get_ident(), 9, 2, when=False).result() \
        == [here] * 5
    numba.set_num_threads(1)
    job = beside.Shared(lambda a, b: (a, threading.get_ident()), 9, 4)
    assert not job.started and job.result() == [(0, here), (4, here), (8, here)]
    assert beside.Shared(lambda a, b: a, 0, 4).result() == []


def test_shared_raises_a_ranges_exception_and_stops_taking_ranges(two_threads):
    took: list = []

    def run(start, stop):
        took.append(start)
        if start == 20:
            raise ValueError("range 20")

    with pytest.raises(ValueError, match="range 20"):
        beside.Shared(run, 1000, 10, when=False).result()
    assert took == [0, 10, 20]  # (none after it)
    took.clear()
    with pytest.raises(ValueError, match="range 20"):
        beside.Shared(run, 1000, 10).result()
    assert len(took) < 100  # (both stopped soon after the failing range)
    job = beside.Shared(lambda a, b: took.append(a), 1000, 10)
    job.drop()  # (a raising caller: no range is started after it)
    n = len(took)
    assert job.result() is not None and len(took) == n


class _Interrupting:
    """A range counter whose caller-side ``next`` raises ``KeyboardInterrupt`` once the
    caller has taken ``after`` ranges: an interrupt that lands between two ranges."""

    def __init__(self, counter, here: int, after: int) -> None:
        self._counter, self._here, self._left = counter, here, after

    def __iter__(self):
        return self

    def __next__(self):
        if threading.get_ident() == self._here:
            if self._left == 0:
                raise KeyboardInterrupt
            self._left -= 1
        return next(self._counter)


def test_an_interrupt_between_the_callers_ranges_stops_the_pool_thread_too(two_threads):
    """An exception raised on the caller outside a range's call (a KeyboardInterrupt
    between two ranges) stops the pool thread taking ranges as a range's exception does:
    ``result()`` waits for the range it is in, not for the rest of the pass."""
    import time

    took: list = []
    pool_began = threading.Event()
    here = threading.get_ident()

    def run(start, stop):
        took.append(start)
        if threading.get_ident() != here:
            pool_began.set()
            time.sleep(0.002)

    job = beside.Shared(run, 1000, 1)
    job._next = _Interrupting(job._next, here, after=2)
    assert pool_began.wait(5)
    with pytest.raises(KeyboardInterrupt):
        job.result()
    n = len(took)
    assert n < 100  # (without the stop: all 1000 ranges but the caller's lost one, ~2 s)
    time.sleep(0.05)
    assert len(took) == n  # (joined: nothing runs after result() raised)
