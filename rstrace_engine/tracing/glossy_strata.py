"""A rough point's glossy samples stratified across its pixel's samples (issue 24, session
34; docs/glossy.md, "session 34"), and where a level's spawned rays go on (:func:`child_paths`).

Without strata a path's first rough bounce draws its G samples (Glossy Samples) from a
Fibonacci lattice of G points rotated by a hash of its node's seed
(:func:`~.glossy_rays._glossy_rays`): the lattices of a pixel's S samples are independent,
so S x G directions cover the lobe no better than S independent sets of G. With strata (a
pixel's seed, shared by its samples, and each sample's index ``s`` of S; :func:`pixel_strata`)
the first rough bounces of a pixel's samples on the same ray-tree path draw from **one
lattice of N = S x G points**, rotated by a hash of the pixel's seed and the path: sample
``s`` takes the points ``s, s + S, ..., s + (G - 1) S``, so the pixel's samples cover the
lobe jointly. (Since session 43 G is the point's own count,
:func:`~.glossy_rays.glossy_counts`: 2 G on a metal, by the view on a plastic; the lattice
is ``S x`` that count, so samples whose counts differ draw from lattices of other sizes
under the same rotation: each sample's points still 1 / n apart and uniform, not one joint
lattice.) A deeper rough bounce (one direction) keeps its own node seed's draw: taking
a permuted point of a lattice shared by the N paths that reach it was tried and measured
worse (docs/glossy.md).

Each point stays uniform over the lattice's domain (the rotation is uniform and independent
of the pixel jitter's scramble), so the estimate is unbiased as before; the strata depend on
the pixel, the sample's index and the ray-tree path only: deterministic, the same in a full
frame, an incremental one and a pixel record's re-trace. At one pixel sample the lattice is
the point's own G points (another rotation).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .glossy_rays import has_glossy
from .soft_lights import mix64, sample_seeds

#: hashed into a path's lattice seed (with the pixel's and the path)
STRATA_SALT = np.uint64(0x5851F42D4C957F2D)
#: hashed into a pixel's strata seed (from its sample 0's seed: the pixel's samples share it)
PIXEL_SALT = np.uint64(0x2545F4914F6CDD1D)


class Strata(NamedTuple):
    """Per input ray: its pixel's strata seed (shared by the pixel's samples) and its
    sample's index of ``count`` samples per pixel."""

    seed: np.ndarray  # (n,) uint64
    index: np.ndarray  # (n,) int64 in [0, count)
    count: int

    def take(self, rows) -> Strata:
        """The strata of input rays ``rows`` (an index array or a slice)."""
        return Strata(self.seed[rows], self.index[rows], self.count)


