"""Evaluated Blender meshes -> :class:`rstrace_engine.geometry.scene.Mesh`, one datablock at a
time, and a cheap fingerprint that tells whether a mesh changed since it was last read.

Everything is read with ``foreach_get`` into numpy (no per-vertex Python), except the
corners of Blender's triangulation, which ``foreach_get`` reads item by item (about 100 ms
per million triangles): :func:`corner_triangles` copies Blender's own contiguous array of
them where it can prove the layout (about 15 ms). :func:`mesh_fingerprint` reads only raw
attribute arrays (about 1 ms per million
values; those :func:`mesh_arrays` just read are not read again), so an unchanged mesh is
recognised without re-reading it where the journal (:mod:`.journal`) cannot vouch for it
(F12 and animation frames, where no ``depsgraph.updates`` say what changed).

Layer: imported by ``export`` only.
"""

from __future__ import annotations

import ctypes
import hashlib

import numpy as np

from rstrace_engine.geometry.scene import Mesh, SceneError

#: Raw attributes whose values decide the exported triangles, normals, uvs and slots.
_FINGERPRINT_ATTRIBUTES = (("position", "vector", 3, np.float32),
                           (".corner_vert", "value", 1, np.int32),
                           ("material_index", "value", 1, np.int32),
                           ("sharp_face", "value", 1, np.bool_),
                           ("sharp_edge", "value", 1, np.bool_),
                           (".edge_verts", "value", 2, np.int32))


def _attribute(me, name: str, prop: str, size: int, dtype) -> np.ndarray | None:
    """A generic attribute's values (``size`` numbers), or None if the mesh lacks it.

    Attribute arrays are read as raw memory (about 1 ms per million values), unlike the
    per-item RNA path of e.g. ``me.loops.foreach_get("vertex_index")`` (about 100 ms).
    """
    attr = me.attributes.get(name)
    if attr is None:
        return None
    out = np.empty(size, dtype)
    attr.data.foreach_get(prop, out)
    return out


def _raw(me, raw: dict, name: str, prop: str, size: int, dtype) -> np.ndarray | None:
    """:func:`_attribute`, kept in ``raw`` (read once for the fingerprint and the mesh)."""
    values = raw.get(name)
    if values is None and name not in raw:
        values = raw[name] = _attribute(me, name, prop, size, dtype)
    return values


#: Triangles whose corners :func:`corner_triangles` compares with Blender's per-item read
#: (spread over the mesh, the first and the last among them) before it trusts its copy.
_CORNER_PROBES = 17


def corner_triangles(tris_rna, nt: int, corners: int) -> np.ndarray:
    """The corners (indices into the mesh's loops) of each of the ``nt`` triangles of
    ``tris_rna`` (``me.loop_triangles``, Blender's triangulation): (nt, 3) int32, what
    ``tris_rna.foreach_get("loops", ...)`` gives.

    ``foreach_get`` reads this array an item at a time (about 100 ms per million
    triangles). Blender keeps it as one contiguous array of ``int3`` (Blender 4.1 and
    later); where the items' addresses (``as_pointer``) say so -- 12 bytes apart, the last
    where a contiguous array puts it -- it is copied in one go, then checked: the corners
    of :data:`_CORNER_PROBES` triangles (the first and the last among them) must equal
    Blender's own per-item answer and every corner must lie in ``0 .. corners - 1``.
    Anything else (another layout, a failed check) reads it with ``foreach_get``.
    """
    out = np.empty((nt, 3), np.int32)
    try:
        first, last = tris_rna[0].as_pointer(), tris_rna[nt - 1].as_pointer()
        second = tris_rna[1].as_pointer() if nt > 1 else first + 12
        contiguous = first != 0 and second - first == 12 and last - first == 12 * (nt - 1)
    except (AttributeError, IndexError, TypeError):
        contiguous = False
    if contiguous:
        out[:] = np.frombuffer((ctypes.c_int32 * (3 * nt)).from_address(first),
                               np.int32).reshape(nt, 3)
        probes = np.unique(np.linspace(0, nt - 1, _CORNER_PROBES).astype(np.int64))
        if all(tuple(out[i]) == tuple(tris_rna[int(i)].loops) for i in probes) \
                and int(out.min()) >= 0 and int(out.max()) < corners:
            return out
    tris_rna.foreach_get("loops", out.reshape(-1))
    return out


