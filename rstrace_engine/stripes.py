"""Parallel loops as Python threads over serial ``nogil`` kernels, instead of ``prange``.

Why: numba's ``parallel=True`` is most of the cold compile of the kernels that take a
NamedTuple of arrays (the scene's ``SceneArrays`` views, the BVH's ``SceneBVH``): its parfor
passes turn every field into a parameter of the loop's own function and work on each. The
same kernel compiled serially costs a third of it or less (the BVH traversal ``trace_kernel``
28 -> 10 s of CPU; docs/KERNELS.md, *Serial kernels without reference counting*).

A serial kernel was slower than the parfor (30-60 % for the traversal) until the cause was
found (session 30): numba's reference counting. Every array a kernel passes to an inlined
helper, or takes out of a NamedTuple, gets an atomic increment and decrement of its
reference count around the use; in a loop over rays that is dozens of atomic operations per
ray, which numba's pruning of pairs does not remove across loops. The parfor's hoisting
moves most of them out of its loop. A kernel compiled with ``_nrt=False`` has no reference
counting at all (it must not allocate: its scratch arrays are passed in) and casts rays as
fast as the parfor did, a few % faster on one thread.

How: a striped kernel takes two more arguments, ``first, step``, and handles the work items
``first, first + step, ...`` (or of blocks of :data:`BLOCK` items: :func:`stripe_item`);
:func:`run` calls it once per thread, ``step`` threads (``numba.get_num_threads()`` of the
calling thread, as ``prange`` would use, at most one per work item), the calling thread
taking stripe 0 and a shared pool the others. Items dealt in turn balance a frame whose
cost varies across the image. Each item is computed exactly as before (items are
independent), so images are bit for bit the same. A striped kernel takes
``error_model="numpy"``, what numba compiles a ``prange`` body with (``parfor_lowering``): a
division by zero gives inf or nan as before, not an exception.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numba
from numba import njit

#: Work items per block of a striped kernel (its threads take blocks in turn).
BLOCK = 64

_POOL: dict = {"pool": None, "size": 0}
_POOL_LOCK = threading.Lock()


@njit(cache=True, nogil=True, inline="always")
def stripe_len(n, first, step):
    """An upper bound of the items of stripe ``first`` of ``step`` over ``n`` items: loop
    ``q`` over it, take item :func:`stripe_item` and stop at the first one ``>= n``."""
    blocks = (n + BLOCK - 1) // BLOCK
    return max(0, (blocks - first + step - 1) // step) * BLOCK


@njit(cache=True, nogil=True, inline="always")
def stripe_item(q, first, step):
    """The ``q``-th item of stripe ``first`` of ``step`` (blocks of :data:`BLOCK`)."""
    return ((q // BLOCK) * step + first) * BLOCK + q % BLOCK


def threads_for(blocks: int) -> int:
    """Threads :func:`run` uses for ``blocks`` blocks of work."""
    return max(1, min(numba.get_num_threads(), blocks))


def _pool(workers: int) -> ThreadPoolExecutor:
    with _POOL_LOCK:
        if _POOL["pool"] is None or _POOL["size"] < workers:
            old = _POOL["pool"]
            _POOL["pool"] = ThreadPoolExecutor(max_workers=workers,
                                               thread_name_prefix="rstrace-stripe")
            _POOL["size"] = workers
            if old is not None:
                old.shutdown(wait=False)
        return _POOL["pool"]


def run(kernel, blocks: int, *args) -> None:
    """``kernel(*args, first, step)`` for ``first`` in ``0 .. step - 1`` on ``step`` threads
    (:func:`threads_for` ``blocks``): stripe 0 in this thread, the others in the pool; returns
    when all are done (an exception in any is raised here, after all ended)."""
    step = threads_for(blocks)
    if step == 1:
        kernel(*args, 0, 1)
        return
    pool = _pool(step - 1)
    futures = [pool.submit(kernel, *args, k, step) for k in range(1, step)]
    try:
        kernel(*args, 0, step)
    finally:
        errors = []
        for f in futures:
            exc = f.exception()
            if exc is not None:
                errors.append(exc)
    if errors:
        raise errors[0]


def blocks_of(n: int) -> int:
    """Blocks of :data:`BLOCK` items in ``n`` items."""
    return (int(n) + BLOCK - 1) // BLOCK
