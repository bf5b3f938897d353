"""Per-object line parameterisation and the 4D linetree (seed 000, sections 2.1-2.2).

Face pairs
----------
Every object gets an *expanded* world box: its world bounds padded on every side by
``LINETREE_PAD_SCENE_REL * scene_extent + LINETREE_PAD_OBJECT_REL * object_diagonal``
(:mod:`.tolerances`), so a flat object still has a box of positive thickness and every surface
point lies strictly inside. Face pair ``f = 2 k + s`` has principal axis ``k`` (x, y, z) and
direction ``+`` (``s = 0``) or ``-`` (``s = 1``); its lateral axes are ``i = (k + 1) % 3`` and
``j = (k + 2) % 3``. With ``L`` the box depth along ``k``, its two faces span the box's
cross-section grown by ``L`` on every side: a line whose direction has its largest component
along ``k`` moves at most ``L`` sideways while crossing the box, so every such line that meets
the box crosses both faces. A line is ``(a, b, c, d)`` in ``[0, 1]^4``: ``(a, b)`` its
intercept with the front face (where it enters), ``(c, d)`` with the back face, as fractions of
the face's ``i`` and ``j`` extents. A ray is assigned the face pair of its dominant direction
(ties go to the lower axis; either pair parameterises such a line exactly). The *depth* of a
point on the line is its distance from the front face along ``k``: the line runs from depth 0
at ``(a, b)`` to depth ``L`` at ``(c, d)``.

Linetrees
---------
One 4D tree per (object, face pair), 16 children per split (one bit per coordinate: child
``bit0 = a, bit1 = b, bit2 = c, bit3 = d``), created lazily. All trees of a scene share one
node pool, :class:`LinetreeArrays` (flat arrays, a numba argument), owned by
:class:`Linetrees`, which allocates the 16 children of a split as one block and recycles
freed blocks. A node at depth ``D`` with lattice coordinates ``coord`` covers
``coord / 2^D <= (a, b, c, d) <= (coord + 1) / 2^D``. A leaf holds ``EMPTY``, an interpolant
id (``>= 0``), or a fail code :func:`fail_code` carrying the pixel class of the failure.
A coordinate exactly on a cell boundary belongs to the upper cell (the last cell keeps 1.0).
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..frame import LINETREE_MAX_DEPTH

log = logging.getLogger(__name__)

N_FACES = 6
#: The deepest cell (the settings' limit on ``depth_cap``).
MAX_DEPTH = LINETREE_MAX_DEPTH
#: Sample keys quantise line coordinates on the lattice of this depth (15 bits each): the
#: deepest cell's test lines sit on it, two levels further down.
LATTICE_DEPTH = MAX_DEPTH + 2
#: Leaf state of a node that holds nothing (yet).
EMPTY = -1
#: Node state of a freed node (in a recycled block).
DEAD_TREE = -1
_BLOCK = 16


def fail_code(pixel_class):
    """Leaf code of a failed cell whose pixels get ``pixel_class`` (a ``CLASS_FAIL_*``;
    works on arrays)."""
    return -2 - pixel_class


def fail_class(code):
    """Inverse of :func:`fail_code` (works on arrays)."""
    return -2 - code


# ----------------------------------------------------------------------------- face pairs


def expanded_boxes(sa, extent: float | None = None) -> np.ndarray:
    """Expanded world boxes of every instance: (I, 2, 3) float64 (see the module doc).

    ``extent``: the scene extent the padding scales with (default: ``sa``'s). A cache
    freezes it when it is made, so that an object's box (its lines' parameterisation)
    depends on that object alone and survives edits of the others. Instances without finite
    bounds (a tombstoned slot) get a unit box at the origin (nothing hits them)."""
    ext = float(sa.scene_extent if extent is None else extent)
    lo = np.array(sa.inst_aabb[:, 0], np.float64)
    hi = np.array(sa.inst_aabb[:, 1], np.float64)
    bad = ~(np.all(np.isfinite(lo), axis=1) & np.all(np.isfinite(hi), axis=1)
            & np.all(lo <= hi, axis=1))
    lo[bad] = -0.5
    hi[bad] = 0.5
    diag = np.linalg.norm(hi - lo, axis=1)
    pad = (tol.LINETREE_PAD_SCENE_REL * ext + tol.LINETREE_PAD_OBJECT_REL * diag)[:, None]
    return np.ascontiguousarray(np.stack([lo - pad, hi + pad], axis=1))


@njit(cache=True, nogil=True, inline="always")
def face_frame(box, inst, face):
    """Geometry of face pair ``face`` of instance ``inst``'s expanded box.

    Returns ``k, i, j, neg, front, L, li, wi, lj, wj``: principal and lateral axes, whether
    the principal direction is negative, the front face's coordinate along ``k``, the depth
    ``L``, and the faces' lateral origins and widths along ``i`` and ``j``.
    """
    k = face >> 1
    neg = (face & 1) == 1
    i = (k + 1) % 3
    j = (k + 2) % 3
    L = box[inst, 1, k] - box[inst, 0, k]
    front = box[inst, 1, k] if neg else box[inst, 0, k]
    li = box[inst, 0, i] - L
    wi = box[inst, 1, i] - box[inst, 0, i] + 2.0 * L
    lj = box[inst, 0, j] - L
    wj = box[inst, 1, j] - box[inst, 0, j] + 2.0 * L
    return k, i, j, neg, front, L, li, wi, lj, wj


@njit(cache=True, nogil=True, inline="always")
def dominant_face(dx, dy, dz):
    """Face pair of a direction: its largest component (ties to the lower axis) and sign."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax >= ay and ax >= az:
        return 0 if dx >= 0.0 else 1
    if ay >= az:
        return 2 if dy >= 0.0 else 3
    return 4 if dz >= 0.0 else 5


