"""When cells do not pay: the INTERPOLANT mode learns from measured costs where to trace
instead ("a user who picks interpolants never loses", issue 20), as the RI-tree's per-object
fallback (:mod:`..ri_tree.fallback`) does. Tracing is always exact, so whatever is decided
the frame keeps its bound; only the time changes.

Three mechanisms, all priced by the frame's own timings:

* **A ledger per frame** (:class:`Budget`). A frame's passes go in tiles, and a tile in
  chunks (:mod:`.render`): a chunk goes through the cells or is traced whole by the base
  tracer. Everything the mode adds (the chunk's time but its tracing of the rays not
  interpolated: line coordinates, walk, builds, inserts, the interpolated pixels' own
  terms) may exceed what its interpolated rays saved (each :data:`SAVE_SHARE` of a traced
  ray's price) by :data:`ALLOWANCE` of the frame's base cost; once spent, the rest of the
  frame is traced. Builds are checked between batches sized by what it has left; a build is
  paid over the frame's passes it serves (a 4-sample frame's first pass pays a quarter), but
  owed at once: what the frame has left counts it whole (:meth:`Budget.left`); a chunk is
  sized by the walk's cost per ray alone (the cells built serve the chunks after it). A
  cell not built stays empty: its rays are traced now and a later frame builds it. The
  cost of a traced ray is learned from every frame's tracing; a renderer's first frame prices it by
  tracing its first chunk whole (:data:`PRICE_SHARE` of a pass, at least
  :data:`CHUNK_MIN` rays) before any cell is walked. On a cache that keeps no cell, the
  first walked chunk is priced before it is walked, at what the cache's last such chunk
  added (:data:`PRICE_FIRST_WALK`, :attr:`Fallback.first_walk`): a frame that cannot pay
  it walks nothing; after :data:`REPROBE_FRAMES` such frames in a row one walks and prices
  it again.
* **Per frame** (:func:`frame_pays`): when the frame's cells together cost more than
  tracing all its rays, the next frames are the base tracer's, as fast (objects too small to
  be judged alone included: on a scene of cheap pixels, the walk of a thousand small objects
  costs more than their pixels), until a re-probe every :data:`REPROBE_FRAMES` frames. A
  frame the ledger cut short is not judged (its cells walked a chunk or a pass, their builds
  served nothing yet) unless it is the :data:`CUT_FRAMES`-th such frame in a row or its walk
  alone, builds left out, did not pay. Nor is a frame during which numba compiled or loaded
  a kernel (:data:`SKIP_COMPILED`: its costs timed the compiler), up to
  :data:`COMPILED_FRAMES` in a row.
* **Per object** (:func:`cells_pay`). After every full frame judged, an object whose rays cost
  more with cells than tracing them all would have -- its share of the walk (by rays
  walked), of the builds (by cells built, counted at ``1 / BUILD_FRAMES``: a cell built
  serves the frames after it) and its rays traced after all -- over at least
  :data:`MIN_RAYS` rays, is traced from the next frame on: its rays skip the linetrees.
  Every :data:`REPROBE_FRAMES` frames it is tried again (a scene or a view that changed can
  make its cells win again), and an edit of the object gives it a new chance at once.

The decision is a function of the measured costs alone (:class:`FrameCosts`; the tests inject
them). ``frame.stats["fallback"]`` reports it: the objects traced, the ledger (allowance,
added, saved, rays walked), the cells deferred, the rays traced to price a ray, the price,
the first walk's price and whether it declined the frame's walk, and whether the frame
compiled or loaded a kernel (``compiled``: not judged).
"""

from __future__ import annotations

import threading
import time
from typing import NamedTuple

import numpy as np
from numba.core import event

from .. import kernel_cache

