"""The scene model's meshes concatenated into the packing's geometry arrays, held once.

:func:`pack_meshes` concatenates every live mesh of a :class:`~.scene.Scene` (vertices,
triangles, the normal and uv rows of :mod:`.attributes`, material slots) and then makes
each mesh dict's arrays views of the concatenation: the scene model holds no second copy.
Mesh data are replaced, never mutated, so scenes sharing a mesh dict see the same values.

A mesh dict's triangles become the concatenation's (global vertex indices) with
``vert0``, the mesh's first vertex there: :func:`mesh_triangles` gives its own indices
back. Its material slots are one constant (``slot`` >= 0, no rows: the usual case, one
material for the whole mesh) or one row per triangle (``slot`` -1): the packing's
``mesh_slot[k]`` is ``(slot, bias)``, the slot of global triangle ``t`` the constant or
``tri_slot[bias + t]`` (:func:`~.attributes.slot_of`).

A dict checked from an ``owned`` Mesh (the add-on's export cache holds it) names it as
``source``: where its rows are that Mesh's own arrays (corner uvs or normals kept as
corners, vertex normals, slot rows, and the triangles of a mesh whose first vertex is the
packing's first), the packed rows are handed back to the Mesh (:func:`share_rows`), so
that the process holds those values once. The mesh with the most triangles has its
vertices first (:func:`_vertex_starts`), so that its triangles are among them.
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from .attributes import bias


def mesh_triangles(mesh: dict) -> np.ndarray:
    """A scene model mesh's triangles, (m, 3) int32 indices into its own vertices."""
    v0 = mesh.get("vert0", 0)
    return mesh["tris"] if v0 == 0 else mesh["tris"] - np.int32(v0)


def mesh_slots(mesh: dict) -> np.ndarray:
    """A scene model mesh's material slot per triangle, (m,) int32."""
    if mesh["slot"] >= 0:
        return np.full(len(mesh["tris"]), mesh["slot"], np.int32)
    return mesh["slots"]


def compact_slots(slots: np.ndarray) -> tuple[int, np.ndarray]:
    """``(slot, rows)`` of a mesh's (m,) int32 slots: one constant and no rows, or -1 and
    the slots."""
    if len(slots) and np.all(slots == slots[0]):
        return int(slots[0]), np.zeros(0, np.int32)
    return -1, slots


def texture_space(mesh: dict | None) -> np.ndarray:
    """``(lo, extent)`` of a mesh's automatic texture space, as Blender computes it (its
    bounding box; a flat axis gets half-size 1, a tiny one 1e-5), for Generated texture
    coordinates ``(p - lo) / extent`` in [0, 1]. A tombstone: the unit box."""
    if mesh is None:
        return np.array([[0.0] * 3, [1.0] * 3])
    lo, hi = np.asarray(mesh["lo"], np.float64), np.asarray(mesh["hi"], np.float64)
    mid, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    half = np.where(half == 0.0, 1.0, np.maximum(half, tol.TEXSPACE_HALF_MIN))
    return np.stack([mid - half, 2.0 * half])


#: (mesh dict field, :class:`~.elements.Mesh` attribute) whose packed rows are handed back
#: to the owned Mesh a dict was checked from, where they hold its very values
_SHARED = (("uvs", "corner_uvs"), ("normals", "corner_normals"),
           ("normals", "vertex_normals"), ("slots", "slots"), ("tris", "triangles"))


def _same_array(a, b) -> bool:
    """Whether ``a`` and ``b`` are the same memory: one start, dtype and size, both
    C-contiguous (a view of the other's whole buffer, e.g. reshaped)."""
    return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype
            and a.size == b.size and a.flags.c_contiguous and b.flags.c_contiguous
            and a.ctypes.data == b.ctypes.data)


def _to_share(m: dict, vert0: int) -> list:
    """The ``(field, attribute)`` of :data:`_SHARED` whose rows in mesh dict ``m``, before
    it is packed, are its source Mesh's own array (an ``owned`` mesh kept as given: nothing
    dropped, no coarser mode), so that the packing's copy holds the same bits; triangles
    only where the mesh's first vertex is the packing's first (``vert0`` 0: the packed
    indices are its own)."""
    src = m.get("source")
    if src is None:
        return []
    return [(f, a) for f, a in _SHARED if (f != "tris" or vert0 == 0)
            and _same_array(m[f], getattr(src, a))]


def _kept(src) -> dict:
    """The kept check's arrays of Mesh ``src`` (:func:`~.mesh_check.checked_mesh`), or an
    empty dict."""
    return src._checked[0] if src._checked is not None else {}