@njit(cache=True, nogil=True)
def line_points(box, inst, face, a, b, c, d, F, B):
    """World points of line ``(a, b, c, d)``: ``F`` on the front face, ``B`` on the back."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    F[k] = front
    B[k] = front - L if neg else front + L
    F[i] = li + a * wi
    F[j] = lj + b * wj
    B[i] = li + c * wi
    B[j] = lj + d * wj


@njit(cache=True, nogil=True, inline="always")
def ray_line(box, inst, ox, oy, oz, dx, dy, dz, abcd):
    """Face pair (returned) and line coordinates ``abcd`` (4,) of one ray that meets
    instance ``inst``'s box; coordinates clamped to [0, 1] (inside up to rounding)."""
    f = dominant_face(dx, dy, dz)
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, f)
    o = (ox, oy, oz)
    dv = (dx, dy, dz)
    back = front - L if neg else front + L
    tf = (front - o[k]) / dv[k]
    tb = (back - o[k]) / dv[k]
    abcd[0] = min(max((o[i] + tf * dv[i] - li) / wi, 0.0), 1.0)
    abcd[1] = min(max((o[j] + tf * dv[j] - lj) / wj, 0.0), 1.0)
    abcd[2] = min(max((o[i] + tb * dv[i] - li) / wi, 0.0), 1.0)
    abcd[3] = min(max((o[j] + tb * dv[j] - lj) / wj, 0.0), 1.0)
    return f


@njit(cache=True, nogil=True)
def parameterize(box, inst, origins, directions, face, abcd):
    """Face pair and line coordinates of ``n`` rays that meet their instance's box.

    box : (I, 2, 3) float64 expanded boxes; inst : (n,) int32; origins, directions : (n, 3)
    float64. Outputs: face (n,) int8, abcd (n, 4) float64 clamped to [0, 1] (a ray that
    meets the box is inside up to rounding).
    """
    for r in range(inst.shape[0]):
        face[r] = ray_line(box, inst[r], origins[r, 0], origins[r, 1], origins[r, 2],
                           directions[r, 0], directions[r, 1], directions[r, 2], abcd[r])