#: what the mode adds to a frame (walk, line coordinates, builds, inserts, the interpolated
#: pixels' own terms) may exceed what its interpolated rays saved by this fraction of the
#: frame's base cost; the rest of the 10% the mode may lose is its fixed bookkeeping and
#: the overshoot of one chunk (measured 3-6% on museum_1999's first frames, 2026-11-27)
ALLOWANCE = 0.02
#: an interpolated ray is counted as saving this share of a traced ray's price: the price is
#: the average of the rays traced, and the rays cells interpolate are the cheap ones (lights
#: fully visible or fully hidden over their cell: on `studio` the interpolated floor pixels
#: cost the base tracer 10.9 us against 16 us for the average ray it traces there)
SAVE_SHARE = 0.5
#: cells built between two looks at the budget: the first batch at most BUDGET_STEP, then
#: what the budget left affords at the measured cost per cell, at least BUDGET_MIN
BUDGET_STEP = 64
BUDGET_MIN = 8
#: before any is built, a cell is expected to cost this many traced rays (twice what cells
#: cost on museum_1999 at 1 spp, 250-300: a first frame's first batch stays in its allowance)
CELL_RAYS = 600
#: a frame counts this fraction of its builds against an object (cells are kept)
BUILD_FRAMES = 4
#: an object is judged only over at least this many of its rays in one frame
MIN_RAYS = 4096
#: a traced object is tried with cells again after this many frames traced
REPROBE_FRAMES = 8
#: a frame's chunks with cells: at least CHUNK_MIN rays (fewer: the rest of the pass is
#: traced), at most CHUNK_MAX (the base tracer's tile)
CHUNK_MIN = 4096
CHUNK_MAX = 1 << 15
#: a first frame prices a traced ray by tracing its first PRICE_SHARE of a pass (at least
#: CHUNK_MIN rays) before any cell is walked
PRICE_SHARE = 1 / 16
#: a frame prices a traced ray only over at least this many traced rays
MIN_PRICE_RAYS = 256
#: a frame the ledger cut short (the rest traced once the allowance was spent) is not judged
#: (its cells were judged over one chunk, its builds not yet served); this many in a row are
CUT_FRAMES = 2
#: the clock of every measurement (wall time: what the user waits for)
CLOCK = time.perf_counter
#: seconds per triangle of building a scene's surface topology (``"topo"``: a walk needs
#: it, for its lines) and the predicate's query structures (``"qs"``: a build needs them),
#: learned from the last build of each (None: not built yet in this process; the tests
#: turn the learning off, :data:`LEARN_STRUCTURES`, as they decide by given costs)
STRUCTURE_RATE: dict = {"topo": None, "qs": None}
LEARN_STRUCTURES = True
#: structures built so far in this process (:func:`timed_structure`), and numba's compiler
#: lock taken (every compile and every cache load takes it; a call of a loaded kernel does
#: not): a chunk that did either does not price a first walk (:data:`PRICE_FIRST_WALK`;
#: counters, not :func:`.kernel_cache.mark`: that walks every dispatcher, 7 ms a frame)
STRUCTURES_BUILT = [0]
NUMBA_LOCKS = [0]
_COUNTING = threading.Lock()  # (numba fires the event before it takes its lock: threads race)


class _LockCounter(event.Listener):
    def on_start(self, ev):
        with _COUNTING:
            NUMBA_LOCKS[0] += 1

    def on_end(self, ev):
        pass


event.register("numba:compiler_lock", _LockCounter())
#: a cache's first walked chunk (no cell kept: its rays find nothing before its builds) is
#: priced before it is walked, at what the cache's last such chunk added per ray walked in
#: traced rays' prices (line coordinates, the walk, its builds whole: their shares put off
#: to later passes included; :attr:`Fallback.first_walk`, :meth:`Budget.first_cost`): a
#: frame whose allowance cannot pay a :data:`CHUNK_MIN` chunk at it walks nothing, as the
#: ledger would have cut it after that chunk. The price is the cache's (its scene's: it
#: dies with it), None until a first chunk that built no structure and loaded no kernel
#: measured it: a new scene's first frame walks. Measured (session 41, process CPU, 1
#: thread, first chunks of 4,096 rays): ``museum_soft`` 320x240 4 spp 0.55-0.6 (its cells
#: pay), ``museum`` 640x480 1 spp 1.5-1.8, ``museum_1999`` 640x480 1 spp 2-6 (they do not).
#: The core tests turn it off (``conftest.py``, as :data:`LEARN_STRUCTURES`)
PRICE_FIRST_WALK = True
#: a frame during which numba's compiler lock was taken (:data:`NUMBA_LOCKS`: a kernel
#: compiled or loaded, by the frame or by another thread -- the add-on's warm-up) is not
#: judged and teaches no price (:meth:`Fallback.learn`): its costs timed numba (``make
#: demo`` from an empty cache: 7.9 s "with cells" against 0.016 s traced, 0.083 s warm) and
#: its compile time cannot be told apart from its own (the lock's hold misses the typing
#: and first calls, and a warm-up's loads run beside the frame). The core tests turn it off
#: (``conftest.py``: whether a test's frame loads a kernel depends on the tests before it)
SKIP_COMPILED = True
#: frames in a row not judged for compiling (:data:`SKIP_COMPILED`) after which one that
#: compiled is judged anyway (a kernel loaded every frame -- a warm-up beside every frame, a
#: new signature each frame -- must not keep cells that do not pay forever): as many as a
#: misjudged frame traces before its re-probe (measured, session 43 review: ``glossy``
#: 120x90 in a warm process loads kernels in its first 5 frames, the others in 1-2)
COMPILED_FRAMES = REPROBE_FRAMES


