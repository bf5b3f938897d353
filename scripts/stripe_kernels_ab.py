"""The striped records kernels alone (docs/first-render.md, *The tile query and a light's
states striped*): their compile, their run time and a hash of their outputs, on the base
(``prange``) or this checkout (striped) alike.

    python scripts/stripe_kernels_ab.py compile-tiles | compile-states
    python scripts/stripe_kernels_ab.py tiles | states [THREADS]

``compile-*``: call the kernel once on empty inputs, as ``tracing/edit_kernels.py``'s
warm-up does (run it under ``scripts/compile_profile.py`` with a fresh ``NUMBA_CACHE_DIR``).
``tiles``: the tile query on 640x480 x 4 spp synthetic records (random codes: nearly every
tile tests its rays), 30 calls; ``states``: a light's states at 1M random points of
museum, 15 calls; each prints the process CPU time (min, median) and wall time (min) per
call and an md5 of the outputs. Run each checkout alternately (``PYTHONPATH=<checkout>``).
"""

from __future__ import annotations

import hashlib
import sys
import time

import numba
import numpy as np

from rstrace_engine import scenes
from rstrace_engine.geometry.elements import LIGHT_POINT, LIGHT_SUN
from rstrace_engine.tracing import light_reshade as lr
from rstrace_engine.tracing import record_queries as rq
from rstrace_engine.tracing.pixel_records import PixelRecords


def _tiles_call(width, height, spp, rng):
    r = PixelRecords(width, height, spp, np.array([[0.0, 0, 0], [1.0, 1, 1]]))
    n = width * height * spp
    combo_inst = np.array([-1, 0, 1, 2, 3, 0], np.int64)
    combo_traced = np.array([[0], [1], [2], [3], [3], [0]], np.uint64)
    combo_dirty = np.array([False, False, False, False, False, True])
    p_combo = rng.choice(6, n, p=[0.05, 0.3, 0.25, 0.2, 0.19, 0.01]).astype(np.uint32)
    p_code = rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
    seg_lo, seg_hi = np.array([[0.2, 0.2, 0.5]]), np.array([[0.3, 0.3, 0.6]])
    reg_lo, reg_hi = np.array([[0.6, 0.55, 0.6]]), np.array([[0.7, 0.65, 0.7]])
    args = (p_combo, p_code, combo_dirty, combo_inst, combo_traced, np.array([0.5, 0.5, -2.0]),
            width, height, width * height, r.lo, r.step, r.levels, r.shift, reg_lo, reg_hi,
            seg_lo, seg_hi, 0.5 * (seg_lo + seg_hi), np.array([0.0866]),
            np.array([LIGHT_POINT, LIGHT_SUN], np.int32),
            np.array([[0.5, 2.0, 0.5, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]]),
            np.array([[0.0, 0.0, 0.0], [0.3, -1.0, 0.2]]))
    fn = getattr(rq, "query_tiles", None) or rq._query_tiles  # striped / base

    def call():
        out = np.zeros(n, np.bool_)
        fn(*args, out)
        return out.tobytes()
    return call


def _states_call(n, rng):
    sa = scenes.museum(64, 48).arrays()
    lo, hi = sa.scene_aabb
    P = lo + rng.random((n, 3)) * (hi - lo)
    NG = rng.normal(size=(n, 3))
    NG /= np.linalg.norm(NG, axis=1)[:, None]
    MAT = rng.integers(0, len(sa.mat_model), n).astype(np.int32)
    INST = rng.integers(0, len(sa.inst_mesh), n).astype(np.int32)
    fn = getattr(lr, "one_light_states", None) or lr._one_light_states
    state, mat = np.empty(n, np.int8), np.empty(n, np.int32)
    NS, Q = NG.copy(), P + 1e-6 * NG

    def call():
        fn(sa, 0, P, NG, NS, Q, MAT, INST, state, mat)
        return state.tobytes() + mat.tobytes()
    return call


def main(argv: list[str]) -> None:
    what = argv[0]
    numba.set_num_threads(int(argv[1]) if len(argv) > 1 else 1)
    rng = np.random.default_rng(7)
    if what.startswith("compile-"):
        call = _tiles_call(8, 8, 1, rng) if what == "compile-tiles" else _states_call(0, rng)
        t0 = time.process_time()
        call()
        sys.stdout.write(f"{what}: {time.process_time() - t0:.2f} s CPU\n")
        return
    call, reps = (_tiles_call(640, 480, 4, rng), 30) if what == "tiles" else (
        _states_call(1_000_000, rng), 15)
    out = call()
    cpu, wall = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        out = call()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    cpu.sort()
    sys.stdout.write(f"{what} threads={numba.get_num_threads()}: CPU min {1e3 * cpu[0]:.1f} "
                     f"median {1e3 * cpu[reps // 2]:.1f} ms, wall min {1e3 * min(wall):.1f} "
                     f"ms, md5 {hashlib.md5(out).hexdigest()[:12]}\n")


if __name__ == "__main__":
    main(sys.argv[1:])
