"""The pixels of kept interpolants take a light edit's term without being rendered again.

Issue 21, items 3 and 4 in INTERPOLANT mode. A light edit that keeps an interpolant changes
its corners by a sum of light terms: an added light ``j`` (:mod:`.added_light`) adds
``S_j I_j`` to every corner sample, a power or colour change or a deletion
(:mod:`.relight`) adds ``S_j (I'_j - I_j)`` -- ``S_j`` the sample's share of light ``j`` --
and a moved one (:mod:`.moved_light`) ``S'_j I'_j - S_j I_j``. Each cell's 16 corner terms
are taken when the batch is applied (a later batch before the frame may move a light and
change its shares).
The interpolation is quadrilinear in the corners (:func:`~.linetree.interpolate16`), so an
interpolated pixel sample changes by the same interpolation of those terms, at the sample's
own line coordinates in the cell. Before, every pixel of such a cell was rendered again (its
camera ray, the walk down the linetrees, the interpolation, its world and sampled terms
taken from the records, the pixel records); a cell the added light proved dark at every
corner (its corners unchanged) was rendered again too.

Now the batch hands the frame reuse a :class:`TermEdit`: the kept cells whose corners took
the terms (``cells``), those an added light left unchanged (``quiet``) and the terms' scale
per light slot. A pixel whose samples were all interpolated by one of those cells (none
traced, none re-rendered by every frame) is not dirty: a quiet cell's pixel is unchanged, a
cell's pixel gains ``sum_c w_c(u) sum_j S_j[c] dI_j`` per sample (:func:`_deltas`: its
camera ray, regenerated with the frame's jitter, gives its line coordinates ``u`` in the
cell, as the walk computed them), averaged over its samples; a sample whose world term the
records keep apart gains it in its kept radiance (``rest``), so that a later world edit
recombines it with the term. The relit value equals the interpolation of the new corners
to float rounding: within the bound of the cell, whose radiance test was run again on the
new corners.

Not taken (rendered again, as before): cells on a rough root (their glossy rays, traced per
pixel, see the edited light), a rescaled, moved or added light with an extent that a
cell's root samples per pixel (its sampled term, :mod:`.sampled_term`, is outside the
interpolant: moved, it changes; added, it is new), pixels whose samples
used several interpolants, were traced, or are re-rendered by every frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..geometry.cameras import camera_rays, pixel_jitter
from ..tracing.edit_kernels import register
from ..tracing.glossy_rays import glossy_materials as rough_materials
from ..tracing.glossy_strata import draws_glossy
from .linetree import ray_line
from .relight import light_scale
from .samples import hit_materials
from .shafts import closed_forms, glossy_materials


class TermEdit(NamedTuple):
    """What a batch of light edits did to the kept interpolants (see the module doc)."""

    cache: object  # the interpolant cache
    cells: np.ndarray  # (k,) int32 interpolants whose corners took the terms
    quiet: np.ndarray  # (u,) int32 interpolants an added light left unchanged
    serial: np.ndarray  # (k,) int64 their serials (a freed and reused id takes nothing)
    corner: np.ndarray  # (k, 16, 3) what each of their corners gained in the batch
    added: frozenset  # the light slots added by the batch
    moved: frozenset = frozenset()  # the light slots moved by it (:mod:`.moved_light`)
    #: ``(ids, old serials, new serials)`` of the interpolants whose dependencies a moved
    #: light renewed (:func:`~.moved_light.renew_dependencies`), or None
    renewed: tuple | None = None

    def pixels(self, pi: np.ndarray, traced: np.ndarray, spp: int):
        """``(take, terms)`` (n_pixels,) bool: the pixels whose samples were all interpolated
        by a cell of :attr:`cells` or :attr:`quiet` (``pi`` the frame's pixel interpolants,
        ``traced`` (n_rays,) bool samples traced or re-rendered by every frame), and of
        those the ones that gain a term (``cells``)."""
        n = len(pi)
        own = pi >= 0
        ok = own & ~traced.reshape(spp, n).any(axis=0)
        terms = ok & np.isin(pi, self.cells)
        return terms | (ok & np.isin(pi, self.quiet)), terms

    def follow(self, renewed) -> None:
        """A later batch gave some of :attr:`cells` new serials (``renewed``, ``(ids, old
        serials, new serials)``: a moved light renewed their dependencies): they are the
        same cells, still to take this batch's terms."""
        ids, old, new = renewed
        at = np.full(int(max(ids.max(initial=-1), self.cells.max(initial=-1))) + 1, -1,
                     np.int64)
        at[ids] = np.arange(len(ids))
        r = at[self.cells]
        m = np.flatnonzero(r >= 0)
        m = m[self.serial[m] == old[r[m]]]
        self.serial[m] = new[r[m]]

    def deltas(self, cp, pix: np.ndarray, pi: np.ndarray, spp: int, seed: int):
        """``(delta (spp, k, 3), good (k,) bool)``: what each sample of pixels ``pix`` (their
        interpolants ``pi``) gains, through camera ``cp`` with the frame's jitter
        (``spp``, ``seed``); ``good`` False where a pixel's cell is gone or its line is not
        in it (to render again)."""
        cache = self.cache
        pool = cache.pool
        k = len(pix)
        delta = np.zeros((spp, k, 3))
        if k == 0:
            return delta, np.zeros(0, np.bool_)
        # only the cells still alive (a cell freed since the edit, by a later batch or the
        # memory cap, takes nothing: its pixels are rendered again)
        alive = pool.live[self.cells] & (pool.serial[self.cells] == self.serial)
        cells = self.cells[alive]
        corner = np.ascontiguousarray(self.corner[alive])  # (c, 16, 3)
        a = cache.trees.arrays
        node = pool.node[cells]
        at = np.full(len(pool.live), -1, np.int64)
        at[cells] = np.arange(len(cells))
        q = np.asarray(pi, np.int64)
        at = np.where((q >= 0) & (q < len(at)), at[np.clip(q, 0, len(at) - 1)], -1)
        good = at >= 0
        jit = pixel_jitter(pix, spp, seed=seed)
        for s in range(spp):
            o, d, _, _ = camera_rays(cp, pix, jit[s])
            _deltas(cache.box, a.tree[node], a.depth[node].astype(np.int64),
                    np.ascontiguousarray(a.coord[node], np.int64), corner, at, o, d, good,
                    delta[s])
        return delta, good


