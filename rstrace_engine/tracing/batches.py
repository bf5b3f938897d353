"""How a frame's pixels become batches of rays: tiles of rows, their jitter, dirty pixels.

A full frame goes tile by tile (:data:`TILE_RAYS` rays); an incremental one gathers the
selected pixels of every tile into batches of about that size, with the jitter each pixel
gets in a full frame, so that a re-rendered pixel comes out bit for bit as in a full frame.
Small batches run numba's parallel kernels on one thread (:func:`threads_for`).
"""

from __future__ import annotations

from contextlib import contextmanager

import numba
import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..frame import CLASS_BACKGROUND, CLASS_TRACED
from ..geometry.cameras import pixel_jitter

#: Rays per batch in :func:`~.whitted.render` (primary rays of one tile of rows, all samples).
#: 32k rays: cancel() is polled about every 30 ms on 2 cores (the viewport's interrupt
#: latency) and full tiles stay above SERIAL_BELOW (every thread). Museum 640x480 BASE
#: frame, best of 3 in one run on a heavily loaded 2-core machine (noise dominates):
#: 64k tiles 3.37 s, 32k 4.13 s, 16k (then single-threaded) 2.41 s.
TILE_RAYS = 1 << 15
#: Batches of fewer rays (the dirty pixels of an incremental frame) run their kernels on
#: one thread: measured on a busy 2-core machine, every parallel region then costs a
#: scheduler time slice, and 5,500 dirty pixels of museum took 0.2 s on two threads and
#: 0.04 s on one.
SERIAL_BELOW = 1 << 14


@contextmanager
def threads_for(n_rays: int):
    """Run numba's parallel kernels on one thread inside, for a small batch."""
    if n_rays >= SERIAL_BELOW:
        yield
        return
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(old)


def row_tiles(w: int, h: int, spp: int, seed: int, rows_per_tile: int,
              border: tuple | None = None):
    """The pixels of a ``w`` x ``h`` frame, or of its ``border`` region (x, y, width,
    height), in tiles of ``rows_per_tile`` rows with their jitter: ``(pix (k,) int64
    row-major, jitter (spp, k, 2), end row)``. The jitter is the pixels' own
    (:func:`~rstrace_engine.geometry.cameras.pixel_jitter` of ``seed``, one sample: the pixel
    centres), the same whatever the tiling."""
    x0, y0, bw, bh = border if border is not None else (0, 0, w, h)
    for ya in range(y0, y0 + bh, rows_per_tile):
        yb = min(y0 + bh, ya + rows_per_tile)
        rows = np.arange(ya, yb, dtype=np.int64)[:, None] * w
        pix = (rows + np.arange(x0, x0 + bw, dtype=np.int64)[None, :]).reshape(-1)
        yield pix, pixel_jitter(pix, spp, seed=seed), yb


def frame_batches(w: int, h: int, spp: int, seed: int, rows_per_tile: int,
                  pixels: np.ndarray | None):
    """The pixels of a frame in batches, with their jitter: ``(pix (k,) int64, jitter
    (spp, k, 2), last row done)``. A full frame goes tile by tile (:func:`row_tiles`);
    an incremental one (``pixels`` (h * w,) bool) gathers the selected pixels of all tiles
    into batches of about a tile's size. A pixel's jitter is its own (not its tile's), so its
    samples are the same either way and in every mode, whatever its tile size."""
    if pixels is None:
        yield from row_tiles(w, h, spp, seed, rows_per_tile)
        return
    chunk = rows_per_tile * w
    pend: list = []
    n_pend = 0
    for ya in range(0, h, rows_per_tile):
        y1 = min(h, ya + rows_per_tile)
        sel = np.flatnonzero(pixels[ya * w:y1 * w]) + ya * w
        if len(sel):
            pend.append(sel.astype(np.int64))
            n_pend += len(sel)
        if n_pend >= chunk or (y1 == h and n_pend):
            pix = np.concatenate(pend)
            yield pix, pixel_jitter(pix, spp, seed=seed), y1
            pend, n_pend = [], 0


# ----------------------------------------------------------------------------- samples


@njit(cache=True, nogil=True)
def scatter_add(dst, idx, src):
    """``dst[idx[i]] += src[i]`` for (n, 3) rows (serial: indices may repeat)."""
    for i in range(idx.shape[0]):
        k = idx[i]
        dst[k, 0] += src[i, 0]
        dst[k, 1] += src[i, 1]
        dst[k, 2] += src[i, 2]


@njit(cache=True, nogil=True, parallel=True)
def accumulate(rad, inst, spp, out, pclass):
    """Average ``spp`` samples per pixel into ``out``, leaving out broken samples.

    rad : (spp * m, 3) float64 sample radiance, sample-major (sample s of pixel p at row
    ``s * m + p``); inst : (spp * m,) int32 primary hit instance. Outputs: out (m, 3)
    float32 mean of the finite samples not above ``RADIANCE_MAX`` (0 if none), pclass (m,)
    uint8 ``CLASS_TRACED`` when some sample hit, else ``CLASS_BACKGROUND``. Returns the
    number of samples left out.
    """
    m = out.shape[0]
    bad = np.zeros(m, np.int64)
    for p in prange(m):
        r = 0.0
        g = 0.0
        b = 0.0
        good = 0
        hit = False
        for s in range(spp):
            k = s * m + p
            hit = hit or inst[k] >= 0
            x, y, z = rad[k, 0], rad[k, 1], rad[k, 2]
            # written so that NaN fails the test
            if (abs(x) <= tol.RADIANCE_MAX and abs(y) <= tol.RADIANCE_MAX
                    and abs(z) <= tol.RADIANCE_MAX):
                r += x
                g += y
                b += z
                good += 1
            else:
                bad[p] += 1
        if good > 0:
            r /= good
            g /= good
            b /= good
        out[p, 0] = r
        out[p, 1] = g
        out[p, 2] = b
        pclass[p] = CLASS_TRACED if hit else CLASS_BACKGROUND
    return bad.sum()
