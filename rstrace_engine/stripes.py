"""Parallel loops as Python threads over serial ``nogil`` kernels, instead of ``prange``.

Why: numba's ``parallel=True`` is most of the cold compile of the kernels that take a
NamedTuple of arrays (the scene's ``SceneArrays`` views, the interpolants' ``QueryScene``):
its parfor passes turn every field into a parameter of the loop's own function and work on
each. The same kernel compiled serially costs a fraction of it, measured (one signature,
CPU seconds, callees loaded from the cache, the shared 2-core machine at load 7-8):
``check_cells`` 22.1 -> 4.0, ``_shade_kernel`` 38.9 -> 5.4, ``_surface_kernel`` 14.9 -> 4.6,
``_query_tiles`` 8.0 -> 3.0 (docs/first-render.md). Not the BVH traversal (28.1 -> 11.8 s):
serial, it cast rays 30-40 % slower (``bench raycast``), so it stays a ``prange`` kernel.

How: a striped kernel takes two more arguments, ``first, step``, and handles the work items
of blocks ``first, first + step, ...`` (:data:`BLOCK` items a block, or its own unit: a cell, a
screen tile); :func:`run` calls it once per thread, ``step`` threads
(``numba.get_num_threads()`` of the calling thread, as ``prange`` would use, at most one
per block), the calling thread taking stripe 0 and a shared pool the others. Blocks dealt in
turn balance a frame whose cost varies across the image about as well as numba's static
schedule, and a block keeps each thread's writes on its own cache lines. Each item is
computed exactly as before (items are independent), so images are bit for bit the same.
A striped kernel takes ``error_model="numpy"``, what numba compiles a ``prange`` body with
(``parfor_lowering``): a division by zero gives inf or nan as before, not an exception, and
the default model's checks slowed the stages' frames by up to 30 %.
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
