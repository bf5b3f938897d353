"""Per-pixel records: what every traced sample of a frame depended on, kept compact.

After an edit with the camera fixed, a frame re-renders only the *dirty* pixels (beyond the
paper, its own future work): a sample is dirty when its ray tree touches the edit. The
records keep, for every ray-tree node of every sample of the last frame,

* which *position-independent* part it had -- a row of a small shared table (``combo``):
  the instance hit (-1 a miss), the lights whose shadow rays were traced, the lights that
  were visible (sets of :mod:`.light_bits`: a uint64 word per 64 light slots), and flags;
* where it ended: the hit point quantised to 32 bits in the scene box (11 + 11 + 10 bits,
  the finest axes where the box is longest), or, for a miss, its direction in 32-bit
  octahedral coordinates;
* for reflection and refraction nodes only: the parent node.

So a primary sample costs 6 bytes (2-byte combo index while the table has fewer than 65,536
rows, 4-byte point) and a secondary node 12. The segments are rebuilt from these: primary
rays start at the camera; a secondary ray at its parent's point; shadow rays go from the
point to each traced light (positions from the scene the records describe). Quantisation
and spawn offsets are covered by growing the edited regions by the quantisation step and a
relative slack, and misses by a cone around the stored direction, so the test is
conservative: a sample is never wrongly left clean.

A sample is dirty when one of its nodes

* has a shadow segment crossing an edited region (old or new world box of a moved, added,
  deleted, hidden or re-meshed object: whatever the edit changed is inside those boxes, so
  a ray that crosses neither hits exactly what it hit);
* has its own segment (primary, reflection/refraction) crossing a place an edited object
  came to (its new box *and* its bounding sphere, :attr:`~.edits.EditEffects.parts`): a ray
  that hit no edited object (one that did is dirty by the next rule) meets what it met
  unless geometry came into its way -- taking an object away changes only the rays that
  hit it (:mod:`.record_queries`);
* hit an object the edits name (moved, added, deleted, its material list changed) or one
  whose material changed;
* had a visible light whose power or colour changed or that was deleted;
* hit anything, when a light moved or was added (which surfaces face a light, and through
  which cone, depends on normals the records do not keep);
* missed, when the world colour changed.

With soft light the cause is kept apart (:meth:`PixelRecords.dirty_split`): a sample dirty
only through its hits' shadow rays to lights with an extent, or their world rays (at the
primary or at a secondary hit), is *re-shaded* rather than traced again
(:mod:`.shadow_reshade`); for that the records also keep every hit's normal, node seed and
soft samples' visibility, a bit per sample and light (:attr:`PixelRecords.p_vis`,
:attr:`PixelRecords.s_vis`).

Why per-pixel records rather than the traced pixels' segments in the ray segment trees
(measured on museum, 640x480, ray depth 5): a frame's samples have 307,200 view segments,
17,811 reflection/refraction segments and 1,178,505 shadow segments. As RST tunnels each
would cost at least a tunnel, a section and an entry (61 + 45 + 8 bytes in
:mod:`~rstrace_engine.interpolants.ray_segment_tree`), about 170 MB, against 2.1 MB for
these records (1.4 bytes per segment: the segments are rebuilt from shared endpoints and
the light positions), and an RST query would then return pixels one segment at a time.
Screen-space tiles were the other candidate: a tile mixes silhouettes and its segments'
bounds grow to the tile's depth range, so a small object's move dirties whole tiles; the
records keep the per-sample precision and use tiles only to cull the query (8x8 pixels).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.edits import PART_NEW
from .batches import threads_for
from .light_bits import mask_of, set_column, words
from .light_records import LightRecords
from .record_codes import (
    POINT_BITS,
    _encode_nodes,
    _mark_used,
    _secondary_depths,
    _secondary_rays,
    _secondary_samples,
    light_geometry,
)
from .record_queries import _mark_rays, _query_primary, _query_secondary, query_tiles
from .sample_proofs import query_samples
from .sample_rays import SampleCandidates
from .soft_lights import world_lights

FLAG_ALWAYS = np.uint64(1)  # this sample is re-rendered by every incremental frame


# ----------------------------------------------------------------------------- kernels
# (the segment queries: record_queries.py)


@njit(cache=True, nogil=True)
def _light_bit_changes(combo, t_traced, t_lit, w, bit, traced, lit, out):
    """The nodes (indices into ``out``, returns how many) whose light bit ``bit`` of word
    ``w`` in their table row's traced / lit sets (C, W) differs from ``traced`` / ``lit``
    (k,) bool."""
    m = 0
    for i in range(combo.shape[0]):
        c = combo[i]
        if ((t_traced[c, w] & bit) != 0) != traced[i] or \
                ((t_lit[c, w] & bit) != 0) != lit[i]:
            out[m] = i
            m += 1
    return m


# ----------------------------------------------------------------------------- records


def _levels_for(extent: np.ndarray):
    """Per axis: quantisation levels (2^bits - 1) and bit shift, most bits on long axes."""
    order = np.argsort(-extent, kind="stable")
    levels = np.zeros(3, np.uint32)
    shift = np.zeros(3, np.uint32)
    pos = 0
    for rank, axis in enumerate(order):
        bits = POINT_BITS[rank]
        levels[axis] = (1 << bits) - 1
        shift[axis] = pos
        pos += bits
    return levels, shift


class PixelRecords:
    """The compact ray trees of every sample of one fixed-camera frame.

    Samples are numbered ``g = s * (width * height) + pixel``. ``box`` (2, 3) is the scene
    box the points are quantised in (the frame's ``scene_aabb``, padded).
    """

    def __init__(self, width: int, height: int, spp: int, box: np.ndarray) -> None:
        self.width, self.height, self.spp = int(width), int(height), int(spp)
        self.n_pixels = self.width * self.height
        self.n_rays = self.n_pixels * self.spp
        lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
        pad = 1e-3 * np.linalg.norm(hi - lo) + 1e-9 * np.abs(np.concatenate([lo, hi])).max()
        self.lo = lo - pad - 1e-12
        ext = np.maximum(hi - lo + 2 * pad, 1e-9)
        self.levels, self.shift = _levels_for(ext)
        self.step = ext / self.levels
        # the shared table of position-independent parts, one row per distinct part
        self.t_inst = np.zeros(0, np.int32)  # instance hit, -1 a miss
        # the traced and visible lights (C, W) (.light_bits; one word as narrow as the lights
        # allow)
        self.t_traced = np.zeros((0, 1), np.uint8)
        self.t_lit = np.zeros((0, 1), np.uint8)
        self.t_flags = np.zeros(0, np.uint8)
        self.p_combo = np.zeros(self.n_rays, np.uint32)
        self.p_code = np.zeros(self.n_rays, np.uint32)
        self.s_parent = np.zeros(0, np.int32)
        self.s_combo = np.zeros(0, np.uint32)
        self.s_code = np.zeros(0, np.uint32)
        self._pending: list = []
        #: the sampled shadow rays of primary hits (:mod:`.sample_rays`): the shading
        #: normal (NaN: not recorded, the shaft tests apply), the node seed, the samples per
        #: light and the light slots when recorded (the world's row is the last)
        self.p_wnorm: np.ndarray | None = None
        self.p_seed: np.ndarray | None = None
        self.w_samples = 0
        self.w_lights = 0
        #: the same for the secondary nodes (reflection and refraction hits), in their
        #: order: shading normal (NaN: a miss, or not recorded), node seed and the soft
        #: samples' visibility (None where not kept: as :attr:`p_vis`)
        self.s_wnorm: np.ndarray | None = None
        self.s_seed: np.ndarray | None = None
        self.s_vis: np.ndarray | None = None
        #: the primary hits' soft samples' visibility (:func:`~.sample_rays.soft_bits`:
        #: (n_rays, L + 1) bits, the world's column last, as narrow as the samples allow),
        #: kept from the frame's first batch on while its lights' shadows stay put
        #: (:meth:`drop_visibility`); None: not kept (lights re-shaded trace all samples)
        self.p_vis: np.ndarray | None = None
        self.vis_off = False
        #: BASE: the light terms of the same nodes (:mod:`.light_records`), or None
        self.light: LightRecords | None = None

    def keep_light_terms(self, n_lights: int, cap_bytes: float, partial: bool = False
                         ) -> None:
        """Also keep every node's light terms (:class:`~.light_records.LightRecords`) for
        ``n_lights`` light slots, up to ``cap_bytes``; ``partial``: an INTERPOLANT frame's
        (only its traced samples have terms)."""
        self.light = LightRecords(self.n_rays, n_lights, cap_bytes, partial)

    # -- building ------------------------------------------------------------------------

    @property
    def n_words(self) -> int:
        """The uint64 words of the table's light sets (:func:`~.light_bits.words`)."""
        return self.t_traced.shape[1]

    def _wide(self, width: int | None = None) -> np.ndarray:
        """The table as (C, 2 + 2 W) uint64 rows (inst bits, traced, lit, flags) for
        interning, its light sets widened to ``width`` words."""
        w = self.n_words if width is None else max(int(width), self.n_words)
        pad = np.zeros((self.n_table, w - self.n_words), np.uint64)
        return np.concatenate([self.t_inst.astype(np.int64).view(np.uint64)[:, None],
                               self.t_traced.astype(np.uint64), pad,
                               self.t_lit.astype(np.uint64), pad,
                               self.t_flags.astype(np.uint64)[:, None]], axis=1)

    def _fit(self, width: int) -> None:
        """Widen the table's light sets to ``width`` words where they are narrower (light
        slots added since the rows were made: none of their bits is set)."""
        if width > self.n_words:
            self._set_table(self._wide(width))

    def _set_table(self, wide: np.ndarray) -> None:
        w = (wide.shape[1] - 2) // 2
        masks = wide[:, 1:1 + 2 * w]
        top = int(masks.max(initial=0)) if w == 1 else 1 << 64
        dt = (np.uint8 if top < 1 << 8 else np.uint16 if top < 1 << 16
              else np.uint32 if top < 1 << 32 else np.uint64)
        self.t_inst = wide[:, 0].view(np.int64).astype(np.int32)
        self.t_traced = wide[:, 1:1 + w].astype(dt)
        self.t_lit = wide[:, 1 + w:1 + 2 * w].astype(dt)
        self.t_flags = wide[:, -1].astype(np.uint8)

    @property
    def n_table(self) -> int:
        return len(self.t_inst)

    def _intern(self, inst, traced, lit, flags) -> np.ndarray:
        """Table ids of rows (inst, traced, lit, flags), adding the rows not there yet
        (``traced``, ``lit``: (k, W) light sets; the table widened to the wider sets)."""
        traced = np.asarray(traced).reshape(len(inst), -1)
        lit = np.asarray(lit).reshape(len(inst), -1)
        w = max(traced.shape[1], self.n_words)
        pad = np.zeros((len(inst), w - traced.shape[1]), np.uint64)
        rows = np.concatenate([inst.astype(np.int64).view(np.uint64)[:, None],
                               traced.astype(np.uint64), pad, lit.astype(np.uint64), pad,
                               flags.astype(np.uint64)[:, None]], axis=1)
        if len(rows) == 0:
            return np.zeros(0, np.uint32)
        old = self._wide(w)
        c = len(old)
        void = np.dtype((np.void, 8 * rows.shape[1]))
        both = np.ascontiguousarray(np.concatenate([old, rows])).view(void).reshape(-1)
        uniq, first, inv = np.unique(both, return_index=True, return_inverse=True)
        is_new = first >= c
        ids = np.where(is_new, c + np.cumsum(is_new) - 1, first)
        if is_new.any():
            self._set_table(np.concatenate([old, np.concatenate([old, rows])[first[is_new]]]))
        return ids[inv.reshape(-1)[c:]].astype(np.uint32)

    def add(self, rays: np.ndarray, levels: list) -> None:
        """Record the trees of a traced batch: ``rays`` (nb,) int64 global sample numbers of
        its input rays; ``levels`` the per-level dicts of :func:`~.whitted.trace`'s
        ``segments``."""
        if not levels:
            return
        inst = np.concatenate([lv["inst"] for lv in levels]).astype(np.int32)
        point = np.concatenate([lv["point"] for lv in levels])
        dirn = np.concatenate([lv["dir"] for lv in levels])
        traced = np.concatenate([lv["traced"] for lv in levels])
        lit = np.concatenate([lv["lit"] for lv in levels])
        # a node that saw a light's own surface: that radiance is in no light term (the
        # light records cannot recombine it), so the sample is traced again by every
        # incremental frame
        saw = np.concatenate([lv.get("seen", np.zeros(len(lv["inst"]), np.bool_))
                              for lv in levels])
        codes = np.empty(len(inst), np.uint32)
        outside = np.empty(len(inst), np.bool_)
        _encode_nodes(inst, np.ascontiguousarray(point), np.ascontiguousarray(dirn), self.lo,
                      self.step, self.levels, self.shift, codes, outside)
        combos = self._intern(inst, traced, lit, np.where(outside | saw, FLAG_ALWAYS, 0))
        if self.n_table > 65535 and self.p_combo.dtype != np.uint32:
            self.p_combo = self.p_combo.astype(np.uint32)
            self.s_combo = self.s_combo.astype(np.uint32)
        nb = len(levels[0]["inst"])
        if self.light is not None:
            if "t_val" in levels[0]:
                self.light.add(np.asarray(rays, np.int64), levels, nb)
            elif self.light.partial:  # (interpolated samples: not recombined)
                self.light.add_blank(np.asarray(rays, np.int64), levels, nb)
            elif self.light.overflow is None:  # (recorded without their terms)
                self.light = None
        self.p_combo[rays] = combos[:nb]
        self.p_code[rays] = codes[:nb]
        self._add_world(np.asarray(rays, np.int64), levels[0])
        if len(inst) > nb:
            parent = np.concatenate([lv["parent"] for lv in levels[1:]]).astype(np.int64)
            self._pending.append((parent, combos[nb:], codes[nb:], np.asarray(rays, np.int64),
                                  nb, _secondary_samples(levels[1:])))

    def _add_world(self, rays: np.ndarray, level: dict) -> None:
        """Record the primary nodes' sampled rays (normal and node seed) where the tracer
        gave them (``normal``, ``seed``, ``n_soft``, ``n_lights`` in its level dict); else
        mark them unknown."""
        if "normal" not in level:
            if self.p_wnorm is not None:
                self.p_wnorm[rays] = np.nan
            if self.p_vis is not None:
                self.drop_visibility()
            return
        n, L = int(level["n_soft"]), int(level["n_lights"])
        if self.p_wnorm is None:
            self.p_wnorm = np.full((self.n_rays, 3), np.nan, np.float32)
            self.p_seed = np.zeros(self.n_rays, np.uint64)
            if "soft_bits" in level and not self.vis_off:  # (a frame's first batch)
                dt = (np.uint8 if n <= 8 else np.uint16 if n <= 16
                      else np.uint32 if n <= 32 else np.uint64)
                self.p_vis = np.zeros((self.n_rays, L + 1), dt)
        elif n != self.w_samples:  # the old rays are unknown now
            self.p_wnorm[:] = np.nan
            self.drop_visibility()
        elif L != self.w_lights:
            # (the world's rays do not depend on the light slots, soft_lights.row_hash; the
            # visibility's columns do)
            self.drop_visibility()
        if self.p_vis is not None:
            bits = level.get("soft_bits")
            if bits is None or bits.shape[1] != self.p_vis.shape[1]:
                self.drop_visibility()
            else:
                self.p_vis[rays] = bits
        self.w_samples, self.w_lights = n, L
        hit = np.asarray(level["inst"]) >= 0
        self.p_wnorm[rays[hit]] = level["normal"][hit]
        self.p_wnorm[rays[~hit]] = np.nan
        self.p_seed[rays] = level["seed"]

    def add_primary(self, rays: np.ndarray, inst: np.ndarray, origins: np.ndarray,
                    directions: np.ndarray, t: np.ndarray) -> None:
        """Record samples that were not traced (interpolated from an interpolant, whose
        own dependencies the ray segment trees track): only their view segment, from
        ``origins`` (n, 3) along ``directions`` (n, 3) to the hit at ``t`` (n,) on ``inst``
        (n,) (-1: a miss). A later :meth:`add` for some of them overwrites this."""
        inst = np.asarray(inst, np.int32)
        d = np.asarray(directions, np.float64)
        nrm = np.linalg.norm(d, axis=1, keepdims=True)
        unit = d / np.where(nrm > 0, nrm, 1.0)
        tt = np.where(inst >= 0, np.asarray(t, np.float64), 0.0)
        point = np.asarray(origins, np.float64) + d * tt[:, None]
        zero = np.zeros(len(inst), np.uint64)
        self.add(np.asarray(rays, np.int64),
                 [dict(ray=np.arange(len(inst)), parent=np.full(len(inst), -1), inst=inst,
                       point=point, dir=unit, traced=zero, lit=zero)])
        if self.light is not None and self.light.partial:
            # a miss is the world colour, which its empty node recombines to
            self.light.add_misses(np.asarray(rays, np.int64)[inst < 0])

    def finish(self, drop_rays: np.ndarray | None = None) -> None:
        """Fold the batches added since the last call into the secondary arrays, first
        dropping the secondary nodes of the samples in ``drop_rays`` ((n_rays,) bool)."""
        base = len(self.s_parent)
        keep = None
        if drop_rays is not None and base:
            keep = ~drop_rays[self.secondary_rays()]
            if not keep.all():
                new_index = np.cumsum(keep) - 1
                par = self.s_parent[keep].astype(np.int64)
                sec = par >= self.n_rays
                par[sec] = new_index[par[sec] - self.n_rays] + self.n_rays
                self.s_parent = par.astype(np.int32)
                self.s_combo = self.s_combo[keep]
                self.s_code = self.s_code[keep]
                base = len(self.s_parent)
                if self.s_wnorm is not None:
                    self.s_wnorm, self.s_seed = self.s_wnorm[keep], self.s_seed[keep]
                    if self.s_vis is not None:
                        self.s_vis = self.s_vis[keep]
        self._finish_samples(base)
        parents, combos, codes = [self.s_parent], [self.s_combo], [self.s_code]
        for parent, comb, code, rays, nb, _ in self._pending:
            # batch rows: 0..nb-1 are the input rays, then the secondary nodes in order
            glob = np.where(parent < nb, rays[np.minimum(parent, nb - 1)],
                            self.n_rays + base + (parent - nb))
            parents.append(glob.astype(np.int32))
            combos.append(comb)
            codes.append(code)
            base += len(parent)
        self._pending = []
        if self.light is not None:
            self.light.finish(keep)
        self.s_parent = np.concatenate(parents).astype(np.int32)
        self.s_combo = np.concatenate(combos).astype(np.uint32)
        self.s_code = np.concatenate(codes).astype(np.uint32)
        self._compact()

    def _finish_samples(self, base: int) -> None:
        """The pending batches' secondary nodes' sampled rays after the ``base`` kept ones
        (:attr:`s_wnorm`, :attr:`s_seed`, :attr:`s_vis`; unknown where a batch gave none)."""
        extra = [e for *_, e in self._pending]
        if self.s_wnorm is None and all(e is None for e in extra):
            return
        sizes = [len(q[0]) for q in self._pending]
        if self.s_wnorm is None:
            self.s_wnorm = np.full((base, 3), np.nan, np.float32)
            self.s_seed = np.zeros(base, np.uint64)
            self.s_vis = None if base or self.p_vis is None else np.zeros(
                (0,) + self.p_vis.shape[1:], self.p_vis.dtype)
        wn, sd, vis = [self.s_wnorm], [self.s_seed], [self.s_vis]
        for e, k in zip(extra, sizes, strict=True):
            wn.append(np.full((k, 3), np.nan, np.float32) if e is None else e[0])
            sd.append(np.zeros(k, np.uint64) if e is None else e[1])
            vis.append(None if e is None else e[2])
        self.s_wnorm, self.s_seed = np.concatenate(wn), np.concatenate(sd)
        pv = self.p_vis
        if pv is None or any(v is None or v.shape[1:] != pv.shape[1:] for v in vis):
            self.s_vis = None
        else:
            self.s_vis = np.concatenate([v.astype(pv.dtype) for v in vis])

    def _compact(self) -> None:
        """Drop table rows no node uses any more; keep indices 16-bit where they fit."""
        used = np.zeros(self.n_table, np.bool_)
        n_used = _mark_used(self.p_combo, used) + _mark_used(self.s_combo, used)
        if self.n_table > min(65535, 2 * n_used + 1024):  # else compact later (amortised)
            remap = np.cumsum(used) - 1
            self._set_table(self._wide()[used])
            self.p_combo = remap[self.p_combo].astype(np.uint32)
            self.s_combo = remap[self.s_combo].astype(np.uint32)
        dt = np.uint16 if self.n_table <= 65535 else np.uint32
        self.p_combo = self.p_combo.astype(dt, copy=False)
        self.s_combo = self.s_combo.astype(dt, copy=False)

    def secondary_rays(self) -> np.ndarray:
        """(m,) int32: the sample of every secondary node."""
        s_ray = np.empty(len(self.s_parent), np.int32)
        if len(s_ray):
            _secondary_rays(self.s_parent, self.n_rays, s_ray)
        return s_ray

    def secondary_depths(self) -> np.ndarray:
        """(m,) int32: the ray depth of every secondary node (1: a primary hit's child)."""
        depth = np.empty(len(self.s_parent), np.int32)
        if len(depth):
            _secondary_depths(self.s_parent, self.n_rays, depth)
        return depth

    def set_light_bits(self, j: int, primary, secondary) -> None:
        """Light ``j``'s bits of every node after it was shaded again
        (:meth:`~.light_records.LightRecords.relight`): ``primary`` and ``secondary`` are
        ``(traced, lit)`` (k,) bool pairs for the primary and the secondary nodes. Only the
        nodes whose bits change are interned again (few, from one step of a drag to the
        next)."""
        w, bit = j >> 6, np.uint64(1) << np.uint64(j & 63)
        self._fit(w + 1)  # (a light slot past the table's sets)
        t_traced = self.t_traced.astype(np.uint64)  # (the table: small)
        t_lit = self.t_lit.astype(np.uint64)
        changed = False
        for name, (tr, lit) in (("p_combo", primary), ("s_combo", secondary)):
            combo = getattr(self, name)
            if len(combo) == 0:
                continue
            ch = np.empty(len(combo), np.int64)
            with threads_for(0):
                m = _light_bit_changes(combo, t_traced, t_lit, w, bit, tr, lit, ch)
            if m == 0:
                continue
            ch = ch[:m]
            c = combo[ch].astype(np.int64)
            new_t = set_column(t_traced[c], j, tr[ch])
            new_l = set_column(t_lit[c], j, lit[ch])
            ids = self._intern(self.t_inst[c], new_t, new_l, self.t_flags[c])
            arr = combo.astype(np.uint32)
            arr[ch] = ids
            setattr(self, name, arr)
            t_traced = self.t_traced.astype(np.uint64)  # (the table grew)
            t_lit = self.t_lit.astype(np.uint64)
            changed = True
        if changed:
            self._compact()

    def drop_visibility(self) -> None:
        """Keep no soft samples' visibility any more (a light's shadows moved): re-shaded
        lights trace all their samples until the next full frame."""
        self.p_vis = self.s_vis = None
        self.vis_off = True

    def set_lit_at(self, done: dict, secondary: bool = False) -> None:
        """Each light ``j``'s visibility bit of the primary (``secondary``: the secondary)
        nodes ``rows`` after it was shaded again there, ``done[j] = (rows, lit)``
        (:mod:`.shadow_reshade`; its traced bit is unchanged: the point and the light
        are); the table compacted once."""
        name = "s_combo" if secondary else "p_combo"
        arr = getattr(self, name)
        wide = False
        for j, (rows, lit) in done.items():
            self._fit((j >> 6) + 1)
            c = arr[rows].astype(np.int64)
            old = self.t_lit[c].astype(np.uint64)
            new = set_column(old, j, lit)
            ch = (new != old).any(axis=1)
            if not ch.any():
                continue
            ids = self._intern(self.t_inst[c[ch]], self.t_traced[c[ch]], new[ch],
                               self.t_flags[c[ch]])
            if not wide:
                arr, wide = arr.astype(np.uint32), True
            arr[rows[ch]] = ids
        if wide:
            setattr(self, name, arr)
            self._compact()

    @property
    def nbytes(self) -> int:
        """Memory of the records (arrays and the shared table), bytes; the light terms
        apart (:attr:`light`)."""
        world = sum(x.nbytes for x in (self.p_wnorm, self.p_seed, self.p_vis, self.s_wnorm,
                                       self.s_seed, self.s_vis) if x is not None)
        return world + int(sum(a.nbytes for a in (self.t_inst, self.t_traced, self.t_lit,
                                                   self.t_flags, self.p_combo, self.p_code,
                                                   self.s_parent, self.s_combo, self.s_code)))

    # -- querying ------------------------------------------------------------------------

    def dirty_rays(self, sa, cp, fx) -> np.ndarray:
        """(n_rays,) bool: the samples edits ``fx`` (an :class:`~.edits.EditEffects`) may
        change. ``sa``: the packing of the scene the records describe (before the edits);
        ``cp``: the frame's camera parameters."""
        full, lights, world, s_lights, s_world, _, _ = self.dirty_split(sa, cp, fx)
        out = full | lights.any(axis=1) | world
        if len(s_lights):
            _mark_rays(self.secondary_rays(), s_lights.any(axis=1) | s_world, out)
        return out

    def dirty_split(self, sa, cp, fx, placed=None) -> tuple:
        """:meth:`dirty_rays` by cause: ``(full (n_rays,) bool, lights (n_rays, W) uint64,
        world (n_rays,) bool, s_lights (m, W) uint64, s_world (m,) bool, cand, s_cand)`` --
        ``full`` the
        samples whose primary ray, reflection or refraction rays, hard lights' shadow rays,
        hit objects, materials or lights the edits may change; for the others, ``lights``
        the lights with an extent (bits) and ``world`` the world's light whose shadow rays
        at the primary hit may cross an edited box, ``s_lights`` and ``s_world`` the same
        at each secondary node (recorded with its normal and seed: :attr:`s_wnorm`; else
        those rays make the sample dirty in full) -- their terms alone may change
        (:mod:`.shadow_reshade`), ``cand`` and ``s_cand`` which of their samples
        (:class:`~.sample_rays.SampleCandidates`). ``placed``: the world balls of the objects the
        edits placed (:func:`~.sample_proofs.placed_balls`), which prove samples stay
        blocked (:func:`~.sample_proofs.query_samples`), or None."""
        self._fit(words(len(sa.light_kind)))  # (lights added since the records)
        combo_inst = self.t_inst.astype(np.int64)
        combo_traced = self.t_traced.astype(np.uint64)
        combo_lit = self.t_lit.astype(np.uint64)
        n_slots = max(len(sa.inst_mesh), int(combo_inst.max(initial=-1)) + 1, 1)
        hot = np.zeros(n_slots + 1, bool)  # last entry: a miss
        for k in fx.objects:
            if 0 <= k < n_slots:
                hot[k] = True
        if fx.materials:
            counts = np.diff(sa.inst_mat_start)
            owner = np.repeat(np.arange(len(counts)), counts)
            hit = np.isin(sa.inst_mat, np.fromiter(fx.materials, np.int64))
            hot[owner[hit]] = True
        lights = mask_of([j for j in fx.lights if j >> 6 < self.n_words], self.n_words)
        is_hit = combo_inst >= 0
        dirty = ((self.t_flags & np.uint8(FLAG_ALWAYS)) != 0) | (combo_lit & lights != 0).any(1)
        dirty |= is_hit & hot[np.where(is_hit, combo_inst, n_slots)]
        if fx.lights_moved:
            dirty |= is_hit
        if fx.world or fx.seen_sky:  # (a seen sun: what misses see)
            dirty |= ~is_hit
        if fx.world:
            if world_lights(sa) or fx.world_lights:
                dirty |= is_hit  # the world lit (or lights now) every surface
        # the world's shadow rays leave every surface point over its hemisphere: hits test
        # their own rays (regenerated from the recorded normal and hash, below) -- the
        # secondary ones where their normals and seeds are recorded; without, any edited
        # box may shade them
        world_rays = world_lights(sa) and len(fx.regions) > 0
        sec_rays = self.s_wnorm is not None and len(self.s_parent) > 0
        sec_dirty = dirty | is_hit if world_rays and not sec_rays else dirty
        regions = fx.region_array()
        margin = self.margin(sa)
        if cp.ortho:
            margin = margin + cp.pixsize
            gx = np.arange(self.n_rays) % self.n_pixels
            u = cp.x0 + (gx % cp.width + 0.5) * cp.pixsize
            v = cp.y0 + (gx // cp.width + 0.5) * cp.pixsize
            m = cp.xform
            origins = m[:3, 3] + u[:, None] * m[:3, 0] + v[:, None] * m[:3, 1]
        else:
            origins = np.zeros((0, 3))
        reg_lo = np.ascontiguousarray(regions[:, 0] - margin)
        reg_hi = np.ascontiguousarray(regions[:, 1] + margin)
        # the edited objects, old and new apart, by box and sphere (grown as the boxes are):
        # the soft lights' and the world's rays at the hits are tested against them,
        # the nodes' own segments (view, reflection, refraction) against the places objects
        # came to (a ray that hit no edited object meets what it met unless geometry came
        # into its way: record_queries)
        p_lo, p_hi, p_c, p_r, p_tag = fx.part_arrays()
        p_lo = np.ascontiguousarray(p_lo - margin)
        p_hi = np.ascontiguousarray(p_hi + margin)
        p_r = np.ascontiguousarray(p_r + float(np.linalg.norm(margin)))
        came = (p_tag & PART_NEW) != 0
        seg = tuple(np.ascontiguousarray(x[came]) for x in (p_lo, p_hi, p_c, p_r))
        combo_dirty = np.ascontiguousarray(dirty)
        sec_dirty = np.ascontiguousarray(sec_dirty)
        inst64 = np.ascontiguousarray(combo_inst)
        kind = np.ascontiguousarray(sa.light_kind, np.int32)
        pos = light_geometry(sa)
        ldir = np.ascontiguousarray(sa.light_dir, np.float64).reshape(-1, 3)
        out = np.zeros(self.n_rays, np.bool_)
        with threads_for(0):  # a few ms of work: one thread beats a parallel region's wake-up
            # the lights with an extent: the primary hits' shadow rays per light (after)
            ext = np.asarray(sa.light_ext, bool) & (np.asarray(sa.light_kind) >= 0)
            soft = mask_of(np.flatnonzero(ext) if len(regions) else [], self.n_words)
            self._query(cp, combo_dirty, sec_dirty, inst64, combo_traced & ~soft,
                        combo_traced & ~soft if sec_rays else combo_traced, origins,
                        reg_lo, reg_hi, seg, kind, pos, ldir, out)
            # the view and mirror segments crossing an edited light's surface (the view
            # segments only where camera rays see it)
            cam = list(fx.seen_camera) + [True] * (len(fx.seen_regions) - len(fx.seen_camera))
            for view in (True, False):
                seen = [b for b, c in zip(fx.seen_regions, cam, strict=True) if c == view]
                if not seen:
                    continue
                lo = np.ascontiguousarray(np.stack(seen)[:, 0] - margin)
                hi = np.ascontiguousarray(np.stack(seen)[:, 1] + margin)
                none = np.zeros(len(combo_dirty), np.bool_)
                no_lights = np.zeros_like(combo_traced)
                crossed = np.zeros(self.n_rays, np.bool_)  # (the queries assign, not or)
                box = (lo, hi, np.ascontiguousarray(0.5 * (lo + hi)),
                       np.ascontiguousarray(0.5 * np.linalg.norm(hi - lo, axis=1)))
                self._query(cp, none, none, inst64, no_lights, no_lights, origins, lo, hi,
                            box, kind, pos, ldir, crossed, primary=view)
                out |= crossed
            parts = (p_lo, p_hi, p_c, p_r, p_tag)
            if placed is not None:  # (the points' error: as the spheres are grown)
                placed = (placed, float(np.linalg.norm(margin)))
            lights, world, cand = query_samples(
                self, sa, self.p_combo, self.p_code, self.p_wnorm, self.p_seed, self.p_vis,
                is_hit, inst64, combo_traced, soft, world_rays, parts, pos, out, placed)
            m = len(self.s_parent)
            s_lights, s_world = np.zeros((m, self.n_words), np.uint64), np.zeros(m, np.bool_)
            s_cand = SampleCandidates.of(len(sa.light_kind) + 1, [])
            if sec_rays:  # the secondary hits' own rays, as the primary hits' (above)
                s_lights, s_world, s_cand = query_samples(
                    self, sa, self.s_combo, self.s_code, self.s_wnorm, self.s_seed,
                    self.s_vis, is_hit, inst64, combo_traced, soft, world_rays, parts, pos,
                    out[self.secondary_rays()], placed)
        return out, lights, world, s_lights, s_world, cand, s_cand

    def _query(self, cp, combo_dirty, sec_dirty, inst64, combo_traced, sec_traced, origins,
               reg_lo, reg_hi, seg, kind, pos, ldir, out, primary: bool = True) -> None:
        """The records' segments against the regions: primary nodes with ``combo_traced``
        lights, secondary ones with ``sec_traced`` (:meth:`dirty_rays`), their shadow
        segments against the boxes ``reg_lo, reg_hi``, their own segments against ``seg``
        ``(lo, hi, centre, radius)`` (box and sphere both); ``primary`` False: the
        secondary nodes alone."""
        if primary and cp.ortho:
            _query_primary(self.p_combo, self.p_code, combo_dirty, inst64, combo_traced,
                           np.ascontiguousarray(cp.xform[:3, 3]),
                           np.ascontiguousarray(origins), self.lo, self.step, self.levels,
                           self.shift, reg_lo, reg_hi, *seg, kind, pos, ldir, out)
        elif primary:
            query_tiles(self.p_combo, self.p_code, combo_dirty, inst64, combo_traced,
                        np.ascontiguousarray(cp.xform[:3, 3]), self.width, self.height,
                        self.n_pixels, self.lo, self.step, self.levels, self.shift, reg_lo,
                        reg_hi, *seg, kind, pos, ldir, out)
        m = len(self.s_parent)
        if m:
            s_dirty = np.zeros(m, np.bool_)
            _query_secondary(self.s_parent, self.s_combo, self.s_code, self.p_combo,
                             self.p_code, self.n_rays, sec_dirty, inst64, sec_traced,
                             self.lo, self.step, self.levels, self.shift, reg_lo, reg_hi,
                             *seg, kind, pos, ldir, s_dirty)
            s_ray = np.empty(m, np.int32)
            _secondary_rays(self.s_parent, self.n_rays, s_ray)
            _mark_rays(s_ray, s_dirty, out)

    def margin(self, sa) -> np.ndarray:
        """(3,) what the edited regions are grown by: the quantisation and the spawn
        offsets (``sa``: the packing the records describe)."""
        scale = float(np.linalg.norm(sa.scene_aabb[1] - sa.scene_aabb[0])
                      + np.abs(sa.scene_aabb).max())
        return 0.5 * self.step + tol.RECORD_SLACK_REL * scale

    def dirty_pixels(self, sa, cp, fx) -> np.ndarray:
        """(height * width,) bool: pixels with a dirty sample."""
        return self.dirty_rays(sa, cp, fx).reshape(self.spp, self.n_pixels).any(axis=0)
