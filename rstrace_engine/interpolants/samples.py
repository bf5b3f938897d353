"""Traced lines of the interpolant builder, keyed by their lattice point.

A *sample* is one lattice line of an object's face pair, ``(instance, face pair, a, b, c, d)``
with the coordinates on the lattice of :data:`~.linetree.LATTICE_DEPTH`: its slab crossing,
its radiance and its ray tree (per node: path, instance, surface class, occluder per light,
point). Neighbouring cells, parents and children share samples through a numba hash map from
the key pair ``(instance * 8 + face, packed coordinates)`` (:class:`KeyMap`). The
:class:`SampleStore` owns growth and compaction; :class:`LineCrossings` holds crossings found
during one build before they are shaded.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..accel.accelerators import Hits
from ..geometry.attributes import slot_of, slots_of
from ..geometry.elements import TEX_METAL, TEX_SPECULAR, TEX_TRANSMISSION_SQRT
from ..geometry.scene import LIGHT_SUN
from ..tracing.glossy_rays import is_glossy
from ..tracing.seen_lights import SEEN_GLOSSY, SEEN_TRANSMISSION, any_seen
from ..tracing.shader import _material_of
from ..tracing.shading import (
    dot3,
    geometric_normal,
    rough_interface,
    spawn_offset,
    texture_lookup,
    texture_uv,
)
from .linetree import corner_weight
from .predicate import SampleArrays


@njit(cache=True, nogil=True, inline="always")
def _slot(k1, k2, mask):
    h = np.uint64(k1) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(k2) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= h >> np.uint64(31)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(29)
    return np.int64(h & np.uint64(mask))


@njit(cache=True, nogil=True)
def _map_lookup(tk1, tk2, tval, k1, k2, out):
    mask = tk1.shape[0] - 1
    for r in range(k1.shape[0]):
        s = _slot(k1[r], k2[r], mask)
        out[r] = -1
        while tk1[s] != -1:
            if tk1[s] == k1[r] and tk2[s] == k2[r]:
                out[r] = tval[s]
                break
            s = (s + 1) & mask


@njit(cache=True, nogil=True)
def _map_insert(tk1, tk2, tval, k1, k2, vals):
    mask = tk1.shape[0] - 1
    for r in range(k1.shape[0]):
        s = _slot(k1[r], k2[r], mask)
        while tk1[s] != -1 and not (tk1[s] == k1[r] and tk2[s] == k2[r]):
            s = (s + 1) & mask
        tk1[s] = k1[r]
        tk2[s] = k2[r]
        tval[s] = vals[r]


@njit(cache=True, nogil=True)
def unique_keys(k1, k2):
    """First occurrences of key pairs, in order of appearance (no sort): returns
    ``(first (u,) int64 indices, inverse (m,) int32)``."""
    m = k1.shape[0]
    cap = 16
    while cap < 2 * m:
        cap *= 2
    tk1 = np.full(cap, -1, np.int64)
    tk2 = np.zeros(cap, np.int64)
    tval = np.zeros(cap, np.int32)
    first = np.empty(m, np.int64)
    inv = np.empty(m, np.int32)
    u = 0
    mask = cap - 1
    for r in range(m):
        s = _slot(k1[r], k2[r], mask)
        while tk1[s] != -1 and not (tk1[s] == k1[r] and tk2[s] == k2[r]):
            s = (s + 1) & mask
        if tk1[s] == -1:
            tk1[s] = k1[r]
            tk2[s] = k2[r]
            tval[s] = u
            first[u] = r
            u += 1
        inv[r] = tval[s]
    return first[:u], inv


class KeyMap:
    """An append-only numba hash map from key pairs (int64, int64) to their insertion index."""

    def __init__(self) -> None:
        self.n = 0
        self.k1 = np.empty(0, np.int64)
        self.k2 = np.empty(0, np.int64)
        self._table(1024)

    def _table(self, cap: int) -> None:
        self.tk1 = np.full(cap, -1, np.int64)
        self.tk2 = np.zeros(cap, np.int64)
        self.tval = np.zeros(cap, np.int32)
        if self.n:
            _map_insert(self.tk1, self.tk2, self.tval, self.k1[:self.n], self.k2[:self.n],
                        np.arange(self.n, dtype=np.int32))

    @property
    def table_bytes(self) -> int:
        return 20 * len(self.tk1)

    def lookup(self, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        """Index of each key, -1 when absent: (m,) int32."""
        out = np.empty(len(k1), np.int32)
        _map_lookup(self.tk1, self.tk2, self.tval, np.ascontiguousarray(k1, np.int64),
                    np.ascontiguousarray(k2, np.int64), out)
        return out

    def add(self, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        """Append new (unique, absent) keys; returns their indices."""
        m = len(k1)
        s0, s1 = self.n, self.n + m
        self.k1 = _grow(self.k1, s1)
        self.k2 = _grow(self.k2, s1)
        self.k1[s0:s1] = k1
        self.k2[s0:s1] = k2
        self.n = s1
        if 2 * s1 > len(self.tk1):
            self._table(1 << int(math.ceil(math.log2(4 * s1))))
        else:
            _map_insert(self.tk1, self.tk2, self.tval, self.k1[s0:s1], self.k2[s0:s1],
                        np.arange(s0, s1, dtype=np.int32))
        return np.arange(s0, s1, dtype=np.int32)

    def keep(self, ids: np.ndarray) -> None:
        """Keep only keys ``ids`` (sorted), renumbered 0.. in that order."""
        self.k1 = self.k1[ids]
        self.k2 = self.k2[ids]
        self.n = len(ids)
        self._table(1 << int(math.ceil(math.log2(max(4 * self.n, 1024)))))


def _grow(arr: np.ndarray, need: int) -> np.ndarray:
    """``arr`` with room for ``need`` rows (doubling)."""
    if len(arr) >= need:
        return arr
    new = np.empty((max(need, 2 * len(arr), 256),) + arr.shape[1:], arr.dtype)
    new[:len(arr)] = arr
    return new


class SampleStore:
    """Traced lines keyed by lattice point, with their ray trees (growth owned here)."""

    _SAMPLE = ("_rad", "_inst", "_cls", "_depth", "_nstart", "_ncount", "_dif", "_tex",
               "_flag", "_share", "_shared")
    _NODE = ("_npath", "_ninst", "_ncls", "_nocc", "_npoint")

    def __init__(self, n_lights: int) -> None:
        self.L = max(int(n_lights), 0)
        #: per-light shares are kept (:meth:`keep_shares`): ``_share`` (n, L, 3)
        self.shares_on = False
        self.clear()

    def clear(self) -> None:
        self.keys = KeyMap()
        self.n_nodes = 0
        self._rad = np.empty((0, 3))
        self._inst = np.empty(0, np.int32)
        self._cls = np.empty(0, np.int32)
        self._depth = np.empty(0)
        self._nstart = np.empty(0, np.int64)
        self._ncount = np.empty(0, np.int32)
        self._dif = np.empty((0, 3))
        self._tex = np.empty((0, 3))
        self._flag = np.empty(0, np.uint8)
        self._share = np.empty((0, self.L if self.shares_on else 0, 3))
        self._shared = np.empty(0, np.bool_)
        self._npath = np.empty(0, np.int64)
        self._ninst = np.empty(0, np.int32)
        self._ncls = np.empty(0, np.int32)
        self._nocc = np.empty((0, self.L), np.int32)
        self._npoint = np.empty((0, 3))

    @property
    def n(self) -> int:
        return self.keys.n

    @property
    def memory_bytes(self) -> int:
        """Bytes of the samples, their ray-tree nodes and keys (not the hash table)."""
        per_sample = 24 + 4 + 4 + 8 + 8 + 4 + 16 + 24 + 24 + 1 + 1
        per_node = 8 + 4 + 4 + 4 * self.L + 24
        return self.n * per_sample + self.n_nodes * per_node + self.share_bytes

    @property
    def share_bytes(self) -> int:
        """Bytes of the per-light shares (:meth:`keep_shares`): ``24 L`` per sample."""
        return self.n * self._share.shape[1] * 24

    def keep_shares(self) -> None:
        """From now on samples may keep their per-light shares (``(n, L, 3)``, see
        :mod:`.relight`); the samples stored so far have none (``shared`` False)."""
        if self.shares_on:
            return
        self.shares_on = True
        share = np.zeros((len(self._rad), self.L, 3))
        self._share = share

    def drop_shares(self) -> None:
        """Forget every share (over the cap); :meth:`keep_shares` starts again."""
        self.shares_on = False
        self._share = np.empty((len(self._rad), 0, 3))
        self._shared[:] = False

    def shares(self):
        """``(share (n, L, 3), shared (n,) bool)``: light j's part of a sample's radiance
        ``R`` per unit of its intensity (radiance for a light with an extent), and whether
        the sample has them (:mod:`.relight`)."""
        return self._share[:self.n], self._shared[:self.n]

    def view(self) -> SampleArrays:
        n, m = self.n, self.n_nodes
        return SampleArrays(self._rad[:n], self._inst[:n], self._cls[:n], self._depth[:n],
                            self._nstart[:n], self._ncount[:n], self._npath[:m],
                            self._ninst[:m], self._ncls[:m], self._nocc[:m], self._npoint[:m])

    def radiance(self) -> np.ndarray:
        """(n, 3) the radiance without the root's texture (``L = R + texel * D``; L itself
        for a line whose root is not textured)."""
        return self._rad[:self.n]

    def texture_terms(self):
        """``(D (n, 3), texel (n, 3), flag (n,) uint8)``: the radiance per unit texel of the
        root's texture, the texel at the root (see :func:`texture_split`) and
        :data:`TEX_BELOW` / :data:`TEX_MISMATCH` flags."""
        return self._dif[:self.n], self._tex[:self.n], self._flag[:self.n]

    def lookup(self, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        return self.keys.lookup(k1, k2)

    def add(self, k1, k2, rad, inst, cls, depth, tree, node_cls, dif=None, tex=None,
            flag=None, share=None, shared=None) -> np.ndarray:
        """Append samples (keys unique and absent) and their ray-tree nodes; returns ids.
        ``rad`` is R, ``dif``/``tex``/``flag`` the texture terms (default: untextured),
        ``share`` (n, L, 3) / ``shared`` (n,) bool the per-light shares (default: none)."""
        n = len(k1)
        s0, s1 = self.n, self.n + n
        for name in self._SAMPLE:
            setattr(self, name, _grow(getattr(self, name), s1))
        order = np.argsort(tree.node_ray, kind="stable")
        count = np.bincount(tree.node_ray, minlength=n).astype(np.int32)
        m0, m1 = self.n_nodes, self.n_nodes + len(order)
        for name in self._NODE:
            setattr(self, name, _grow(getattr(self, name), m1))
        self._rad[s0:s1] = rad
        self._inst[s0:s1] = inst
        self._cls[s0:s1] = cls
        self._depth[s0:s1] = depth
        self._ncount[s0:s1] = count
        self._dif[s0:s1] = 0.0 if dif is None else dif
        self._tex[s0:s1] = 1.0 if tex is None else tex
        self._flag[s0:s1] = 0 if flag is None else flag
        self._shared[s0:s1] = False if shared is None or not self.shares_on else shared
        if self.shares_on:
            self._share[s0:s1] = 0.0 if share is None else share
        self._nstart[s0:s1] = m0 + np.concatenate([[0], np.cumsum(count)[:-1]])
        self._npath[m0:m1] = tree.node_path[order]
        self._ninst[m0:m1] = tree.node_inst[order]
        self._ncls[m0:m1] = node_cls[order]
        self._nocc[m0:m1] = tree.node_occluder[order].reshape(len(order), self.L)
        self._npoint[m0:m1] = tree.node_point[order]
        self.n_nodes = m1
        return self.keys.add(k1, k2)

    def compact(self, keep: np.ndarray) -> np.ndarray:
        """Keep samples where ``keep`` (n,) bool; returns the old -> new id map (-1: gone)."""
        remap = np.full(self.n, -1, np.int32)
        ids = np.flatnonzero(keep)
        remap[ids] = np.arange(len(ids), dtype=np.int32)
        cnt = self._ncount[ids]
        start = np.concatenate([[0], np.cumsum(cnt)[:-1]]).astype(np.int64)
        rows = np.repeat(self._nstart[ids] - start, cnt) + np.arange(int(cnt.sum()))
        for name in self._SAMPLE:
            setattr(self, name, getattr(self, name)[ids])
        self._ncount, self._nstart = cnt, start
        for name in self._NODE:
            setattr(self, name, getattr(self, name)[rows])
        self.n_nodes = len(rows)
        self.keys.keep(ids)
        return remap


class LineCrossings:
    """Slab crossings of lines computed during one build (before any is shaded)."""

    def __init__(self) -> None:
        self.keys = KeyMap()
        self.o = np.empty((0, 3))
        self.d = np.empty((0, 3))
        self.t = np.empty(0)
        self.inst = np.empty(0, np.int32)
        self.prim = np.empty(0, np.int32)
        self.u = np.empty(0)
        self.v = np.empty(0)
        self.cls = np.empty(0, np.int32)

    def add(self, k1, k2, o, d, hits: Hits, cls) -> None:
        s0 = self.keys.n
        s1 = s0 + len(k1)
        for name, val in (("o", o), ("d", d), ("t", hits.t), ("inst", hits.inst),
                          ("prim", hits.prim), ("u", hits.u), ("v", hits.v), ("cls", cls)):
            arr = _grow(getattr(self, name), s1)
            arr[s0:s1] = val
            setattr(self, name, arr)
        self.keys.add(k1, k2)

    def hits(self, ids) -> Hits:
        return Hits(self.t[ids], self.inst[ids], self.prim[ids], self.u[ids], self.v[ids])


# ----------------------------------------------------------------------------- line crossings


@njit(cache=True, nogil=True)
def facing(sa, inst, prim, d, front):
    """front[r]: hit r is on the side its geometric normal points to (against d)."""
    for r in range(inst.shape[0]):
        if inst[r] < 0:
            front[r] = True
            continue
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, sa.inst_nmat[inst[r]], prim[r])
        front[r] = dot3(gx, gy, gz, d[r, 0], d[r, 1], d[r, 2]) < 0.0


@njit(cache=True, nogil=True)
def skip_tmin(o, d, t, ext, out):
    """Parameter just past hit t (the tracer's spawn offset along the line)."""
    for r in range(t.shape[0]):
        px = o[r, 0] + d[r, 0] * t[r]
        py = o[r, 1] + d[r, 1] * t[r]
        pz = o[r, 2] + d[r, 2] * t[r]
        dl = math.sqrt(d[r, 0] ** 2 + d[r, 1] ** 2 + d[r, 2] ** 2)
        out[r] = t[r] + spawn_offset(px, py, pz, ext) / dl


# ----------------------------------------------------------------------------- textures
#
# A texture multiplies the diffuse albedo of the material it is on, so the radiance of a line
# is affine in the texel at its first hit: L = R + texel * D (per channel), with R and D
# smooth where the untextured radiance is. Interpolants interpolate R and D and apply the
# texture per pixel, at the pixel's own hit (exactly what the base tracer does): a texture's
# detail never enters the interpolation, however fine it is. A texture further down the ray
# tree (a textured floor in a mirror) is baked into R: cells whose samples have one fail.
# A texel may weight more than the diffuse colour (a metal colour, a specular tint, a
# transmission tint): the split holds where the radiance stays affine in it (a mirror, a
# Glass BSDF); cells whose root's radiance is not (nonlinear_roots) fail.

#: flag bits of a sample: a textured material below the root of its ray tree; the affine
#: split did not reproduce the traced radiance; a rough (glossy) surface in its ray tree
#: (:func:`glossy_flags`).
TEX_BELOW = 1
TEX_MISMATCH = 2
GLOSSY = 4
SEES_LIGHT = 8


@njit(cache=True, nogil=True)
def _glossy_nodes(sa, node_inst, node_tri, out):
    for k in range(node_inst.shape[0]):
        out[k] = node_inst[k] >= 0 and is_glossy(sa, _material_of(sa, node_inst[k],
                                                                    node_tri[k]))


@njit(cache=True, nogil=True)
def _far_lit_roots(sa, node_inst, node_tri, node_origin, node_point, node_occ, n, out):
    """Roots on a rough interface (:func:`~..tracing.shading.rough_interface`) whose tree
    names a light that may lie on the surface's far side (its light comes through the
    transmission lobe): a point or spot light or a sun behind the surface, any light with
    an extent that was sampled there (conservatively)."""
    for k in range(n):
        out[k] = False
        if node_inst[k] < 0:
            continue
        if not rough_interface(sa, _material_of(sa, node_inst[k], node_tri[k])):
            continue
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, sa.inst_nmat[node_inst[k]],
                                      node_tri[k])
        px, py, pz = node_point[k, 0], node_point[k, 1], node_point[k, 2]
        if dot3(node_origin[k, 0] - px, node_origin[k, 1] - py, node_origin[k, 2] - pz,
                gx, gy, gz) < 0.0:
            gx, gy, gz = -gx, -gy, -gz
        for j in range(node_occ.shape[1]):
            if node_occ[k, j] == -2 or sa.light_kind[j] < 0:
                continue
            if sa.light_ext[j]:
                out[k] = True
            elif sa.light_kind[j] == LIGHT_SUN:
                out[k] = -dot3(gx, gy, gz, sa.light_dir[j, 0], sa.light_dir[j, 1],
                               sa.light_dir[j, 2]) <= 0.0
            else:
                out[k] = dot3(gx, gy, gz, sa.light_pos[j, 0] - px, sa.light_pos[j, 1] - py,
                              sa.light_pos[j, 2] - pz) <= 0.0
            if out[k]:
                break