def timed_structure(kind: str, n_tris: int, build):
    """``build()``, its cost per triangle learned as ``kind``'s :data:`STRUCTURE_RATE`."""
    STRUCTURES_BUILT[0] += 1
    if not LEARN_STRUCTURES:
        return build()
    since = kernel_cache.mark()
    t0 = CLOCK()
    out = build()
    took = CLOCK() - t0
    c = kernel_cache.counts(since=since)
    # a build that compiled or loaded a numba kernel timed numba, not the build (a process's
    # first build: 270-1300x the steady rate), and a rate too high is never corrected (a
    # frame that cannot pay it builds nothing): such a build is not learned
    if not (c["compiled"] or c["loaded"]):
        STRUCTURE_RATE[kind] = took / max(int(n_tris), 1)
    return out


def structures_owed(missing, n_tris: int) -> float:
    """Seconds the scene's structures ``missing`` (kinds of :data:`STRUCTURE_RATE` not
    built for it) are expected to cost over ``n_tris`` triangles, at the rates learned (0
    for a kind never built: the first build in a process is not foreseen)."""
    return sum(STRUCTURE_RATE[k] * int(n_tris) for k in missing
               if STRUCTURE_RATE.get(k) is not None)


def owed_at_once(missing, n_tris: int, cells_kept: bool) -> tuple[float, float]:
    """``(walk, build)``: seconds of the structures ``missing`` a frame's first walk and
    its first build owe at once (:attr:`Budget.owed`, :attr:`Budget.owed_build`). A walk
    needs the topology; with no cell kept it finds nothing to interpolate, so it owes the
    query structures its builds need too (else a build owes them)."""
    walk = [k for k in missing if k == "topo" or not cells_kept]
    return (structures_owed(walk, n_tris),
            structures_owed([k for k in missing if k not in walk], n_tris))


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
    """(with cells, traced) seconds per object (module doc): an interpolated ray saves
    :data:`SAVE_SHARE` of a traced ray's price."""
    w = c.walked.astype(np.float64)
    b = c.cells.astype(np.float64)
    walk = c.walk_s * w / max(w.sum(), 1.0)
    build = c.build_s * b / max(b.sum(), 1.0) / BUILD_FRAMES
    cells = walk + build + (c.rays - SAVE_SHARE * c.interpolated) * c.ray_s
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
    """What one frame may spend on cells (module doc): ``rays`` the frame's samples,
    ``ray_s`` the price of one traced ray (None: not known yet -- the frame traces its
    first chunk to price it, :meth:`price`), ``vis_s`` of one closest-hit ray, ``hit_share``
    the share of the rays that hit (the misses cost the tracer nothing)."""

    def __init__(self, rays: int, ray_s: float | None = None, n_inst: int = 0,
                 vis_s: float = 0.0, hit_share: float = 1.0, passes: int = 1) -> None:
        self.rays = int(rays)
        self.passes = max(int(passes), 1)  # the frame's passes (samples per pixel)
        self.pass_no = 0  # the pass being rendered
        self.later = 0.0  # build seconds charged to the passes after this one
        self.cut = False  # the ledger cut a pass short: the rest of the frame was traced
        self.deferred_inst = np.zeros(n_inst, np.int64)  # cells left unbuilt per object
        self.ray_s: float | None = None
        self.limit = float("inf")
        self.spent = 0.0  # seconds the mode added so far (walk, builds, terms, ...)
        self.built = 0  # cells built so far
        self.build_s = 0.0  # seconds of it building them
        self.build_paid = 0.0  # of them paid so far (in spent: the passes' shares)
        self.saved = 0  # rays interpolated in the chunks before the current one
        self.walked = 0  # rays that went through the cells (chunks with cells)
        self.deferred = 0  # cells left unbuilt
        self.pricing = 0  # rays traced to price a ray (a first frame's first chunk)
        #: seconds of the scene's structures (topology, query structures) not built yet
        #: that the next walk, and the next build, would pay at once (:func:`owed_at_once`)
        self.owed = 0.0
        self.owed_build = 0.0
        self.opened: float | None = None  # when the chunk being walked began (:meth:`open`)
        self.open_built = 0.0  # seconds of builds since then (charged as they went)
        #: the cache kept no cell when the frame began: its first walked chunk is priced
        #: before it is walked at ``first_walk`` (:data:`PRICE_FIRST_WALK`, :meth:`first_cost`;
        #: None: not priced) and teaches the price (``learned``, :meth:`walked_chunk`)
        self.empty = False
        self.first_walk: float | None = None
        self.learned: float | None = None
        self.declined = False  # the first walk's price declined the frame's walk
        self.first_marks = None  # (compiler locks, structures built) when it began
        self.locks = NUMBA_LOCKS[0]  # compiler locks taken before the frame's ledger
        self.compiled = False  # one was taken since (:meth:`seal`: the frame not judged)
        if ray_s is not None:
            self.price(ray_s, vis_s, hit_share)

    def price(self, ray_s: float, vis_s: float = 0.0, hit_share: float = 1.0) -> None:
        """Set the price of a traced ray (and so the limit: :data:`ALLOWANCE` of the frame's
        base cost, ``rays`` closest-hit rays and the ones that hit traced)."""
        self.ray_s = float(ray_s)
        self.limit = ALLOWANCE * self.rays * (hit_share * self.ray_s + max(vis_s, 0.0))

    def open(self) -> None:
        """A chunk's walk begins: until :meth:`close` its time so far counts as spent in
        :meth:`left` (the builds' decisions within the chunk see its line coordinates and
        walk; without it a first frame's first chunk built 20-33 cells on a walk that had
        spent the allowance already, ``museum_1999``: 10-18 ms added against 1.5 ms)."""
        self.opened = CLOCK()
        self.open_built = 0.0
        if self.walked == 0 and self.empty and PRICE_FIRST_WALK:
            self.first_marks = (NUMBA_LOCKS[0], STRUCTURES_BUILT[0])

    def seal(self, in_row: int = 0) -> bool:
        """The frame's costs are measured: whether numba's compiler lock was taken since the
        ledger began (``compiled``: a kernel compiled or loaded, the frame is not judged,
        :data:`SKIP_COMPILED`), unless the ``in_row`` frames before it were not judged for
        that (:attr:`Fallback.compiled`: :data:`COMPILED_FRAMES` of them, it is)."""
        self.compiled = (SKIP_COMPILED and NUMBA_LOCKS[0] != self.locks
                         and in_row < COMPILED_FRAMES)
        return self.compiled

    def first_cost(self) -> float:
        """Seconds the frame's first walked chunk is expected to add (``first_walk``'s
        price of a :data:`CHUNK_MIN` chunk; 0 after a walk, or where it is not priced)."""
        if self.walked or self.first_walk is None or self.ray_s is None:
            return 0.0
        return self.first_walk * CHUNK_MIN * self.ray_s

    def walked_chunk(self, rays: int, added: float) -> None:
        """A chunk walked ``rays`` rays and added ``added`` seconds (its builds whole). The
        first of a frame on a cache with no cell, of at least :data:`CHUNK_MIN` rays, that
        built no structure and loaded no kernel (:meth:`open` marked them), measures its
        price per ray walked in traced rays' prices (``learned``: the cache's
        :attr:`Fallback.first_walk` from then on)."""
        marks, self.first_marks = self.first_marks, None
        first = self.walked == 0
        self.walked += int(rays)
        if not (first and marks is not None and rays >= CHUNK_MIN and self.ray_s):
            return
        if (NUMBA_LOCKS[0], STRUCTURES_BUILT[0]) == marks:
            self.learned = max(float(added), 0.0) / (rays * self.ray_s)

    def close(self) -> None:
        """The chunk's walk and builds are over (the chunk then books all it added)."""
        self.opened = None

    def running(self) -> float:
        """Seconds of the open chunk not booked yet (its time but the builds charged)."""
        if self.opened is None:
            return 0.0
        return max(CLOCK() - self.opened - self.open_built, 0.0)

    def defer(self, inst: np.ndarray) -> None:
        """Cells of objects ``inst`` are left unbuilt."""
        self.deferred += len(inst)
        inst = inst[inst < len(self.deferred_inst)]
        np.add.at(self.deferred_inst, inst, 1)

    def share(self) -> float:
        """The share of a build that the current pass pays: a cell built serves this pass
        and the frame's passes after it, and its cost is spread evenly over them (the
        last pass pays what is left; a 1-sample frame pays it all at once)."""
        return 1.0 / (self.passes - min(self.pass_no, self.passes - 1))

    def start_pass(self, s: int) -> None:
        """Pass ``s`` begins: it pays its share of the builds put off to it."""
        self.pass_no = int(s)
        now = self.later * self.share()
        self.later -= now
        self.spent += now
        self.build_paid += now

    def charge(self, seconds: float, cells: int) -> float:
        """A batch of ``cells`` cells took ``seconds`` to build: the current pass pays its
        :meth:`share`, the rest is put off to the passes after it (returned)."""
        put_off = seconds * (1.0 - self.share())
        self.spent += seconds - put_off
        self.build_paid += seconds - put_off
        self.later += put_off
        self.build_s += seconds
        self.built += int(cells)
        self.open_built += seconds
        return put_off

    def left(self, interpolated_now: int = 0) -> float:
        """Seconds the frame may still add (``interpolated_now``: rays interpolated in the
        current chunk so far, each saving a traced ray); inf while not priced. The builds'
        shares put off to the passes after this one are owed already: a later pass pays
        them whether or not its own walk earns them back (``museum_soft`` at 4 spp, world
        lit, every pass walks again: its first frame built 0.62 s of cells against an
        allowance of 0.13 s when only the current pass's share counted, and lost 15%)."""
        if self.ray_s is None:
            return float("inf")
        return (self.limit + SAVE_SHARE * (self.saved + interpolated_now) * self.ray_s
                - self.spent - self.later - self.running())

    def batch(self, step: int, interpolated_now: int) -> int:
        """How many cells the next batch may build (0: none), at most ``step``: the first
        at most :data:`BUDGET_STEP` (what the budget affords at :data:`CELL_RAYS` rays a
        cell), then what the budget left affords at the cost per cell measured so far, at
        least :data:`BUDGET_MIN` (small batches cost more per cell)."""
        if self.ray_s is None:
            return step
        if not self.may_build(interpolated_now):
            return 0
        if self.built == 0:  # at what a cell is expected to cost (CELL_RAYS traced rays)
            return min(step, BUDGET_STEP,
                       max(1, int(self.left(interpolated_now) / (CELL_RAYS * self.ray_s))))
        left = self.left(interpolated_now)
        return min(step, max(BUDGET_MIN, int(left / (self.build_s / self.built))))

    def may_build(self, interpolated_now: int) -> bool:
        """Whether the next batch may be built (``interpolated_now``: rays interpolated in
        the current chunk so far), the query structures it may owe paid (:attr:`owed_build`)."""
        return self.left(interpolated_now) >= self.owed_build

    def chunk(self, rest: int) -> int:
        """Rays the next chunk of a pass (``rest`` rays left in it) sends through the cells
        (0: none, the rest is traced): as many as the allowance left affords at what the
        mode added per ray walked so far but its builds (those :meth:`batch` paces: a cell
        built serves the chunks after it), between :data:`CHUNK_MIN` and :data:`CHUNK_MAX`
        rays; none once it affords fewer than :data:`CHUNK_MIN`. The scene's structures
        not built yet (:attr:`owed`) are owed at once: a frame whose allowance cannot pay
        them walks nothing (its cells could be neither found nor built without them; on
        ``studio`` at 320x240 and 1 sample they are 20-30 ms against an allowance of ~10).
        Not priced: 0."""
        if self.ray_s is None:
            return 0
        left = self.left() - self.owed
        walk = self.spent - self.build_paid
        if self.walked == 0 or walk <= 0.0:
            first = self.first_cost()
            if left < first:  # (first: what a first walk on an empty cache is priced at)
                self.cut |= rest > 0
                self.declined |= rest > 0 and left >= 0.0
                return 0
            return min(rest, CHUNK_MIN)
        can = int(left / (walk / self.walked))
        if can < CHUNK_MIN:
            self.cut |= rest > 0
            return 0
        return min(rest, can, CHUNK_MAX)


    def spent_for_good(self, reprojectable: int) -> bool:
        """Whether no chunk of the frame can walk again (:meth:`chunk`): what is left, plus
        the most the frame's later passes can still save (``reprojectable`` rays that may
        be interpolated without a walk: the later samples of the pixels interpolated so
        far), affords fewer than :data:`CHUNK_MIN` rays at the walk's cost per ray so far
        (nothing at all before a walk). Only time spent makes it less: the rest of the
        frame is then traced whatever comes, and may be traced as the base tracer traces
        it (:func:`.render.render_frame`). Not priced: False."""
        if self.ray_s is None:
            return False
        left = self.left() - self.owed + SAVE_SHARE * max(int(reprojectable), 0) * self.ray_s
        walk = self.spent - self.build_paid
        if self.walked == 0 or walk <= 0.0:  # (as chunk: it walks CHUNK_MIN at 0 left)
            return left < self.first_cost()
        return left < CHUNK_MIN * (walk / self.walked)


