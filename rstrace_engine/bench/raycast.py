"""Ray-cast throughput: the numba BVH against Embree on the same rays, in one run.

``python -m rstrace_engine.bench raycast [--json] [--repeats N] [--random N]``

Workloads on :func:`~rstrace_engine.scenes.grid` (20 icospheres on a plane, ~102k
triangles): ``grid-primary``, the 640x480 primary rays of its camera, and ``grid-random``,
1M rays with origins uniform in the scene box and uniformly random directions. Each runs with
1 and 2 threads (``numba.set_num_threads``; the Embree backend splits a batch into as many
chunks on a thread pool, ``embreex`` releases the GIL). Both backends take the same float64
rays through the accelerator interface and return :class:`~rstrace_engine.accel.accelerators.Hits`;
both are warmed up first, and the best of ``--repeats`` interleaved runs is kept.
``--json`` prints one object
``{"workloads": [{"name", "threads", "numba_mrays", "embree_mrays", "ratio"}, ...]}``
with ``ratio = numba / embree``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numba
import numpy as np

from ..accel.accelerators import AcceleratorUnavailable, create_accelerator
from ..geometry.cameras import camera_rays
from ..scenes import grid


def random_rays(box: np.ndarray, n: int, seed: int = 1):
    """``n`` rays with origins uniform in ``box`` (2, 3) and uniform random unit directions."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(box[0], box[1], (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d, np.zeros(n), np.full(n, np.inf)


def _time(fn, args) -> float:
    t0 = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0


def run(repeats: int = 7, n_random: int = 1_000_000, threads=(1, 2)) -> dict:
    """Measure every workload; returns the ``{"workloads": [...]}`` dict (plus ``"scene"``)."""
    scene = grid()
    sa = scene.arrays()
    t0 = time.perf_counter()
    accs = {"numba": create_accelerator("BVH", sa)}
    build = {"numba": time.perf_counter() - t0}
    try:
        t0 = time.perf_counter()
        accs["embree"] = create_accelerator("EMBREE", sa)
        build["embree"] = time.perf_counter() - t0
    except AcceleratorUnavailable:
        pass
    workloads = {"grid-primary": camera_rays(scene.camera),
                 "grid-random": random_rays(sa.scene_aabb, n_random)}
    saved = numba.get_num_threads()
    out = []
    try:
        for name, rays in workloads.items():
            n = len(rays[0])
            for th in threads:
                numba.set_num_threads(min(th, numba.config.NUMBA_NUM_THREADS))
                row = {"name": name, "threads": th, "rays": n}
                for acc in accs.values():
                    acc.closest_hit(*rays)  # warm-up (compiles the numba kernels)
                best = dict.fromkeys(accs, np.inf)
                for _ in range(repeats):  # interleaved, so load from elsewhere hits both
                    for key, acc in accs.items():
                        best[key] = min(best[key], _time(acc.closest_hit, rays))
                for key, dt in best.items():
                    row[f"{key}_mrays"] = round(n / dt / 1e6, 3)
                hits = accs["numba"].closest_hit(*rays)
                row["hit_fraction"] = round(float(np.mean(hits.inst >= 0)), 3)
                emb = row.get("embree_mrays")
                row["embree_mrays"] = emb
                row["ratio"] = round(row["numba_mrays"] / emb, 3) if emb else None
                out.append(row)
    finally:
        numba.set_num_threads(saved)
    return {"workloads": out,
            "scene": {"name": "grid", "triangles": scene.triangle_count,
                      "build_s": {k: round(v, 4) for k, v in build.items()}}}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m rstrace_engine.bench raycast")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--random", type=int, default=1_000_000, help="number of random rays")
    args = ap.parse_args(argv)
    res = run(args.repeats, args.random)
    if args.json:
        print(json.dumps({"workloads": [
            {k: r[k] for k in ("name", "threads", "numba_mrays", "embree_mrays", "ratio")}
            for r in res["workloads"]]}))
        return 0
    sc = res["scene"]
    print(f"raycast on grid: {sc['triangles']:,} triangles; build "
          + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in sc["build_s"].items()))
    print(f"{'workload':<14}{'threads':>8}{'rays':>10}{'hit %':>7}{'numba Mray/s':>14}"
          f"{'embree Mray/s':>15}{'ratio':>8}")
    for r in res["workloads"]:
        emb = "n/a" if r["embree_mrays"] is None else f"{r['embree_mrays']:.2f}"
        ratio = "n/a" if r["ratio"] is None else f"{r['ratio']:.2f}"
        print(f"{r['name']:<14}{r['threads']:>8}{r['rays']:>10}{100 * r['hit_fraction']:>7.1f}"
              f"{r['numba_mrays']:>14.2f}{emb:>15}{ratio:>8}")
    if "embree" not in res["scene"]["build_s"]:
        print("Embree: embreex is not installed, no comparison", file=sys.stderr)
    return 0
