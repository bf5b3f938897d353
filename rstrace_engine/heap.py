"""The C heap kept between a frame's batches (glibc's ``malloc``).

A frame's tracer allocates and frees tens of megabytes of numpy arrays per batch of rays
(hits, surface points, shadow rays; :func:`~.tracing.whitted.trace`). glibc's ``malloc``
by default gives freed memory at the top of its heap back to the system once it exceeds a
threshold that it adapts to the largest block freed so far, and serves blocks above another
such threshold with fresh ``mmap`` pages: whether a batch's arrays land on pages already
touched or on new ones (a page fault each, the kernel zeroing it) then depends on what the
process allocated before. Measured (issue 20): an INTERPOLANT frame that interpolates
nothing, ``museum_1999`` 320x240 at 1 spp, took 5,000-10,000 minor page faults inside its
:func:`~.tracing.whitted.trace` calls (the heap grown and trimmed around every batch: 60
``brk`` calls a frame) against about 50-800 for the BASE frame of the same rays, and cost
0.80x-0.86x of it in process CPU time; at 4 spp 22,000-26,000 faults and 0.77x-0.90x. With
the heap kept (:func:`keep`) both frames take a handful of faults and the ratio is
1.00x / 1.02x.

:func:`keep` fixes both thresholds (``mallopt``) once per process: blocks below
:data:`MMAP_THRESHOLD` come from the heap, and trimming it keeps :data:`TOP_PAD` bytes
free at its top for the next batch. The price: up to that much freed memory stays with the
process between frames. Elsewhere (no glibc, or another ``malloc`` in front of it) it does
nothing and says so.
"""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger(__name__)

#: glibc's mallopt parameters (malloc.h)
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
#: blocks of fewer bytes come from the heap, not fresh mmap pages (glibc's largest: 32 MiB on
#: 64-bit; a frame's per-batch arrays are 0.1-2 MB)
MMAP_THRESHOLD = 32 << 20
#: bytes of free heap kept at its top when glibc trims it (a 32k-ray batch's arrays in all,
#: a few tens of MB, with room)
TOP_PAD = 64 << 20

_kept: bool | None = None


def keep() -> bool:
    """Fix glibc's heap thresholds (module doc), once per process; returns whether they
    are set (False where the C library is not glibc or refuses them)."""
    global _kept
    if _kept is None:
        _kept = _set()
    return _kept


def _set() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # noqa: B018 (glibc only: musl's mallopt does nothing)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = (mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
          and mallopt(M_TOP_PAD, TOP_PAD) == 1)
    if not ok:
        log.info("heap: glibc's mallopt refused the thresholds; the heap is not kept")
    return ok
