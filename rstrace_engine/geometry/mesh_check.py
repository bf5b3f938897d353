"""A :class:`~.elements.Mesh` validated into the scene model's compact mesh dict.

:func:`checked_mesh` checks a host's mesh (shapes, finite values, index range, the
coordinate limit), drops degenerate triangles and stores its corner attributes in their
coarsest exact mode (:mod:`.attributes`). The checks are kernel passes over the arrays as
given (no (m, 3, 3) temporaries); the arrays are copied only where the caller may still
change them: a mesh given with ``owned=True`` (the add-on's exports, fresh arrays it never
changes) is kept as it is where its dtype is already the stored one, and its validation is
kept with it, so a later scene adding the same :class:`~.elements.Mesh` object (a new
session over the add-on's export cache) takes its checked arrays without checking them
again (a mesh dict of its own: scenes of different sessions share no dict, and the kept
result holds only the Mesh's own arrays and its compact rows, no packing and no float64
vertices). An owned mesh's dict holds its vertices as given (float32 from the add-on)
until the packing converts them into its own float64 array: the checks read float32
vertices as they are (their kernels convert each value where they read it: no float64 copy
of a mesh's size), and a kept result is taken with no conversion at all.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..beside import Beside
from ..errors import SceneError
from .attributes import ATTR_NONE, ATTR_VERTEX, compact_normals, compact_uvs, vertex_rows
from .mesh_math import start_proper_triangles, vertex_normals
from .packing import compact_slots


@njit(cache=True, nogil=True, error_model="numpy")
def _vertex_stats(v):
    """``(non_finite, max_abs, lo, hi)`` of vertices ``v`` (n, 3) float64 (or float32,
    each value read as float64) in one pass: the largest magnitude of the finite values and
    the box of the finite values per axis (``lo`` (3,) ``inf`` and ``hi`` ``-inf`` where
    an axis has none)."""
    bad = 0
    big = 0.0
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(v.shape[0]):
        for q in range(3):
            x = np.float64(v[i, q])
            if not np.isfinite(x):
                bad += 1
                continue
            if abs(x) > big:
                big = abs(x)
            if x < lo[q]:
                lo[q] = x
            if x > hi[q]:
                hi[q] = x
    return bad, big, lo, hi


@njit(cache=True, nogil=True, error_model="numpy")
def _non_finite32(a):
    """How many of the float32 values ``a`` (1-d) are NaN or infinite."""
    bad = 0
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            bad += 1
    return bad


@njit(cache=True, nogil=True, error_model="numpy")
def _index_range(t):
    """``(min, max)`` of the int32 indices ``t`` (1-d, not empty) in one pass."""
    lo = t[0]
    hi = t[0]
    for i in range(t.shape[0]):
        x = t[i]
        if x < lo:
            lo = x
        elif x > hi:
            hi = x
    return lo, hi


def _rows(name: str, what: str, value, tail: tuple, dtype, keep: bool) -> np.ndarray:
    """``value`` as an ``(n, *tail)`` array of ``dtype``, checked finite; a copy unless
    ``keep`` (the caller hands it over) and it is already a C-contiguous ``dtype`` array."""
    try:
        arr = np.asarray(value, dtype=dtype) if keep else np.array(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{what} '{name}': cannot read as numbers ({exc})") from None
    if arr.ndim != len(tail) + 1 or arr.shape[1:] != tail:
        raise SceneError(f"{what} '{name}': expected shape (n, {', '.join(map(str, tail))}),"
                         f" got {arr.shape}")
    arr = np.ascontiguousarray(arr)
    flat = arr.reshape(-1)
    bad = (_non_finite32(flat) if arr.dtype == np.float32
           else int(np.count_nonzero(~np.isfinite(flat))))
    if bad:
        raise SceneError(f"{what} '{name}': {bad} NaN or infinite value(s)")
    return arr


def _vertices(name: str, value, keep: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh's vertices as (n, 3) float64 (a copy unless handed over as float64; handed
    over as C-contiguous float32 -- the add-on's -- they are checked as they are, no float64
    copy: the checks' kernels read each value as float64) and their box, checked finite and
    within :data:`~.tolerances.COORD_MAX`."""
    try:
        arr = np.asarray(value) if keep else None
        if arr is None or not (arr.dtype == np.float32 and arr.flags.c_contiguous):
            arr = np.asarray(value, np.float64) if keep else np.array(value, np.float64)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"mesh '{name}': cannot read as numbers ({exc})") from None
    if arr.ndim != 2 or arr.shape[1:] != (3,):
        raise SceneError(f"mesh '{name}': expected shape (n, 3), got {arr.shape}")
    arr = np.ascontiguousarray(arr)
    if arr.shape[0] == 0:
        raise SceneError(f"mesh '{name}': has no triangles")
    bad, big, lo, hi = _vertex_stats(arr)
    if bad:
        raise SceneError(f"mesh '{name}': {bad} NaN or infinite value(s)")
    if big > tol.COORD_MAX:
        raise SceneError(f"mesh '{name}': vertex coordinates exceed {tol.COORD_MAX:g}")
    if not (np.all(lo) and np.all(hi)):
        # a zero bound: which of two signed zeros numpy's min and max keep is theirs (the
        # box the scene has always had), so they decide it (two more passes over float64
        # values, only here)
        a64 = np.asarray(arr, np.float64)
        return arr, a64.min(axis=0), a64.max(axis=0)
    return arr, lo, hi


