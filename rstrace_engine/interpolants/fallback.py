"""When cells do not pay: the INTERPOLANT mode learns from measured costs where to trace
instead ("a user who picks interpolants never loses", issue 20), as the RI-tree's per-object
fallback (:mod:`..ri_tree.fallback`) does. Tracing is always exact, so whatever is decided
the frame keeps its bound; only the time changes.

Two mechanisms, both priced by the frame's own timings:

* **A build budget per frame** (:class:`Budget`). Building cells (tracing their samples, the
  predicate, the radiance test) may spend at most :data:`ALLOWANCE` of what tracing the
  frame's rays would cost, plus what the rays interpolated so far in the frame saved (each
  at the cost of one traced ray). It is checked between batches sized by what it has left
  (at the cost per cell measured so far; at least :data:`BUDGET_STEP` cells); a cell not
  built stays empty: its rays are traced now and a later frame builds it. This bounds the
  first frame, which has no history. The cost of a traced ray is learned from every frame's
  tracing; a renderer's first frame prices it with a *probe*: every
  :data:`PROBE_STRIDE`-th ray that hits is traced before any cell is built, timed (those
  rays are then done: exactly the base tracer's).
* **Per frame** (:func:`frame_pays`): when the frame's cells together cost more than
  tracing all its rays, the next frames are the base tracer's, as fast (objects too small to
  be judged alone included: on a scene of cheap pixels, the walk of a thousand small objects
  costs more than their pixels), until a re-probe every :data:`REPROBE_FRAMES` frames.
* **Per object** (:func:`cells_pay`). After every full frame, an object whose rays cost
  more with cells than tracing them all would have -- its share of the walk (by rays
  walked), of the builds (by cells built, counted at ``1 / BUILD_FRAMES``: a cell built
  serves the frames after it) and its rays traced after all -- over at least
  :data:`MIN_RAYS` rays, is traced from the next frame on: its rays skip the linetrees.
  Every :data:`REPROBE_FRAMES` frames it is tried again (a scene or a view that changed can
  make its cells win again), and an edit of the object gives it a new chance at once.

The decision is a function of the measured costs alone (:class:`FrameCosts`; the tests inject
them). ``frame.stats["fallback"]`` reports it: the objects traced, the cells the budget
deferred, the probe, the price of a ray.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

#: building may spend this fraction of what tracing the frame's rays costs (plus what the
#: rays interpolated so far saved); the rest of the 10% the mode may lose is the walk's
ALLOWANCE = 0.05
#: cells built between two looks at the budget
BUDGET_STEP = 64
#: a frame counts this fraction of its builds against an object (cells are kept)
BUILD_FRAMES = 4
#: an object is judged only over at least this many of its rays in one frame
MIN_RAYS = 4096
#: a traced object is tried with cells again after this many frames traced
REPROBE_FRAMES = 8
#: the probe of a renderer's first frame: every PROBE_STRIDE-th ray that hits, if at least
#: PROBE_MIN rays
PROBE_STRIDE = 64
PROBE_MIN = 64
#: a frame prices a traced ray only over at least this many traced rays
MIN_PRICE_RAYS = 256
#: the clock of every measurement (wall time: what the user waits for)
CLOCK = time.perf_counter


class FrameCosts(NamedTuple):
    """What one full frame measured, per instance slot (arrays (I,)) and in total (s)."""

    rays: np.ndarray  # (I,) int64 rays whose visible object it is (walked or reprojected)
    walked: np.ndarray  # (I,) int64 of them walked down its linetrees
    interpolated: np.ndarray  # (I,) int64 of them interpolated
    cells: np.ndarray  # (I,) int64 cells built of its linetrees
    walk_s: float  # the frame's resolve time without the builds
    build_s: float  # the frame's build time
    ray_s: float  # one traced ray (the frame's tracing time over its traced rays)


def object_costs(c: FrameCosts) -> tuple[np.ndarray, np.ndarray]:
    """(with cells, traced) seconds per object (module doc)."""
    w = c.walked.astype(np.float64)
    b = c.cells.astype(np.float64)
    walk = c.walk_s * w / max(w.sum(), 1.0)
    build = c.build_s * b / max(b.sum(), 1.0) / BUILD_FRAMES
    cells = walk + build + (c.rays - c.interpolated) * c.ray_s
    traced = c.rays * c.ray_s
    return cells, traced


def frame_pays(c: FrameCosts) -> bool:
    """False when the frame's cells together cost more than tracing all its rays over at
    least :data:`MIN_RAYS` rays (every object is traced then: small objects that are never
    judged alone included)."""
    cells, traced = object_costs(c)
    return not (c.rays.sum() >= MIN_RAYS and cells.sum() > traced.sum())


def cells_pay(c: FrameCosts) -> np.ndarray:
    """(I,) bool: False where an object's cells cost more than tracing its rays, over at
    least :data:`MIN_RAYS` rays (those objects are traced)."""
    cells, traced = object_costs(c)
    return ~((c.rays >= MIN_RAYS) & (cells > traced))


class Budget:
    """The build budget of one frame (module doc): ``rays`` the frame's rays, ``ray_s`` the
    price of one traced ray (None: not known yet, no limit until :meth:`price`)."""

    def __init__(self, rays: int, ray_s: float | None = None, n_inst: int = 0) -> None:
        self.rays = int(rays)
        self.deferred_inst = np.zeros(n_inst, np.int64)  # cells left unbuilt per object
        self.ray_s: float | None = None
        self.limit = float("inf")
        self.spent = 0.0  # seconds of building so far
        self.built = 0  # cells built so far
        self.saved = 0  # rays interpolated in the passes before the current one
        self.deferred = 0  # cells left unbuilt
        if ray_s is not None:
            self.price(ray_s)

    def price(self, ray_s: float) -> None:
        """Set the price of a traced ray (and so the limit)."""
        self.ray_s = float(ray_s)
        self.limit = ALLOWANCE * self.rays * self.ray_s

    def defer(self, inst: np.ndarray) -> None:
        """Cells of objects ``inst`` are left unbuilt."""
        self.deferred += len(inst)
        inst = inst[inst < len(self.deferred_inst)]
        np.add.at(self.deferred_inst, inst, 1)

    def charge(self, seconds: float, cells: int) -> None:
        """A batch of ``cells`` cells took ``seconds`` to build."""
        self.spent += seconds
        self.built += int(cells)

    def batch(self, step: int, interpolated_now: int) -> int:
        """How many cells the next batch may build (0: none), at most ``step``: what the
        budget left affords at the cost per cell measured so far, at least
        :data:`BUDGET_STEP` (small batches cost more per cell)."""
        if self.ray_s is None:
            return step
        if not self.may_build(interpolated_now):
            return 0
        if self.built == 0:
            return min(step, BUDGET_STEP)
        left = self.limit + (self.saved + interpolated_now) * self.ray_s - self.spent
        return min(step, max(BUDGET_STEP, int(left / (self.spent / self.built))))

    def may_build(self, interpolated_now: int) -> bool:
        """Whether the next batch may be built (``interpolated_now``: rays interpolated in
        the current pass so far)."""
        if self.ray_s is None:
            return True
        return self.spent <= self.limit + (self.saved + interpolated_now) * self.ray_s


class Fallback:
    """What INTERPOLANT mode has learned for one cache (module doc)."""

    def __init__(self, n_inst: int) -> None:
        self.traced = np.zeros(n_inst, np.bool_)  # objects traced instead of cells
        self.frames_traced = np.zeros(n_inst, np.int64)  # frames since last judged
        self.ray_s: float | None = None  # price of one traced ray, learned
        self.all_traced = False  # the whole frame did not pay: every object traced
        self.frames_all = 0  # frames since the whole frame was last judged
        self.last: FrameCosts | None = None

    def resize(self, n_inst: int) -> None:
        """Instance slots added by an edit start with cells."""
        m = len(self.traced)
        if n_inst > m:
            self.traced = np.concatenate([self.traced, np.zeros(n_inst - m, np.bool_)])
            self.frames_traced = np.concatenate([self.frames_traced,
                                                 np.zeros(n_inst - m, np.int64)])

    def forget(self, objects, n_inst: int = 0) -> None:
        """Edited objects get a new chance with cells (``n_inst``: the edited scene's
        instance slots, :meth:`resize`)."""
        self.resize(n_inst)
        idx = np.asarray([int(k) for k in objects if 0 <= int(k) < len(self.traced)], np.int64)
        self.traced[idx] = False
        self.frames_traced[idx] = 0

    def whole_frame_traced(self) -> bool:
        """Whether this frame is the base tracer's (the whole frame did not pay; not due
        for a re-probe)."""
        return self.all_traced and self.frames_all < REPROBE_FRAMES

    def frame_traced(self) -> np.ndarray:
        """(I,) bool: the objects a frame with cells traces (traced ones not due for a
        re-probe; none in the re-probe of a whole frame)."""
        if self.all_traced:
            return np.zeros(len(self.traced), np.bool_)
        return self.traced & (self.frames_traced < REPROBE_FRAMES)

    def learn(self, c: FrameCosts, traced_now: np.ndarray,
              deferred: np.ndarray | None = None) -> None:
        """After a full frame that traced the objects ``traced_now`` (its
        :meth:`frame_traced`): objects that went through cells are judged (:func:`cells_pay`)
        unless the budget deferred some of their cells (``deferred`` (I,) counts: they have
        not had their chance yet), the others count one more frame traced."""
        self.last = c
        if c.ray_s > 0.0:
            self.ray_s = float(c.ray_s)
        judged = ~traced_now
        if deferred is not None:
            judged &= deferred[:len(judged)] == 0
        pays = cells_pay(c)
        self.traced[judged] = ~pays[judged]
        self.frames_traced[judged] = 0
        self.frames_traced[traced_now] += 1
        # the whole frame (deferred cells or not: cheap pixels must not wait for them)
        self.all_traced = not frame_pays(c)
        self.frames_all = 0

    def stats(self, budget: Budget | None, probe_rays: int) -> dict:
        """The frame's ``stats["fallback"]``."""
        return dict(traced_objects=int(np.count_nonzero(self.traced)),
                    all_traced=bool(self.all_traced),
                    deferred_cells=0 if budget is None else int(budget.deferred),
                    build_budget_s=(None if budget is None or budget.ray_s is None
                                    else budget.limit),
                    probe_rays=int(probe_rays),
                    ray_us=None if self.ray_s is None else 1e6 * self.ray_s)


