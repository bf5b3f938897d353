"""Per-light records: light edits without re-tracing (BASE frames).

The base tracer's radiance of a ray-tree node with path weight ``w`` is (:mod:`.whitted`)::

    contrib = w * (((E + a_1 I_1) + a_2 I_2) + ... + b_1 R_1 + ... + c W)

``E`` the emission (a miss: the world colour), ``a_j`` the hard light j's BRDF times
irradiance over its intensity ``I_j``, ``b_j`` the sampled light j's estimate over its
radiance ``R_j`` and ``c`` the world light's over its colour ``W`` (hard lights in slot
order, then the sampled lights, then the world: the shader's order). For every sample a
frame keeps and every node of its ray tree these records keep ``w`` and the terms the
shader added (float64), so that:

* a light's power or colour, the world's colour or strength: the frame is *recombined* --
  every term times the light's new intensity, summed in the shader's order, the nodes'
  contributions summed in the tracer's order and the samples averaged by the tracer's own
  :func:`~.batches.accumulate` -- bit for bit the frame a fresh render gives (the same
  float64 operations on the same operands), no ray traced;
* a light moved, rotated, resized, its kind, radius, angle, shape, spread or cone changed,
  a light added into a slot or deleted: only that light's term is shaded again, at every
  node that hit a surface, with its own shadow rays (or samples) alone, by the tracer's own
  stages (:func:`~.whitted.surfaces`, :func:`~.whitted.shadow_rays`,
  :func:`~.soft_lights.soft_visibility`, :func:`~.whitted.shade`).

Compact, and still exact:

* **sparse terms** -- a node keeps only the terms the shader added (the lights that reach
  it, the world's where it lights, the emission where not zero), as ``(slot, value)``
  entries in slot order (CSR: ``start`` per node); a miss keeps none (its radiance is the
  world colour);
* **no stored geometry** -- what re-shading needs is rebuilt by the tracer's own surface
  stage from the node's ray (origin, direction), its hit (``t``, instance, triangle,
  barycentrics) and its sample seed: 88 bytes per surface node instead of the surface
  point, two normals, direction and shadow origin;
* primary nodes keep no path weight (it is 1, and ``1 * x == x``).

Terms stay float64: float32 terms would differ from a fresh frame in the last bits of about
half the pixels. Memory (:meth:`LightRecords.nbytes`): 9 bytes per node, 88 more per node
that hit a surface, 24 more per secondary node, 25 per term. A cap
(``RenderSettings.relight_memory_mb``) bounds it: over the cap the geometry goes first
(moved and added lights then re-trace the pixels they touch; power, colour and the world
still recombine), then, if the terms alone are still over it, everything (every light edit
re-traces). :attr:`LightRecords.overflow` and :attr:`LightRecords.no_geometry` say why.

Nodes are laid out as :class:`~.pixel_records.PixelRecords` lays out its nodes (primary
nodes by global sample id, secondary nodes in its order), which owns and fills these
records, so that a node's light bits there can be updated after a relit light.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..accel.accelerators import Hits
from ..geometry.elements import MAX_LIGHTS
from ..geometry.scene import SceneArrays
from .batches import accumulate, threads_for
from .light_nodes import (
    EMIT,
    GEO_KEYS,
    RECORD_SLOTS,
    WORLD,
    _splice_geo,
    count_terms,
    detach_terms,
    fill_terms,
    node_ranges,
    replace_entries,
    splice,
    term_of,
)
from .light_reshade import relight_light
from .record_codes import _secondary_rays
from .shader import Surfaces
from .soft_lights import world_lights
from .whitted import surfaces
from .world_samples import TermSamples, WorldSamples

#: what shading a light again needs, per node that hit a surface
_GEO = dict(o=((3,), np.float64), d=((3,), np.float64), t=((), np.float64),
            inst=((), np.int32), prim=((), np.int32), u=((), np.float64),
            v=((), np.float64), seed=((), np.uint64))
GEO_BYTES = 88
ENTRY_BYTES = 25
NODE_BYTES = 9  # hit flag and CSR start
WEIGHT_BYTES = 24  # secondary nodes


# ----------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True, inline="always")
def _node_light(k, start, slot, val, use, scale, dj, d_on, d_val):
    """A surface node's radiance before its path weight, in the shader's order: the
    emission, the hard lights in slot order, the sampled lights, the world. ``dj`` >= 0:
    light slot ``dj``'s term is the detached one (``d_on[k]``, ``d_val[k]``; a dragged
    light's, :meth:`_Part.detach`), its entries in the CSR are stale and skipped; it is
    added where its entry would be."""
    s0 = start[k]
    s1 = start[k + 1]
    lr = 0.0
    lg = 0.0
    lb = 0.0
    if s1 > s0 and slot[s1 - 1] == EMIT:
        s1 -= 1
        lr = val[s1, 0]
        lg = val[s1, 1]
        lb = val[s1, 2]
    # entries are in slot order: the hard lights', the sampled lights' (slot order too),
    # then the world's (slot WORLD): two passes put the sampled lights after the hard ones
    # (one when no sampled light is alive: use 2 unused)
    two = use[WORLD + 1] != 0
    dg = -1  # the pass the detached term belongs to (-1: none at this node)
    if dj >= 0 and d_on[k] and use[dj] != 0:
        dg = 1 if (use[dj] == 1 or not two) else 2
    for group in range(1, 3 if two else 2):
        placed = dg != group
        for e in range(s0, s1):
            c = slot[e]
            if c == dj:
                continue
            u = use[c]
            if u == group or (group == 2 and u == 3) or (u == 3 and not two):
                if not placed and c > dj:
                    lr += d_val[k, 0] * scale[dj, 0]
                    lg += d_val[k, 1] * scale[dj, 1]
                    lb += d_val[k, 2] * scale[dj, 2]
                    placed = True
                lr += val[e, 0] * scale[c, 0]
                lg += val[e, 1] * scale[c, 1]
                lb += val[e, 2] * scale[c, 2]
        if not placed:
            lr += d_val[k, 0] * scale[dj, 0]
            lg += d_val[k, 1] * scale[dj, 1]
            lb += d_val[k, 2] * scale[dj, 2]
    return lr, lg, lb


@njit(cache=True, nogil=True, parallel=True)
def _recombine_primary(hit, start, slot, val, use, scale, dj, d_on, d_val, world, rad):
    for g in prange(hit.shape[0]):
        if hit[g]:
            r, gg, b = _node_light(g, start, slot, val, use, scale, dj, d_on, d_val)
            rad[g, 0] = 0.0 + 1.0 * r
            rad[g, 1] = 0.0 + 1.0 * gg
            rad[g, 2] = 0.0 + 1.0 * b
        else:
            rad[g, 0] = 0.0 + 1.0 * (1.0 * world[0])
            rad[g, 1] = 0.0 + 1.0 * (1.0 * world[1])
            rad[g, 2] = 0.0 + 1.0 * (1.0 * world[2])


@njit(cache=True, nogil=True)
def _recombine_secondary(hit, start, slot, val, w, use, scale, dj, d_on, d_val, world, s_ray,
                         rad):
    """Secondary nodes in the records' order (per sample, the tracer's level order),
    serially: samples repeat."""
    for k in range(hit.shape[0]):
        if hit[k]:
            r, gg, b = _node_light(k, start, slot, val, use, scale, dj, d_on, d_val)
        else:
            r, gg, b = 1.0 * world[0], 1.0 * world[1], 1.0 * world[2]
        g = s_ray[k]
        rad[g, 0] += w[k, 0] * r
        rad[g, 1] += w[k, 1] * gg
        rad[g, 2] += w[k, 2] * b


def light_weights(sa: SceneArrays) -> tuple:
    """What the recombination kernels weigh the terms by, for the lights of ``sa``: ``(use
    (256,) int8, scale (256, 3), world colour (3,))`` -- per slot its pass (0 none, 1 a
    hard light, 2 a sampled one, 3 the world; ``use[EMIT]``: two passes) and its
    intensity or radiance."""
    L = len(sa.light_kind)
    alive = np.asarray(sa.light_kind) >= 0
    ext = np.asarray(sa.light_ext, bool)
    use = np.zeros(256, np.int8)
    use[:L] = np.where(alive, np.where(ext, 2, 1), 0)
    if world_lights(sa):
        use[WORLD] = 3
    use[EMIT] = 1 if (alive & ext).any() else 0  # (read as use[WORLD + 1]: two passes)
    scale = np.zeros((256, 3))
    scale[:L] = np.where(ext[:, None], sa.light_radiance, sa.light_intensity)
    scale[WORLD] = sa.world_light
    return use, scale, np.ascontiguousarray(sa.world_color, np.float64)


def load_kernels() -> None:
    """Load (or compile) the recombination kernels: called once per process, after the
    first frame that keeps light terms (:data:`~.edit_kernels.LOADERS`), so that the
    first light edit does not pay it."""
    p = _Part.empty(True, False)
    s = _Part.empty(False, False)
    use, scale = np.zeros(256, np.int8), np.zeros((256, 3))
    rad = np.zeros((0, 3))
    _recombine_primary(p.hit, p.start, p.slot, p.val, use, scale, *p.detached(), np.zeros(3),
                       rad)
    _recombine_secondary(s.hit, s.start, s.slot, s.val, s.weight, use, scale, *s.detached(),
                         np.zeros(3), np.zeros(0, np.int64), rad)
    s.replace_slot(0, np.zeros(0, bool), np.zeros((0, 3)))
    s.detach(0, np.zeros(0, np.int64), np.zeros((0, 3), bool), np.zeros((0, 3, 3)))
    g = _Part.empty(True, True)  # (an incremental frame's splice)
    g.splice(np.zeros(0, np.int64), _Part.empty(True, True))
    e = g.geo  # (and the copying splice of a frame whose replaced nodes change hit flags)
    _splice_geo(np.zeros(0, np.int64), *([e[k] for k in GEO_KEYS] * 3))
    # the samples of the secondary nodes, which every recombination asks for (a kernel
    # that only runs over nodes: an empty frame's records never load it)
    _secondary_rays(np.zeros(0, np.int32), 0, np.zeros(0, np.int32))


# ----------------------------------------------------------------------------- parts


class _Part:
    """The records of some nodes: hit flag, CSR terms, path weight (secondary nodes) and,
    for the nodes that hit a surface (in node order), what re-shading needs (``geo``;
    None when dropped by the cap)."""

    def __init__(self, hit, start, slot, val, weight, geo) -> None:
        self.hit, self.start, self.slot, self.val = hit, start, slot, val
        self.weight = weight  # (k, 3) or None (primary nodes: 1)
        self.geo = geo  # dict of _GEO arrays over the hit nodes, or None
        #: the hit nodes' Surfaces rebuilt from ``geo`` (kept while the nodes are: a light
        #: dragged is shaded again at every step), or None
        self.surf: Surfaces | None = None
        #: a dragged light's term kept apart (:meth:`detach`): slot ``dj`` (-1: none), present
        #: where ``d_on`` (k,), value ``d_val`` (k, 3); its CSR entries are stale meanwhile
        self.dj = -1
        self.d_on: np.ndarray | None = None
        self.d_val: np.ndarray | None = None
        #: a dragged light's shadow-ray proof over the hit nodes (light_reshade._Proof), or
        #: None (kept with the nodes: a part taken or spliced starts without)
        self.proof = None

    @classmethod
    def empty(cls, primary: bool, geometry: bool) -> _Part:
        geo = ({key: np.zeros((0,) + sh, dt) for key, (sh, dt) in _GEO.items()}
               if geometry else None)
        return cls(np.zeros(0, np.bool_), np.zeros(1, np.int64), np.zeros(0, np.uint8),
                   np.zeros((0, 3)), None if primary else np.zeros((0, 3)), geo)

    @classmethod
    def from_levels(cls, a: dict, primary: bool, geometry: bool) -> _Part:
        hit = np.ascontiguousarray(a["mat"] >= 0)
        n = len(hit)
        count = np.empty(n, np.int64)
        t_on, t_val = np.ascontiguousarray(a["t_on"]), np.ascontiguousarray(a["t_val"])
        count_terms(t_on, t_val, hit, count)
        start = np.zeros(n + 1, np.int64)
        np.cumsum(count, out=start[1:])
        slot = np.empty(int(start[-1]), np.uint8)
        val = np.empty((int(start[-1]), 3))
        fill_terms(t_on, t_val, hit, start, slot, val)
        geo = None
        if geometry:
            geo = {key: np.ascontiguousarray(a[key][hit], dt)
                   for key, (_, dt) in _GEO.items()}
        return cls(hit, start, slot, val,
                   None if primary else np.ascontiguousarray(a["weight"]), geo)

    def __len__(self) -> int:
        return len(self.hit)

    @property
    def nbytes(self) -> int:
        arrays = [self.hit, self.start, self.slot, self.val]
        if self.weight is not None:
            arrays.append(self.weight)
        if self.geo is not None:
            arrays += list(self.geo.values())
        if self.surf is not None:
            arrays += list(self.surf)
        if self.dj >= 0:
            arrays += [self.d_on, self.d_val]
        proof = 0 if self.proof is None else self.proof.nbytes
        return int(sum(x.nbytes for x in arrays)) + proof

    @property
    def geo_bytes(self) -> int:
        return 0 if self.geo is None else int(sum(x.nbytes for x in self.geo.values()))

    def drop_geometry(self) -> None:
        self.geo = self.surf = self.proof = None

    def surfaces(self, sa: SceneArrays, keep: bool) -> Surfaces:
        """The hit nodes' surfaces (points, normals, shadow origins, materials), rebuilt by
        the tracer's own surface stage from the rays and hits (bit for bit the traced
        ones); cached when ``keep``. Their ``sh_state`` is empty."""
        if self.surf is not None:
            return self.surf
        g = self.geo
        k = len(g["t"])
        hits = Hits(g["t"], g["inst"], g["prim"], g["u"], g["v"])
        no_lights = sa._replace(light_kind=np.empty(0, sa.light_kind.dtype))
        with threads_for(k):
            surf = surfaces(no_lights, g["o"], g["d"], np.full(k, np.inf), hits)
        if keep:
            self.surf = surf
        return surf

    def detached(self) -> tuple:
        """``(dj, d_on, d_val)`` for the recombination kernels (empty arrays: none)."""
        if self.dj < 0:
            return -1, np.zeros(0, np.bool_), np.zeros((0, 3))
        return self.dj, self.d_on, self.d_val

    def detach(self, j: int, rows: np.ndarray, tp: np.ndarray, tv: np.ndarray,
               c: int = 0) -> None:
        """Light slot ``j``'s term replaced: present at nodes ``rows[r]`` where ``tp[r,
        c]`` ((k, C) bool), with the value ``tv[r, c]`` ((k, C, 3): the shade kernel's
        terms), absent elsewhere -- kept apart from the CSR entries (a light dragged step
        after step replaces it in place; :meth:`fold` merges it)."""
        n = len(self.hit)
        if self.dj != j:
            self.fold()
            self.dj = int(j)
            self.d_on = np.zeros(n, np.bool_)
            self.d_val = np.empty((n, 3))
        detach_terms(np.ascontiguousarray(rows, np.int64), tp, tv, int(c), self.d_on,
                      self.d_val)

    def fold(self) -> None:
        """The detached term back into the CSR entries (before the nodes are taken or
        merged)."""
        if self.dj < 0:
            return
        j, on, val = self.dj, self.d_on, self.d_val
        self.dj, self.d_on, self.d_val = -1, None, None
        self.replace_slot(j, on, val)

    def take(self, rows: np.ndarray) -> _Part:
        """The nodes ``rows`` (int64) in that order (a detached term taken along)."""
        hit = self.hit[rows]
        idx, n = node_ranges(self.start, rows)
        start = np.zeros(len(rows) + 1, np.int64)
        np.cumsum(n, out=start[1:])
        geo = None
        if self.geo is not None:
            grow = (np.cumsum(self.hit) - 1)[rows[hit]]
            geo = {key: x[grow] for key, x in self.geo.items()}
        out = _Part(hit, start, self.slot[idx], self.val[idx],
                    None if self.weight is None else self.weight[rows], geo)
        if self.dj >= 0:
            out.dj, out.d_on, out.d_val = self.dj, self.d_on[rows], self.d_val[rows]
        return out

    def splice(self, rows: np.ndarray, new: _Part) -> _Part:
        """These nodes with the sorted ``rows`` replaced by ``new``'s nodes (a detached
        term carried: :mod:`.light_splice`)."""
        hit, start, slot, val, geo = splice(self, rows, new)
        out = _Part(hit, start, slot, val, self.weight, geo)  # (nodes replaced in place)
        if self.dj >= 0:
            out.dj, out.d_on, out.d_val = self.dj, self.d_on, self.d_val
        return out

    @staticmethod
    def concat(parts: list) -> _Part:
        dj = {p.dj for p in parts if p.dj >= 0}
        for p in parts:  # (two lights detached: folded; a fresh part's own entry carried)
            if len(dj) > 1:
                p.fold()
            elif dj and p.dj < 0:
                p.dj, (p.d_on, p.d_val) = min(dj), term_of(p.start, p.slot, p.val, min(dj))
        starts, off = [np.zeros(1, np.int64)], 0
        for p in parts:
            starts.append(p.start[1:] + off)
            off += int(p.start[-1])
        geo = None
        if all(p.geo is not None for p in parts):
            geo = {key: np.concatenate([p.geo[key] for p in parts]) for key in _GEO}
        weight = None
        if parts[0].weight is not None:
            weight = np.concatenate([p.weight for p in parts])
        out = _Part(np.concatenate([p.hit for p in parts]), np.concatenate(starts),
                    np.concatenate([p.slot for p in parts]),
                    np.concatenate([p.val for p in parts]), weight, geo)
        if parts[0].dj >= 0:
            out.dj = parts[0].dj
            out.d_on = np.concatenate([p.d_on for p in parts])
            out.d_val = np.concatenate([p.d_val for p in parts])
        return out

    def replace_slot(self, j: int, on: np.ndarray, nval: np.ndarray) -> None:
        """Light slot ``j``'s entries replaced (present where ``on`` (k,), ``nval`` (k, 3))."""
        new_start = np.empty_like(self.start)
        empty = np.zeros(0, np.uint8), np.zeros((0, 3))
        replace_entries(self.start, self.slot, self.val, j, on, nval, new_start, *empty)
        slot = np.empty(int(new_start[-1]), np.uint8)
        val = np.empty((len(slot), 3))
        if len(slot):
            replace_entries(self.start, self.slot, self.val, j, on, nval, new_start, slot, val)
        self.start, self.slot, self.val = new_start, slot, val