def _as64(verts: np.ndarray) -> np.ndarray:
    """``verts`` as float64 (the kernels of normals read float64 vertices)."""
    return np.ascontiguousarray(verts, np.float64)


def _triangles(name: str, value, nverts: int, keep: bool) -> np.ndarray:
    tris = np.asarray(value)
    if tris.size == 0:
        raise SceneError(f"mesh '{name}': has no triangles")
    if tris.ndim != 2 or tris.shape[1] != 3 or tris.dtype.kind not in "iu":
        raise SceneError(f"mesh '{name}': triangles must be (m, 3) integers, got "
                         f"{tris.shape} {tris.dtype}")
    if tris.dtype == np.int32:
        tris = np.ascontiguousarray(tris)
        lo, hi = _index_range(tris.reshape(-1))
    else:
        lo, hi = tris.min(), tris.max()
    if lo < 0 or hi >= nverts:
        raise SceneError(f"mesh '{name}': triangle index out of range [0, {nverts})")
    if keep and tris.dtype == np.int32:
        return tris
    return np.array(tris, np.int32)  # a copy: the caller may change its array later


def _attribute_rows(n: str, mesh, m: int, nverts: int, keep: bool) -> tuple:
    """``(normals, uvs, vertex normals, slots)`` of ``mesh`` (``m`` triangles, ``nverts``
    vertices) as arrays of their stored dtypes, checked (shapes, counts, finite values,
    slots not negative); None where it has none."""
    cn, cu, vn = mesh.corner_normals, mesh.corner_uvs, mesh.vertex_normals
    if cn is not None and vn is not None:
        raise SceneError(f"mesh '{n}': give corner normals or vertex normals, not both")
    normals = None if cn is None else _rows(n, "mesh normals", cn, (3, 3), np.float32, keep)
    uvs = None if cu is None else _rows(n, "mesh uvs", cu, (3, 2), np.float32, keep)
    if vn is not None:
        vn = _rows(n, "mesh vertex normals", vn, (3,), np.float32, keep)
        if len(vn) != nverts:
            raise SceneError(f"mesh '{n}': {len(vn)} vertex normals for {nverts} "
                             f"vertices")
    for what, a in (("corner normal", normals), ("corner uv", uvs)):
        if a is not None and len(a) != m:
            raise SceneError(f"mesh '{n}': {len(a)} {what} triples for {m} triangles")
    slots = None
    if mesh.slots is not None:
        slots = (np.asarray if keep else np.array)(mesh.slots, dtype=np.int32).reshape(-1)
        if len(slots) != m or (m and slots.min() < 0):
            raise SceneError(f"mesh '{n}': material slots must be {m} non-negative ints")
    return normals, uvs, vn, slots


def _stored_vertices(given) -> np.ndarray:
    """The vertices an ``owned`` mesh's dict holds until the packing: the given (n, 3)
    array itself where it is a C-contiguous float32 or float64 array (the packing converts
    float32 to float64 once, as it copies them into its own array: no float64 copy of a
    mesh's size is made beside it), else a float64 copy. The caller checked them."""
    arr = np.asarray(given)
    if arr.dtype in (np.float32, np.float64) and arr.flags.c_contiguous:
        return arr
    return np.ascontiguousarray(arr, np.float64)


#: Triangles from which a mesh's checks run on two threads (:func:`checked_mesh`)
BESIDE_TRIANGLES = 1 << 16


def _large(mesh) -> bool:
    """Whether ``mesh``'s checks run on two threads: arrays of vertices and triangles
    (not lists: their length is known before they are read), :data:`BESIDE_TRIANGLES`
    triangles or more."""
    v, t = mesh.vertices, mesh.triangles
    return (isinstance(v, np.ndarray) and isinstance(t, np.ndarray) and v.ndim == 2
            and t.ndim == 2 and len(t) >= BESIDE_TRIANGLES)


def _vertices_and_triangles(n: str, mesh, keep: bool):
    """``(verts, lo, hi, tris)``: :func:`_vertices` and :func:`_triangles`, the vertices'
    pass beside the triangles' for a large mesh; a vertex error is raised before a
    triangle error, as when they ran one after the other."""
    if not _large(mesh):
        verts, lo, hi = _vertices(n, mesh.vertices, keep)
        return verts, lo, hi, _triangles(n, mesh.triangles, len(verts), keep)
    job = Beside(_vertices, n, mesh.vertices, keep)
    try:
        tris = _triangles(n, mesh.triangles, len(mesh.vertices), keep)
    except BaseException:
        job.result()  # (raises a vertex error first)
        raise
    verts, lo, hi = job.result()
    return verts, lo, hi, tris


