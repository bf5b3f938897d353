"""Per-light records: light edits without re-tracing (BASE frames).

The base tracer's radiance of a ray-tree node with path weight ``w`` is (:mod:`.whitted`)::

    contrib = w * (((E + a_1 I_1) + a_2 I_2) + ... + b_1 R_1 + ... + c W)

``E`` the emission (a miss: the world colour), ``a_j`` the hard light j's BRDF times
irradiance over its intensity ``I_j``, ``b_j`` the sampled light j's estimate over its
radiance ``R_j`` and ``c`` the world light's over its colour ``W`` (hard lights in slot
order, then the sampled lights, then the world: the shader's order). For every sample a
frame keeps and every node of its ray tree these records keep ``w``, ``E`` and each light's
term (float64, with whether the shader added it), so that:

* a light's power or colour, the world's colour or strength: the frame is *recombined* --
  every term times the light's new intensity, summed in the shader's order, the nodes'
  contributions summed in the tracer's order and the samples averaged by the tracer's own
  :func:`~.batches.accumulate` -- bit for bit the frame a fresh render gives (the same
  float64 operations on the same operands), no ray traced;
* a light moved, rotated, resized, its kind, radius, angle, shape, spread or cone changed,
  a light added into a slot or deleted: only that light's term is shaded again, at every
  node that hit a surface, with its own shadow rays (or samples) alone, by the tracer's own
  stages (:func:`~.whitted.surfaces`' light states, :func:`~.whitted.shadow_rays`,
  :func:`~.soft_lights.soft_visibility`, :func:`~.whitted.shade`); for that the records keep
  per node what re-shading needs: hit point, normals, ray direction, shadow origin,
  material, texture coordinates and the soft samples' seed.

Terms are float64 because recombination is then exact: float32 terms would differ from a
fresh frame in the last bits of about half the pixels. The cost is memory (about
``177 + 25 (L + 2)`` bytes per node for ``L`` light slots); a cap
(``RenderSettings.relight_memory_mb``) drops the records when a frame's would be larger,
and light edits then take the per-pixel records' path (re-tracing what they touched).

Nodes are laid out as :class:`~.pixel_records.PixelRecords` lays out its nodes (primary
nodes by global sample id, secondary nodes in its order), which owns and fills these
records, so that a node's light bits there can be updated after a relit light.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..accel.accelerators import Hits
from ..geometry.scene import SceneArrays
from .batches import accumulate, threads_for
from .shader import Surfaces, light_state
from .soft_lights import soft_visibility, world_lights
from .whitted import shade, shadow_rays

#: the per-node arrays (their trailing shapes; ``L`` the light slots)
_VEC = ("weight", "point", "dir", "NG", "NS", "Q")
_KEYS = _VEC + ("u", "v", "seed", "mat", "prim", "enter", "t_val", "t_on")
_DTYPES = dict(u=np.float64, v=np.float64, seed=np.uint64, mat=np.int32, prim=np.int32,
               enter=np.bool_, t_val=np.float64, t_on=np.bool_)


def node_bytes(n_lights: int) -> int:
    """Bytes per ray-tree node of the records with ``n_lights`` light slots."""
    return 6 * 24 + 8 + 8 + 8 + 4 + 4 + 1 + (n_lights + 2) * 25


def _alloc(k: int, n_lights: int) -> dict:
    c = n_lights + 2
    out = {key: np.zeros((k, 3)) for key in _VEC}
    for key in ("u", "v", "seed", "mat", "prim", "enter"):
        out[key] = np.zeros(k, _DTYPES[key])
    out["t_val"] = np.zeros((k, c, 3))
    out["t_on"] = np.zeros((k, c), np.bool_)
    return out


def _level_arrays(levels: list) -> dict:
    cat = np.concatenate
    return dict(weight=cat([lv["weight"] for lv in levels]),
                point=cat([lv["point"] for lv in levels]),
                dir=cat([lv["dir"] for lv in levels]),
                NG=cat([lv["NG"] for lv in levels]), NS=cat([lv["NS"] for lv in levels]),
                Q=cat([lv["Q"] for lv in levels]), u=cat([lv["u"] for lv in levels]),
                v=cat([lv["v"] for lv in levels]), seed=cat([lv["seed"] for lv in levels]),
                mat=cat([lv["mat"] for lv in levels]), prim=cat([lv["prim"] for lv in levels]),
                enter=cat([lv["enter"] for lv in levels]),
                t_val=cat([lv["t_val"] for lv in levels]),
                t_on=cat([lv["t_on"] for lv in levels]))


# ----------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True, inline="always")
def _node_radiance(k, w, mat, t_val, t_on, order, scale, world, E):
    """One node's contribution, in the shader's order of operations."""
    if mat[k] < 0:
        return (w[k, 0] * (t_val[k, E, 0] * world[0]), w[k, 1] * (t_val[k, E, 1] * world[1]),
                w[k, 2] * (t_val[k, E, 2] * world[2]))
    lr = t_val[k, E, 0]
    lg = t_val[k, E, 1]
    lb = t_val[k, E, 2]
    for t in range(order.shape[0]):
        c = order[t]
        if t_on[k, c]:
            lr += t_val[k, c, 0] * scale[c, 0]
            lg += t_val[k, c, 1] * scale[c, 1]
            lb += t_val[k, c, 2] * scale[c, 2]
    return w[k, 0] * lr, w[k, 1] * lg, w[k, 2] * lb


@njit(cache=True, nogil=True, parallel=True)
def _recombine_primary(w, mat, t_val, t_on, order, scale, world, rad):
    E = t_val.shape[1] - 1
    for g in prange(w.shape[0]):
        r, gg, b = _node_radiance(g, w, mat, t_val, t_on, order, scale, world, E)
        rad[g, 0] = 0.0 + r
        rad[g, 1] = 0.0 + gg
        rad[g, 2] = 0.0 + b


@njit(cache=True, nogil=True)
def _recombine_secondary(w, mat, t_val, t_on, order, scale, world, s_ray, rad):
    """Secondary nodes in the records' order (per sample, the tracer's level order),
    serially: samples repeat."""
    E = t_val.shape[1] - 1
    for k in range(w.shape[0]):
        r, gg, b = _node_radiance(k, w, mat, t_val, t_on, order, scale, world, E)
        g = s_ray[k]
        rad[g, 0] += r
        rad[g, 1] += gg
        rad[g, 2] += b


@njit(cache=True, nogil=True, parallel=True)
def _one_light_states(sa, j, P, NG, NS, Q, mat, state):
    """Shadow-ray state (:func:`~.whitted.light_state`) of light ``j`` at every node
    (misses: not facing)."""
    for i in prange(P.shape[0]):
        state[i] = -2
        if mat[i] >= 0:
            state[i] = light_state(sa, j, P[i, 0], P[i, 1], P[i, 2], NG[i, 0], NG[i, 1],
                                   NG[i, 2], NS[i, 0], NS[i, 1], NS[i, 2], Q[i, 0], Q[i, 1],
                                   Q[i, 2])


_loaded = [False]


def load_kernels(n_lights: int) -> None:
    """Load (or compile) the recombination kernels once per process, after the first
    frame that keeps light terms, so that the first light edit does not pay it."""
    if _loaded[0]:
        return
    _loaded[0] = True
    c = n_lights + 2
    w, tv, tp = np.zeros((0, 3)), np.zeros((0, c, 3)), np.zeros((0, c), np.bool_)
    mat, order, scale = np.zeros(0, np.int32), np.zeros(0, np.int64), np.zeros((c, 3))
    rad = np.zeros((0, 3))
    _recombine_primary(w, mat, tv, tp, order, scale, np.zeros(3), rad)
    _recombine_secondary(w, mat, tv, tp, order, scale, np.zeros(3), np.zeros(0, np.int64), rad)


# ----------------------------------------------------------------------------- records


class LightRecords:
    """Light terms of every node of a frame's samples (see the module doc), laid out as
    the owning :class:`~.pixel_records.PixelRecords`' nodes. ``overflow``: None, or why the
    records were dropped (the cap); then nothing else is kept."""

    def __init__(self, n_rays: int, n_lights: int, cap_bytes: float) -> None:
        self.n_rays = int(n_rays)
        self.L = int(n_lights)
        self.cap = float(cap_bytes)
        self.overflow: str | None = None
        self.p: dict | None = None
        self.s: dict = _alloc(0, self.L)
        self._pending: list = []
        need = self.n_rays * node_bytes(self.L)
        if need > self.cap:
            self._drop(need)

    @property
    def nbytes(self) -> int:
        if self.p is None:
            return 0
        return int(sum(a.nbytes for d in (self.p, self.s) for a in d.values()))

    def _drop(self, need: float) -> None:
        self.overflow = (f"per-light records need at least {need / 1e6:.0f} MB, over the cap "
                         f"(setting 'relight_memory_mb' {self.cap / 1e6:.0f} MB): light "
                         f"edits re-trace the pixels they touch")
        self.p = None
        self.s = _alloc(0, self.L)
        self._pending = []

    def add(self, rays: np.ndarray, levels: list, nb: int) -> None:
        """A traced batch (the per-level dicts of :func:`~.whitted.trace`'s ``segments``
        with ``terms``); ``rays`` (nb,) its global sample ids."""
        if self.overflow is not None:
            return
        a = _level_arrays(levels)
        self.widen(a["t_val"].shape[1] - 2)  # (a light slot added in a re-traced batch)
        if self.p is None:
            self.p = _alloc(self.n_rays, self.L)
        for key in _KEYS:
            self.p[key][rays] = a[key][:nb]
        if len(a["mat"]) > nb:
            self._pending.append({key: a[key][nb:] for key in _KEYS})

    def finish(self, keep: np.ndarray | None) -> None:
        """Drop the secondary nodes not in ``keep`` (None: keep all), then append the
        batches added since (as :meth:`~.pixel_records.PixelRecords.finish` does)."""
        if self.overflow is not None:
            return
        if keep is not None and not keep.all():
            self.s = {key: a[keep] for key, a in self.s.items()}
        if self._pending:
            parts = [self.s] + self._pending
            self.s = {key: np.concatenate([d[key] for d in parts]) for key in _KEYS}
            self._pending = []
        need = (self.n_rays + len(self.s["mat"])) * node_bytes(self.L)
        if need > self.cap:
            self._drop(need)

    def widen(self, n_lights: int) -> None:
        """Light slots were added: their columns (nothing present yet) go before the
        world's and the emission's."""
        if n_lights <= self.L or self.overflow is not None:
            return
        for d in ((self.p,) if self.p is not None else ()) + (self.s,):
            for key in ("t_val", "t_on"):
                old = d[key]
                new = np.zeros((old.shape[0], n_lights + 2) + old.shape[2:], old.dtype)
                new[:, :self.L] = old[:, :self.L]
                new[:, n_lights:] = old[:, self.L:]
                d[key] = new
        self.L = int(n_lights)

    # -- relighting ----------------------------------------------------------------------

    def recombine(self, sa: SceneArrays, s_ray: np.ndarray, spp: int, n_pixels: int
                  ) -> np.ndarray:
        """The frame's radiance (n_pixels, 3) float32 from the terms and the lights of
        ``sa``: the tracer's sums in its order (bit for bit a fresh frame's)."""
        L = len(sa.light_kind)
        self.widen(L)
        alive = np.asarray(sa.light_kind) >= 0
        ext = np.asarray(sa.light_ext, bool)
        order = list(np.flatnonzero(alive & ~ext)) + list(np.flatnonzero(alive & ext))
        if world_lights(sa):
            order.append(L)
        scale = np.zeros((L + 2, 3))
        scale[:L] = np.where(ext[:, None], sa.light_radiance, sa.light_intensity)
        scale[L] = sa.world_light
        order = np.asarray(order, np.int64)
        world = np.ascontiguousarray(sa.world_color, np.float64)
        rad = np.empty((self.n_rays, 3))
        p, s = self.p, self.s
        out = np.empty((n_pixels, 3), np.float32)
        pc = np.empty(n_pixels, np.uint8)
        inst = np.where(p["mat"] >= 0, 0, -1).astype(np.int32)
        # a few multiply-adds per node: one thread (a parallel region's wake-up on a busy
        # machine costs more than the work, see batches.SERIAL_BELOW)
        with threads_for(0):
            _recombine_primary(p["weight"], p["mat"], p["t_val"], p["t_on"], order, scale,
                               world, rad)
            if len(s["mat"]):
                _recombine_secondary(s["weight"], s["mat"], s["t_val"], s["t_on"], order,
                                     scale, world, np.ascontiguousarray(s_ray, np.int64), rad)
            accumulate(rad, inst, spp, out, pc)
        return out

    def relight(self, sa: SceneArrays, accel, j: int, light_samples: int,
                counters: dict | None = None):
        """Shade light ``j`` of ``sa`` again at every node (its term replaced, nothing
        else), with its own shadow rays through ``accel``, at the nodes it faces. Returns
        its per-node light bits for the pixel records: ``(traced, lit)`` of the primary
        nodes and of the secondary ones, each (k,) bool."""
        self.widen(len(sa.light_kind))
        bits = []
        for d in (self.p, self.s):
            n = len(d["mat"])
            state = np.empty(n, np.int8)
            if n:
                with threads_for(n):
                    _one_light_states(sa, j, d["point"], d["NG"], d["NS"], d["Q"], d["mat"],
                                      state)
            d["t_on"][:, j] = False
            d["t_val"][:, j] = 0.0
            rows = np.flatnonzero(state != -2)  # the nodes it faces: a shadow ray each
            lit = np.zeros(n, bool)
            for a in range(0, len(rows), 1 << 16):
                idx = rows[a:a + (1 << 16)]
                lit[idx] = self._shade_one(sa, accel, j, light_samples, d, idx, state[idx],
                                           counters)
            bits.append((state != -2, lit))
        return bits[0], bits[1]

    def _shade_one(self, sa, accel, j, light_samples, d, idx, state, counters):
        """Light ``j``'s terms at nodes ``idx`` of ``d`` (their states ``state``), by the
        tracer's own stages; returns whether it is visible from each."""
        L = len(sa.light_kind)
        k = len(idx)
        sh_state = np.full((k, L), -2, np.int8)
        sh_state[:, j] = state
        surf = Surfaces(*(np.ascontiguousarray(d[key][idx])
                          for key in ("point", "NG", "NS", "dir", "enter", "mat", "Q")),
                        sh_state.reshape(-1))
        with threads_for(k):
            todo, so, sd, st = shadow_rays(sa, surf)
            vis = np.zeros(k * L, np.bool_)
            if len(todo):
                vis[todo] = ~np.asarray(accel.any_hit(so, sd, np.zeros(len(todo)), st),
                                        np.bool_)
                if counters is not None:
                    counters["shadow"] = counters.get("shadow", 0) + len(todo)
            sa1 = sa._replace(world_light=np.zeros(3))  # the world's samples are not redone
            soft = None
            if sa.light_ext[j]:
                def occluded(o, dd, tmax, r):
                    return accel.any_hit(o, dd, np.zeros(len(o)), tmax)
                soft, srows, any_vis = soft_visibility(
                    sa1, surf, np.ascontiguousarray(d["seed"][idx]), int(light_samples),
                    surf.sh_state, occluded, counters)
                vis[srows[srows >= 0]] = any_vis[srows >= 0]
            hits = Hits(np.zeros(k), np.zeros(k, np.int32), np.ascontiguousarray(d["prim"][idx]),
                        np.ascontiguousarray(d["u"][idx]), np.ascontiguousarray(d["v"][idx]))
            _, _, (tv, tp) = shade(sa1, hits, surf, vis, np.ones((k, 3)), False, soft, True)
        d["t_on"][idx, j] = tp[:, j]
        d["t_val"][idx, j] = tv[:, j]
        return vis.reshape(k, L)[:, j]