def count_cells(counts: np.ndarray, inst: np.ndarray, n_inst: int) -> np.ndarray:
    """``counts`` (cells built per instance slot) plus the cells of objects ``inst`` (grown
    to ``n_inst`` slots)."""
    if len(counts) < n_inst:
        counts = np.concatenate([counts, np.zeros(n_inst - len(counts), np.int64)])
    np.add.at(counts, inst, 1)
    return counts


class FrameLedger:
    """One frame's counts and times for :class:`FrameCosts` (``n_inst`` instance slots)."""

    def __init__(self, n_inst: int) -> None:
        self.rays = np.zeros(n_inst, np.int64)
        self.walked = np.zeros(n_inst, np.int64)
        self.interpolated = np.zeros(n_inst, np.int64)
        self.cells = np.zeros(n_inst, np.int64)
        self.walk_s = 0.0
        self.build_s = 0.0
        self.trace_s = 0.0
        self.traced_rays = 0

    def count(self, walked_inst, interpolated_inst, reprojected_inst) -> None:
        """Objects of a pass's walked rays, of those interpolated, and of its reprojected
        (interpolated, not walked) rays."""
        m = len(self.rays)
        w = np.bincount(walked_inst, minlength=m)[:m]
        r = np.bincount(reprojected_inst, minlength=m)[:m]
        self.walked += w
        self.rays += w + r
        self.interpolated += np.bincount(interpolated_inst, minlength=m)[:m] + r

    def costs(self, fallback: Fallback) -> FrameCosts | None:
        """The frame's :class:`FrameCosts` (None when no traced ray prices it)."""
        if self.traced_rays >= MIN_PRICE_RAYS:
            ray_s = self.trace_s / self.traced_rays
        elif fallback.ray_s is not None:
            ray_s = fallback.ray_s
        else:
            return None
        return FrameCosts(self.rays, self.walked, self.interpolated, self.cells,
                          max(self.walk_s, 0.0), self.build_s, ray_s)
