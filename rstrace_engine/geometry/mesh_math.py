"""Per-mesh geometry the scene model needs: which triangles have an area, smooth vertex
normals, flat triangle normals, the world box of a transformed object box (float64; the
area test and the flat normals kernels); and the add-on's gather of a host mesh's corners
into per-triangle arrays (:func:`gather_corners`)."""

from __future__ import annotations

import threading
import weakref

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..beside import Shared
from ..cancel import Cancelled

#: Triangles tested per kernel call by :func:`proper_triangles`: ``cancel`` is polled
#: between chunks (a chunk takes about a millisecond), and a large mesh's chunks are shared
#: by two threads (:func:`start_proper_triangles`).
PROPER_CHUNK = 1 << 16


def proper_triangles(verts: np.ndarray, tris: np.ndarray, cancel=None) -> np.ndarray:
    """(m,) bool: the triangles of positive area (doubled area above
    ``DEGENERATE_AREA_REL`` times the longest edge squared); the others are dropped at scene
    build, and a mesh with none is refused.

    ``tris`` must index ``verts`` (checked by the caller). One pass of a kernel over chunks
    of :data:`PROPER_CHUNK` triangles, no temporaries: C-contiguous float32 vertices (the
    add-on's) are read as they are, each value converted to float64 where it is read (the
    same values as a float64 copy's, no copy); anything else as float64. ``cancel`` (a
    ``() -> bool``) is polled between chunks and raises
    :class:`~rstrace_engine.cancel.Cancelled`.
    """
    return start_proper_triangles(verts, tris, cancel, shared=False).result()


class _Proper:
    """:func:`start_proper_triangles`' answer: :meth:`result` joins it."""

    def __init__(self, verts, tris, cancel, shared: bool) -> None:
        v = np.asarray(verts)
        if not (v.dtype == np.float32 and v.flags.c_contiguous):
            v = np.ascontiguousarray(v, np.float64)
        t = np.ascontiguousarray(tris, np.int32)
        self.keep = keep = np.empty(len(t), np.bool_)
        rel = tol.DEGENERATE_AREA_REL

        def proper_chunk(start: int, stop: int) -> None:
            if cancel is not None and cancel():
                raise Cancelled
            _proper_kernel(v, t, start, stop, rel, keep)

        self._chunks = Shared(proper_chunk, len(t), PROPER_CHUNK, when=shared)

    @property
    def started(self) -> bool:
        """Whether the pool thread takes chunks too."""
        return self._chunks.started

    def result(self) -> np.ndarray:
        """The (m,) bool answer: the chunks left taken here, the pool thread's joined."""
        self._chunks.result()
        return self.keep

    def drop(self) -> None:
        """For a caller that is raising (:meth:`~rstrace_engine.beside.Shared.drop`)."""
        self._chunks.drop()


def start_proper_triangles(verts: np.ndarray, tris: np.ndarray, cancel=None,
                           shared: bool = True) -> _Proper:
    """:func:`proper_triangles`, its chunks started on the pool thread where ``shared``
    (:class:`~rstrace_engine.beside.Shared`): the caller does other work, then ``result()``
    has it take the chunks left and returns the answer, the same bits whichever thread
    tested which chunk (each chunk writes its own rows). ``drop()`` for a caller that is
    raising. ``verts`` and ``tris`` must not change until then."""
    return _Proper(verts, tris, cancel, shared)