@njit(cache=True, nogil=True, inline="always")
def point_depth(box, inst, face, px, py, pz):
    """Depth of world point ``p`` below the front face of ``face`` (along its axis)."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    pk = px if k == 0 else (py if k == 1 else pz)
    return front - pk if neg else pk - front


@njit(cache=True, nogil=True, inline="always")
def cell_bounds(lt, nd, lo, hi):
    """The 4D box of linetree node ``nd`` in unit face coordinates, into ``lo``, ``hi`` (4,)."""
    sc = 1.0 / float(1 << lt.depth[nd])
    for m in range(4):
        lo[m] = lt.coord[nd, m] * sc
        hi[m] = (lt.coord[nd, m] + 1) * sc


@njit(cache=True, nogil=True)
def lattice_lines(box, inst, face, lattice, origins, directions):
    """Lines of lattice points: origin on the front face, direction to the back face.

    inst (n,) int32, face (n,) int8, lattice (n, 4) int64 coordinates at
    :data:`LATTICE_DEPTH`. Outputs origins, directions (n, 3) float64; the line reaches the
    back face at parameter 1 and depth ``L * t`` at parameter ``t``.
    """
    scale = 1.0 / (1 << LATTICE_DEPTH)
    for r in range(inst.shape[0]):
        F = np.empty(3)
        B = np.empty(3)
        line_points(box, inst[r], face[r], lattice[r, 0] * scale, lattice[r, 1] * scale,
                    lattice[r, 2] * scale, lattice[r, 3] * scale, F, B)
        for m in range(3):
            origins[r, m] = F[m]
            directions[r, m] = B[m] - F[m]


# ----------------------------------------------------------------------------- interpolation


@njit(cache=True, nogil=True, inline="always")
def corner_weight(corner, u0, u1, u2, u3):
    """Quadrilinear weight of corner ``corner`` (bit m set: upper end of coordinate m)."""
    w = u0 if corner & 1 else 1.0 - u0
    w *= u1 if corner & 2 else 1.0 - u1
    w *= u2 if corner & 4 else 1.0 - u2
    w *= u3 if corner & 8 else 1.0 - u3
    return w


@njit(cache=True, nogil=True)
def interpolate16(rad16, q, rad, r, u0, u1, u2, u3):
    """``rad[r]`` = the quadrilinear interpolation of interpolant ``q``'s 16 corner
    radiances ``rad16[q]`` at local coordinates ``u`` in [0, 1]."""
    x = 0.0
    y = 0.0
    z = 0.0
    for c in range(16):
        w = corner_weight(c, u0, u1, u2, u3)
        x += w * rad16[q, c, 0]
        y += w * rad16[q, c, 1]
        z += w * rad16[q, c, 2]
    rad[r, 0] = x
    rad[r, 1] = y
    rad[r, 2] = z


def corner_weights(u: np.ndarray) -> np.ndarray:
    """Quadrilinear weights of local coordinates ``u`` (n, 4) in [0, 1]: (n, 16) float64."""
    u = np.asarray(u, np.float64).reshape(-1, 4)
    bits = (np.arange(16)[:, None] >> np.arange(4)[None, :]) & 1  # (16, 4)
    f = np.where(bits[None, :, :] == 1, u[:, None, :], 1.0 - u[:, None, :])
    return f.prod(axis=2)


@njit(cache=True, nogil=True)
def local_coords(depth, coord, abcd, out):
    """Local coordinates in [0, 1] of ``abcd`` (4,) in the cell (depth, coord (4,))."""
    s = float(1 << depth)
    for m in range(4):
        u = abcd[m] * s - coord[m]
        out[m] = min(max(u, 0.0), 1.0)


# ----------------------------------------------------------------------------- linetrees


class LinetreeArrays(NamedTuple):
    """The node pool of all linetrees (capacity ``N``; see the module doc)."""

    child: np.ndarray  # (N,) int32 first node of the 16 children, -1 for a leaf
    leaf: np.ndarray  # (N,) int32 EMPTY, interpolant id (>= 0) or fail_code(class)
    depth: np.ndarray  # (N,) int8
    coord: np.ndarray  # (N, 4) int32 lattice coordinates at the node's depth
    tree: np.ndarray  # (N,) int32 inst * 6 + face, DEAD_TREE for a freed node
    dirty: np.ndarray  # (N,) bool invalidated by the last edit (children inherit it)
    fstamp: np.ndarray  # (N,) int64 stamp of the node's fail code (edits' dependencies)


@njit(cache=True, nogil=True, inline="always")
def descend_one(lt, nd, abcd, inherited):
    """Leaf below node ``nd`` holding line ``abcd`` (4,); returns ``(leaf, inherited)``
    where ``inherited`` becomes the fail code of the deepest split node passed (a failed
    cell that was split keeps its code), if any."""
    while lt.child[nd] >= 0:
        if lt.leaf[nd] < EMPTY:
            inherited = lt.leaf[nd]
        s = float(1 << (lt.depth[nd] + 1))
        bits = 0
        for m in range(4):
            c2 = 2 * lt.coord[nd, m]
            x = int(np.floor(abcd[m] * s))
            if x < c2:
                x = c2
            elif x > c2 + 1:
                x = c2 + 1
            bits |= (x - c2) << m
        nd = lt.child[nd] + bits
    return nd, inherited


@njit(cache=True, nogil=True, parallel=True)
def descend(lt, start, abcd, out, inherited):
    """Leaf holding each line: from node ``start[r]`` down by ``abcd[r]`` (see
    :func:`descend_one`). start (n,) int32, abcd (n, 4) float64; out (n,) int32 leaves;
    inherited (n,) int32 updated in place."""
    for r in prange(start.shape[0]):
        out[r], inherited[r] = descend_one(lt, start[r], abcd[r], inherited[r])


@njit(cache=True, nogil=True)
def _init_children(lt, parents, bases):
    for q in range(parents.shape[0]):
        p = parents[q]
        base = bases[q]
        lt.child[p] = base  # lt.leaf[p] stays: a collapse restores it
        for c in range(_BLOCK):
            nd = base + c
            lt.child[nd] = -1
            lt.leaf[nd] = EMPTY
            lt.depth[nd] = lt.depth[p] + 1
            lt.tree[nd] = lt.tree[p]
            lt.dirty[nd] = lt.dirty[p]
            lt.fstamp[nd] = 0
            for m in range(4):
                lt.coord[nd, m] = 2 * lt.coord[p, m] + ((c >> m) & 1)


@njit(cache=True, nogil=True)
def _collapse_pass(lt, n, freed):
    """Turn inner nodes whose 16 children are EMPTY leaves back into leaves (with the state
    they had before their split: EMPTY or a fail code).

    Writes the freed block starts to ``freed``; returns how many.
    """
    nf = 0
    for p in range(n):
        base = lt.child[p]
        if base < 0 or lt.tree[p] == DEAD_TREE:
            continue
        ok = True
        for c in range(_BLOCK):
            if lt.child[base + c] >= 0 or lt.leaf[base + c] != EMPTY:
                ok = False
                break
        if ok:
            for c in range(_BLOCK):
                if lt.dirty[base + c]:
                    lt.dirty[p] = True  # a cell rebuilt here replaces invalidated ones
                lt.tree[base + c] = DEAD_TREE
            lt.child[p] = -1
            freed[nf] = base
            nf += 1
    return nf


@njit(cache=True, nogil=True)
def _free_subtrees(lt, roots, freed, held):
    """Free every block below ``roots`` (which become dirty EMPTY leaves); interpolant ids
    found in leaves go to ``held``. Returns (blocks freed, ids held)."""
    nf = 0
    nh = 0
    stack = np.empty(64 * _BLOCK, np.int32)
    for r in range(roots.shape[0]):
        root = roots[r]
        sp = 0
        if lt.child[root] >= 0:
            stack[0] = lt.child[root]
            sp = 1
        elif lt.leaf[root] >= 0:
            held[nh] = lt.leaf[root]
            nh += 1
        while sp > 0:
            sp -= 1
            base = stack[sp]
            for c in range(_BLOCK):
                nd = base + c
                if lt.child[nd] >= 0:
                    stack[sp] = lt.child[nd]
                    sp += 1
                elif lt.leaf[nd] >= 0:
                    held[nh] = lt.leaf[nd]
                    nh += 1
                lt.tree[nd] = DEAD_TREE
                lt.child[nd] = -1
                lt.leaf[nd] = EMPTY
            freed[nf] = base
            nf += 1
        lt.child[root] = -1
        lt.leaf[root] = EMPTY
        lt.dirty[root] = True
    return nf, nh


@njit(cache=True, nogil=True)
def _assign_roots(table, keys, next_id, out, new_keys):
    """Root of each key (inst * 6 + face), numbering missing roots from ``next_id``."""
    n_new = 0
    for r in range(keys.shape[0]):
        k = keys[r]
        if table[k] < 0:
            table[k] = next_id + n_new
            new_keys[n_new] = k
            n_new += 1
        out[r] = table[k]
    return n_new


class Linetrees:
    """Owner of the linetree node pool: lazy roots, splits, freed-block recycling."""

    #: bytes per node (child, leaf, depth, coord, tree)
    NODE_BYTES = 4 + 4 + 1 + 16 + 4 + 1 + 8

    def __init__(self, n_instances: int, capacity: int = 4096) -> None:
        self.roots = np.full((max(int(n_instances), 0), N_FACES), -1, np.int32)
        #: per instance: roots made from now on start dirty (their object was reset)
        self.fresh_dirty = np.zeros(len(self.roots), np.bool_)
        self.n_nodes = 0
        self._free: list[int] = []
        self.arrays = self._alloc(max(int(capacity), _BLOCK))

    @staticmethod
    def _alloc(cap: int) -> LinetreeArrays:
        return LinetreeArrays(np.full(cap, -1, np.int32), np.full(cap, EMPTY, np.int32),
                              np.zeros(cap, np.int8), np.zeros((cap, 4), np.int32),
                              np.full(cap, DEAD_TREE, np.int32), np.zeros(cap, np.bool_),
                              np.zeros(cap, np.int64))

    def _reserve(self, extra: int) -> None:
        need = self.n_nodes + extra
        cap = len(self.arrays.child)
        if need <= cap:
            return
        new = self._alloc(max(need, 2 * cap))
        for old, fresh in zip(self.arrays, new, strict=True):
            fresh[:cap] = old
        self.arrays = new

    @property
    def live_nodes(self) -> int:
        return self.n_nodes - _BLOCK * len(self._free)

    @property
    def memory_bytes(self) -> int:
        return self.live_nodes * self.NODE_BYTES

    def get_roots(self, inst: np.ndarray, face: np.ndarray) -> np.ndarray:
        """Root node of each (inst, face) pair, creating missing roots: (n,) int32."""
        keys = np.asarray(inst, np.int64) * N_FACES + np.asarray(face, np.int64)
        table = self.roots.reshape(-1)
        out = np.empty(len(keys), np.int32)
        new_keys = np.empty(min(len(keys), len(table)), np.int64)
        n_new = _assign_roots(table, keys, self.n_nodes, out, new_keys)
        if n_new:
            self._reserve(n_new)
            ids = np.arange(self.n_nodes, self.n_nodes + n_new, dtype=np.int32)
            self.n_nodes += n_new
            a = self.arrays
            a.child[ids] = -1
            a.leaf[ids] = EMPTY
            a.depth[ids] = 0
            a.coord[ids] = 0
            a.tree[ids] = new_keys[:n_new].astype(np.int32)
            a.dirty[ids] = self.fresh_dirty[new_keys[:n_new] // N_FACES]
            a.fstamp[ids] = 0
        return out

    def grow_instances(self, n_instances: int) -> None:
        """Room for roots of ``n_instances`` instances (slots are stable: new ones append)."""
        n = int(n_instances)
        if n > len(self.roots):
            roots = np.full((n, N_FACES), -1, np.int32)
            roots[:len(self.roots)] = self.roots
            self.roots = roots
            fd = np.zeros(n, np.bool_)
            fd[:len(self.fresh_dirty)] = self.fresh_dirty
            self.fresh_dirty = fd

    def reset_trees(self, insts: np.ndarray) -> np.ndarray:
        """Empty the six trees of each instance in ``insts`` (their roots become EMPTY
        leaves; every block below is freed). Returns the interpolant ids their leaves held
        (the caller frees them)."""
        insts = np.asarray(insts, np.int64)
        insts = insts[insts < len(self.roots)]
        roots = self.roots[insts].reshape(-1)
        roots = roots[roots >= 0].astype(np.int32)
        if len(roots) == 0:
            return np.empty(0, np.int32)
        freed = np.empty(max(self.n_nodes // _BLOCK + 1, 1), np.int32)
        held = np.empty(max(self.n_nodes, 1), np.int32)
        nf, nh = _free_subtrees(self.arrays, roots, freed, held)
        self._free.extend(int(x) for x in freed[:nf])
        return held[:nh].copy()

    def mark_dirty(self, nodes: np.ndarray) -> None:
        self.arrays.dirty[np.asarray(nodes, np.int64)] = True

    def clear_dirty(self) -> None:
        self.arrays.dirty[:] = False
        self.fresh_dirty[:] = False

    def split(self, nodes: np.ndarray) -> None:
        """Give each leaf in ``nodes`` (unique) 16 EMPTY children. A split leaf must not hold
        an interpolant; its EMPTY or fail state is kept for :meth:`collapse`."""
        nodes = np.asarray(nodes, np.int32)
        if len(nodes) == 0:
            return
        if np.any(self.arrays.child[nodes] >= 0) or np.any(self.arrays.leaf[nodes] >= 0):
            raise ValueError("linetree: split of a node that is not an empty or failed leaf")
        reuse = min(len(self._free), len(nodes))
        fresh = len(nodes) - reuse
        self._reserve(fresh * _BLOCK)
        bases = np.empty(len(nodes), np.int32)
        if reuse:
            bases[:reuse] = self._free[-reuse:]
            del self._free[-reuse:]
        bases[reuse:] = self.n_nodes + _BLOCK * np.arange(fresh, dtype=np.int32)
        self.n_nodes += _BLOCK * fresh
        _init_children(self.arrays, nodes, bases)

    def collapse(self) -> int:
        """Compact: recursively free every block of 16 EMPTY leaves (the parent gets back
        the state it had when it was split). Returns the number of blocks freed."""
        total = 0
        freed = np.empty(max(self.n_nodes // _BLOCK + 1, 1), np.int32)
        while True:
            nf = _collapse_pass(self.arrays, self.n_nodes, freed)
            if nf == 0:
                return total
            self._free.extend(int(x) for x in freed[:nf])
            total += nf