def glossy_flags(sa, tree, n: int) -> np.ndarray:
    """(n,) uint8 :data:`GLOSSY` where a line's ray tree hits a rough surface below its
    root: its radiance is a sampled estimate (glossy rays), not a function of the line that
    cells may interpolate (docs/INTERPOLANTS.md, "Rough surfaces"). A rough root is not
    flagged: its own light is the sample (traced with ``roots="own"``), its glossy rays are
    traced per pixel (:mod:`.glossy_term`) -- unless it is a rough interface lit from its
    far side (through its transmission lobe, :func:`_far_lit_roots`): no proof bounds that
    term across a cell, so such a line fails its cell too."""
    g = np.empty(len(tree.node_inst), np.bool_)
    _glossy_nodes(sa, np.ascontiguousarray(tree.node_inst, np.int32),
                  np.ascontiguousarray(np.maximum(tree.node_tri, 0), np.int32), g)
    far = np.zeros(n, np.bool_)
    if n:  # (always called: the interpolants' warm-up compiles it)
        _far_lit_roots(sa, np.ascontiguousarray(tree.node_inst[:n], np.int32),
                       np.ascontiguousarray(np.maximum(tree.node_tri[:n], 0), np.int32),
                       np.ascontiguousarray(tree.node_origin[:n], np.float64),
                       np.ascontiguousarray(tree.node_point[:n], np.float64),
                       np.ascontiguousarray(tree.node_occluder[:n], np.int32), n, far)
    g[:n] = far  # the roots (the first n rows): only those lit through the far side
    hit = np.bincount(tree.node_ray[g], minlength=n)[:n] > 0
    return np.where(hit, GLOSSY, 0).astype(np.uint8)