@njit(cache=True, nogil=True)
def _deltas(box, tree, depth, coord, corner, at, o, d, good, out):
    """``out[r]`` = the quadrilinear interpolation of cell ``at[r]``'s 16 ``corner`` terms
    at ray ``r``'s line coordinates in that cell (the walk's: :func:`~.linetree.ray_line`
    on the object's box, local coordinates in the leaf), one coordinate at a time;
    ``good[r]`` becomes False where the ray's face pair or coordinates are not the cell's,
    or the result is not finite. ``tree``, ``depth``, ``coord``: the cells' leaves'."""
    abcd = np.empty(4)
    u = np.empty(4)
    v = np.empty((16, 3))
    for r in range(at.shape[0]):
        if not good[r]:
            continue
        c = at[r]
        t = tree[c]
        f = ray_line(box, t // 6, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2], abcd)
        inside = f == t % 6
        s = float(1 << depth[c])
        for m in range(4):
            u[m] = abcd[m] * s - coord[c, m]
            if not 0.0 <= u[m] <= 1.0:
                inside = False
        if not inside:
            good[r] = False
            continue
        for k in range(16):
            v[k, 0] = corner[c, k, 0]
            v[k, 1] = corner[c, k, 1]
            v[k, 2] = corner[c, k, 2]
        size = 16
        for m in range(4):  # (corner bit m: coordinate m)
            size //= 2
            for i in range(size):
                for ch in range(3):
                    v[i, ch] = v[2 * i, ch] * (1.0 - u[m]) + v[2 * i + 1, ch] * u[m]
        for ch in range(3):
            if not np.isfinite(v[0, ch]):
                good[r] = False
            out[r, ch] = v[0, ch]


def _recombinable(cache, ids: np.ndarray, sas, ext_lights) -> np.ndarray:
    """(k,) bool: interpolants ``ids`` whose pixels' samples are their interpolation alone
    (plus terms the edit does not change): not on a rough root (its glossy rays are traced
    per pixel), and no light of ``ext_lights`` sampled at their root per pixel in either
    packing of ``sas`` (before and after; its term is outside the interpolant: a glossy
    lobe under a light with an extent, or a light with an extent without a closed
    form)."""
    ids = np.asarray(ids, np.int32)
    if len(ids) == 0:
        return np.zeros(0, np.bool_)
    sa = sas[0]
    inst = (cache.trees.arrays.tree[cache.pool.node[ids]] // 6).astype(np.int64)
    m = hit_materials(sa, inst, cache.pool.cls[ids])
    ok = m >= 0
    if draws_glossy(sa, cache.max_depth):
        ok &= ~rough_materials(sa)[np.maximum(m, 0)]
    for s in sas:
        ext = [j for j in ext_lights if j < len(s.light_kind) and s.light_kind[j] >= 0
               and bool(np.asarray(s.light_ext, bool)[j])]
        if ext and not np.all(closed_forms(s)[ext]):
            return np.zeros(len(ids), np.bool_)
        if ext:
            ok &= ~glossy_materials(s)[np.maximum(m, 0)]
    return ok


def term_edit(cache, old_sa, sa, slots, changed, quiet, rescaled, resc_lights, moved=(),
              delta=None, renewed=None):
    """The :class:`TermEdit` of a batch (None: nothing to take): light ``slots`` added
    or lights ``moved`` (``changed`` the live interpolants whose corners took their term,
    ``quiet`` those left unchanged; ``delta`` (n, 3) what each sample gained from the moved
    lights, :class:`~.moved_light.MoveResult`), lights ``resc_lights`` rescaled
    (``rescaled`` the live interpolants kept with their corners rescaled). ``old_sa``,
    ``sa``: the packings before and after. Each cell's corner terms are taken now, with
    the shares of this batch (a later batch may move a light: its shares change)."""
    L = len(sa.light_kind)
    scale = np.zeros((L, 3))
    new, old = light_scale(sa), light_scale(old_sa)
    for j in slots:
        scale[j] = new[j]
    for j in resc_lights:
        scale[j] += new[j] - old[j]
    sas = (old_sa, sa)
    # (a moved light with an extent before or after: its sampled terms, per pixel, move too;
    # an added one's are new)
    ext_lights = sorted(set(int(j) for j in resc_lights) | set(int(j) for j in moved)
                        | set(int(j) for j in slots))
    cells = np.union1d(np.asarray(changed, np.int32), np.asarray(rescaled, np.int32))
    cells = cells[_recombinable(cache, cells, sas, ext_lights)].astype(np.int32)
    quiet = np.setdiff1d(np.asarray(quiet, np.int32), cells)
    quiet = quiet[_recombinable(cache, quiet, sas, ext_lights)].astype(np.int32)
    if len(cells) == 0 and len(quiet) == 0 and renewed is None:
        return None
    # each cell's 16 corner terms (its samples' shares times the intensity changes, and
    # what the moved lights changed)
    sm, pool = cache.samples, cache.pool
    share, _ = sm.shares()
    on = np.flatnonzero(np.any(scale != 0.0, axis=1))
    on = on[on < share.shape[1]]
    s = pool.samples[cells]
    corner = np.einsum("cklm,lm->ckm", share[s][:, :, on], scale[on])
    if delta is not None:
        corner += delta[s]
    return TermEdit(cache, cells, quiet, pool.serial[cells].copy(), corner,
                    frozenset(int(j) for j in slots), frozenset(int(j) for j in moved),
                    renewed)


def load_kernels(records, sa, camera) -> None:
    """Load :func:`_deltas` with the end of a session's first INTERPOLANT frame that keeps
    light terms (:data:`~..tracing.edit_kernels.LOADERS`), not on its first light edit."""
    e3, i64 = np.zeros((0, 3)), np.zeros(0, np.int64)
    _deltas(np.zeros((0, 2, 3)), np.zeros(0, np.int32), i64, np.zeros((0, 4), np.int64),
            np.zeros((0, 16, 3)), i64, e3, e3, np.zeros(0, np.bool_), e3)


register("term_pixels", load_kernels, lambda records, sa: records.light.partial)
