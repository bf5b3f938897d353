"""Camera rays, following Blender's camera model (sensor fit, lens, shift, clipping).

Pixel ``(x, y)`` has ``y = 0`` at the *bottom* row, as in Blender's render result; pixel
index ``i = y * width + x``. Ray math is float64.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .scene import Camera


def same_camera(a: Camera | None, b: Camera | None) -> bool:
    """True when two cameras give the same rays: the one camera comparison of rstrace
    (matrices compared exactly, every other field of :class:`Camera` by value)."""
    if a is None or b is None:
        return a is b
    if not np.array_equal(a.matrix, b.matrix):
        return False
    return all(getattr(a, f.name) == getattr(b, f.name) for f in dataclasses.fields(Camera)
               if f.name != "matrix")


class CameraParams(NamedTuple):
    """A camera reduced to what ray generation needs (all float64 except the flags)."""

    xform: np.ndarray  # (4, 4) camera -> world (unit axes)
    ortho: bool
    pixsize: float  # image-plane size of one pixel (at distance 1 for perspective)
    x0: float  # image-plane coordinate of the left edge of pixel column 0
    y0: float  # image-plane coordinate of the bottom edge of pixel row 0
    clip_start: float
    clip_end: float
    width: int
    height: int


def camera_params(cam: Camera, width: int | None = None, height: int | None = None,
                  ) -> CameraParams:
    """Blender's viewplane (``BKE_camera_params_compute_viewplane``) for ``cam``."""
    w = int(width or cam.width)
    h = int(height or cam.height)
    m = np.array(cam.matrix, dtype=np.float64, order="C")  # one layout: one compiled kernel
    # Normalise axes: object scale on a camera does not change its projection in Blender.
    for k in range(3):
        m[:3, k] /= np.linalg.norm(m[:3, k])
    fit = cam.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if w >= h else "VERTICAL"
        sensor = cam.sensor_width
    else:
        sensor = cam.sensor_width if fit == "HORIZONTAL" else cam.sensor_height
    viewfac = float(w if fit == "HORIZONTAL" else h)
    ortho = cam.kind == "ORTHO"
    pixsize = (cam.ortho_scale if ortho else sensor / cam.lens) / viewfac
    x0 = (-0.5 * w + cam.shift_x * viewfac) * pixsize
    y0 = (-0.5 * h + cam.shift_y * viewfac) * pixsize
    return CameraParams(m, ortho, pixsize, x0, y0, float(cam.clip_start), float(cam.clip_end),
                        w, h)


@njit(cache=True, nogil=True, parallel=True)
def generate_rays(cp, pixels, jitter, origins, directions, tmin, tmax):
    """Fill rays through ``pixels`` (n,) int64 at sub-pixel offsets ``jitter`` (n, 2) in [0,1).

    origins, directions : (n, 3) float64 outputs (directions unit length)
    tmin, tmax : (n,) float64 outputs: the clipping range as distances along each ray
    """
    m = cp.xform
    for i in prange(pixels.shape[0]):
        p = pixels[i]
        px = p % cp.width
        py = p // cp.width
        u = cp.x0 + (px + jitter[i, 0]) * cp.pixsize
        v = cp.y0 + (py + jitter[i, 1]) * cp.pixsize
        if cp.ortho:
            for k in range(3):
                origins[i, k] = m[k, 3] + u * m[k, 0] + v * m[k, 1]
                directions[i, k] = -m[k, 2]
            tmin[i] = cp.clip_start
            tmax[i] = cp.clip_end
        else:
            dx = u * m[0, 0] + v * m[0, 1] - m[0, 2]
            dy = u * m[1, 0] + v * m[1, 1] - m[1, 2]
            dz = u * m[2, 0] + v * m[2, 1] - m[2, 2]
            ln = np.sqrt(dx * dx + dy * dy + dz * dz)
            origins[i, 0] = m[0, 3]
            origins[i, 1] = m[1, 3]
            origins[i, 2] = m[2, 3]
            directions[i, 0] = dx / ln
            directions[i, 1] = dy / ln
            directions[i, 2] = dz / ln
            # clipping distances are measured along the view axis, as in Blender
            tmin[i] = cp.clip_start * ln
            tmax[i] = cp.clip_end * ln


def camera_rays(cam: Camera | CameraParams, pixels: np.ndarray | None = None,
                jitter: np.ndarray | None = None):
    """Rays for ``pixels`` (default: every pixel, centre samples).

    Returns ``origins (n, 3)``, ``directions (n, 3)``, ``tmin (n,)``, ``tmax (n,)``.
    """
    cp = cam if isinstance(cam, CameraParams) else camera_params(cam)
    if pixels is None:
        pixels = np.arange(cp.width * cp.height, dtype=np.int64)
    pixels = np.ascontiguousarray(pixels, dtype=np.int64)
    n = len(pixels)
    if jitter is None:
        jitter = np.full((n, 2), 0.5)
    origins = np.empty((n, 3))
    directions = np.empty((n, 3))
    tmin = np.empty(n)
    tmax = np.empty(n)
    generate_rays(cp, pixels, np.ascontiguousarray(jitter, dtype=np.float64), origins,
                  directions, tmin, tmax)
    return origins, directions, tmin, tmax