@njit(cache=True, nogil=True, error_model="numpy")
def _proper_kernel(v, tris, start, stop, rel, keep):
    """``keep[start:stop]`` of :func:`proper_triangles`: the same float64 operations, in
    the same order, as ``|cross(b - a, c - a)| > rel * max(|b - a|^2, |c - a|^2,
    |c - b|^2)`` with a longest edge above zero (``v`` float64, or float32 read as
    float64)."""
    for k in range(start, stop):
        a, b, c = tris[k, 0], tris[k, 1], tris[k, 2]
        ax, ay, az = np.float64(v[a, 0]), np.float64(v[a, 1]), np.float64(v[a, 2])
        bx, by, bz = np.float64(v[b, 0]), np.float64(v[b, 1]), np.float64(v[b, 2])
        qx, qy, qz = np.float64(v[c, 0]), np.float64(v[c, 1]), np.float64(v[c, 2])
        e0x, e0y, e0z = bx - ax, by - ay, bz - az
        e1x, e1y, e1z = qx - ax, qy - ay, qz - az
        e2x, e2y, e2z = qx - bx, qy - by, qz - bz
        cx = e0y * e1z - e0z * e1y
        cy = e0z * e1x - e0x * e1z
        cz = e0x * e1y - e0y * e1x
        area2 = np.sqrt(cx * cx + cy * cy + cz * cz)
        longest = max(e0x * e0x + e0y * e0y + e0z * e0z, e1x * e1x + e1y * e1y + e1z * e1z,
                      e2x * e2x + e2y * e2y + e2z * e2z)
        keep[k] = area2 > rel * longest and longest > 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def flat_normal32(verts, tris, k):
    """Triangle ``k``'s own unit normal ``cross(b - a, c - a) / |cross(b - a, c - a)|``,
    each component rounded to float32 and returned as float64 (NaN for a triangle whose
    cross product has no length: the scene model drops those). ``verts`` (V, 3) float32
    or float64, ``tris`` (m, 3) int32. The same float64 operations, in the same order,
    as ``np.cross`` and ``np.linalg.norm`` of the differences in float64 (a test compares
    them)."""
    a, b, c = tris[k, 0], tris[k, 1], tris[k, 2]
    ax, ay, az = np.float64(verts[a, 0]), np.float64(verts[a, 1]), np.float64(verts[a, 2])
    ux = np.float64(verts[b, 0]) - ax
    uy = np.float64(verts[b, 1]) - ay
    uz = np.float64(verts[b, 2]) - az
    vx = np.float64(verts[c, 0]) - ax
    vy = np.float64(verts[c, 1]) - ay
    vz = np.float64(verts[c, 2]) - az
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if not length > 0.0:
        return np.nan, np.nan, np.nan
    return (np.float64(np.float32(nx / length)), np.float64(np.float32(ny / length)),
            np.float64(np.float32(nz / length)))


@njit(cache=True, nogil=True, error_model="numpy")
def flat_triangle_normals(verts, tris, normals):
    """Each triangle's own unit normal (:func:`flat_normal32`) at its three corners:
    ``normals`` (m, 3, 3) float32 gets it where the triangle has an area (a degenerate
    triangle's rows are left as they are). One pass instead of a dozen (m, 3)
    temporaries."""
    for k in range(tris.shape[0]):
        fx, fy, fz = flat_normal32(verts, tris, k)
        if fx == fx:  # not NaN: the triangle has an area
            for corner in range(3):
                normals[k, corner, 0] = fx
                normals[k, corner, 1] = fy
                normals[k, corner, 2] = fz


def transform_aabb(lo: np.ndarray, hi: np.ndarray, m: np.ndarray) -> np.ndarray:
    """World box (2, 3) of the object box ``lo, hi`` under the affine matrix ``m``."""
    c = 0.5 * (lo + hi)
    e = 0.5 * (hi - lo)
    wc = m[:3, :3] @ c + m[:3, 3]
    we = np.abs(m[:3, :3]) @ e
    return np.stack([wc - we, wc + we])


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted smooth vertex normals, (n, 3) float64, unit (or zero where isolated)."""
    v = vertices[triangles]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    acc = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(acc, triangles[:, k], fn)
    ln = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, ln, out=np.zeros_like(acc), where=ln > 0)


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (one kernel signature whether the host's array is a
    read-only view of its memory or a writable copy)."""
    v = a.view()
    v.flags.writeable = False
    return v


