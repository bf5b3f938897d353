"""Per-mesh geometry the scene model needs: which triangles have an area, smooth vertex
normals, flat triangle normals, the world box of a transformed object box (float64; the
area test and the flat normals kernels)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..cancel import Cancelled

#: Triangles tested per kernel call by :func:`proper_triangles`: ``cancel`` is polled
#: between chunks (a chunk takes a few milliseconds).
PROPER_CHUNK = 1 << 18


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
    v = np.asarray(verts)
    if not (v.dtype == np.float32 and v.flags.c_contiguous):
        v = np.ascontiguousarray(v, np.float64)
    t = np.ascontiguousarray(tris, np.int32)
    keep = np.empty(len(t), np.bool_)
    for start in range(0, len(t), PROPER_CHUNK):
        if cancel is not None and cancel():
            raise Cancelled
        _proper_kernel(v, t, start, min(start + PROPER_CHUNK, len(t)),
                       tol.DEGENERATE_AREA_REL, keep)
    return keep


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
