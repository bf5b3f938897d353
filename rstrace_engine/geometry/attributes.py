"""Per-corner attributes (shading normals, uvs) held only as finely as a mesh needs them.

A mesh's corner normals and corner uvs (float32, ``(m, 3, 3)`` and ``(m, 3, 2)`` as given)
are stored in one of four *modes*, the coarsest whose rows give every corner its value
bit for bit (:func:`compact_normals`, :func:`compact_uvs`):

* :data:`ATTR_NONE`: no rows. Normals: the triangle's own flat normal, computed where it is
  read (:func:`~.mesh_math.flat_normal32`, the float32 rounding of the float64 unit cross
  product: what a flat-shaded mesh's corners hold); uvs: all zero.
* :data:`ATTR_VERTEX`: one row per vertex (a smooth mesh without split normals, uvs without
  seams): corner ``j`` of triangle ``t`` reads row ``tris[t, j]``.
* :data:`ATTR_FACE`: one row per triangle (three equal corners).
* :data:`ATTR_CORNER`: one row per corner, as given.

A smooth 1M-triangle mesh (~0.5 vertices a triangle) then holds 6 bytes of normals a
triangle instead of 36, a flat one none, and a mesh without uvs none instead of 24.

In the packing (:class:`~.scene.SceneArrays`) every mesh's rows are concatenated
(``normals`` (N, 3), ``uvs`` (U, 2) float32) and mesh ``k`` has ``(mode, bias)`` in
``mesh_nrm[k]`` / ``mesh_uv[k]``: the row of corner ``j`` of global triangle ``t`` is
``bias + tris[t, j]`` (VERTEX, global vertex indices), ``bias + t`` (FACE) or ``bias + 3 t +
j`` (CORNER). The kernels read a corner through :func:`corner_normals` /
:func:`corner_uvs`: the same float32 values as the per-corner arrays held before, so the
same float64 arithmetic on them, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .mesh_math import flat_normal32, flat_triangle_normals

ATTR_NONE = 0
ATTR_VERTEX = 1
ATTR_FACE = 2
ATTR_CORNER = 3
MODE_NAMES = {ATTR_NONE: "none", ATTR_VERTEX: "vertex", ATTR_FACE: "face",
              ATTR_CORNER: "corner"}


# -- kernels: reading a corner ---------------------------------------------------------


@njit(cache=True, nogil=True)
def _rows(mode, bias, tris, tri):
    """Rows of the three corners of global triangle ``tri`` (not for ATTR_NONE)."""
    if mode == ATTR_VERTEX:
        return bias + tris[tri, 0], bias + tris[tri, 1], bias + tris[tri, 2]
    if mode == ATTR_FACE:
        r = bias + tri
        return r, r, r
    r = bias + 3 * tri
    return r, r + 1, r + 2


@njit(cache=True, nogil=True)
def corner_normals(s, k, tri):
    """The three corners' shading normals of global triangle ``tri`` of mesh ``k``, as
    float64 (their float32 values), ``(x0, y0, z0, x1, y1, z1, x2, y2, z2)``. ``s``: a
    struct with ``normals``, ``mesh_nrm``, ``verts`` and ``tris``
    (:class:`~.scene.SceneArrays` or a view of it)."""
    mode = s.mesh_nrm[k, 0]
    if mode == ATTR_NONE:
        x, y, z = flat_normal32(s.verts, s.tris, tri)
        return x, y, z, x, y, z, x, y, z
    r0, r1, r2 = _rows(mode, s.mesh_nrm[k, 1], s.tris, tri)
    n = s.normals
    return (np.float64(n[r0, 0]), np.float64(n[r0, 1]), np.float64(n[r0, 2]),
            np.float64(n[r1, 0]), np.float64(n[r1, 1]), np.float64(n[r1, 2]),
            np.float64(n[r2, 0]), np.float64(n[r2, 1]), np.float64(n[r2, 2]))


@njit(cache=True, nogil=True)
def corner_uvs(s, k, tri):
    """The three corners' uvs of global triangle ``tri`` of mesh ``k``, as float64
    ``(u0, v0, u1, v1, u2, v2)``. ``s``: a struct with ``uvs``, ``mesh_uv`` and ``tris``."""
    mode = s.mesh_uv[k, 0]
    if mode == ATTR_NONE:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    r0, r1, r2 = _rows(mode, s.mesh_uv[k, 1], s.tris, tri)
    u = s.uvs
    return (np.float64(u[r0, 0]), np.float64(u[r0, 1]), np.float64(u[r1, 0]),
            np.float64(u[r1, 1]), np.float64(u[r2, 0]), np.float64(u[r2, 1]))


@njit(cache=True, nogil=True)
def slot_of(s, k, tri):
    """Material slot of global triangle ``tri`` of mesh ``k`` (``s``: a struct with
    ``mesh_slot`` and ``tri_slot``, :mod:`.packing`)."""
    c = s.mesh_slot[k, 0]
    if c >= 0:
        return c
    return s.tri_slot[s.mesh_slot[k, 1] + tri]


def slots_of(sa, meshes: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(n,) int64: :func:`slot_of` over arrays of mesh ids and global triangles."""
    meshes = np.asarray(meshes, np.int64)
    out = sa.mesh_slot[meshes, 0].copy()
    rows = np.flatnonzero(out < 0)
    out[rows] = sa.tri_slot[sa.mesh_slot[meshes[rows], 1] + np.asarray(tris, np.int64)[rows]]
    return out


