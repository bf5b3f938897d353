"""Evaluated Blender meshes -> :class:`rstrace_engine.geometry.scene.Mesh`, one datablock at a
time, and a cheap fingerprint that tells whether a mesh changed since it was last read.

Blender's arrays are read in place where they are one array (:func:`blender_array`: a
read-only view of Blender's memory, its layout proven from the items' addresses and checked
against Blender's own per-item answer), else with ``foreach_get`` into numpy (no per-vertex
Python): the corners of Blender's triangulation, which ``foreach_get`` reads item by item
(about 100 ms per million triangles), the raw attribute arrays (positions, corner vertices,
edges, uvs). Only what the Mesh keeps is written: the positions' copy and the per-triangle
arrays, gathered straight from Blender's arrays (no temporaries of a mesh's size: fresh
memory is most of a large first read's cost). :func:`mesh_fingerprint` hashes only raw
attribute arrays (those :func:`mesh_arrays` just read are not read again), so an unchanged
mesh is recognised without re-reading it where the journal (:mod:`.journal`) cannot vouch
for it (F12 and animation frames, where no ``depsgraph.updates`` say what changed).

Layer: imported by ``export`` only.
"""

from __future__ import annotations

import ctypes

import numpy as np

from rstrace_engine.accel.content_hash import ContentHash
from rstrace_engine.beside import Beside
from rstrace_engine.geometry.mesh_math import gather_corners
from rstrace_engine.geometry.scene import Mesh, SceneError

#: Raw attributes whose values decide the exported triangles, normals, uvs and slots (with
#: the faces' offsets, :func:`mesh_fingerprint`). The edges (``.edge_verts``) are not among
#: them: no exported value reads them. The faces (their offsets into the corners, the
#: corners' vertices) decide the triangulation and the vertex normals; where a sharp edge
#: matters, the normals are per corner and hashed themselves.
_FINGERPRINT_ATTRIBUTES = (("position", "vector", 3, np.float32),
                           (".corner_vert", "value", 1, np.int32),
                           ("material_index", "value", 1, np.int32),
                           ("sharp_face", "value", 1, np.bool_),
                           ("sharp_edge", "value", 1, np.bool_))


#: Items of a collection whose values :func:`blender_array` compares with Blender's own
#: per-item answer (spread over it, the first and the last among them) before it trusts
#: its view.
_PROBES = 17


def blender_array(items, n: int, width: int, dtype, prop: str) -> np.ndarray | None:
    """Blender's own array behind the collection ``items`` (``n`` items of ``width``
    values of ``dtype``, the item property ``prop``) as a read-only numpy view of it, no
    copy; None where it cannot be proven to be one (then the caller copies it with
    ``foreach_get``).

    The items' addresses (``as_pointer``) must say one contiguous array -- each item
    ``width`` values after the last, the last where such an array puts it -- and
    :data:`_PROBES` items read through the view must equal Blender's own per-item answer.
    The view is valid only while the mesh is: it is read within one mesh read
    (:func:`mesh_arrays`, :func:`mesh_fingerprint`) and never kept (what the Mesh keeps
    is gathered or copied from it into arrays of its own). The check proves the layout, not
    the lifetime: it relies on these collections being views of the mesh's own layers and
    caches (checked on Blender 5.0.1), not buffers built at each access.
    """
    if n <= 0:
        return None
    itemsize = width * np.dtype(dtype).itemsize
    try:
        first, last = items[0].as_pointer(), items[n - 1].as_pointer()
        second = items[1].as_pointer() if n > 1 else first + itemsize
    except (AttributeError, IndexError, TypeError, ReferenceError):
        return None
    if first == 0 or second - first != itemsize or last - first != itemsize * (n - 1):
        return None
    view = np.frombuffer((ctypes.c_char * (itemsize * n)).from_address(first), dtype)
    rows = view.reshape(n, width)
    for i in np.unique(np.linspace(0, n - 1, _PROBES).astype(np.int64)):
        try:
            want = getattr(items[int(i)], prop)
        except (AttributeError, IndexError, TypeError, ReferenceError):
            return None
        if ((want,) if width == 1 else tuple(want)) != tuple(rows[i].tolist()):
            return None
    view.flags.writeable = False
    return view