def seen_flags(sa, tree, n: int) -> np.ndarray:
    """(n,) uint8 :data:`SEES_LIGHT` where a line's ray tree goes below its root while
    mirror or refraction rays may see a light's own surface (:mod:`~..tracing.seen_lights`):
    the lines between the samples may see a light they miss, so the cell is traced per
    pixel (``tunnel_light``). The roots' own rays are the camera's: a pixel whose camera ray
    can see a light is traced (:mod:`.render`), the lattice lines see none."""
    if not any_seen(sa, (SEEN_GLOSSY, SEEN_TRANSMISSION)):
        return np.zeros(n, np.uint8)
    below = np.bincount(np.asarray(tree.node_ray[n:], np.int64), minlength=n)[:n] > 0
    return np.where(below, SEES_LIGHT, 0).astype(np.uint8)


@njit(cache=True, nogil=True)
def hit_material(sa, inst, prim):
    """Material id of triangle ``prim`` on instance ``inst`` (-1 for a miss)."""
    if inst < 0:
        return -1
    s0 = sa.inst_mat_start[inst]
    cnt = sa.inst_mat_start[inst + 1] - s0
    slot = slot_of(sa, sa.inst_mesh[inst], prim)
    if slot >= cnt:
        slot = cnt - 1
    return sa.inst_mat[s0 + slot]


