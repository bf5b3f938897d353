"""When an RI-tree does not pay: the per-object, measured decision to trace an object instead
("model only what a scene requires", issue 9).

After every RI_TREE frame the renderer compares, per object with a tree, what its queries
cost with what tracing them would have cost, from the frame's own counts and timings:

* with the tree: its share of the queries' lookups and tests (the frame's query time
  without sampling, split by query count), its share of the samples traced for the trees
  (split by sample count, counted at ``1 / SAMPLE_FRAMES``: a tree refined in one frame
  serves the next ones of a session), and the rays traced anyway after a failed query
  (each at the measured cost of one ray against one object);
* traced: every query as one ray against the object, plus the rays an interpolated answer
  skipped (the internal segments of a glass path, the exit crossing of the thickness
  view), each at the measured cost of one ray of the traced scene.

An object whose tree costs more (:func:`tree_pays` False) over at least
:data:`MIN_QUERIES` queries is traced from the next frame on and its tree is freed; it stays
traced until an edit changes it or the RI-tree settings change.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

#: a frame counts this fraction of its samples' cost against a tree (samples are kept)
SAMPLE_FRAMES = 4
#: an object is judged only over at least this many queries in one frame
MIN_QUERIES = 256


class FrameCosts(NamedTuple):
    """What one frame measured, per instance slot (arrays (I,)) and in total (seconds)."""

    queries: np.ndarray  # (I,) int64 RI queries of the object
    failed: np.ndarray  # (I,) int64 of them traced after all (failed tests, sparse leaves)
    skipped: np.ndarray  # (I,) int64 rays interpolated answers saved beyond the entry
    samples: np.ndarray  # (I,) int64 samples traced for the object's tree
    lookup_s: float  # the frame's query time without sampling
    sample_s: float  # the frame's sampling time
    obj_ray_s: float  # one ray against one object
    ray_s: float  # one ray through the traced scene


def object_costs(c: FrameCosts) -> tuple[np.ndarray, np.ndarray]:
    """(tree, traced) seconds per object (module doc)."""
    q = c.queries.astype(np.float64)
    s = c.samples.astype(np.float64)
    lookups = c.lookup_s * q / max(q.sum(), 1.0)
    samples = c.sample_s * s / max(s.sum(), 1.0) / SAMPLE_FRAMES
    tree = lookups + samples + c.failed * c.obj_ray_s
    traced = q * c.obj_ray_s + c.skipped * c.ray_s
    return tree, traced


def tree_pays(c: FrameCosts) -> np.ndarray:
    """(I,) bool: False where an object's tree cost more than tracing its queries over at
    least :data:`MIN_QUERIES` queries (those objects fall back to tracing)."""
    tree, traced = object_costs(c)
    return ~((c.queries >= MIN_QUERIES) & (tree > traced))


class Ledger:
    """One frame's counts and CPU times for :class:`FrameCosts` (``cache``: the frame's
    :class:`~.cache.RITreeCache`, whose sampling time and per-object samples it reads)."""

    def __init__(self, cache) -> None:
        n = len(cache.inst_samples)
        self.cache = cache
        self.queries = np.zeros(n, np.int64)
        self.failed = np.zeros(n, np.int64)
        self.skipped = np.zeros(n, np.int64)
        self.samples0 = cache.inst_samples.copy()
        self.sample_s0 = cache.counters["sample_s"]
        self.time = dict(query=[0.0, 0], ray=[0.0, 0], obj=[0.0, 0])

    def timed(self, key: str, n: int, fn, *args):
        """``fn(*args)``; its CPU time and ``n`` rays are added to ``key`` ("query": RI
        queries, "ray": rays through the traced scene, "obj": rays against one object)."""
        t = time.process_time()
        out = fn(*args)
        acc = self.time[key]
        acc[0] += time.process_time() - t
        acc[1] += n
        return out

    def count(self, queried, failed, skipping, skipped) -> None:
        """Objects of a query batch's rays, of those traced after all, and of interpolated
        answers that saved ``skipped`` rays each beyond the entry."""
        m = len(self.queries)
        self.queries += np.bincount(queried, minlength=m)
        self.failed += np.bincount(failed, minlength=m)
        self.skipped += np.bincount(skipping, weights=skipped, minlength=m).astype(np.int64)

    def costs(self) -> FrameCosts | None:
        """The frame's :class:`FrameCosts` (None when it traced no ray to price one by)."""
        c = self.cache
        sample_s = c.counters["sample_s"] - self.sample_s0
        (rt, rn), (ot, on) = self.time["ray"], self.time["obj"]
        ray_s = rt / rn if rn else 0.0
        obj_s = ot / on if on else ray_s
        if obj_s <= 0.0:
            return None
        return FrameCosts(self.queries, self.failed, self.skipped,
                          c.inst_samples - self.samples0,
                          max(self.time["query"][0] - sample_s, 0.0), sample_s, obj_s,
                          ray_s if ray_s > 0.0 else obj_s)
