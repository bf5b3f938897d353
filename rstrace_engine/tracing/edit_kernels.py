"""The kernels a session's first edits load, loaded at the end of its first frame instead.

numba keeps compiled kernels on disk (:mod:`~..kernel_cache`), but a process still loads
each kernel, per argument types, the first time it calls it: 5-20 ms apiece. The
recombination kernels are loaded at the end of the first frame that keeps light terms
(:func:`~.light_records.load_kernels`, and :func:`~.shadow_reshade.load_kernels` under soft
light in BASE). The first light *moved or added* (BASE or INTERPOLANT) and the first records
query (any edit that is not only a light's power, colour or deletion) still loaded theirs
on the edit (issue 21; 7 kernels, 40-70 ms wall on the bench scenes at a load of 6):

* the records' dirty query (:mod:`.record_queries`), on the frame's records' own array
  types (their combo codes are 16 or 32 bits wide);
* a light's states and shadow rays shaded alone (:func:`~.light_reshade._one_light`'s
  scene packing: the interpolants' added light shades its samples with it too), its light
  bits in the pixel records, and the recombination's average of the samples;
* what other modules register in :data:`LOADERS` (the interpolants' term kernel,
  :mod:`~..interpolants.term_pixels`): called with the records and the scene packing.

Each is called once per process on empty arrays of the frame's types (no work).
"""

from __future__ import annotations

import numpy as np

from ..geometry.cameras import camera_params
from .batches import accumulate, threads_for
from .light_reshade import _one_light, _one_light_states
from .pixel_records import _light_bit_changes
from .record_queries import _mark_rays, _query_primary, _query_secondary, _query_tiles
from .shader import _shadow_kernel

#: more loaders, ``fn(records, sa)``, registered by the modules that own their kernels
LOADERS: list = []

_loaded = [False]


def load_kernels(records, sa, camera) -> None:
    """Load (or compile) the first light move's or add's and the first records query's
    kernels once per process, for ``records`` (:class:`~.pixel_records.PixelRecords` of a
    frame that keeps light terms), its scene packing ``sa`` and its ``camera``."""
    if _loaded[0] or records is None or records.light is None or len(sa.light_kind) == 0:
        return
    _loaded[0] = True
    e3, e1 = np.zeros((0, 3)), np.zeros(0)
    i32, i64 = np.zeros(0, np.int32), np.zeros(0, np.int64)
    u64, b = np.zeros(0, np.uint64), np.zeros(0, np.bool_)
    one = _one_light(sa, 0)
    with threads_for(0):
        _one_light_states(one, 0, e3, e3, e3, e3, i32, i32, np.zeros(0, np.int8), i32)
        _shadow_kernel(one, e3, e3, e3, np.zeros(0, np.int8), i64, e3, e3, e1)
        accumulate(e3, i32, 1, np.zeros((0, 3), np.float32), np.zeros(0, np.uint8))
        for combo in (records.p_combo, records.s_combo):
            _light_bit_changes(combo[:0], u64, u64, np.uint64(1), b, b, i64)
        r = records
        kind = np.zeros(0, np.int32)
        tail = (r.lo, r.step, r.levels, r.shift, e3, e3, e3, e3, e3, e1, kind, e3, e3)
        cp = camera_params(camera)
        if cp.ortho:
            _query_primary(r.p_combo[:0], r.p_code[:0], b, i64, u64, np.zeros(3), e3, *tail,
                           b)
        else:
            _query_tiles(r.p_combo[:0], r.p_code[:0], b, i64, u64, np.zeros(3), 1, 1, 1,
                         *tail, b)
        _query_secondary(r.s_parent[:0], r.s_combo[:0], r.s_code[:0], r.p_combo[:0],
                         r.p_code[:0], 0, b, i64, u64, *tail, b)
        _mark_rays(i32, b, b)
    for fn in LOADERS:
        fn(records, sa)