def _in_range(index: np.ndarray, size: int, name: str, what: str) -> None:
    """Raise a clear error unless every entry of ``index`` lies in ``0 .. size - 1`` (what
    :func:`_gather` then relies on)."""
    if index.size and (int(index.min()) < 0 or int(index.max()) >= size):
        raise SceneError(f"mesh '{name}': a {what} index out of range 0..{size - 1} "
                         f"(Blender's mesh data is inconsistent)")


def _gather(values: np.ndarray, index: np.ndarray, out: np.ndarray) -> None:
    """``out[...] = values[index]`` (rows of ``values`` along its first axis), written
    straight into ``out``: ``np.take`` with ``out=`` and its default ``mode="raise"``
    gathers into a temporary of ``out``'s size and copies it (a 24 MB temporary for a
    million triangles' uvs, fresh pages each time); ``mode="clip"`` writes in place, and
    clips nothing here: the caller checked the range (:func:`_in_range`)."""
    np.take(values, index, axis=0, out=out, mode="clip")


def mesh_arrays(me, name: str, raw: dict | None = None) -> Mesh | None:
    """Triangles of an evaluated mesh datablock as a :class:`Mesh`, or None if it has none.

    Everything is read once with ``foreach_get`` into numpy arrays allocated for it, from
    raw attribute arrays where Blender has them; the corners of Blender's own triangulation
    (``loop_triangles.loops``, read item by item by ``foreach_get``) are copied in one go
    where the layout allows (:func:`corner_triangles`). The per-triangle
    arrays are gathered (``np.take(..., out=)``) straight into the arrays the Mesh keeps.
    Normals come from the mesh's normals domain: per vertex as Blender holds them (POINT,
    ``Mesh.vertex_normals``), none for an all-flat mesh (FACE: ``smooth=False``, the engine
    computes each triangle's own) or per corner (CORNER); uvs from the active render UV
    map. The Mesh is ``owned``: its arrays are fresh, handed over without a copy.
    ``raw`` (attribute name -> values) holds the raw arrays
    :func:`mesh_fingerprint` already read, and receives those read here (for it).
    """
    tris_rna = me.loop_triangles
    nt = len(tris_rna)
    if nt == 0:
        return None
    raw = {} if raw is None else raw
    nv, nl, nf = len(me.vertices), len(me.loops), len(me.polygons)
    verts = _raw(me, raw, "position", "vector", nv * 3, np.float32)
    if verts is None:
        verts = np.empty(nv * 3, np.float32)
        me.vertices.foreach_get("co", verts)
    corner_vert = _raw(me, raw, ".corner_vert", "value", nl, np.int32)
    if corner_vert is None:
        corner_vert = np.empty(nl, np.int32)
        me.loops.foreach_get("vertex_index", corner_vert)
    loops = corner_triangles(tris_rna, nt, nl)
    _in_range(loops, nl, name, "triangle corner")
    tris = np.empty((nt, 3), np.int32)
    _gather(corner_vert, loops, tris)
    face_mat = _raw(me, raw, "material_index", "value", nf, np.int32)
    slots = np.zeros(nt, np.int32)
    if face_mat is not None:
        poly = np.empty(nt, np.int32)
        me.loop_triangle_polygons.foreach_get("value", poly)
        _in_range(poly, nf, name, "triangle face")
        _gather(face_mat, poly, slots)

    normals = vn = None
    domain = me.normals_domain
    if domain == "POINT":  # (every corner its vertex's normal: handed over per vertex)
        vn = np.empty((nv, 3), np.float32)
        me.vertex_normals.foreach_get("vector", vn.reshape(-1))
    elif domain != "FACE":  # CORNER: custom or split normals
        normals = np.empty((nt, 3, 3), np.float32)
        cn = raw.get("corner_normals")
        if cn is None:
            cn = raw["corner_normals"] = np.empty(nl * 3, np.float32)
            me.corner_normals.foreach_get("vector", cn)
        # (Cycles too shades every triangle with the corner normals here, flat faces with
        # their polygon's normal: no per-triangle normals)
        _gather(cn.reshape(nl, 3), loops, normals)

    uvs = None
    layer = next((u for u in me.uv_layers if u.active_render), None)
    if layer is not None:
        named = raw.get("uv")
        if named is not None and named[0] == layer.name:
            uv = named[1]
        else:
            uv = np.empty(nl * 2, np.float32)
            layer.uv.foreach_get("vector", uv)
            raw["uv"] = (layer.name, uv)
        uv = uv.reshape(nl, 2)
        uvs = np.empty((nt, 3, 2), np.float32)
        _gather(uv, loops, uvs)
    nslots = max(len(me.materials), 1)
    np.clip(slots, 0, nslots - 1, out=slots)  # Blender clamps out-of-range indices
    # FACE (all flat): no normals and smooth=False, so that each triangle is shaded with
    # its own normal, as Cycles shades such triangles with their geometric normal (the
    # triangles of a non-planar quad or n-gon each have their own, where Blender's polygon
    # normal is one for them all); the engine computes it where it reads it. The arrays
    # are fresh and never changed: handed over (owned), not copied again.
    return Mesh(name, verts.reshape(nv, 3), tris, corner_normals=normals, corner_uvs=uvs,
                slots=slots, smooth=domain != "FACE", vertex_normals=vn, owned=True)


