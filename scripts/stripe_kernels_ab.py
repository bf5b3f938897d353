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
from pathlib import Path

import numba
import numpy as np

from rstrace_engine import scenes
from rstrace_engine.tracing import light_reshade as lr
from rstrace_engine.tracing import record_queries as rq

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_stripes import light_state_points, tile_query_case  # noqa: E402  (the tests' inputs)


def _tiles_call(width, height, spp, rng):
    n, head, tail = tile_query_case(rng, width, height, spp, False)
    args = (*head, width, height, width * height, *tail)
    fn = getattr(rq, "query_tiles", None) or rq._query_tiles  # striped / base

    def call():
        out = np.zeros(n, np.bool_)
        fn(*args, out)
        return out.tobytes()
    return call


def _states_call(n, rng):
    sa = scenes.museum(64, 48).arrays()
    P, NG, MAT, INST = light_state_points(sa, n, rng)
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