def pixel_strata(gids: np.ndarray, npix: int, seed: int, spp: int) -> Strata:
    """:class:`Strata` of the pixel samples with global ids ``gids`` (``sample * npix +
    pixel``) of a frame of ``npix`` pixels, ``spp`` samples each, and the frame's ``seed``."""
    g = np.ascontiguousarray(gids, np.int64)
    pix = g % npix
    return Strata(_pixel_seeds(sample_seeds(pix, seed)), g // npix, max(1, int(spp)))


def draws_glossy(sa, max_depth: int) -> bool:
    """Whether a frame of the scene (its :class:`~.geometry.scene.SceneArrays` ``sa``) at ray
    depth ``max_depth`` draws glossy rays: a rough surface and a depth above 0. The one
    place that decides whether a frame computes strata (:func:`frame_strata`) and whether
    the interpolants look for rough roots."""
    return int(max_depth) > 0 and has_glossy(sa)


def frame_strata(sa, max_depth: int, gids: np.ndarray, npix: int, seed: int,
                 spp: int) -> Strata | None:
    """:func:`pixel_strata` of a frame's pixel samples ``gids``, or None where the frame
    draws no glossy rays (:func:`draws_glossy`): their cost is the rough scenes' only (the
    base tracer's tiles, the interpolants' passes and tail and the RI-tree's tiles all ask
    here)."""
    if not draws_glossy(sa, max_depth):
        return None
    return pixel_strata(gids, npix, seed, spp)


@njit(cache=True, nogil=True)
def _pixel_seeds(s):
    out = np.empty_like(s)
    for k in range(s.shape[0]):
        out[k] = mix64(s[k] ^ PIXEL_SALT)
    return out


def no_strata(n: int) -> np.ndarray:
    """The shade kernel's lattice rows when nothing is stratified (each point its own)."""
    return np.zeros((0, 4), np.uint64)


@njit(cache=True, nogil=True)
def _lattices(pseed, index, src, path, fresh, glossy, spp, counts, out):
    for i in range(src.shape[0]):
        out[i, 0] = out[i, 1] = out[i, 2] = out[i, 3] = np.uint64(0)
        if glossy[i] and fresh[i]:  # n points, one every S, from the sample's index
            r = src[i]
            out[i, 0] = mix64(pseed[r] ^ mix64(np.uint64(path[i])) ^ STRATA_SALT)
            out[i, 1] = np.uint64(index[r] % spp)
            out[i, 2] = np.uint64(spp)
            out[i, 3] = np.uint64(spp * max(1, counts[i]))


def lattices(strata: Strata | None, src, path, fresh, glossy, counts):
    """(n, 4) uint64 rows of a level's points (input rays ``src``, ray-tree paths ``path``,
    ``fresh`` their paths' first rough bounce, ``glossy`` drawing glossy rays, ``counts``
    (n,) int64 their glossy samples, or one int for all: :func:`~.glossy_rays.glossy_counts`)
    for :func:`~.glossy_rays._glossy_rays`: the lattice's rotation seed, the point's first
    lattice index, the step between its samples' indices and the lattice's size (``S x
    count``); a zero row (size 0: the point's own lattice) where a point is not a first
    rough bounce; an empty array where ``strata`` is None (each point its own). A pixel's
    samples that hit a material at the same path with the same count cover one lattice
    jointly; with different counts (a layer's, which follows the view) each sample's points
    are still spread over the lobe, and every point is uniform: unbiased either way."""
    if strata is None or glossy is None:
        return no_strata(len(src))
    out = np.empty((len(src), 4), np.uint64)
    c = (np.full(len(src), counts, np.int64) if np.ndim(counts) == 0  # (one writable
         else np.require(counts, np.int64, ("C", "W")))  # signature: not a read-only view)
    _lattices(strata.seed, np.ascontiguousarray(strata.index, np.int64),
              np.ascontiguousarray(src, np.int64), np.ascontiguousarray(path, np.int64),
              np.ascontiguousarray(fresh, np.bool_), np.ascontiguousarray(glossy, np.bool_),
              np.int64(strata.count), c, out)
    return out


def child_paths(slots: np.ndarray, gstart: np.ndarray | None, glossy: np.ndarray | None,
                fresh: np.ndarray, tag: np.ndarray, nseeds: np.ndarray | None):
    """Where spawned rays ``slots`` (indices into a level's :class:`~.shader.Spawned`) come
    from and how their paths go on, as :func:`~.whitted.trace` follows them: ``(which (k,)
    int64 their points, fresh (k,) bool no glossy samples drawn yet on their paths, tag (k,)
    uint64 hashed into their node seeds: a glossy sample's hashes its point's seed
    ``nseeds`` and its sample index, any other keeps its point's)``; ``gstart``, ``glossy``
    as :func:`~.whitted.shade_paths` returns them, ``fresh``, ``tag`` the points'."""
    pair = slots // 2
    if gstart is None:
        return pair, fresh[pair], tag[pair]
    which = np.searchsorted(gstart, pair, side="right") - 1
    out = np.empty(len(slots), np.uint64)
    _child_tags(nseeds, which, pair - gstart[which], glossy, tag, out)
    return which, fresh[which] & ~glossy[which], out


@njit(cache=True, nogil=True, inline="always")
def _glossy_tag(nseed, sample):
    """A glossy sample's tag: its point's node seed hashed with its sample index (its
    children's seeds differ from its siblings')."""
    return mix64(nseed ^ mix64(np.uint64(sample + 1)))


@njit(cache=True, nogil=True)
def _child_tags(nseeds, which, sample, glossy, tag, out):
    """Tags of spawned rays: a glossy sample's :func:`_glossy_tag`, any other keeps its
    parent's."""
    for k in range(which.shape[0]):
        p = which[k]
        if glossy[p]:
            out[k] = _glossy_tag(nseeds[p], sample[k])
        else:
            out[k] = tag[p]


def next_paths(ok, gstart, glossy, src, path, fresh, tag, nseeds, ko, kd, kw, sees_lobe,
               sees_mirror, sees_refract):
    """A level's spawned rays in one pass (what :func:`child_paths`, a ``np.flatnonzero`` of
    ``ok`` and the gathers of the rays and their points' values gave, the same values):
    ``(slots, which, src, path, fresh, tag, sees, o, d, w)`` of the slots where ``ok``
    (2m,) bool, ``ko, kd, kw`` (2m, 3) the spawned rays, ``src, path, fresh, tag`` (n,) the
    points' (``path`` the child's: ``2 path + slot & 1``), ``sees`` (int8): ``sees_lobe``
    below a glossy point, else ``sees_refract`` for a refraction slot, ``sees_mirror`` for
    a reflection; ``gstart, glossy`` as :func:`child_paths` (None: one pair a point)."""
    n = len(fresh)
    if gstart is None:
        gstart = np.arange(n + 1, dtype=np.int64)
        glossy = np.zeros(n, np.bool_)
    if nseeds is None:
        nseeds = np.zeros(0, np.uint64)
    c = int(np.count_nonzero(ok))
    out = (np.empty(c, np.int64), np.empty(c, np.int64), np.empty(c, src.dtype),
           np.empty(c, np.int64), np.empty(c, np.bool_), np.empty(c, np.uint64),
           np.empty(c, np.int8), np.empty((c, 3)), np.empty((c, 3)), np.empty((c, 3)))
    _next_paths(ok, gstart, glossy, src, path, fresh, tag, nseeds, ko, kd, kw,
                np.int8(sees_lobe), np.int8(sees_mirror), np.int8(sees_refract), *out)
    return out


@njit(cache=True, nogil=True)
def _next_paths(ok, gstart, glossy, src, path, fresh, tag, nseeds, ko, kd, kw, s_lobe,
                s_mirror, s_refract, slots, which, c_src, c_path, c_fresh, c_tag, c_sees, o,
                d, w):
    """:func:`next_paths`' pass: ``which`` by a merge of the ascending slots with
    ``gstart`` (``searchsorted(gstart, slot // 2, "right") - 1``), the tags as
    :func:`_child_tags`'."""
    c = 0
    p = 0
    for s in range(ok.shape[0]):
        if not ok[s]:
            continue
        pair = s // 2
        while gstart[p + 1] <= pair:
            p += 1
        slots[c] = s
        which[c] = p
        c_src[c] = src[p]
        c_path[c] = path[p] * 2 + (s & 1)
        if glossy[p]:
            c_fresh[c] = False
            c_tag[c] = _glossy_tag(nseeds[p], pair - gstart[p])
            c_sees[c] = s_lobe
        else:
            c_fresh[c] = fresh[p]
            c_tag[c] = tag[p]
            c_sees[c] = s_refract if s & 1 else s_mirror
        for a in range(3):
            o[c, a] = ko[s, a]
            d[c, a] = kd[s, a]
            w[c, a] = kw[s, a]
        c += 1