class Fallback:
    """What INTERPOLANT mode has learned for one cache (module doc)."""

    def __init__(self, n_inst: int) -> None:
        self.traced = np.zeros(n_inst, np.bool_)  # objects traced instead of cells
        self.frames_traced = np.zeros(n_inst, np.int64)  # frames since last judged
        self.ray_s: float | None = None  # price of one traced ray, learned
        self.vis_s = 0.0  # price of one closest-hit ray, learned
        self.hit_share = 1.0  # share of a frame's rays that hit, learned
        self.all_traced = False  # the whole frame did not pay: every object traced
        self.frames_all = 0  # frames since the whole frame was last judged
        self.cuts = 0  # frames in a row the ledger cut short and that were not judged
        #: what a first walked chunk on this cache emptied of cells adds per ray walked, in
        #: traced rays' prices (:data:`PRICE_FIRST_WALK`; None: not measured yet)
        self.first_walk: float | None = None
        self.declined = 0  # frames in a row whose first walk's price declined their walk
        self.compiled = 0  # frames in a row not judged as they compiled (COMPILED_FRAMES)
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

    def budget(self, rays: int, n_inst: int, passes: int, empty: bool) -> Budget:
        """A frame's :class:`Budget` (``empty``: the cache keeps no cell). Its first walk
        is priced before it is walked (:attr:`first_walk`) but after
        :data:`REPROBE_FRAMES` frames in a row that it declined: that frame walks, and its
        first chunk prices it again (a price too high is corrected)."""
        b = Budget(rays, self.ray_s, n_inst, self.vis_s, self.hit_share, passes)
        b.empty = bool(empty) and PRICE_FIRST_WALK
        if b.empty and self.declined < REPROBE_FRAMES:
            b.first_walk = self.first_walk
        return b

    def walked_or_declined(self, b: Budget) -> None:
        """After a frame's ledger ``b``: its first chunk's price learned, the frames
        declined in a row counted (a frame that walked starts them over; one that did
        neither, cancelled before its first chunk or all reprojected, keeps the count)."""
        if b.learned is not None:
            self.first_walk = b.learned
        if b.declined:
            self.declined += 1
        elif b.walked:
            self.declined = 0

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
              deferred: np.ndarray | None = None, cut: bool = False,
              declined: bool = False, compiled: bool = False) -> None:
        """After a full frame that traced the objects ``traced_now`` (its
        :meth:`frame_traced`): objects that went through cells are judged (:func:`cells_pay`)
        unless the budget deferred some of their cells (``deferred`` (I,) counts: they have
        not had their chance yet), the others count one more frame traced. A frame the
        ledger ``cut`` short (:class:`Budget`) is judged only as the :data:`CUT_FRAMES`-th
        in a row, or when its walk alone (its builds left out) did not pay: its cells walked
        a chunk or a pass, and the cells it built have served none of the frames after it
        (the ledger kept the frame itself within its allowance). A frame whose first walk
        was ``declined`` (:meth:`budget`) walked nothing: nothing is judged (a frame
        re-probing the whole frame waits :data:`REPROBE_FRAMES` frames again). A frame that
        ``compiled`` (:meth:`Budget.seal`) timed numba: nothing is judged or learned, not
        even the price of a ray (a whole-frame re-probe stays due: the next frame is one)."""
        self.compiled = self.compiled + 1 if compiled else 0
        if c.ray_s > 0.0 and not compiled:
            self.ray_s = float(c.ray_s)
        if declined or compiled:
            self.frames_traced[traced_now] += 1
            self.frames_all = 0 if declined else self.frames_all
            return
        self.last = c
        self.cuts = self.cuts + 1 if cut else 0
        if 0 < self.cuts < CUT_FRAMES and frame_pays(c._replace(build_s=0.0)):
            # (a cut frame whose walk alone did not pay is judged: builds cannot help it)
            self.frames_traced[traced_now] += 1
            return
        self.cuts = 0
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

    def notes(self, budget: Budget | None = None) -> list[str]:
        """What was decided, for the user (a frame's ``stats["fallback_notes"]``): the whole
        frame traced, or objects traced, with the costs measured, and the frame's first
        walk declined (``budget``: its ledger); none while cells are used everywhere."""
        out = []
        if budget is not None and budget.compiled:
            out.append("Interpolants: kernels were compiled or loaded during this frame, so "
                       "its timings are not judged; the next frame's decide where cells pay")
        if budget is not None and budget.declined:
            out.append(f"Interpolants: this frame walked no cell, the cache keeps none and a "
                       f"first walk here cost {self.first_walk:.1f} traced rays a ray, more "
                       f"than the frame may add; walked again after {REPROBE_FRAMES} such "
                       f"frames in a row ({self.declined} so far; setting "
                       f"'interpolant_fallback' off: cells always)")
        return out + self._decided()

    def _decided(self) -> list[str]:
        c = self.last
        measured = ""
        if c is not None:
            cells, traced = object_costs(c)
            measured = (f" (measured: {cells.sum():.3f} s with cells against "
                        f"{traced.sum():.3f} s traced)")
        if self.all_traced:
            return [f"Interpolants: this scene's frames are traced, its cells cost more than "
                    f"they save{measured}; tried again every {REPROBE_FRAMES} frames "
                    f"(setting 'interpolant_fallback' off: cells always)"]
        n = int(np.count_nonzero(self.traced))
        if n:
            return [f"Interpolants: {n} object(s) traced, their cells cost more than "
                    f"tracing their rays; tried again every {REPROBE_FRAMES} frames "
                    f"(setting 'interpolant_fallback' off: cells always)"]
        return []

    def stats(self, budget: Budget | None) -> dict:
        """The frame's ``stats["fallback"]``: what was decided (objects traced, the whole
        frame traced) and what the frame's ledger measured (:class:`Budget`: the
        allowance, what the mode added and saved, rays walked, cells deferred, rays traced
        to price a ray, whether the frame compiled or loaded a kernel: not judged; and
        ``build_compiling``: the frame was the base tracer's while the cell build's kernels
        compiled beside it, :mod:`.build_beside`)."""
        b = budget
        priced = b is not None and b.ray_s is not None
        return dict(traced_objects=int(np.count_nonzero(self.traced)),
                    all_traced=bool(self.all_traced),
                    deferred_cells=0 if b is None else int(b.deferred),
                    build_budget_s=b.limit if priced else None,
                    added_s=0.0 if b is None else b.spent,
                    saved_s=SAVE_SHARE * b.saved * b.ray_s if priced else 0.0,
                    walked_rays=0 if b is None else int(b.walked),
                    probe_rays=0 if b is None else int(b.pricing),
                    ray_us=None if self.ray_s is None else 1e6 * self.ray_s,
                    first_walk=self.first_walk, declined=bool(b is not None and b.declined),
                    declined_in_row=self.declined,
                    compiled=bool(b is not None and b.compiled),
                    build_compiling=False)


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
