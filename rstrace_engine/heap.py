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
free at its top for the next batch.

Soft light (session 34): a 32k-ray tile's soft shadow samples (16 per sampled light and
point, :func:`~.tracing.soft_lights.soft_rays` and the shadow rays traced of them) take
200-300 MB at once, far past :data:`TOP_PAD`: glibc trimmed its heap back after every tile
(its trim threshold, 128 KiB by default, is not adapted once the mmap threshold is fixed)
and grew it again in the next, and the blocks above 32 MiB came from fresh ``mmap`` pages.
``museum_soft`` 320x240 at 4 spp: 100,000-107,000 minor page faults and 0.6-0.8 s of system
CPU per frame (of 5-6 s) in BASE and INTERPOLANT frames alike. :data:`TRIM_THRESHOLD` keeps
the heap at its largest tile: blocks above the mmap threshold are then served from the free
heap too (glibc maps fresh pages for them only when the heap's top cannot hold them), and
the frames after a process's first take a handful of faults.

The price: up to :data:`TRIM_THRESHOLD` bytes of freed memory stay with the process between
frames (the peak of one tile, which the frame needed a moment before); the setting is the
process's, so inside Blender its own freed memory is kept the same way. A tile's peak past
the threshold (32 light samples: the review measured 194k faults a frame against main's
299k) is trimmed again. A worker thread's
frames use their own glibc arena, which these thresholds do not keep the same way (a fresh
thread's first tiles fault; see docs/bench-trade-first-frames.md, session 34). Elsewhere
(no glibc, or another ``malloc`` in front of it) it does nothing and says so.
"""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger(__name__)

#: glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
#: blocks of fewer bytes come from the heap, not fresh mmap pages (glibc's largest: 32 MiB on
#: 64-bit; a frame's per-batch arrays are 0.1-2 MB)
MMAP_THRESHOLD = 32 << 20
#: bytes of free heap kept at its top when glibc trims it (a 32k-ray batch's arrays in all,
#: a few tens of MB, with room)
TOP_PAD = 64 << 20
#: free bytes at the heap's top past which glibc gives them back (its default: 128 KiB): a
#: soft-lit tile's arrays, 200-300 MB at 16 light samples (module doc), kept between tiles
TRIM_THRESHOLD = 512 << 20

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
        glibc = ctypes.CDLL("libc.so.6")
    except (OSError, AttributeError):
        return False
    if ctypes.cast(libc.malloc, ctypes.c_void_p).value != \
            ctypes.cast(glibc.malloc, ctypes.c_void_p).value:
        # another malloc in front of glibc's (LD_PRELOAD'ed jemalloc, tcmalloc): glibc's
        # thresholds would be set and mean nothing
        log.info("heap: malloc is not glibc's; the heap is not kept")
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = (mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
          and mallopt(M_TOP_PAD, TOP_PAD) == 1
          and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1)
    if not ok:
        log.info("heap: glibc's mallopt refused the thresholds; the heap is not kept")
    return ok