@njit(cache=True, nogil=True)
def textured_roots(sa, inst, prim, out):
    """out[r]: hit r (instance, triangle) is on a textured material."""
    for r in range(inst.shape[0]):
        m = hit_material(sa, inst[r], prim[r])
        out[r] = m >= 0 and sa.mat_tex[m] >= 0


@njit(cache=True, nogil=True)
def _root_texels(sa, inst, prim, u, v, out):
    for r in range(inst.shape[0]):
        m = hit_material(sa, inst[r], prim[r])
        uu, vv = texture_uv(sa, sa.mat_tex[m], prim[r], u[r], v[r])
        out[r, 0], out[r, 1], out[r, 2] = texture_lookup(sa.tex_data, sa.tex_start,
                                                         sa.tex_size, sa.mat_tex[m], uu, vv)


def nonlinear_roots(sa, inst: np.ndarray, prim: np.ndarray) -> np.ndarray:
    """(n,) bool: hits (instance, triangle; instance -1 a miss) on a material whose
    radiance is not affine in its texel: the texel's square root tints its transmission
    (``TEX_TRANSMISSION_SQRT``), its largest channel scales the base under a tinted layer
    (``TEX_SPECULAR``), or it multiplies the metal colour of a GGX lobe (``TEX_METAL`` at GGX
    alpha ``>= GLOSSY_ALPHA_MIN``: the lobe's multiple-scattering factor
    ``1 + F0 (1 - E) / E`` holds it once more; or a mirror metal whose F82 tint is not
    white: that curve is clamped). A mirror's Fresnel
    ``F0 + (1 - F0) (1 - cos)^5`` and a transmission tint are affine in it."""
    mats = np.zeros(len(sa.mat_tex), np.bool_)
    has = sa.mat_tex >= 0
    flags = sa.tex_size[sa.mat_tex[has], 2]
    lobe = sa.mat_roughness[has] >= tol.GLOSSY_ALPHA_MIN
    # (an F82 tint other than white: its curve is clamped to [0, 1], not affine in F0)
    tinted = (np.asarray(sa.mat_metal_tint)[has] != 1.0).any(axis=1)
    mats[has] = ((flags & (TEX_TRANSMISSION_SQRT | TEX_SPECULAR)) != 0) | (
        ((flags & TEX_METAL) != 0) & (lobe | tinted))
    if not mats.any():
        return np.zeros(len(inst), np.bool_)
    m = hit_materials(sa, inst, prim)
    return (m >= 0) & mats[np.maximum(m, 0)]