def read_array(items, n: int, width: int, dtype, prop: str) -> np.ndarray:
    """The ``n * width`` values of ``items``' property ``prop``, flat: Blender's own array
    read in place where it is one (:func:`blender_array`: valid only within the mesh
    read), else a copy with ``foreach_get``."""
    view = blender_array(items, n, width, dtype, prop)
    if view is not None:
        return view
    out = np.empty(n * width, dtype)
    items.foreach_get(prop, out)
    return out


def _attribute(me, name: str, prop: str, size: int, dtype) -> np.ndarray | None:
    """A generic attribute's values (``size`` numbers), or None if the mesh lacks it: a
    read-only view of Blender's own array where it is one (:func:`blender_array`, no
    copy), else read as raw memory with ``foreach_get`` (about 1 ms per million values,
    unlike the per-item RNA path of e.g. ``me.loops.foreach_get("vertex_index")``, about
    100 ms). Not to be kept beyond the mesh read (the view is Blender's memory)."""
    attr = me.attributes.get(name)
    if attr is None:
        return None
    data = attr.data
    n = len(data)
    if n and size % n == 0:
        return read_array(data, n, size // n, dtype, prop)
    out = np.empty(size, dtype)
    data.foreach_get(prop, out)
    return out


def _raw(me, raw: dict, name: str, prop: str, size: int, dtype) -> np.ndarray | None:
    """:func:`_attribute`, kept in ``raw`` (read once for the fingerprint and the mesh)."""
    values = raw.get(name)
    if values is None and name not in raw:
        values = raw[name] = _attribute(me, name, prop, size, dtype)
    return values


def _uv(me, layer, raw: dict, nl: int) -> np.ndarray:
    """The corner uvs (nl * 2 float32) of UV map ``layer``, kept in ``raw`` as ``(name,
    values)``: Blender's own array where it is one (:func:`blender_array`), else a copy."""
    named = raw.get("uv")
    if named is not None and named[0] == layer.name:
        return named[1]
    uv = read_array(layer.uv, nl, 2, np.float32, "vector")
    raw["uv"] = (layer.name, uv)
    return uv


def _corner_normals(me, raw: dict, nl: int) -> np.ndarray:
    """The corner normals (nl * 3 float32), kept in ``raw``: Blender's own array where it
    is one (:func:`blender_array`), else a copy."""
    cn = raw.get("corner_normals")
    if cn is None:
        cn = raw["corner_normals"] = read_array(me.corner_normals, nl, 3, np.float32,
                                                "vector")
    return cn


def corner_triangles(tris_rna, nt: int, corners: int) -> np.ndarray:
    """The corners (indices into the mesh's loops) of each of the ``nt`` triangles of
    ``tris_rna`` (``me.loop_triangles``, Blender's triangulation): (nt, 3) int32, what
    ``tris_rna.foreach_get("loops", ...)`` gives (the caller checks that every corner lies
    in ``0 .. corners - 1``, :func:`_in_range`).

    ``foreach_get`` reads this array an item at a time (about 100 ms per million
    triangles). Blender keeps it as one contiguous array of ``int3`` (Blender 4.1 and
    later): where :func:`blender_array` proves it, it is read in place (a read-only view
    of Blender's array, no copy: valid only within the mesh read), else read with
    ``foreach_get``.
    """
    return read_array(tris_rna, nt, 3, np.int32, "loops").reshape(nt, 3)


#: Bytes from which a mesh's fingerprint is hashed, and its positions copied, beside its
#: read (:func:`read_mesh`, :func:`mesh_arrays`): below, handing the work to another
#: thread costs more than it saves.
BESIDE_BYTES = 1 << 20

#: Triangles from which a mesh's gathered triangles and uvs get room around them
#: (:func:`spare_rows`)
ROOM_MIN_TRIANGLES = 1 << 16
#: The room on each side, as a fraction of the mesh's triangles
ROOM_FRACTION = 1 / 16


def spare_rows(nt: int) -> int:
    """Rows of room left on each side of a mesh's gathered triangles and uvs
    (``mesh_math.with_room``): a 16th of its ``nt`` triangles for a mesh of 65,536 or
    more, else none. Where the scene's largest mesh has them and the other meshes' rows
    fit, the packing lays those beside its rows instead of copying them (the packing's
    copy of a 1M-triangle mesh's triangles and uvs, 36 MB of fresh memory: session 37 in
    ``docs/bench-scale-bpy.md``). The room is mostly address space until the packing
    writes into it: the transparent huge pages numpy asks for on large arrays back the
    part at the rows' edges (1.4-1.7 MB of its 4.5 MB at 1M triangles, 3.8 of 18 MB at 4M)."""
    return int(nt * ROOM_FRACTION) if nt >= ROOM_MIN_TRIANGLES else 0


def _in_range(index: np.ndarray, size: int, name: str, what: str) -> None:
    """Raise a clear error unless every entry of ``index`` lies in ``0 .. size - 1`` (what
    :func:`_gather` then relies on)."""
    if index.size and (int(index.min()) < 0 or int(index.max()) >= size):
        raise SceneError(f"mesh '{name}': a {what} index out of range 0..{size - 1} "
                         f"(Blender's mesh data is inconsistent)")


def _gather(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``values[index]`` (rows of ``values`` along its first axis) as a fresh array, the
    one the Mesh keeps, bit for bit. Numpy's indexing casts the int32 ``index`` in small
    buffered chunks; ``np.take`` converts all of it to int64 first (a temporary of 8 bytes
    an index: 96 MB for the corners of 4M triangles, twice per mesh). A row of several
    values (a corner normal) is moved as one item of the row's bytes (``uint64`` for 8,
    raw bytes otherwise): numpy's path for one-dimensional items is about 2x faster than
    its path for rows on the normals. The caller checked the range (:func:`_in_range`).
    (The triangles' vertices and uvs are gathered by one kernel pass instead:
    :func:`~rstrace_engine.geometry.mesh_math.gather_corners`.)"""
    if values.ndim == 1:
        return values[index]
    shape, width = values.shape, int(np.prod(values.shape[1:]))
    size = values.dtype.itemsize * width
    rows = np.ascontiguousarray(values).reshape(shape[0], width)
    one = rows.view(np.uint64 if size == 8 else np.dtype((np.void, size))).reshape(shape[0])
    return one[index].view(values.dtype).reshape(*index.shape, *shape[1:])


def mesh_arrays(me, name: str, raw: dict | None = None) -> Mesh | None:
    """Triangles of an evaluated mesh datablock as a :class:`Mesh`, or None if it has none.

    Blender's arrays (positions, corner vertices, the corners of its own triangulation,
    uvs, corner normals) are read in place where they are one array
    (:func:`blender_array`: a view, no copy), else with ``foreach_get``; the per-triangle
    arrays the Mesh keeps are gathered straight from them (the triangles' vertices and uvs
    in one kernel pass, :func:`~rstrace_engine.geometry.mesh_math.gather_corners`; the
    normals and slots with :func:`_gather`) and the positions copied once: nothing else of
    a mesh's size is allocated. Normals come from the mesh's normals domain: per vertex
    as Blender holds them (POINT, ``Mesh.vertex_normals``), none for an all-flat mesh
    (FACE: ``smooth=False``, the engine computes each triangle's own) or per corner
    (CORNER); uvs from the active
    render UV map; material slots only where the mesh has material indices (else none:
    every triangle slot 0). The Mesh is ``owned``: its arrays are fresh, handed over
    without a copy. ``raw`` (attribute name -> values) holds the raw arrays
    :func:`mesh_fingerprint` already read, and receives those read here (for it); they
    may be views of Blender's memory, valid only during this read.
    """
    tris_rna = me.loop_triangles
    nt = len(tris_rna)
    if nt == 0:
        return None
    raw = {} if raw is None else raw
    nv, nl, nf = len(me.vertices), len(me.loops), len(me.polygons)
    verts = _raw(me, raw, "position", "vector", nv * 3, np.float32)
    copied = None
    if verts is None:
        verts = np.empty(nv * 3, np.float32)
        me.vertices.foreach_get("co", verts)
    elif not verts.flags.owndata:  # Blender's own array: the Mesh keeps a copy, made
        # beside the per-triangle gathers (the fresh memory's first touch on another core)
        copied = Beside(np.copy, verts, when=verts.nbytes >= BESIDE_BYTES)
    try:
        tris, uvs, slots, normals, vn = _per_triangle(me, name, raw, tris_rna, nv, nl, nf)
    except BaseException:
        if copied is not None:
            copied.drop()
        raise
    if copied is not None:
        verts = copied.result()
    domain = me.normals_domain
    # FACE (all flat): no normals and smooth=False, so that each triangle is shaded with
    # its own normal, as Cycles shades such triangles with their geometric normal (the
    # triangles of a non-planar quad or n-gon each have their own, where Blender's polygon
    # normal is one for them all); the engine computes it where it reads it. The arrays
    # are fresh and never changed: handed over (owned), not copied again.
    return Mesh(name, verts.reshape(nv, 3), tris, corner_normals=normals, corner_uvs=uvs,
                slots=slots, smooth=domain != "FACE", vertex_normals=vn, owned=True)


def _per_triangle(me, name: str, raw: dict, tris_rna, nv: int, nl: int, nf: int) -> tuple:
    """``(tris, uvs, slots, corner normals, vertex normals)`` of :func:`mesh_arrays`: the
    per-triangle arrays gathered from Blender's (None where the mesh has none)."""
    nt = len(tris_rna)
    corner_vert = _raw(me, raw, ".corner_vert", "value", nl, np.int32)
    if corner_vert is None:
        corner_vert = np.empty(nl, np.int32)
        me.loops.foreach_get("vertex_index", corner_vert)
    loops = corner_triangles(tris_rna, nt, nl)
    layer = next((u for u in me.uv_layers if u.active_render), None)
    # (the triangles' vertices and uvs in one pass, which checks the corners' range)
    gathered = gather_corners(corner_vert, loops, None if layer is None else
                              _uv(me, layer, raw, nl).reshape(nl, 2), spare=spare_rows(nt))
    if gathered is None:
        _in_range(loops, nl, name, "triangle corner")  # (raises: says which)
        raise SceneError(f"mesh '{name}': a triangle corner out of range")
    tris, uvs = gathered
    face_mat = _raw(me, raw, "material_index", "value", nf, np.int32)
    nslots = max(len(me.materials), 1)
    slots = None  # (no material indices: every triangle slot 0, no rows)
    if face_mat is not None:
        poly = read_array(me.loop_triangle_polygons, nt, 1, np.int32, "value")
        _in_range(poly, nf, name, "triangle face")
        slots = _gather(face_mat, poly)
        np.clip(slots, 0, nslots - 1, out=slots)  # Blender clamps out-of-range indices

    normals = vn = None
    domain = me.normals_domain
    if domain == "POINT":  # (every corner its vertex's normal: handed over per vertex)
        vn = np.empty((nv, 3), np.float32)
        me.vertex_normals.foreach_get("vector", vn.reshape(-1))
    elif domain != "FACE":  # CORNER: custom or split normals
        # (Cycles too shades every triangle with the corner normals here, flat faces with
        # their polygon's normal: no per-triangle normals)
        normals = _gather(_corner_normals(me, raw, nl).reshape(nl, 3), loops)
    return tris, uvs, slots, normals, vn


def mesh_fingerprint(me, raw: dict | None = None) -> bytes:
    """A digest of everything :func:`mesh_arrays` reads, from raw attribute arrays only
    (Blender's own, read in place where they are one array: :func:`blender_array`):
    :func:`fingerprint_digest` of :func:`fingerprint_parts`.

    Two reads of an unchanged mesh give the same digest; any change of positions, faces
    (each face's first corner -- Blender's face offsets, read in place: 4 bytes a face --
    and the corners' vertices), material indices, sharpness, custom normals (per corner, or
    free per vertex) or the render UV map changes it. The edges are not hashed: the faces
    decide what is exported (the triangulation, the vertex normals), and a sharp edge's
    effect is in the corner normals, which are. (The edges' vertices, once hashed in the
    offsets' place, are 8 bytes an edge, about four times the offsets' bytes, which Blender
    copied for the read, and they miss a face boundary moved between corners whose edges
    stay.) ``raw``: arrays :func:`mesh_arrays` already read (not read again), and receives
    those read here.
    :class:`~rstrace_engine.accel.content_hash.ContentHash` (16 bytes: NH under a
    per-process random key, then SHA-256; two different meshes give equal digests with
    probability below 2^-128; 4-5x faster than SHA-256 alone); digests are compared only
    within the process (the key is drawn per process).
    """
    return fingerprint_digest(fingerprint_parts(me, raw))


def fingerprint_parts(me, raw: dict | None = None) -> list:
    """What :func:`mesh_fingerprint` hashes, in order (bytes and arrays: the arrays may be
    views of Blender's memory, valid only during the mesh read): everything read from
    ``me`` (the Blender API, this thread), nothing hashed yet, so that the hashing
    (:func:`fingerprint_digest`, no Blender call) can run beside the mesh read."""
    raw = {} if raw is None else raw
    parts: list = []
    counts = (len(me.vertices), len(me.edges), len(me.loops), len(me.polygons),
              len(me.materials))
    parts.append(np.array(counts, np.int64).tobytes())
    parts.append(me.normals_domain.encode())
    domain_size = {"POINT": counts[0], "EDGE": counts[1], "CORNER": counts[2],
                   "FACE": counts[3]}
    if counts[3]:
        parts.append(b"faces")
        parts.append(read_array(me.polygons, counts[3], 1, np.int32, "loop_start"))
    for name, prop, width, dtype in _FINGERPRINT_ATTRIBUTES:
        attr = me.attributes.get(name)
        if attr is None:
            continue
        values = _raw(me, raw, name, prop, domain_size.get(attr.domain, 0) * width, dtype)
        parts.append(name.encode())
        parts.append(values)  # (its buffer: no copy, the same bytes)
    if me.normals_domain == "CORNER":  # custom or split normals
        parts.append(_corner_normals(me, raw, counts[2]))
    elif me.normals_domain == "POINT" and _free_point_normals(me):
        # (Blender 4.5+'s free custom normals per vertex: the vertex normals are them)
        parts.append(b"custom_normal")
        parts.append(_raw(me, raw, "custom_normal", "vector", counts[0] * 3, np.float32))
    layer = next((u for u in me.uv_layers if u.active_render), None)
    if layer is not None:
        parts.append(layer.name.encode())
        parts.append(_uv(me, layer, raw, counts[2]))
    return parts


def fingerprint_digest(parts: list) -> bytes:
    """The 16-byte digest of :func:`fingerprint_parts` (no Blender call: any thread)."""
    h = ContentHash()
    for p in parts:
        h.update(p)
    return h.digest()[:16]


def parts_bytes(parts: list) -> int:
    """The bytes :func:`fingerprint_digest` hashes for ``parts``."""
    return sum(len(p) if isinstance(p, bytes) else p.nbytes for p in parts)


def read_mesh(me, name: str, raw: dict, fingerprint: bytes | None = None
              ) -> tuple[Mesh | None, bytes]:
    """``(mesh_arrays(me, name, raw), fingerprint)``: the fingerprint as given, else
    :func:`mesh_fingerprint` of the same arrays, whose hashing (:func:`fingerprint_digest`:
    no Blender call) runs on a second thread while this one reads the mesh
    (:class:`~rstrace_engine.beside.Beside`, from :data:`BESIDE_BYTES` hashed): the same
    digest, its time off the first render's serial read (``docs/bench-scale-bpy.md``,
    session 38). The hashed arrays may be views of Blender's memory: the hash is joined
    before this returns or raises, within the mesh read."""
    if fingerprint is not None:
        return mesh_arrays(me, name, raw), fingerprint
    parts = fingerprint_parts(me, raw)
    job = Beside(fingerprint_digest, parts, when=parts_bytes(parts) >= BESIDE_BYTES)
    try:
        mesh = mesh_arrays(me, name, raw)
    except BaseException:
        job.drop()
        raise
    return mesh, job.result()


def _free_point_normals(me) -> bool:
    """Whether ``me`` has free custom normals per vertex (a ``custom_normal`` float vector
    attribute on points, Blender 4.5+: Set Mesh Normal's Free mode), which
    ``me.vertex_normals`` returns and nothing else hashed covers."""
    attr = me.attributes.get("custom_normal")
    return attr is not None and attr.domain == "POINT" and attr.data_type == "FLOAT_VECTOR"


def same_mesh(a: Mesh | None, b: Mesh | None) -> bool:
    """True when two reads gave the same triangles, normals, uvs and slots."""
    if a is None or b is None:
        return a is b
    return a.smooth == b.smooth and all(
        _same(x, y) for x, y in ((a.vertices, b.vertices), (a.triangles, b.triangles),
                                 (a.corner_normals, b.corner_normals),
                                 (a.vertex_normals, b.vertex_normals),
                                 (a.corner_uvs, b.corner_uvs), (a.slots, b.slots)))


def _same(x, y) -> bool:
    if x is None or y is None:
        return x is y
    return x.shape == y.shape and np.array_equal(x, y)
