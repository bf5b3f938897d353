"""A minimal reader for uncompressed scanline OpenEXR files (what the tests write).

The tests render with ``exr_codec = 'NONE'`` and 32-bit floats, so no decompression is
needed; this keeps the bpy tests free of an OpenEXR dependency. Rows are returned bottom-up
(row 0 is the bottom of the image), the convention of Blender's render result and of
``rstrace_engine.frame.Frame``.
"""

from __future__ import annotations

import struct

import numpy as np

_PIXEL_DTYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}


def _cstr(buf: bytes, pos: int) -> tuple[str, int]:
    end = buf.index(b"\0", pos)
    return buf[pos:end].decode("latin-1"), end + 1


def _header(buf: bytes, pos: int, path) -> tuple[dict, int]:
    """One header: attribute name -> raw value (channels parsed); returns the end position."""
    attrs: dict = {}
    while buf[pos] != 0:
        name, pos = _cstr(buf, pos)
        _type, pos = _cstr(buf, pos)
        (size,) = struct.unpack_from("<i", buf, pos)
        pos += 4
        value = buf[pos:pos + size]
        pos += size
        if name == "channels":
            chans, p = [], 0
            while value[p] != 0:
                cname, p = _cstr(value, p)
                (ptype,) = struct.unpack_from("<i", value, p)
                xs, ys = struct.unpack_from("<ii", value, p + 8)
                if (xs, ys) != (1, 1):
                    raise ValueError(f"{path}: subsampled channel {cname}")
                chans.append((cname, ptype))
                p += 16
            attrs[name] = chans
        else:
            attrs[name] = value
    for need in ("channels", "dataWindow", "compression"):
        if need not in attrs:
            raise ValueError(f"{path}: header lacks {need}")
    if attrs["compression"][0] != 0:
        raise ValueError(f"{path}: compressed EXR (codec {attrs['compression'][0]}); write "
                         f"with exr_codec='NONE'")
    if attrs.get("type", b"scanlineimage\0")[:4] not in (b"scan",):
        raise ValueError(f"{path}: only scanline parts are supported")
    return attrs, pos + 1


def read_exr(path) -> dict[str, np.ndarray]:
    """Channels of an uncompressed scanline EXR (single- or multi-part, as Blender 5 writes
    multilayer files): channel name -> (h, w) float32."""
    with open(path, "rb") as f:
        buf = f.read()
    magic, version = struct.unpack_from("<ii", buf, 0)
    if magic != 20000630:
        raise ValueError(f"{path}: not an OpenEXR file")
    if version & 0x200:
        raise ValueError(f"{path}: tiled EXR is not supported by this reader")
    multipart = bool(version & 0x1000)
    pos = 8
    parts = []
    while True:
        attrs, pos = _header(buf, pos, path)
        parts.append(attrs)
        if not multipart or buf[pos] == 0:
            break
    if multipart:
        pos += 1  # the empty header that ends the header list
    out: dict[str, np.ndarray] = {}
    layouts = []
    for attrs in parts:
        x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
        w, h = x1 - x0 + 1, y1 - y0 + 1
        chans = attrs["channels"]
        layouts.append((y0, w, h, chans,
                        np.dtype([(n, _PIXEL_DTYPES[t], (w,)) for n, t in chans])))
        for n, _ in chans:
            out[n] = np.empty((h, w), np.float32)
        count = struct.unpack("<i", attrs["chunkCount"])[0] if "chunkCount" in attrs else h
        offsets = np.frombuffer(buf, "<u8", count, pos)
        pos += 8 * count
        layouts[-1] = layouts[-1] + (offsets,)
    for k, (y0, _w, h, chans, row_dtype, offsets) in enumerate(layouts):
        for off in offsets:
            p = int(off)
            if multipart:
                (part,) = struct.unpack_from("<i", buf, p)
                if part != k:
                    raise ValueError(f"{path}: chunk of part {part} in the table of part {k}")
                p += 4
            y, _size = struct.unpack_from("<ii", buf, p)
            row = np.frombuffer(buf, row_dtype, 1, p + 8)[0]
            for n, _ in chans:
                # EXR rows run top-down; flip to bottom-up
                out[n][h - 1 - (y - y0)] = row[n]
    return out


def read_pass(channels: dict[str, np.ndarray], pass_name: str, layer: str = "ViewLayer",
              components: str = "RGB") -> np.ndarray:
    """Stack ``layer.pass.R/G/B...`` of a multilayer EXR into (h, w, len(components))."""
    keys = [f"{layer}.{pass_name}.{c}" for c in components]
    missing = [k for k in keys if k not in channels]
    if missing:
        raise KeyError(f"channels {missing} not in EXR (has {sorted(channels)})")
    return np.stack([channels[k] for k in keys], axis=-1)