def hit_materials(sa, inst: np.ndarray, prim: np.ndarray) -> np.ndarray:
    """(n,) int64: the material of each hit (instance, triangle), -1 for a miss
    (:func:`hit_material` over arrays)."""
    out = np.full(len(inst), -1, np.int64)
    hit = np.flatnonzero(np.asarray(inst) >= 0)
    k = np.asarray(inst, np.int64)[hit]
    s0 = sa.inst_mat_start[k]
    slot = np.minimum(slots_of(sa, sa.inst_mesh[k], np.asarray(prim, np.int64)[hit]),
                      sa.inst_mat_start[k + 1] - s0 - 1)
    out[hit] = sa.inst_mat[s0 + slot]
    return out


def texture_split(sa, accel, o, d, hits: Hits, tree, rad, max_depth: int, trace):
    """Split the radiance of traced lines into ``R + texel * D`` (module comment above).

    o, d, hits: the lines and their root hits; tree: their recorded ray trees; rad (n, 3)
    their radiance; trace: :func:`~.whitted.trace`. Lines whose root is textured are traced
    again twice (no ray trees): with every texel 0 (R) and with no texture (R + D); a root
    whose texel is not affine (:func:`nonlinear_roots`) is flagged :data:`TEX_MISMATCH`
    instead. Returns ``R, D, texel, flag`` ((n, 3) x 3, (n,) uint8).
    """
    n = len(rad)
    R = np.array(rad, np.float64)
    D = np.zeros((n, 3))
    texel = np.ones((n, 3))
    flag = np.zeros(n, np.uint8)
    if n == 0 or not np.any(sa.mat_tex >= 0):
        return R, D, texel, flag
    below = tree.node_path > 1
    tex_node = np.empty(len(tree.node_inst), np.bool_)
    textured_roots(sa, tree.node_inst, np.maximum(tree.node_tri, 0), tex_node)
    bad = np.bincount(tree.node_ray[below & tex_node], minlength=n)[:n] > 0
    flag[bad] = TEX_BELOW
    flag[nonlinear_roots(sa, hits.inst, np.maximum(hits.prim, 0))] |= TEX_MISMATCH
    bad |= flag != 0
    root = np.empty(n, np.bool_)
    textured_roots(sa, np.ascontiguousarray(hits.inst, np.int32),
              np.ascontiguousarray(np.maximum(hits.prim, 0), np.int32), root)
    idx = np.flatnonzero(root & ~bad)
    if len(idx) == 0:
        return R, D, texel, flag
    h = Hits(hits.t[idx], hits.inst[idx], hits.prim[idx], hits.u[idx], hits.v[idx])
    zero = sa._replace(tex_data=np.zeros_like(sa.tex_data))
    plain = sa._replace(mat_tex=np.full_like(sa.mat_tex, -1))
    r0, _ = trace(zero, accel, o[idx], d[idx], 0.0, 1.0, max_depth, primary=h)
    r1, _ = trace(plain, accel, o[idx], d[idx], 0.0, 1.0, max_depth, primary=h)
    tx = np.empty((len(idx), 3))
    _root_texels(sa, h.inst.astype(np.int32), h.prim.astype(np.int32),
                 np.asarray(h.u, np.float64), np.asarray(h.v, np.float64), tx)
    R[idx] = r0
    D[idx] = r1 - r0
    texel[idx] = tx
    err = np.abs(r0 + tx * (r1 - r0) - rad[idx]).max(axis=1)
    scale = np.abs(rad[idx]).max(axis=1) + np.abs(r1).max(axis=1)
    flag[idx[~(err <= tol.TEX_SPLIT_REL * scale + 1e-300)]] |= TEX_MISMATCH
    return R, D, texel, flag


