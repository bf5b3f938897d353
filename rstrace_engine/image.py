"""Images: the display transform, error metrics against a reference, PNG and .npy files.

Rendered images are linear RGB with rows bottom-up (row 0 is the bottom, as in Blender).
The *display* image is the linear image clamped to [0, 1] and sRGB-encoded; every accuracy
number rstrace reports is measured there (it is what the user sees).
"""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function of values in [0, 1] (IEC 61966-2-1), same shape, float64."""
    x = np.asarray(linear, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308),
                                                                   1.0 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode`, float64."""
    y = np.asarray(encoded, dtype=np.float64)
    return np.where(y <= 0.04045, y / 12.92, np.power((np.maximum(y, 0.04045) + 0.055) / 1.055,
                                                       2.4))


def to_display(linear: np.ndarray) -> np.ndarray:
    """Display transform: clamp linear RGB to [0, 1] (NaN -> 0), then sRGB-encode.

    linear : (..., 3) float -> (..., 3) float64 in [0, 1].
    """
    x = np.nan_to_num(np.asarray(linear, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return srgb_encode(np.clip(x, 0.0, 1.0))


def to_uint8(display: np.ndarray) -> np.ndarray:
    """Display values in [0, 1] -> uint8 (rounded), same shape."""
    return np.clip(np.rint(np.asarray(display, np.float64) * 255.0), 0, 255).astype(np.uint8)


def compare(image: np.ndarray, reference: np.ndarray, epsilon: float = 0.01) -> dict:
    """Error of a linear image against a linear reference, measured in display space.

    image, reference : (h, w, 3) linear RGB. Returns a dict: ``mean_error`` (mean absolute
    display difference over all pixels and channels), ``max_error`` (largest), ``frac_over``
    (fraction of pixels whose largest channel error exceeds ``epsilon``), ``n_over`` (their
    count), ``psnr`` (dB, peak 1; ``inf`` for identical images) and ``epsilon``.
    """
    a = to_display(image)
    b = to_display(reference)
    if a.shape != b.shape:
        raise ValueError(f"compare: image {a.shape} and reference {b.shape} differ in shape")
    diff = np.abs(a - b)
    per_pixel = diff.max(axis=-1)
    mse = float(np.mean(diff * diff)) if diff.size else 0.0
    n_over = int(np.count_nonzero(per_pixel > epsilon))
    return dict(
        mean_error=float(diff.mean()) if diff.size else 0.0,
        max_error=float(diff.max()) if diff.size else 0.0,
        frac_over=n_over / max(per_pixel.size, 1),
        n_over=n_over,
        psnr=math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse),
        epsilon=float(epsilon),
    )


# ----------------------------------------------------------------------------- PNG


def _chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))


def write_png(path, pixels: np.ndarray, bottom_up: bool = True) -> Path:
    """Write an 8-bit RGB or RGBA PNG (zlib, no other dependency).

    pixels : (h, w, 3 | 4) uint8, or float display values in [0, 1] (use
    :func:`write_render_png` for linear radiance). ``bottom_up``: row 0 is the bottom row
    (rstrace's and Blender's convention); PNG stores the top row first.
    """
    px = np.asarray(pixels)
    if px.dtype != np.uint8:
        px = to_uint8(np.nan_to_num(px.astype(np.float64)))
    if px.ndim != 3 or px.shape[2] not in (3, 4) or px.shape[0] < 1 or px.shape[1] < 1:
        raise ValueError(f"write_png: expected (h, w, 3|4) pixels, got {px.shape}")
    if bottom_up:
        px = px[::-1]
    h, w, c = px.shape
    raw = np.zeros((h, 1 + w * c), np.uint8)  # filter byte 0 (None) per row
    raw[:, 1:] = px.reshape(h, w * c)
    header = struct.pack(">IIBBBBB", w, h, 8, 6 if c == 4 else 2, 0, 0, 0)
    data = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(raw.tobytes(), 6)) + _chunk(b"IEND", b""))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def write_render_png(path, radiance: np.ndarray) -> Path:
    """Write linear radiance (h, w, 3), rows bottom-up, through the display transform."""
    return write_png(path, to_uint8(to_display(radiance)), bottom_up=True)


def _unfilter(raw: np.ndarray, h: int, stride: int, bpp: int) -> np.ndarray:
    out = np.zeros((h, stride), np.uint8)
    prev = np.zeros(stride, np.int32)
    for y in range(h):  # per row (PNG filters are sequential within a row for Sub/Paeth)
        f = raw[y, 0]
        line = raw[y, 1:].astype(np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) & 0xFF
        else:
            cur = np.zeros(stride, np.int32)
            for x in range(stride):
                a = cur[x - bpp] if x >= bpp else 0
                b = prev[x]
                if f == 1:
                    p = a
                elif f == 3:
                    p = (a + b) // 2
                elif f == 4:
                    c = prev[x - bpp] if x >= bpp else 0
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                else:
                    raise ValueError(f"read_png: unknown filter type {f}")
                cur[x] = (line[x] + p) & 0xFF
        out[y] = cur
        prev = cur
    return out


def read_png(path, bottom_up: bool = True) -> np.ndarray:
    """Read an 8-bit, non-interlaced RGB/RGBA/grey PNG as (h, w, c) uint8.

    Meant for checking files this module (or another simple writer) produced; row 0 is the
    bottom when ``bottom_up``.
    """
    data = Path(path).read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"read_png: {path} is not a PNG file")
    pos, idat, hdr = 8, [], None
    while pos < len(data):
        (ln,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + ln]
        pos += 12 + ln
        if kind == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if hdr is None:
        raise ValueError(f"read_png: {path} has no IHDR")
    w, h, depth, ctype, _, _, interlace = hdr
    chans = {0: 1, 2: 3, 4: 2, 6: 4}.get(ctype)
    if depth != 8 or chans is None or interlace:
        raise ValueError(f"read_png: unsupported PNG (bit depth {depth}, colour type {ctype}, "
                         f"interlace {interlace})")
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, 1 + w * chans)
    px = _unfilter(raw, h, w * chans, chans).reshape(h, w, chans)
    return px[::-1].copy() if bottom_up else px


# ----------------------------------------------------------------------------- float images


def save_npy(path, image: np.ndarray) -> Path:
    """Save a float image (h, w, c) as .npy (linear values kept exactly)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, np.asarray(image))
    return path


def load_npy(path) -> np.ndarray:
    """Load a float image saved by :func:`save_npy`."""
    return np.load(Path(path), allow_pickle=False)