def _level_arrays(levels: list, geometry: bool) -> dict:
    keys = ["weight", "t_val", "t_on", "mat"] + (list(_GEO) if geometry else [])
    return {key: np.concatenate([lv[key] for lv in levels]) for key in keys}


# ----------------------------------------------------------------------------- records


class LightRecords:
    """Light terms of every node of a frame's samples (see the module doc), laid out as
    the owning :class:`~.pixel_records.PixelRecords`' nodes. ``overflow``: None, or why the
    records were dropped (the cap); then nothing else is kept. ``no_geometry``: None, or
    why the geometry was dropped (moved lights then re-trace)."""

    def __init__(self, n_rays: int, n_lights: int, cap_bytes: float,
                 partial: bool = False) -> None:
        self.n_rays = int(n_rays)
        self.L = int(n_lights)
        self.cap = float(cap_bytes)
        #: an INTERPOLANT frame's records: batches recorded without their terms (samples
        #: interpolated, their glossy rays) get empty nodes (:meth:`add_blank`) and only the
        #: samples in :attr:`ok` can be recombined
        self.partial = bool(partial)
        #: (n_rays,) bool: the samples whose latest record holds its light terms
        self.ok = np.zeros(self.n_rays, np.bool_)
        self.overflow: str | None = None
        self.no_geometry: str | None = None
        self.p: _Part | None = None  # primary nodes by sample id (None: no frame yet)
        self.s: _Part = _Part.empty(False, True)
        self._pending_p: list = []  # (rays, _Part) of the batches traced since finish
        self._pending_s: list = []
        self._pending_bytes = 0
        #: INTERPOLANT frames while the world lights: the interpolated samples' world terms
        #: (:meth:`set_world`; None: no such sample yet)
        self.world: WorldSamples | None = None
        #: and their sampled terms of lights with an extent (:class:`~.world_samples.
        #: TermSamples`; None: none kept)
        self.sampled: TermSamples | None = None
        if self.cap <= 0.0:
            self._drop(0)
        self.widen(self.L)

    @property
    def has_geometry(self) -> bool:
        return self.no_geometry is None

    @property
    def nbytes(self) -> int:
        if self.p is None:
            return 0
        return self.p.nbytes + self.s.nbytes + self.world_bytes

    @property
    def world_bytes(self) -> int:
        """The interpolated samples' world terms (:meth:`set_world`) and sampled terms."""
        return (0 if self.world is None else self.world.nbytes) + (
            0 if self.sampled is None else self.sampled.nbytes)

    def _parts(self) -> list:
        return ([self.p] if self.p is not None else []) + [self.s] + \
            [q for _, q in self._pending_p] + self._pending_s

    def _message(self, need: float, what: str) -> str:
        return (f"per-light records need {need / 1e6:.1f} MB, over the cap (setting "
                f"'relight_memory_mb' {self.cap / 1e6:.1f} MB): {what}")

    def _drop(self, need: float) -> None:
        self.overflow = self._message(need, "light edits re-trace the pixels they touch")
        self.p = None
        self.s = _Part.empty(False, False)
        self._pending_p, self._pending_s = [], []
        self.world = self.sampled = None

    def _check_cap(self) -> None:
        """Over the cap: drop the geometry, then everything."""
        parts = self._parts()
        total = sum(q.nbytes for q in parts) + self.world_bytes
        if total <= self.cap:
            return
        for q in parts:  # the rebuilt surfaces first (a cache), a drag's proof
            q.surf = q.proof = None
        total = sum(q.nbytes for q in parts) + self.world_bytes
        if total <= self.cap:
            return
        if self.no_geometry is None:
            self.forget_geometry(self._message(
                total, "moved or added lights re-trace the pixels they touch "
                "(power and colour still relight)"))
            total = sum(q.nbytes for q in parts) + self.world_bytes
        if total > self.cap:
            self._drop(total)

    def forget_geometry(self, why: str) -> None:
        """Drop what re-shading a light needs (power and colour still relight); ``why``
        becomes :attr:`no_geometry`. Also when the nodes' triangle numbers go stale: a
        mesh added, deleted or re-meshed renumbers the packed triangles after it."""
        self.no_geometry = why
        for q in self._parts():
            q.surf = None
            q.drop_geometry()

    def add(self, rays: np.ndarray, levels: list, nb: int) -> None:
        """A traced batch (the per-level dicts of :func:`~.whitted.trace`'s ``segments``
        with ``terms``); ``rays`` (nb,) its global sample ids."""
        if self.overflow is not None:
            return
        self.ok[rays] = True
        self._renewed(rays)
        self.widen(levels[0]["t_val"].shape[1] - 2)  # (a light slot added: re-traced)
        if self.overflow is not None:
            return
        a = _level_arrays(levels, self.has_geometry)
        first = {key: x[:nb] for key, x in a.items()}
        self._pending_p.append((np.asarray(rays, np.int64),
                                _Part.from_levels(first, True, self.has_geometry)))
        if len(a["mat"]) > nb:
            rest = {key: x[nb:] for key, x in a.items()}
            self._pending_s.append(_Part.from_levels(rest, False, self.has_geometry))
        if self.p is None:
            # a full frame: checked as it grows (an incremental frame's batches replace
            # kept nodes: checked once merged, in finish)
            self._check_cap()

    def add_blank(self, rays: np.ndarray, levels: list, nb: int) -> None:
        """A batch recorded without its light terms (:attr:`partial` records: interpolated
        samples, their glossy rays): empty nodes that keep the layout of the pixel records'
        nodes; its samples leave :attr:`ok`."""
        if self.overflow is not None:
            return
        rays = np.asarray(rays, np.int64)
        n = sum(len(lv["inst"]) for lv in levels)
        if n == 0:
            return  # (nothing: the kept nodes are not merged again)
        self.ok[rays] = False
        self._renewed(rays)

        def blank(k: int, primary: bool) -> _Part:
            geo = ({key: np.zeros((0,) + sh, dt) for key, (sh, dt) in _GEO.items()}
                   if self.has_geometry else None)
            return _Part(np.zeros(k, np.bool_), np.zeros(k + 1, np.int64),
                         np.zeros(0, np.uint8), np.zeros((0, 3)),
                         None if primary else np.ones((k, 3)), geo)

        self._pending_p.append((rays, blank(nb, True)))
        if n > nb:
            self._pending_s.append(blank(n - nb, False))

    def _renewed(self, rays: np.ndarray) -> None:
        """Samples ``rays`` are rendered again: their world terms kept by :meth:`set_world`
        go (a sample's latest record wins). The interpolants' passes keep them again for
        the samples they interpolate (after adding their records); any other renderer of
        the samples -- the base tracer's frame that the measured fallback or a zero epsilon
        chooses -- leaves them recombined from their light terms, as traced."""
        if self.world is not None:
            self.world.forget(rays)

    def add_misses(self, rays: np.ndarray) -> None:
        """Samples ``rays`` whose primary ray missed and was not traced (an INTERPOLANT
        frame gives them the world colour): their empty node recombines to exactly that,
        so they count as recombinable (:attr:`ok`)."""
        if self.overflow is None:
            self.ok[np.asarray(rays, np.int64)] = True

    def set_world(self, rays: np.ndarray, on: np.ndarray, coef: np.ndarray,
                  rest: np.ndarray) -> None:
        """INTERPOLANT: samples ``rays`` were rendered; ``on`` of them were interpolated
        with radiance ``rest + coef * world_light`` (:class:`~.world_samples.WorldSamples`:
        a world colour or strength edit recombines them too)."""
        if self.overflow is not None:
            return
        if self.world is None:
            if len(on) == 0:
                return
            self.world = WorldSamples(self.n_rays)
        self.world.set(rays, on, coef, rest)

    def relit_pixels(self, spp: int, n_pixels: int, world: bool = False) -> np.ndarray:
        """(n_pixels,) bool: the pixels whose every sample can be recombined (``world``:
        or rescaled by its world term, :meth:`set_world`)."""
        ok = self.ok
        if world and self.world is not None:
            ok = ok | self.world.ok
        return ok.reshape(spp, n_pixels).all(axis=0)

    def finish(self, keep: np.ndarray | None) -> None:
        """Drop the secondary nodes not in ``keep`` (None: keep all), then append the
        batches added since (as :meth:`~.pixel_records.PixelRecords.finish` does)."""
        if self.overflow is not None:
            return
        if self._pending_p and self.p is not None and len(self.p) == self.n_rays:
            # an incremental frame: its samples' new nodes spliced in place (later batches
            # win), the kept ones copied, a dragged light's term kept apart (light_splice)
            rays = np.concatenate([r for r, _ in self._pending_p])
            last = len(rays) - 1 - np.unique(rays[::-1], return_index=True)[1]
            new = _Part.concat([q for _, q in self._pending_p]).take(last)
            self.p = self.p.splice(rays[last], new)
            self._pending_p = []
        if self._pending_p:
            old = self.p if self.p is not None else _Part.empty(True, self.has_geometry)
            parts = [old] + [q for _, q in self._pending_p]
            row = np.full(self.n_rays, -1, np.int64)
            if len(old):
                row[:] = np.arange(self.n_rays)
            base = len(old)
            for rays, q in self._pending_p:  # later batches win
                row[rays] = base + np.arange(len(q))
                base += len(q)
            if (row < 0).any():  # (samples never traced: empty misses; not in a BASE frame)
                filler = _Part.from_levels(dict(
                    t_val=np.zeros((1, self.L + 2, 3)), t_on=np.zeros((1, self.L + 2), bool),
                    mat=np.full(1, -1, np.int32), weight=np.ones((1, 3))), True, False)
                if self.has_geometry:
                    filler.geo = {key: np.zeros((0,) + sh, dt)
                                  for key, (sh, dt) in _GEO.items()}
                parts.append(filler)
                row[row < 0] = base
            self.p = _Part.concat(parts).take(row)
            self._pending_p = []
        if keep is not None and not keep.all():
            self.s = self.s.take(np.flatnonzero(keep))
        if self._pending_s:
            self.s = _Part.concat([self.s] + self._pending_s)
            self._pending_s = []
        self._check_cap()

    def widen(self, n_lights: int) -> None:
        """Light slots were added (the entries name their slots: nothing to move); past
        :data:`~.light_nodes.RECORD_SLOTS` the records are dropped, and it is said."""
        self.L = max(self.L, int(n_lights))
        if self.L > RECORD_SLOTS and self.overflow is None:
            self._drop(0)
            self.overflow = (f"the scene has {self.L} light slots, over the {RECORD_SLOTS} "
                             f"the per-light records name in a byte (MAX_LIGHTS "
                             f"{MAX_LIGHTS}): light edits re-trace the pixels they touch")

    # -- relighting ----------------------------------------------------------------------

    def recombine(self, sa: SceneArrays, s_ray: np.ndarray, spp: int, n_pixels: int,
                  world: bool = False, extra: tuple | None = None) -> np.ndarray:
        """The frame's radiance (n_pixels, 3) float32 from the terms and the lights of
        ``sa``: the tracer's sums in its order (bit for bit a fresh frame's). ``world``:
        the samples kept by :meth:`set_world` are ``rest + coef * world_light`` (what the
        INTERPOLANT frame computes for them). ``extra``: ``(rows, value (m, 3))`` added to
        those samples first (INTERPOLANT: a light edit's term their cells took,
        :mod:`~..interpolants.term_pixels`)."""
        rescale_world = world
        use, scale, world = light_weights(sa)
        rad = np.empty((self.n_rays, 3))
        p, s = self.p, self.s
        out = np.empty((n_pixels, 3), np.float32)
        pc = np.empty(n_pixels, np.uint8)
        inst = np.where(p.hit, 0, -1).astype(np.int32)
        # a few multiply-adds per node: one thread (a parallel region's wake-up on a busy
        # machine costs more than the work, see batches.SERIAL_BELOW)
        with threads_for(0):
            _recombine_primary(p.hit, p.start, p.slot, p.val, use, scale, *p.detached(),
                               world, rad)
            if len(s):
                _recombine_secondary(s.hit, s.start, s.slot, s.val, s.weight, use, scale,
                                     *s.detached(), world,
                                     np.ascontiguousarray(s_ray, np.int64), rad)
            if rescale_world and self.world is not None and world_lights(sa):
                self.world.apply(rad, sa.world_light)
            if extra is not None:
                rad[extra[0]] += extra[1]
            accumulate(rad, inst, spp, out, pc)
        return out

    def relight(self, sa: SceneArrays, accel, j: int, light_samples: int,
                counters: dict | None = None, tiles: tuple | None = None):
        """Shade light ``j`` of ``sa`` again at every node (its term replaced, nothing
        else), with its own shadow rays through ``accel``, at the nodes it faces. Returns
        its per-node light bits for the pixel records: ``(traced, lit)`` of the primary
        nodes and of the secondary ones, each (k,) bool. ``counters``: adds ``shadow`` (rays
        traced), ``shadow_skipped`` (proven, not traced) and the stages' seconds
        (``split``, :data:`~.light_reshade.SPLIT`). ``tiles``: ``(pixels, width)`` of the
        frame (a dragged light's proofs group the primary nodes by tile)."""
        if not self.has_geometry:
            raise RuntimeError("light records without geometry cannot shade a light again")
        self.widen(len(sa.light_kind))
        return relight_light(self, sa, accel, j, light_samples, counters, tiles)