# -- kernels: choosing the mode --------------------------------------------------------


@njit(cache=True, nogil=True)
def _coarsest(tris, bits, nverts):
    """``(mode, rows)`` for corner values ``bits`` (m, 3, c) uint32 (their bit patterns):
    VERTEX and one row per vertex (zero where no corner names it) when every corner of a
    vertex holds the same bits, else FACE and one row per triangle when its three corners
    do, else CORNER and no rows (the corners are the rows). A vertex's row is written when
    a corner first names it and the rows no corner names are zeroed at the end, only for a
    VERTEX answer: no zero-fill of the rows first (fresh memory of a mesh's vertices, most
    of it never read where a seam ends the pass early, as on a mesh with uv seams)."""
    m, c = bits.shape[0], bits.shape[2]
    rows = np.empty((nverts, c), np.uint32)
    seen = np.zeros(nverts, np.bool_)
    ok = True
    for t in range(m):
        for j in range(3):
            v = tris[t, j]
            if seen[v]:
                for q in range(c):
                    if rows[v, q] != bits[t, j, q]:
                        ok = False
            else:
                seen[v] = True
                for q in range(c):
                    rows[v, q] = bits[t, j, q]
        if not ok:
            break
    if ok:
        for v in range(nverts):
            if not seen[v]:
                for q in range(c):
                    rows[v, q] = np.uint32(0)
        return ATTR_VERTEX, rows
    rows = np.empty((m, c), np.uint32)
    for t in range(m):
        for q in range(c):
            b = bits[t, 0, q]
            if bits[t, 1, q] != b or bits[t, 2, q] != b:
                return ATTR_CORNER, np.zeros((0, c), np.uint32)
            rows[t, q] = b
    return ATTR_FACE, rows


@njit(cache=True, nogil=True)
def _same32(a, b):
    """float32 ``a`` and float64 ``b`` (a float32 value) hold the same bits (signed zeros
    told apart; NaN never)."""
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


@njit(cache=True, nogil=True)
def _all_flat(verts, tris, corners):
    """Every corner normal is its triangle's :func:`~.mesh_math.flat_normal32`, bit for bit."""
    for t in range(tris.shape[0]):
        x, y, z = flat_normal32(verts, tris, t)
        for j in range(3):
            if not (_same32(corners[t, j, 0], x) and _same32(corners[t, j, 1], y)
                    and _same32(corners[t, j, 2], z)):
                return False
    return True


@njit(cache=True, nogil=True)
def _all_flat_vertex(verts, tris, rows):
    """:func:`_all_flat` of the corners ``rows[tris]`` (per-vertex rows), not gathered."""
    for t in range(tris.shape[0]):
        x, y, z = flat_normal32(verts, tris, t)
        for j in range(3):
            r = tris[t, j]
            if not (_same32(rows[r, 0], x) and _same32(rows[r, 1], y)
                    and _same32(rows[r, 2], z)):
                return False
    return True


def vertex_rows(verts: np.ndarray, tris: np.ndarray,
                rows: np.ndarray) -> tuple[int, np.ndarray]:
    """``(mode, rows)`` of per-vertex normals ``rows`` (V, 3) float32: what
    :func:`compact_normals` gives for the corners ``rows[tris]`` without gathering them
    (NONE where every corner is its triangle's flat normal, else VERTEX and ``rows``
    themselves; rows no triangle names are never read)."""
    rows = np.ascontiguousarray(rows, np.float32)
    if _all_flat_vertex(verts, tris, rows):
        return ATTR_NONE, np.zeros((0, 3), np.float32)
    return ATTR_VERTEX, rows


def _compact(tris: np.ndarray, nverts: int, corners: np.ndarray) -> tuple[int, np.ndarray]:
    """VERTEX, FACE or CORNER rows of ``corners`` (m, 3, c) float32, the coarsest exact."""
    corners = np.ascontiguousarray(corners, np.float32)
    mode, rows = _coarsest(tris, corners.view(np.uint32), nverts)
    if mode == ATTR_CORNER:
        return ATTR_CORNER, corners.reshape(-1, corners.shape[2])
    return int(mode), rows.view(np.float32)


