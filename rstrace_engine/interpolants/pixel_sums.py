"""The per-sample and per-pixel kernels of an INTERPOLANT frame (:mod:`.render`): the rays a
chunk traces, a sample's radiance checked and counted, and the pixels' sums over their samples."""

from __future__ import annotations

from numba import njit

from ..frame import CLASS_BACKGROUND


@njit(cache=True, nogil=True)
def _to_trace(inst, interp, world, rad, todo):
    """Misses get the world colour (what the tracer gives them); the other rays that were
    not interpolated go to ``todo``. Returns their number."""
    k = 0
    for r in range(inst.shape[0]):
        if interp[r]:  # reprojected rays are interpolated without a hit
            continue
        if inst[r] < 0:
            rad[r, 0] = world[0]
            rad[r, 1] = world[1]
            rad[r, 2] = world[2]
        else:
            todo[k] = r
            k += 1
    return k


@njit(cache=True, nogil=True)
def _finish(rad, radmax, ray_class, good, counts):
    """good[r]: ray r's radiance is finite and at most ``radmax`` per channel (else it
    becomes 0); counts[c] += rays of class c. Returns the number of bad rays."""
    bad = 0
    for r in range(rad.shape[0]):
        ok = True
        for c in range(3):
            if not abs(rad[r, c]) <= radmax:  # also false for NaN
                ok = False
        good[r] = ok
        if not ok:
            rad[r, 0] = 0.0
            rad[r, 1] = 0.0
            rad[r, 2] = 0.0
            bad += 1
        counts[ray_class[r]] += 1
    return bad


@njit(cache=True, nogil=True)
def _accumulate(rad, good, ray_class, interp, acc_rad, acc_good, acc_cls, acc_lo, acc_hi):
    """Adds one sample of every pixel (``rad`` etc. (k, ...)) to the pixels' sums: radiance
    (bad samples are 0 in the sum, not counted), good samples, the class of the first
    sample that is not background, the least and largest interpolant used."""
    for i in range(rad.shape[0]):
        acc_rad[i, 0] += rad[i, 0]
        acc_rad[i, 1] += rad[i, 1]
        acc_rad[i, 2] += rad[i, 2]
        if good[i]:
            acc_good[i] += 1
        if acc_cls[i] == CLASS_BACKGROUND:
            acc_cls[i] = ray_class[i]
        q = interp[i]
        if q >= 0:
            if acc_lo[i] < 0 or q < acc_lo[i]:
                acc_lo[i] = q
            if q > acc_hi[i]:
                acc_hi[i] = q


@njit(cache=True, nogil=True)
def _assemble(acc_rad, acc_good, acc_cls, acc_lo, acc_hi, pix, image, pclass, pinterp):
    """Pixels from their sums (:func:`_accumulate`): mean radiance of the good samples'
    count, class, the interpolant all its interpolated samples used (-1: none, -2:
    several)."""
    for i in range(pix.shape[0]):
        ng = max(acc_good[i], 1)
        p = pix[i]
        image[p, 0] = acc_rad[i, 0] / ng
        image[p, 1] = acc_rad[i, 1] / ng
        image[p, 2] = acc_rad[i, 2] / ng
        pclass[p] = acc_cls[i]
        lo = acc_lo[i]
        hi = acc_hi[i]
        pinterp[p] = -1 if hi < 0 else (hi if lo == hi else -2)
