"""The continuation check (issue 22): pixels re-traced where what an interpolated ray went on
to meet is not the same across a pixel's neighbourhood.

The cell test (:mod:`.tree_cache`) bounds an object's interpolated output rays by its own
geometry, but not what they meet next: an exit ray a hundredth of a degree off lands a
millimetre from the exact point, and where that point is on the edge of a shadow or of
another object's silhouette the sample's colour flips (the random volumes at 300x300 x9: a
floor seen through a blob at the edge of the blob's own shadow, docs/RI_TREE.md). The
objects beyond are not the tree's to test (a tree depends on its object alone), but the
frame sees them: every sample of an RI_TREE frame carries a *continuation key*, a hash of
what its ray tree met outside the RI-tree objects (per node: its ray-tree path, the instance
hit or a miss, and which lights its shadow rays found visible), and whether any of its nodes
was interpolated (*tainted*). Nodes on an RI-tree object are left out of the key: a traced
path through glass has hits inside the object that an interpolated exit skips, and both
carry the same key to the same landing point.

A pixel with a tainted sample whose 3x3 neighbourhood of samples (its own and its
neighbours', all of them) holds more than one key is near an edge of what the continuations
meet: one of its interpolated samples may be on the wrong side. Its samples are traced again
by the base tracer (:func:`~..tracing.whitted.trace_pixels`: the same rays, jitter and seeds
as a base frame), so the pixel is the base frame's, bit for bit. Elsewhere the neighbourhood
agrees: a flip there needs an error larger than a pixel's footprint, which the cell test
bounds. Pixels over smooth glass in front of a uniform background never differ; those along
shadow edges and silhouettes seen through glass or in mirrors are re-traced (measured:
docs/RI_TREE.md).
"""

from __future__ import annotations

import numpy as np

from ..cancel import cancelled
from ..geometry.cameras import pixel_jitter
from ..tracing.batches import TILE_RAYS, accumulate
from ..tracing.whitted import trace_pixels

_K_PATH = np.uint64(0x9E3779B97F4A7C15)
_K_INST = np.uint64(0xC2B2AE3D27D4EB4F)
_K_LIGHT = np.uint64(0x165667B19E3779F9)


def _mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser (wrapping uint64 arithmetic)."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def node_keys(path: np.ndarray, inst: np.ndarray, vis: np.ndarray) -> np.ndarray:
    """(nb,) uint64 keys of a level's nodes: ``path`` (nb,) int64 ray-tree paths, ``inst``
    (nb,) instance hit (-1: a miss), ``vis`` (nb, L) bool lights found visible."""
    with np.errstate(over="ignore"):
        k = _mix(path.astype(np.uint64) * _K_PATH
                 ^ (inst.astype(np.int64) + 1).astype(np.uint64) * _K_INST)
        for light in range(vis.shape[1]):
            k = _mix(k ^ vis[:, light].astype(np.uint64) * _K_LIGHT
                     + np.uint64(light + 1))
    return k


class Continuations:
    """The frame's continuation keys and taint (module doc), filled tile by tile, kept per
    pixel (17 bytes, whatever the samples): ``lo``, ``hi`` (h * w,) uint64 the least and
    the largest key of its samples (a sample's key: the sum of its nodes' keys, the nodes
    of a level coming in any order); ``taint`` (h * w,) bool: one of them tainted."""

    def __init__(self, w: int, h: int, spp: int) -> None:
        self.w, self.h, self.spp = w, h, spp
        self.lo = np.zeros(h * w, np.uint64)
        self.hi = np.zeros(h * w, np.uint64)
        self.taint = np.zeros(h * w, np.bool_)

    def store(self, pix: np.ndarray, key: np.ndarray, taint: np.ndarray) -> None:
        """A tile's samples (sample-major over its pixels ``pix``)."""
        key = key.reshape(self.spp, len(pix))
        self.lo[pix] = key.min(axis=0)
        self.hi[pix] = key.max(axis=0)
        self.taint[pix] = taint.reshape(self.spp, len(pix)).any(axis=0)

    def flagged(self) -> np.ndarray:
        """(k,) int64 pixels to re-trace: a tainted sample, and more than one key among the
        samples of its 3x3 neighbourhood (the frame's border clamps it)."""
        h, w = self.h, self.w
        lo = _neighbourhood(self.lo.reshape(h, w), np.minimum)
        hi = _neighbourhood(self.hi.reshape(h, w), np.maximum)
        return np.flatnonzero((self.taint.reshape(h, w) & (lo != hi)).ravel())


def _neighbourhood(a: np.ndarray, op) -> np.ndarray:
    """``op`` over each element's 3x3 neighbourhood of the 2D array ``a``."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    out = a.copy()
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            out = op(out, p[dy:dy + h, dx:dx + w])
    return out


def retrace(sa, accel, cp, pixels: np.ndarray, spp: int, seed: int, max_depth: int,
            light_samples: int, glossy_samples: int, image: np.ndarray,
            pclass: np.ndarray, counters: dict, cancel=None) -> int:
    """Trace ``pixels`` (k,) int64 again with the base tracer (every sample, as a base
    frame traces them), writing their means into ``image`` (h * w, 3) and their classes
    into ``pclass`` (h * w,). ``cancel()`` is polled between batches: returns the number of
    pixels done, in order. (The frame's count of samples left out stays its first
    pass's.)"""
    chunk = max(1, TILE_RAYS // max(1, spp))
    w, h = cp.width, cp.height
    cc: dict = {}
    done = 0
    for a in range(0, len(pixels), chunk):
        if cancelled(cancel):
            break
        pix = pixels[a:a + chunk]
        jitter = pixel_jitter(pix, spp, seed=seed)
        gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * h) + pix[None, :]).ravel()
        rad, inst = trace_pixels(sa, accel, cp, np.tile(pix, spp), jitter.reshape(-1, 2),
                                 max_depth, None, cc, None, gids, seed, light_samples,
                                 False, glossy_samples, spp)
        out = np.empty((len(pix), 3), np.float32)
        cls = np.empty(len(pix), np.uint8)
        accumulate(rad, inst, spp, out, cls)
        image[pix] = out
        pclass[pix] = cls
        done += len(pix)
    counters["rays"] = counters.get("rays", 0) + cc.get("primary", 0) + cc.get("secondary", 0)
    counters["shadow"] = counters.get("shadow", 0) + cc.get("shadow", 0)
    return done