#: Arrays allocated with spare rows around their values (:func:`with_room`), by ``id``,
#: until a packing claims their room (:func:`claim_room`); weak: gone with the array
_ROOMY: dict = {}
#: Reentrant: a collection may start inside its locked region (at an allocation there) and
#: free an array with room, whose weakref callback then takes it again on the same thread
_ROOMY_LOCK = threading.RLock()


def _root(a: np.ndarray) -> np.ndarray:
    """The array that owns ``a``'s memory (``a`` itself, or the last ndarray base)."""
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def with_room(rows: int, tail: tuple, dtype, spare: int) -> np.ndarray:
    """A fresh C-contiguous ``(rows, *tail)`` array of ``dtype`` (uninitialised), with
    ``spare`` uninitialised rows before and after it in the same allocation (its base)
    when ``spare`` > 0: room a packing may claim once (:func:`claim_room`) to lay the
    other meshes' rows beside these, instead of copying these (numbers in
    ``docs/bench-scale-bpy.md``). The spare rows are never written unless claimed (fresh
    memory: mostly unbacked until written, but for the transparent huge pages at the rows'
    edges: ``docs/bench-scale-bpy.md``, session 37)."""
    if spare <= 0:
        return np.empty((rows, *tail), dtype)
    root = np.empty((spare + rows + spare, *tail), dtype)
    key = id(root)

    def gone(ref, key=key):
        with _ROOMY_LOCK:
            if _ROOMY.get(key) is ref:
                del _ROOMY[key]

    with _ROOMY_LOCK:
        _ROOMY[key] = weakref.ref(root, gone)
    return root[spare:spare + rows]


def _room(a: np.ndarray, root: np.ndarray) -> tuple[int, int, int]:
    """``(row bytes, bytes before, bytes after)`` of C-contiguous ``a`` within ``root``'s
    memory."""
    row = a.nbytes // len(a)
    before = a.ctypes.data - root.ctypes.data
    return row, before, root.ctypes.data + root.nbytes - (a.ctypes.data + a.nbytes)


def has_room(a: np.ndarray) -> bool:
    """Whether ``a`` lies in an array of :func:`with_room` whose room no packing claimed
    (its memory beyond ``a`` is unused: it holds no other array's values)."""
    root = _root(a)
    with _ROOMY_LOCK:
        ref = _ROOMY.get(id(root))
        return ref is not None and ref() is root


def claim_room(a: np.ndarray, before: int, after: int) -> np.ndarray | None:
    """The ``(before + len(a) + after, *a.shape[1:])`` array of ``a``'s dtype whose rows
    ``before .. before + len(a) - 1`` are ``a`` itself (its memory: no copy), the others
    the spare rows around it, where ``a`` (C-contiguous, rows along its first axis) lies
    in an array of :func:`with_room` with that much room on each side that no one claimed
    yet; then the room is this caller's (no later claim gets it: two packings sharing
    a mesh never write the same spare rows). Else None (the caller copies ``a``)."""
    if not (isinstance(a, np.ndarray) and a.ndim >= 1 and len(a) and a.flags.c_contiguous):
        return None
    root = _root(a)
    row, lo, hi = _room(a, root)
    if (not root.flags.c_contiguous or lo % row or hi % row or lo < before * row
            or hi < after * row):
        return None
    with _ROOMY_LOCK:
        ref = _ROOMY.get(id(root))
        if ref is None or ref() is not root:
            return None
        del _ROOMY[id(root)]
    return np.ndarray((before + len(a) + after, *a.shape[1:]), a.dtype, buffer=root,
                      offset=lo - before * row)


#: Triangles per range of :func:`gather_corners`' pass; a mesh of two ranges or more is
#: gathered by two threads (:class:`~rstrace_engine.beside.Shared`)
GATHER_CHUNK = 1 << 17