def share_rows(m: dict, shared: list) -> None:
    """Hand the packed rows of mesh dict ``m`` (views of the packing, after it) back to
    its source Mesh and to that Mesh's kept check, for the ``(field, attribute)`` pairs
    :func:`_to_share` chose: the Mesh's own copies (the same bits) are then freed, and the
    process holds those values once, in the packing (the add-on's export cache held them
    beside it: 145 MB of uvs and triangles at 4M triangles). Packed arrays are never
    changed; a later packing hands its own rows back in turn."""
    src = m["source"]
    kept = _kept(src)
    for f, a in shared:
        old = getattr(src, a)
        if _same_array(kept.get(f), old):
            kept[f] = m[f]
        setattr(src, a, m[f] if m[f].shape == old.shape else m[f].reshape(old.shape))


def _unpin_triangles(src) -> None:
    """An owned Mesh's triangles that an older packing handed back (a view of its whole
    ``tris``: :func:`share_rows`), not handed back by this one (the mesh's first vertex is
    no longer the packing's first), copied: the view would keep that packing's triangles of
    every mesh alive (12 bytes a triangle) beside this one's."""
    tris = src.triangles
    root = tris
    while isinstance(root.base, np.ndarray):
        root = root.base
    if root.nbytes > tris.nbytes:
        own = tris.copy()
        kept = _kept(src)
        if kept.get("tris") is tris:
            kept["tris"] = own
        src.triangles = own


def _vertex_starts(live: list) -> np.ndarray:
    """Where each live mesh's vertices start in the packing (``vert0``): the mesh with the
    most triangles first (the first of them on a tie), the others after it in their order.
    Its packed triangles are then its own (``vert0`` 0), which :func:`share_rows` hands
    back to an owned source Mesh: the largest mesh's triangles are held once (46 MB at 4M
    triangles). Only the vertices' order changes: the triangles, the rows and every
    mesh's range of triangles are the meshes' order, and each mesh's vertices stay one
    block in their own order, so everything read through the triangles is the same."""
    starts = np.zeros(len(live), np.int64)
    if not live:
        return starts
    first = max(range(len(live)), key=lambda k: (len(live[k]["tris"]), -k))
    at = len(live[first]["verts"])
    for k, m in enumerate(live):
        if k != first:
            starts[k] = at
            at += len(m["verts"])
    return starts


#: the row fields a packing may take over from the export (:func:`_adopted`): (mesh dict
#: field, :class:`~.elements.Mesh` attributes whose array it may be, packed dtype, width)
_ROWS = (("uvs", ("corner_uvs",), np.float32, 2),
         ("normals", ("corner_normals", "vertex_normals"), np.float32, 3),
         ("slots", ("slots",), np.int32, 1))


def _row_starts(live: list, field: str, first: int | None) -> np.ndarray:
    """Where each live mesh's ``field`` rows start in the packing: mesh ``first`` (if any)
    at row 0, the others after it in their order (else all in their order). Rows are read
    through each mesh's ``bias`` (:func:`~.attributes.bias`), so their order is free."""
    starts, at = np.zeros(len(live), np.int64), 0
    if first is not None:
        at = len(live[first][field])
    for k, m in enumerate(live):
        if k != first:
            starts[k] = at
            at += len(m[field])
    return starts


def _adoptable(m: dict, field: str, attrs: tuple) -> str | None:
    """The attribute of ``m``'s source Mesh (an ``owned`` one, the export's) whose array
    is ``m[field]``, when that array is the whole of its own buffer (so that nothing but
    its views can hold it: :func:`_adopted` proves there are none), else None."""
    src = m.get("source")
    rows = m[field]
    if src is None or len(rows) == 0:
        return None
    root = rows.base if isinstance(rows.base, np.ndarray) else rows
    if not (root.flags.owndata and root.flags.c_contiguous and root.nbytes == rows.nbytes):
        return None
    return next((a for a in attrs if _same_array(rows, getattr(src, a))), None)