def mesh_fingerprint(me, raw: dict | None = None) -> bytes:
    """A digest of everything :func:`mesh_arrays` reads, from raw attribute arrays only.

    Two reads of an unchanged mesh give the same digest; any change of positions, topology,
    material indices, sharpness, custom normals or the render UV map changes it. ``raw``:
    arrays :func:`mesh_arrays` already read (not read again), and receives those read here.
    SHA-256 (its first 16 bytes; with the CPU's SHA instructions about twice as fast as
    BLAKE2b); digests are compared only within the process.
    """
    raw = {} if raw is None else raw
    h = hashlib.sha256()
    counts = (len(me.vertices), len(me.edges), len(me.loops), len(me.polygons),
              len(me.materials))
    h.update(np.array(counts, np.int64).tobytes())
    h.update(me.normals_domain.encode())
    domain_size = {"POINT": counts[0], "EDGE": counts[1], "CORNER": counts[2],
                   "FACE": counts[3]}
    for name, prop, width, dtype in _FINGERPRINT_ATTRIBUTES:
        attr = me.attributes.get(name)
        if attr is None:
            continue
        values = _raw(me, raw, name, prop, domain_size.get(attr.domain, 0) * width, dtype)
        h.update(name.encode())
        h.update(values)  # (its buffer: no copy, the same bytes)
    if me.normals_domain == "CORNER":  # custom or split normals
        cn = raw.get("corner_normals")
        if cn is None:
            cn = raw["corner_normals"] = np.empty(counts[2] * 3, np.float32)
            me.corner_normals.foreach_get("vector", cn)
        h.update(cn)
    layer = next((u for u in me.uv_layers if u.active_render), None)
    if layer is not None:
        named = raw.get("uv")
        if named is not None and named[0] == layer.name:
            uv = named[1]
        else:
            uv = np.empty(counts[2] * 2, np.float32)
            layer.uv.foreach_get("vector", uv)
            raw["uv"] = (layer.name, uv)
        h.update(layer.name.encode())
        h.update(uv)
    return h.digest()[:16]


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