def compact_normals(verts: np.ndarray, tris: np.ndarray,
                    corners: np.ndarray) -> tuple[int, np.ndarray]:
    """``(mode, rows)`` of a mesh's corner normals ``corners`` (m, 3, 3) float32: NONE where
    every corner holds its triangle's flat normal (``verts`` (V, 3) float64, ``tris`` (m, 3)
    int32 the mesh's own), else the coarsest of VERTEX, FACE, CORNER that is exact."""
    corners = np.ascontiguousarray(corners, np.float32)
    if _all_flat(verts, tris, corners):
        return ATTR_NONE, np.zeros((0, 3), np.float32)
    return _compact(tris, len(verts), corners)


def compact_uvs(tris: np.ndarray, nverts: int, corners) -> tuple[int, np.ndarray]:
    """``(mode, rows)`` of a mesh's corner uvs (m, 3, 2) float32 or None: NONE where there
    are none or every bit is zero, else the coarsest of VERTEX, FACE, CORNER that is exact."""
    if corners is None or not _any_bit(corners):
        return ATTR_NONE, np.zeros((0, 2), np.float32)
    return _compact(tris, nverts, corners)


#: Words :func:`_any_bit` looks at first
HEAD_WORDS = 1 << 12


def _any_bit(a) -> bool:
    """Whether any bit of the array ``a`` is set: its first :data:`HEAD_WORDS` 32-bit
    words first, the rest only where those are all zero (a mesh's uvs hold a non-zero
    value at once: no pass over all of them, 0.05 s at 4M triangles)."""
    words = np.ascontiguousarray(a).reshape(-1).view(np.uint32)
    return bool(words[:HEAD_WORDS].any() or words[HEAD_WORDS:].any())


# -- host: the per-corner arrays back ----------------------------------------------------


def expand(mode: int, rows: np.ndarray, tris: np.ndarray, verts: np.ndarray | None,
           width: int) -> np.ndarray:
    """The per-corner array ``(m, 3, width)`` float32 that ``(mode, rows)`` holds for the
    triangles ``tris`` (indices into ``verts`` and, for VERTEX, into ``rows``; ``verts``
    is needed for NONE normals). FACE and CORNER rows start at the first of ``tris``."""
    m = len(tris)
    if mode == ATTR_NONE:
        out = np.zeros((m, 3, width), np.float32)
        if width == 3:
            flat_triangle_normals(np.ascontiguousarray(verts, np.float64),
                                  np.ascontiguousarray(tris, np.int32), out)
        return out
    if mode == ATTR_VERTEX:
        return rows[tris]
    if mode == ATTR_FACE:
        return np.repeat(rows[:m, None, :], 3, axis=1)
    return rows[:3 * m].reshape(m, 3, width).copy()


def mesh_corners(mesh: dict, which: str) -> np.ndarray | None:
    """A scene model mesh's ``(m, 3, 3)`` corner normals (``which="normals"``) or ``(m, 3,
    2)`` corner uvs (``"uvs"``, None where it has none), float32, as given to it."""
    tris = mesh["tris"] - np.int32(mesh.get("vert0", 0))  # its own vertex indices
    if which == "normals":
        return expand(mesh["nmode"], mesh["normals"], tris, mesh["verts"], 3)
    if mesh["uvmode"] == ATTR_NONE:
        return None
    return expand(mesh["uvmode"], mesh["uvs"], tris, None, 2)


def scene_corners(sa, which: str) -> np.ndarray:
    """``(T, 3, 3)`` corner normals (``which="normals"``) or ``(T, 3, 2)`` corner uvs
    (``"uvs"``) of every triangle of the packing ``sa``, float32 (host code: the mesh
    topology's edge pass, exports)."""
    table, modes, width = ((sa.normals, sa.mesh_nrm, 3) if which == "normals"
                           else (sa.uvs, sa.mesh_uv, 2))
    out = np.empty((len(sa.tris), 3, width), np.float32)
    for k in range(len(sa.mesh_tri_start) - 1):
        t0, t1 = int(sa.mesh_tri_start[k]), int(sa.mesh_tri_start[k + 1])
        if t1 == t0:
            continue
        mode, bias = int(modes[k, 0]), int(modes[k, 1])
        tris = sa.tris[t0:t1]
        if mode == ATTR_VERTEX:
            out[t0:t1] = table[bias + tris]
        elif mode == ATTR_FACE:
            out[t0:t1] = table[bias + t0:bias + t1][:, None, :]
        elif mode == ATTR_CORNER:
            out[t0:t1] = table[bias + 3 * t0:bias + 3 * t1].reshape(-1, 3, width)
        else:
            out[t0:t1] = expand(ATTR_NONE, table, tris, sa.verts, width)
    return out


def bias(mode: int, row0: int, vert0: int, tri0: int) -> int:
    """The packing's ``bias`` of a mesh whose rows start at ``row0``, vertices at ``vert0``
    and triangles at ``tri0`` in the concatenation."""
    return {ATTR_NONE: 0, ATTR_VERTEX: row0 - vert0, ATTR_FACE: row0 - tri0,
            ATTR_CORNER: row0 - 3 * tri0}[mode]