def _adopted(m: dict, field: str, attr: str, total: int, dtype, width: int):
    """The packing's ``field`` rows (``total`` of ``width`` ``dtype`` values) made of the
    source Mesh's own array ``m[field]`` grown in place (``ndarray.resize``: ``realloc``,
    which moves a large buffer's pages without a copy), its rows first; None (nothing
    changed) where numpy refuses, i.e. where anything else refers to the buffer. The
    export wrote those rows into fresh memory once; the packing then writes only the
    other meshes' rows (at 4M triangles, 92 MB of uvs not written to new pages again).
    The mesh dict, the Mesh and its kept check are handed views of the grown array (the
    same bits: the packing's own rows, as :func:`share_rows` would hand them)."""
    src = m["source"]
    kept = _kept(src)
    rows = m[field]
    in_kept = _same_array(kept.get(field), rows)
    shape_attr, shape_m = getattr(src, attr).shape, rows.shape
    shape_kept = kept[field].shape if in_kept else None
    root = rows.base if isinstance(rows.base, np.ndarray) else rows
    row_bytes = np.dtype(dtype).itemsize * width
    if total * row_bytes == rows.nbytes:  # (its rows alone: the array itself, unchanged;
        # never resized to its own size, which numpy does in place without a check)
        return root.reshape(-1).view(dtype).reshape(total, width)
    if (total * row_bytes) % root.itemsize:
        return None
    # (only the buffer's owner may hold it while it is resized: the views are dropped
    # and made again from it afterwards, whether numpy resized it or refused)
    setattr(src, attr, None)
    m[field] = None
    if in_kept:
        kept[field] = None
    del rows
    try:
        root.resize((total * row_bytes // root.itemsize,), refcheck=True)
        grown = True
    except ValueError:  # (something else refers to it: the packing copies instead)
        root = root.reshape(-1)
        grown = False
    flat = root.view(dtype)
    n_own = int(np.prod(shape_m)) // width
    own = flat[:n_own * width]
    setattr(src, attr, own.reshape(shape_attr))
    m[field] = own.reshape(shape_m)
    if in_kept:
        kept[field] = own.reshape(shape_kept)
    return flat.reshape(total, width) if grown else None


def pack_meshes(meshes: list) -> dict:
    """The packing's geometry fields of ``meshes`` (mesh dicts, None for a tombstoned slot,
    which owns no vertices and no triangles: ``mesh_tri_start[k] == mesh_tri_start[k +
    1]``); every live mesh dict's arrays become views of them (module docstring)."""
    live = [m for m in meshes if m is not None]
    ids = [k for k, m in enumerate(meshes) if m is not None]

    nt = np.cumsum([0] + [len(m["tris"]) for m in live])
    nv = _vertex_starts(live)
    tstart = np.cumsum([0] + [0 if m is None else len(m["tris"])
                              for m in meshes]).astype(np.int32)
    shared = [_to_share(m, int(nv[k])) for k, m in enumerate(live)]
    packed = dict(
        verts=np.empty((sum(len(m["verts"]) for m in live), 3)),
        tris=np.empty((nt[-1], 3), np.int32), mesh_nrm=np.zeros((len(meshes), 2), np.int64),
        mesh_uv=np.zeros((len(meshes), 2), np.int64),
        mesh_slot=np.zeros((len(meshes), 2), np.int64))
    # the rows: the largest owned mesh's own array grown in place where it can be (its
    # rows first), else a fresh array; the other meshes' rows copied after it
    row0, taken = {}, {}
    for field, attrs, dtype, width in _ROWS:
        total = sum(len(m[field]) for m in live)
        cand = [(len(m[field]), -k, k, a) for k, m in enumerate(live)
                if (a := _adoptable(m, field, attrs)) is not None]
        first, rows = None, None
        if cand:
            _, _, first, attr = max(cand)
            rows = _adopted(live[first], field, attr, total, dtype, width)
        if rows is None:
            first = None
            rows = np.empty((total, width) if width > 1 else (total,), dtype)
        elif width == 1:
            rows = rows.reshape(total)
        packed["tri_slot" if field == "slots" else field] = rows
        row0[field], taken[field] = _row_starts(live, field, first), first
    nn, nu, ns = row0["normals"], row0["uvs"], row0["slots"]
    for k, m in enumerate(live):
        v, t = slice(nv[k], nv[k] + len(m["verts"])), slice(nt[k], nt[k + 1])
        packed["verts"][v] = m["verts"]
        np.add(m["tris"], np.int32(nv[k] - m.get("vert0", 0)), out=packed["tris"][t])
        for field, _, _, _ in _ROWS:
            if taken[field] != k:  # (the adopted rows are in place already)
                at = row0[field][k]
                packed["tri_slot" if field == "slots" else field][
                    at:at + len(m[field])] = m[field]
        packed["mesh_nrm"][ids[k]] = m["nmode"], bias(m["nmode"], nn[k], nv[k], nt[k])
        packed["mesh_uv"][ids[k]] = m["uvmode"], bias(m["uvmode"], nu[k], nv[k], nt[k])
        packed["mesh_slot"][ids[k]] = m["slot"], ns[k] - nt[k]
    for k, m in enumerate(live):  # (after every copy: a mesh may be in the scene twice)
        v, t = slice(nv[k], nv[k] + len(m["verts"])), slice(nt[k], nt[k + 1])
        rn = slice(nn[k], nn[k] + len(m["normals"]))
        ru, rs = slice(nu[k], nu[k] + len(m["uvs"])), slice(ns[k], ns[k] + len(m["slots"]))
        m.update(verts=packed["verts"][v], tris=packed["tris"][t], vert0=int(nv[k]),
                 normals=packed["normals"][rn], uvs=packed["uvs"][ru],
                 slots=packed["tri_slot"][rs])
        if shared[k]:
            share_rows(m, shared[k])
    handed = {id(m["source"]) for k, m in enumerate(live) if ("tris", "triangles") in shared[k]}
    for m in live:
        if m.get("source") is not None and id(m["source"]) not in handed:
            _unpin_triangles(m["source"])
    packed["mesh_tri_start"] = tstart
    packed["mesh_gen"] = np.stack([texture_space(m) for m in meshes]).reshape(-1, 2, 3)
    return packed
