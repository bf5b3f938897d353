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