def gather_corners(corner_vert: np.ndarray, corners: np.ndarray,
                   corner_uvs: np.ndarray | None = None, spare: int = 0):
    """The per-triangle vertex indices ``corner_vert[corners]`` ((m, 3) int32) and, where
    ``corner_uvs`` (one uv (2,) float32 row per corner) are given, the per-triangle uvs
    ``corner_uvs[corners]`` ((m, 3, 2) float32, bit for bit: moved as their bits), as
    fresh arrays; None where a corner lies outside ``0 .. len(corner_vert) - 1``.

    ``corners`` (m, 3) int32: the corners (indices into the host mesh's loops) of each
    triangle; ``corner_vert`` (n,) int32: each corner's vertex (an integer dtype of
    either that does not fit int32 raises TypeError: its cast would wrap indices past 2^31
    into others silently). ``spare``: rows of room around each result for the packing
    (:func:`with_room`). One pass of a kernel
    (:func:`_gather_corners`) over the corners, which checks their range as it reads them:
    what numpy's two gathers and a range check did in four passes (about 3x the CPU at 1M
    triangles, ``docs/bench-scale-bpy.md``). The pass runs over ranges of
    :data:`GATHER_CHUNK` triangles taken by two threads (the calling thread and the pool's,
    :class:`~rstrace_engine.beside.Shared`): most of its time is the first touch of the
    fresh results (0.24 s on one thread at 4M triangles, ``docs/bench-scale-bpy.md``,
    session 40); each range writes its own rows, the same bits.
    """
    _int32_indices(corner_vert, "corner vertices")
    _int32_indices(corners, "corners")
    n = len(corner_vert)
    cv = _read_only(np.ascontiguousarray(corner_vert, np.int32).reshape(n))
    tri = _read_only(np.ascontiguousarray(corners, np.int32).reshape(-1, 3))
    m = len(tri)
    if corner_uvs is None:
        uv_in, uv_out = np.zeros((0, 2), np.uint32), np.empty((0, 3, 2), np.uint32)
    else:
        uv_in = np.ascontiguousarray(corner_uvs, np.float32).reshape(-1, 2)
        if len(uv_in) != n:
            raise ValueError(f"{len(uv_in)} corner uvs for {n} corners")
        uv_in, uv_out = uv_in.view(np.uint32), with_room(m, (3, 2), np.float32, spare)
    tris = with_room(m, (3,), np.int32, spare)
    uv_in, uv_bits = _read_only(uv_in), uv_out.view(np.uint32)

    def gather(start: int, stop: int) -> bool:
        return _gather_corners(cv, tri, uv_in, tris, uv_bits, start, stop)

    if not all(Shared(gather, m, GATHER_CHUNK).result()):
        return None
    return tris, (None if corner_uvs is None else uv_out)


def _int32_indices(a, what: str) -> None:
    """Raise TypeError unless ``a``'s dtype casts to int32 without a loss (the dtype
    alone: no pass over the values)."""
    dtype = np.asarray(a).dtype
    if not np.can_cast(dtype, np.int32, "safe"):
        raise TypeError(f"gather_corners: {what} must be int32 (or a narrower integer "
                        f"type), not {dtype}")


@njit(cache=True, nogil=True)
def _gather_corners(corner_vert, corners, uvs, tris, uvs_out, start, stop):
    """:func:`gather_corners`' pass over triangles ``start .. stop - 1``: ``tris[t, j] =
    corner_vert[c]`` and, where ``uvs`` has rows, ``uvs_out[t, j] = uvs[c]`` (uint32 bits)
    for each corner ``c = corners[t, j]``; False at the first corner out of range (the
    outputs then partly written)."""
    n = corner_vert.shape[0]
    with_uvs = uvs.shape[0] > 0
    for t in range(start, stop):
        for j in range(3):
            c = corners[t, j]
            if c < 0 or c >= n:
                return False
            tris[t, j] = corner_vert[c]
            if with_uvs:
                uvs_out[t, j, 0] = uvs[c, 0]
                uvs_out[t, j, 1] = uvs[c, 1]
    return True