def _attributes(verts, tris, normals, vn, uvs, slots, smooth: bool) -> tuple:
    """``(nmode, normals, uvmode, uvs, slot, slots)``: a checked mesh's rows in their
    coarsest exact modes (:mod:`.attributes`) for its kept triangles ``tris``."""
    if normals is not None:
        nmode, normals = compact_normals(_as64(verts), tris, normals)
    elif vn is not None:  # (the same mode and rows the corners vn[tris] would give)
        nmode, normals = vertex_rows(_as64(verts), tris, vn)
    elif smooth:  # (the vertex normals' float32 rows: what every corner reads)
        nmode, normals = ATTR_VERTEX, vertex_normals(_as64(verts), tris).astype(np.float32)
    else:  # flat: each corner reads its triangle's own normal, computed
        nmode, normals = ATTR_NONE, np.zeros((0, 3), np.float32)
    uvmode, uvs = compact_uvs(tris, len(verts), uvs)
    slot, slots = (0, np.zeros(0, np.int32)) if slots is None else compact_slots(slots)
    return nmode, normals, uvmode, uvs, slot, slots


def checked_mesh(mesh, cancel=None, dropped_fn=None) -> dict:
    """``mesh`` (a :class:`~.elements.Mesh`) validated (errors name it,
    :class:`SceneError`) into the scene model's mesh dict; ``dropped_fn(count)`` is called
    with the number of degenerate triangles dropped, when there are any (before a mesh
    with nothing else left is refused). ``cancel``: a ``() -> bool`` polled by the area
    test. A mesh given with ``owned=True`` keeps its result: the same Mesh object checked
    again gives a mesh dict of its own, with the same arrays, without a check (module
    docstring).

    A large mesh (:data:`BESIDE_TRIANGLES`) is checked on two threads
    (:class:`~rstrace_engine.beside.Beside`): the vertices' pass beside the triangles'
    index range, then the area test's chunks on the pool thread while this one checks the
    attributes and computes their modes for every triangle (those of the kept triangles
    instead where the area test drops some, the rare case), then on both
    (:class:`~rstrace_engine.beside.Shared`). The same results and the same first error
    as one thread: the checks that ran first on one thread are raised first."""
    keep = bool(getattr(mesh, "owned", False))
    if keep and mesh._checked is not None:
        kept, dropped = mesh._checked
        if dropped and dropped_fn is not None:
            dropped_fn(dropped)
        return dict(kept, verts=_stored_vertices(mesh.vertices), source=mesh)
    n = mesh.name
    verts, lo, hi, tris = _vertices_and_triangles(n, mesh, keep)
    m = len(tris)
    # (the area test reads checked vertices and triangles only; a large mesh's chunks are
    # taken by the pool thread now, and by this one once its attributes are done)
    area = start_proper_triangles(verts, tris, cancel, shared=_large(mesh))
    try:
        normals, uvs, vn, slots = _attribute_rows(n, mesh, m, len(verts), keep)
        ahead = (_attributes(verts, tris, normals, vn, uvs, slots, mesh.smooth)
                 if area.started else None)
    except BaseException:
        area.drop()
        raise
    keep_tris = area.result()
    dropped = int(m - np.count_nonzero(keep_tris))
    if dropped and dropped_fn is not None:
        dropped_fn(dropped)
    if dropped == m:
        raise SceneError(f"mesh '{n}': all {m} triangles are degenerate (zero area)")
    if dropped:  # (not the usual case: otherwise no gather, no copy)
        tris, normals, uvs, slots = (None if a is None else a[keep_tris]
                                     for a in (tris, normals, uvs, slots))
    if dropped or ahead is None:
        ahead = _attributes(verts, tris, normals, vn, uvs, slots, mesh.smooth)
    nmode, normals, uvmode, uvs, slot, slots = ahead
    if keep:  # (float32 checked as given, or a float64 copy for the checks: the packing
        verts = _stored_vertices(mesh.vertices)  # converts them itself)
    out = dict(name=n, verts=verts, tris=tris, normals=normals, nmode=nmode, uvs=uvs,
               uvmode=uvmode, slots=slots, slot=slot, lo=lo, hi=hi)
    if keep:  # (the arrays before packing: the Mesh's own, or compact rows; each scene
        # gets its own dict, whose arrays its packing replaces by views of itself)
        mesh._checked = (dict(out, verts=None), dropped)
        out["source"] = mesh  # (the packing hands its rows back: packing.share_rows)
    return out