class TextureApplier:
    """Applies textures to a frame's interpolated rays, level by level of the walk (an
    interpolant used at one level may be evicted by the memory cap before the next)."""

    def __init__(self, cache, hits: Hits) -> None:
        if hits is None:
            raise ValueError("resolve: a scene with textures needs the rays' hits")
        self.cache = cache
        self.inst = np.ascontiguousarray(hits.inst, np.int32)
        self.prim = np.ascontiguousarray(hits.prim, np.int32)
        self.u = np.ascontiguousarray(hits.u, np.float64)
        self.v = np.ascontiguousarray(hits.v, np.float64)
        self.done = np.zeros(len(self.inst), np.bool_)

    def apply(self, abcd, pinterp, rad) -> None:
        c = self.cache
        lt = c.trees.arrays
        apply_textures(c.sa, lt.depth, lt.coord, c.pool.node, c.pool.samples,
                       c.samples.texture_terms()[0], pinterp, abcd, self.inst, self.prim,
                       self.u, self.v, rad, self.done)


@njit(cache=True, nogil=True)
def apply_textures(sa, lt_depth, lt_coord, pool_node, pool_samples, dif, pinterp, abcd, inst,
                   prim, u, v, rad, done):
    """Add ``texel * D`` to interpolated rays on textured materials: D interpolated
    quadrilinearly from the interpolant's 16 corner samples like R, the texel looked up at
    the ray's own hit (bilinear, as the tracer does). ``pinterp[r]``: the interpolant ray r
    used (-1: none); rays with ``done[r]`` are skipped, the others marked."""
    for r in range(pinterp.shape[0]):
        q = pinterp[r]
        if q < 0 or done[r]:
            continue
        done[r] = True
        m = hit_material(sa, inst[r], prim[r])
        if m < 0 or sa.mat_tex[m] < 0:
            continue
        nd = pool_node[q]
        s = float(1 << lt_depth[nd])
        u0 = min(max(abcd[r, 0] * s - lt_coord[nd, 0], 0.0), 1.0)
        u1 = min(max(abcd[r, 1] * s - lt_coord[nd, 1], 0.0), 1.0)
        u2 = min(max(abcd[r, 2] * s - lt_coord[nd, 2], 0.0), 1.0)
        u3 = min(max(abcd[r, 3] * s - lt_coord[nd, 3], 0.0), 1.0)
        x = 0.0
        y = 0.0
        z = 0.0
        for k in range(16):
            w = corner_weight(k, u0, u1, u2, u3)
            sid = pool_samples[q, k]
            x += w * dif[sid, 0]
            y += w * dif[sid, 1]
            z += w * dif[sid, 2]
        uu, vv = texture_uv(sa, sa.mat_tex[m], prim[r], u[r], v[r])
        tr, tg, tb = texture_lookup(sa.tex_data, sa.tex_start, sa.tex_size, sa.mat_tex[m],
                                    uu, vv)
        rad[r, 0] += tr * x
        rad[r, 1] += tg * y
        rad[r, 2] += tb * z
