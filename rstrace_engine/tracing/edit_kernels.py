"""The kernels a session's first edits load, loaded at the end of its first frame instead.

numba keeps compiled kernels on disk (:mod:`~..kernel_cache`), but a process still loads
each kernel, per argument types, the first time it calls it: 5-20 ms apiece. Every group of
kernels an edit would load is a loader in :data:`LOADERS`, called once per process by
:func:`load_kernels` at the end of the first frame that keeps light terms and meets the
loader's condition (:meth:`~.frame_reuse.FrameReuse.finish`; issue 21):

* the recombination kernels (:func:`~.light_records.load_kernels`): every such frame;
* the first light *moved or added* (BASE or INTERPOLANT) and the first records query (any
  edit that is not only a light's power, colour or deletion; :func:`_edit_kernels`):
  the records' dirty query (:mod:`.record_queries`), on the frame's records' own array
  types (their combo codes are 16 or 32 bits wide); a light's states and shadow rays shaded
  alone (:func:`~.light_reshade._one_light`'s scene packing: the interpolants' added and
  moved lights shade their samples with it too), its light bits in the pixel records, and
  the recombination's average of the samples, and the count of the table rows the nodes
  use (:func:`~.record_codes._mark_used`, for 16- and 32-bit codes: a first frame's
  compaction counts its 32-bit codes, an incremental frame's its kept 16-bit ones) -- a
  frame of a scene with lights;
* the soft lights' re-shade (:func:`~.shadow_reshade.load_kernels`): a BASE frame under
  soft light;
* the records' sampled-ray queries an object edit runs in :meth:`~.pixel_records.
  PixelRecords.dirty_split` (:func:`~.sample_proofs.query_samples`: the soft lights' and the
  world's samples, and the placed objects' proofs; :func:`_sample_kernels`): a frame under
  soft light whose records keep the samples' normals and seeds (0.04 s of the first edit's
  ``apply`` on ``studio`` before);
* what other modules register (:func:`register`; the interpolants' term kernel,
  :mod:`~..interpolants.term_pixels`: an INTERPOLANT frame).

Each is called on empty arrays of the frame's types (no work). A loader whose condition the
first frame does not meet (a BASE frame, then an INTERPOLANT one) loads with the first frame
that does.
"""

from __future__ import annotations

import numpy as np

from ..geometry.cameras import camera_params
from ..geometry.edits import PART_NEW, PART_OLD
from .batches import accumulate, threads_for
from .light_bits import mask_of
from .light_records import load_kernels as recombine_kernels
from .light_reshade import _one_light, one_light_states
from .pixel_records import _light_bit_changes
from .record_codes import _mark_used, light_geometry
from .record_queries import _mark_rays, _query_primary, _query_secondary, query_tiles
from .sample_proofs import query_samples
from .shader import _shadow_kernel
from .shadow_reshade import load_kernels as reshade_kernels
from .soft_lights import has_soft_light, world_lights

#: the loaders, ``(name, fn(records, sa, camera), when(records, sa) -> bool)``
LOADERS: list = []

_loaded: set = set()  # the names of the loaders run in this process


def register(name: str, fn, when=None) -> None:
    """Add loader ``fn(records, sa, camera)``, run once per process by :func:`load_kernels`
    at the end of the first frame for which ``when(records, sa)`` holds (default: every
    frame that keeps light terms)."""
    LOADERS.append((name, fn, (lambda records, sa: True) if when is None else when))


def load_kernels(records, sa, camera) -> None:
    """Run each loader not yet run in this process whose condition holds, for ``records``
    (:class:`~.pixel_records.PixelRecords` of a frame that keeps light terms), its scene
    packing ``sa`` and its ``camera``."""
    if records is None or records.light is None or sa is None:
        return
    for name, fn, when in LOADERS:
        if name not in _loaded and when(records, sa):
            _loaded.add(name)
            fn(records, sa, camera)


def _edit_kernels(records, sa, camera) -> None:
    """The first light move's or add's and the first records query's kernels."""
    e3, e1 = np.zeros((0, 3)), np.zeros(0)
    i32, i64 = np.zeros(0, np.int32), np.zeros(0, np.int64)
    u64, b = np.zeros((0, 1), np.uint64), np.zeros(0, np.bool_)  # (light sets: (n, W))
    one = _one_light(sa, 0)
    with threads_for(0):
        one_light_states(one, 0, e3, e3, e3, e3, i32, i32, np.zeros(0, np.int8), i32)
        _shadow_kernel(one, e3, e3, e3, np.zeros(0, np.int8), i64, e3, e3, e1)
        accumulate(e3, i32, 1, np.zeros((0, 3), np.float32), np.zeros(0, np.uint8))
        for combo in (records.p_combo, records.s_combo):
            _light_bit_changes(combo[:0], u64, u64, 0, np.uint64(1), b, b, i64)
        r = records
        kind = np.zeros(0, np.int32)
        tail = (r.lo, r.step, r.levels, r.shift, e3, e3, e3, e3, e3, e1, kind, e3, e3)
        cp = camera_params(camera)
        if cp.ortho:
            _query_primary(r.p_combo[:0], r.p_code[:0], b, i64, u64, np.zeros(3), e3, *tail,
                           b)
        else:
            query_tiles(r.p_combo[:0], r.p_code[:0], b, i64, u64, np.zeros(3), 1, 1, 1,
                        *tail, b)
        _query_secondary(r.s_parent[:0], r.s_combo[:0], r.s_code[:0], r.p_combo[:0],
                         r.p_code[:0], 0, b, i64, u64, *tail, b)
        _mark_rays(i32, b, b)
        for dt in (np.uint16, np.uint32):  # (the records' compaction, every frame)
            _mark_used(np.zeros(0, dt), b)


def _sample_kernels(records, sa, camera) -> None:
    """The first object edit's sampled-ray queries under soft light, at the primary and the
    secondary nodes, with a placed object's proof (zero rows: the records' own array
    types)."""
    r = records
    ext = np.asarray(sa.light_ext, bool) & (np.asarray(sa.light_kind) >= 0)
    soft = mask_of(np.flatnonzero(ext), r.n_words)
    e3, e1 = np.zeros((1, 3)), np.zeros(1)
    parts = (e3, e3.copy(), e3.copy(), e1, np.full(1, PART_OLD | PART_NEW, np.int8))
    placed = ((e3.copy(), np.ones(1), np.ones(1)), 0.0)
    pos = light_geometry(sa)
    inst64 = r.t_inst.astype(np.int64)[:0]
    traced = r.t_traced.astype(np.uint64)[:0]
    none = np.zeros(0, np.bool_)
    nodes = [(r.p_combo, r.p_code, r.p_wnorm, r.p_seed, r.p_vis)]
    if r.s_wnorm is not None:
        nodes.append((r.s_combo, r.s_code, r.s_wnorm, r.s_seed, r.s_vis))
    with threads_for(0):
        for combo, code, wnorm, seed, vis in nodes:
            query_samples(r, sa, combo[:0], code[:0], wnorm[:0], seed[:0],
                          None if vis is None else vis[:0], none, inst64, traced, soft,
                          world_lights(sa), parts, pos, none, placed)


register("recombine", lambda records, sa, camera: recombine_kernels())
register("edit", _edit_kernels, lambda records, sa: len(sa.light_kind) > 0)
register("reshade", lambda records, sa, camera: reshade_kernels(sa),
         lambda records, sa: (not records.light.partial and len(sa.light_kind) > 0
                              and has_soft_light(sa)))
register("samples", _sample_kernels,
         lambda records, sa: records.p_wnorm is not None and has_soft_light(sa))