def _mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser over a uint64 array (wrapping arithmetic): a bijective hash."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _reverse32(x: np.ndarray) -> np.ndarray:
    """The bits of a uint32 array in reverse order."""
    for shift, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF)):
        sh, m = np.uint32(shift), np.uint32(mask)
        x = ((x >> sh) & m) | ((x & m) << sh)
    return (x >> np.uint32(16)) | (x << np.uint32(16))


def _owen_reversed(r: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Nested uniform (Owen) scrambling by ``seed``, hash-based (Burley 2020, "Practical
    Hash-based Owen Scrambling", JCGT 9(4)), on the *bit-reversed* uint32 values ``r``
    (result bit-reversed too): the Laine-Karras permutation with Vegdahl's constants (2021;
    Cycles' ``reversed_bit_owen``). A bit of the (unreversed) result depends on the seed and
    the bits above it only, so an aligned block of ``2^k`` values is permuted onto an
    aligned block of ``2^k``."""
    r = r ^ (r * np.uint32(0x3D20ADEA))
    r = r + seed
    r *= (seed >> np.uint32(16)) | np.uint32(1)
    r ^= r * np.uint32(0x05526C56)
    r ^= r * np.uint32(0x53A22864)
    return r


def _sobol1_table() -> np.ndarray:
    """Sobol's second dimension of the indices ``0 .. 2^16 - 1``, bit-reversed (uint32): the
    XOR of the direction numbers (``v_0 = 2^31``, ``v_k = v_{k-1} ^ (v_{k-1} >> 1)``:
    Pascal's matrix mod 2) of the index's set bits, shifted by 16 bits for the upper half
    of an index (row 1). A full index's value is the XOR of its two halves' entries."""
    v = np.empty(32, np.uint32)
    v[0] = 1 << 31
    for k in range(1, 32):
        v[k] = v[k - 1] ^ (v[k - 1] >> 1)
    i = np.arange(1 << 16, dtype=np.uint32)
    lo = np.zeros(1 << 16, np.uint32)
    hi = np.zeros(1 << 16, np.uint32)
    for k in range(16):
        bit = ((i >> np.uint32(k)) & np.uint32(1)).astype(np.bool_)
        lo[bit] ^= v[k]
        hi[bit] ^= v[k + 16]
    return _reverse32(np.stack([lo, hi]))


_SOBOL1 = _sobol1_table()


def pixel_jitter(pixels: np.ndarray, samples: int, seed: int = 0) -> np.ndarray:
    """Jitter offsets for ``samples`` per pixel of the pixel indices ``pixels`` (k,):
    (samples, k, 2) in [0, 1). One sample: the pixel centres.

    Each pixel's samples are an Owen-scrambled Sobol (0, 2)-sequence with hash-based
    shuffling and scrambling (Burley 2020, "Practical Hash-based Owen Scrambling"): sample
    ``s`` is the Sobol point (dimensions 0 and 1) of the pixel's scrambled index of ``s``,
    each coordinate scrambled with its own seed. The index scramble maps the first ``2^m``
    samples onto an aligned block of ``2^m`` Sobol points, a (0, m, 2)-net, for every m:
    a power of 2 of samples is a net (every elementary interval of area ``1/samples`` holds
    one), any other count is the net of the largest power of 2 below it plus the first of
    the next block's points (which is another such net). Sample ``s`` is the same whatever
    the count. The seeds are a hash of the frame's ``seed`` and the pixel, never of the batch
    it is traced in, so every mode and every tiling (a full frame, the dirty pixels of an
    incremental one, the RI-tree's larger tiles, the viewport's) traces the same rays
    through a pixel. (Measured against the jittered grid it replaced: docs/accuracy.md,
    "Pixel samples".)"""
    pixels = np.asarray(pixels, np.int64)
    k = len(pixels)
    if samples <= 1:
        return np.full((1, k, 2), 0.5)
    s = _mix64(np.array([int(seed) & 0xFFFFFFFFFFFFFFFF], np.uint64)
               + np.uint64(0x3C6EF372FE94F82A))
    h1 = _mix64(pixels.astype(np.uint64) ^ s)
    h2 = _mix64(h1)
    lo32 = np.uint64(0xFFFFFFFF)
    seed_i = (h1 & lo32).astype(np.uint32)[None, :]
    seed_x = (h1 >> np.uint64(32)).astype(np.uint32)[None, :]
    seed_y = (h2 & lo32).astype(np.uint32)[None, :]
    idx = _reverse32(_owen_reversed(_reverse32(np.arange(samples, dtype=np.uint32))[:, None],
                                    seed_i))
    out = np.empty((samples, k, 2))
    # Sobol's dimension 0 is the index's bits reversed: its scramble needs no reversal
    out[..., 0] = _reverse32(_owen_reversed(idx, seed_x))
    out[..., 1] = _reverse32(_owen_reversed(
        _SOBOL1[0][idx & np.uint32(0xFFFF)] ^ _SOBOL1[1][idx >> np.uint32(16)], seed_y))
    out *= 2.0 ** -32
    return out
