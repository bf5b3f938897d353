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
vertices first (:func:`_vertex_starts`), so that its triangles are among them. Where that
mesh's triangles and uvs were gathered with room around them (the add-on's large meshes:
``mesh_math.with_room``), the packing claims the room and writes the other meshes' rows
there, beside them, instead of copying them (:func:`_in_place`).
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from ..beside import Beside
from .attributes import bias
from .mesh_math import claim_room, has_room


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
    if root.nbytes > tris.nbytes and not has_room(tris):  # (unclaimed room: its own)
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
    first = _largest(live)
    at = len(live[first]["verts"])
    for k, m in enumerate(live):
        if k != first:
            starts[k] = at
            at += len(m["verts"])
    return starts


def _largest(live: list) -> int:
    """The live mesh with the most triangles (the first of them on a tie)."""
    return max(range(len(live)), key=lambda k: (len(live[k]["tris"]), -k))


def _in_place(live: list, nv, starts: dict) -> tuple[int, dict]:
    """``(k, {field: packed array})``: the packing's arrays (``tris``, ``uvs``) laid in
    the room around the rows of the largest live mesh ``k`` (:func:`~.mesh_check`'s dict
    of an owned Mesh: the add-on's, whose gathers leave room, ``mesh_math.with_room``),
    where it has that room and no one claimed it (``mesh_math.claim_room``): its rows
    are then already the packing's (its triangles where its first vertex is the
    packing's first, as the largest mesh's is), and only the other meshes' rows are
    written, beside them. The largest mesh's rows are no longer copied (36 MB of fresh
    memory at 1M triangles: ``docs/bench-scale-bpy.md``, session 37). ``starts``: field
    -> the rows' starts per live mesh (their cumulative sums)."""
    if not live:
        return -1, {}
    k = _largest(live)
    m = live[k]
    if m.get("source") is None:
        return k, {}
    out = {}
    for f in ("tris", "uvs"):
        at = starts[f]
        if len(m[f]) == 0 or (f == "tris" and nv[k] != m.get("vert0", 0)):
            continue
        room = claim_room(m[f], int(at[k]), int(at[-1] - at[k + 1]))
        if room is not None:
            out[f] = room
    return k, out


#: Rows from which the packing writes a mesh's rows in two halves on two threads
BESIDE_ROWS = 1 << 16


def _in_halves(fn, n: int) -> None:
    """``fn(0, h)`` here and ``fn(h, n)`` beside (:class:`~rstrace_engine.beside.Beside`)
    from :data:`BESIDE_ROWS` rows; ``fn(0, n)`` below. ``fn`` writes rows ``[a, b)`` with
    a numpy copy or cast, which releases the GIL: the same values, the fresh memory's
    first touch (most of a large mesh's packing: its float64 vertices) on two cores."""
    if n < BESIDE_ROWS:
        fn(0, n)
        return
    h = n // 2
    job = Beside(fn, h, n)
    try:
        fn(0, h)
    except BaseException:
        job.drop()
        raise
    job.result()


def _copy(dst: np.ndarray, src: np.ndarray, add=None) -> None:
    """``dst[:] = src`` (``src + add`` where ``add``: an int32 offset), in halves
    (:func:`_in_halves`)."""
    def rows(a: int, b: int) -> None:
        if add is None:
            np.copyto(dst[a:b], src[a:b], casting="unsafe")
        else:
            np.add(src[a:b], add, out=dst[a:b])

    _in_halves(rows, len(src))


def pack_meshes(meshes: list) -> dict:
    """The packing's geometry fields of ``meshes`` (mesh dicts, None for a tombstoned slot,
    which owns no vertices and no triangles: ``mesh_tri_start[k] == mesh_tri_start[k +
    1]``); every live mesh dict's arrays become views of them (module docstring)."""
    live = [m for m in meshes if m is not None]
    ids = [k for k, m in enumerate(meshes) if m is not None]

    def starts(key):
        return np.cumsum([0] + [len(m[key]) for m in live])

    nt, nn, nu, ns = (starts(k) for k in ("tris", "normals", "uvs", "slots"))
    nv = _vertex_starts(live)
    tstart = np.cumsum([0] + [0 if m is None else len(m["tris"])
                              for m in meshes]).astype(np.int32)
    shared = [_to_share(m, int(nv[k])) for k, m in enumerate(live)]
    big, rooms = _in_place(live, nv, {"tris": nt, "uvs": nu})
    packed = dict(
        verts=np.empty((sum(len(m["verts"]) for m in live), 3)),
        tris=rooms["tris"] if "tris" in rooms else np.empty((nt[-1], 3), np.int32),
        normals=np.empty((nn[-1], 3), np.float32),
        uvs=rooms["uvs"] if "uvs" in rooms else np.empty((nu[-1], 2), np.float32),
        tri_slot=np.empty(ns[-1], np.int32), mesh_nrm=np.zeros((len(meshes), 2), np.int64),
        mesh_uv=np.zeros((len(meshes), 2), np.int64),
        mesh_slot=np.zeros((len(meshes), 2), np.int64))
    for k, m in enumerate(live):
        v, t = slice(nv[k], nv[k] + len(m["verts"])), slice(nt[k], nt[k + 1])
        rn, ru, rs = slice(nn[k], nn[k + 1]), slice(nu[k], nu[k + 1]), slice(ns[k], ns[k + 1])
        _copy(packed["verts"][v], m["verts"])  # (float32 -> float64 for the add-on's)
        if not (k == big and "tris" in rooms):  # (else its rows are there already)
            _copy(packed["tris"][t], m["tris"], np.int32(nv[k] - m.get("vert0", 0)))
        _copy(packed["normals"][rn], m["normals"])
        if not (k == big and "uvs" in rooms):
            _copy(packed["uvs"][ru], m["uvs"])
        packed["tri_slot"][rs] = m["slots"]
        packed["mesh_nrm"][ids[k]] = m["nmode"], bias(m["nmode"], nn[k], nv[k], nt[k])
        packed["mesh_uv"][ids[k]] = m["uvmode"], bias(m["uvmode"], nu[k], nv[k], nt[k])
        packed["mesh_slot"][ids[k]] = m["slot"], ns[k] - nt[k]
    for k, m in enumerate(live):  # (after every copy: a mesh may be in the scene twice)
        v, t = slice(nv[k], nv[k] + len(m["verts"])), slice(nt[k], nt[k + 1])
        rn, ru, rs = slice(nn[k], nn[k + 1]), slice(nu[k], nu[k + 1]), slice(ns[k], ns[k + 1])
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
