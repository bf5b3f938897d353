"""One call run beside the calling thread: a serial ``nogil`` kernel, a numpy copy or a
hash started on a pool thread while the caller does other work, then joined.

Why: the first render's work outside the parallel BVH builds is serial (the export's mesh
read and fingerprint, the scene model's checks, the packing's copies, the mesh keys, the
BVH's concatenation): one core works, the other waits. Where two pieces of it are
independent, :class:`Beside` runs one on a second thread while the caller runs the other
(``docs/bench-scale-bpy.md``, session 38).

Safety: only calls that launch no parallel region (numba ``nogil`` kernels compiled
without ``parallel=True``, numpy copies, ``hashlib``) are run beside: two threads then never
launch parallel kernels at once, which numba's ``workqueue`` threading layer does not
survive (``addon/runtime.py``). The call must not touch what the caller changes meanwhile.

How: one pool thread (made on first use, kept, as :mod:`.stripes`' pool is). ``result()``
joins: where the pool thread has not started the call yet (it is busy with another one:
a nested or a concurrent :class:`Beside`), the caller takes the call back and runs it
itself, so nothing ever waits on a queue. Where the calling thread may use one thread
only (``numba.get_num_threads()`` 1: the render's thread setting), or the caller says the
work is too small to pay for the hand-off (``when=False``; a hand-off costs tens of
microseconds), the call runs in ``result()`` on the calling thread. The values are the
same whichever thread computes them.
"""

from __future__ import annotations

import itertools
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

_POOL: dict = {"pool": None}
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    with _POOL_LOCK:
        if _POOL["pool"] is None:
            _POOL["pool"] = ThreadPoolExecutor(max_workers=1,
                                               thread_name_prefix="rstrace-beside")
        return _POOL["pool"]


class Beside:
    """``fn(*args)`` started on the pool thread (unless ``when`` is False or the calling
    thread may use one thread only); :meth:`result` joins it and returns its value or
    raises its exception (running it here where the pool thread had not started it);
    :meth:`drop` is for a caller that is raising. One of them must be called before the
    caller leaves what ``fn`` reads."""

    def __init__(self, fn, *args, when: bool = True) -> None:
        self._fn, self._args = fn, args
        self._future = (_pool().submit(fn, *args)
                        if when and numba.get_num_threads() > 1 else None)
        self._handed = self._future is not None
        self._joined = False
        self._value = None
        self._error: BaseException | None = None

    @property
    def started(self) -> bool:
        """Whether the call was handed to the pool thread (it may have been queued, then
        taken back by :meth:`result`)."""
        return self._handed

    def _join(self) -> None:
        if self._joined:
            return
        future, self._future = self._future, None
        try:
            if future is None or future.cancel():  # (never started: run here)
                self._value = self._fn(*self._args)
            else:
                self._value = future.result()
        except BaseException as exc:  # handed to result()
            self._error = exc
        self._joined = True
        self._fn = self._args = None

    def result(self):
        """The call's value (joined: run here where the pool thread had not started it)."""
        self._join()
        if self._error is not None:
            raise self._error
        return self._value

    def drop(self) -> None:
        """For a caller that is raising: join the call if the pool thread runs it (it may
        read the caller's arrays), else never run it; its value and exception ignored."""
        if not self._joined:
            future, self._future = self._future, None
            if future is not None and not future.cancel():
                future.exception()  # (waits for it to end)
            self._joined = True
            self._fn = self._args = None


class Shared:
    """``fn(start, stop)`` over consecutive ranges of ``0 .. n`` (``chunk`` items each),
    shared by the pool thread and the calling thread: the pool thread starts taking ranges
    now; :meth:`result` has the caller take the ones left (after whatever it did
    meanwhile), then joins and returns the ranges' values in range order.

    Each range is taken once, from a shared counter, by whichever thread is free: where the
    pool thread is busy (a :class:`Beside` call before this one) or the other core is taken
    by another process, the caller takes more of them, and waits at most for the range the
    pool thread is in. ``fn`` must launch no parallel region (as for :class:`Beside`), and
    two ranges' work must not overlap (each writes its own rows). An exception in a range
    stops both threads taking more and is raised by :meth:`result` (the caller's own
    first); ``when`` False (or one range, or the caller may use one thread only): every
    range runs on the caller in :meth:`result`, in order."""

    def __init__(self, fn, n: int, chunk: int, when: bool = True) -> None:
        step = max(int(chunk), 1)
        self._fn = fn
        self._bounds = [(s, min(s + step, n)) for s in range(0, n, step)]
        self._values: list = [None] * len(self._bounds)
        self._next = itertools.count()  # (its next() is atomic: one C call under the GIL)
        self._stop = False
        self._job = Beside(self._take, when=when and len(self._bounds) > 1)

    @property
    def started(self) -> bool:
        """Whether the pool thread was asked to take ranges too."""
        return self._job.started

    def _take(self) -> None:
        """Run the ranges not taken yet, one at a time, until none is left or one failed."""
        bounds = self._bounds
        for i in self._next:
            if i >= len(bounds) or self._stop:
                return
            try:
                self._values[i] = self._fn(*bounds[i])
            except BaseException:
                self._stop = True
                raise

    def result(self) -> list:
        """Take the ranges left here, join the pool thread's; the values in range order."""
        try:
            self._take()
        except BaseException:  # (a range's, or an interrupt between ranges: the pool
            self.drop()        # thread starts no range after it either)
            raise
        self._job.result()
        return self._values

    def drop(self) -> None:
        """For a caller that is raising: no range is started after this; the one the pool
        thread is in is waited for."""
        self._stop = True
        self._job.drop()
