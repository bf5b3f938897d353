"""Accelerators side by side: the BVH, Embree and the visibility field on the same rays.

``python -m rstrace_engine.bench accel [--json] [--quick] [--random N] [--frames F]
[--threads T] [--parts static,figure2,settings] [--plot PATH]`` (one thread by default, as
the paper's single processor).

* ``static``: ``primary`` (the scene camera's 640x480 rays) and ``random`` (``--random``
  rays, origins uniform in the scene box, uniform directions) on ``grid`` (~102k triangles)
  and ``museum`` (~300k triangles, 2,002 objects): throughput (Mrays/s, best of
  ``--repeats``), build time, memory.
* ``figure2``: the paper's Figure 2 experiment: ``grid`` as the static scene plus 0, 1, 2, 4,
  8, 16 moving "dolphins" (a bent, tapered ellipsoid of 528 triangles) swimming above it.
  Every frame moves every dolphin; ``update_ms`` is the accelerator's ``update`` after the
  move (the visibility field re-rasterises the dynamic objects under a new GV, the BVH
  rebuilds its top level, the Embree wrapper rebuilds its scene and commits), median over
  ``--frames``; ``mrays`` is the primary-ray throughput of the moved frame (median).
* ``settings``: the visibility field on ``grid`` for several ``l`` (directions) and ``n``
  (tiles): build time, memory, primary-ray throughput; and the same field with the
  order along the beam switched off (``primary-unordered``), which measures what the
  ordering with early exit buys.

``--json`` prints ``{"rows": [{"scene", "accelerator", "dynamic_objects", "workload",
"mrays", "update_ms", "build_s", "memory_mb", ...}]}`` (accelerator names as in the
settings; ``null`` where a number does not apply or is not reported, e.g. Embree's memory).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from ..accel.accelerators import AcceleratorUnavailable, create_accelerator
from ..geometry import shapes
from ..geometry.cameras import camera_rays
from ..geometry.scene import Material, Mesh
from ..scenes import grid, museum
from .raycast import random_rays

NAMES = ("BVH", "EMBREE", "VISIBILITY_FIELD")
DYNAMIC_COUNTS = (0, 1, 2, 4, 8, 16)


def dolphin() -> Mesh:
    """A dolphin-like body: a uv-sphere (24 x 12, 528 triangles) stretched, tapered towards
    the tail and bent."""
    m = shapes.uv_sphere(24, 12, 1.0, name="dolphin")
    v = m.vertices.copy()
    x = v[:, 2]  # the sphere's pole axis becomes the body axis
    taper = 0.25 + 0.75 * np.sqrt(np.clip(1.0 - ((x - 0.3) / 1.3) ** 2, 0.0, 1.0))
    body = np.stack([1.2 * x, 0.35 * taper * v[:, 0], 0.3 * taper * v[:, 1]], axis=1)
    body[:, 2] += 0.15 * np.sin(1.8 * body[:, 0])
    return Mesh("dolphin", body, m.triangles)


def memory_mb(acc) -> float | None:
    """The accelerator's memory in MB: its own count, or the BVH's arrays; None if unknown."""
    if "memory_mb" in acc.stats:
        return float(acc.stats["memory_mb"])
    sb = getattr(acc, "sb", None)
    if sb is not None:
        return sum(a.nbytes for a in sb) / 2**20
    return None


def _build(name: str, sa, **options):
    t0 = time.perf_counter()
    acc = create_accelerator(name, sa, **options)
    return acc, time.perf_counter() - t0


def _mrays(acc, rays, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        acc.closest_hit(*rays)
        best = min(best, time.perf_counter() - t0)
    return len(rays[0]) / best / 1e6


def _row(scene, acc, workload, dyn=0, mrays=None, update_ms=None, build_s=None, mem=None,
         **extra) -> dict:
    return {"scene": scene, "accelerator": acc, "dynamic_objects": dyn, "workload": workload,
            "mrays": mrays, "update_ms": update_ms, "build_s": build_s, "memory_mb": mem,
            **extra}


def available(names) -> list[str]:
    out = []
    for n in names:
        if n == "EMBREE":
            from ..accel.embree import available as embree_available

            if not embree_available():
                continue
        out.append(n)
    return out


def run_static(names, n_random: int, repeats: int, options: dict, log) -> list[dict]:
    rows = []
    for scene_name, make in (("grid", grid), ("museum", museum)):
        sc = make()
        sa = sc.arrays()
        work = {"primary": camera_rays(sc.camera),
                "random": random_rays(sa.scene_aabb, n_random, seed=2)}
        for name in names:
            acc, build_s = _build(name, sa, **options)
            for wname, rays in work.items():
                acc.closest_hit(*(a[:1000] for a in rays))  # warm-up (compilation)
                mr = _mrays(acc, rays, repeats)
                rows.append(_row(scene_name, name, wname, 0, mr, None, build_s, memory_mb(acc)))
                log(f"{scene_name:7s} {name:17s} {wname:8s} {mr:7.2f} Mrays/s  build "
                    f"{build_s:6.2f} s")
            del acc
    return rows


def dynamic_scene(k: int, small: bool = False):
    """``grid`` plus ``k`` dolphins; returns (scene, dolphin instance ids). ``small``: a
    160x120 camera and coarse spheres (for tests)."""
    sc = grid(160, 120, subdivisions=2) if small else grid()
    fin = sc.add_material(Material("dolphin", diffuse=(0.3, 0.35, 0.45)))
    mesh = sc.add_mesh(dolphin())
    ids = [sc.add_instance(mesh, _swim(j, k, 0), [fin], name=f"Dolphin{j:02d}")
           for j in range(k)]
    return sc, ids


def _swim(j: int, k: int, frame: int) -> np.ndarray:
    """Dolphin ``j`` of ``k`` at ``frame``: circling above the spheres."""
    a = 2.0 * math.pi * j / max(k, 1) + 0.15 * frame
    r = 4.0 + 1.5 * (j % 3)
    return shapes.transform((r * math.cos(a), r * math.sin(a), 2.6 + 0.4 * math.sin(a + j)),
                            1.0, math.degrees(a) + 90.0)


def run_figure2(names, frames: int, counts, options: dict, log,
                small: bool = False) -> list[dict]:
    rows = []
    for k in counts:
        sc, ids = dynamic_scene(k, small)
        sa = sc.arrays()
        rays = camera_rays(sc.camera)
        for name in names:
            acc, build_s = _build(name, sa, **options)
            acc.closest_hit(*(a[:1000] for a in rays))
            upd, mr = [], []
            for f in range(frames + 1):
                for j, i in enumerate(ids):
                    sc.set_instance_matrix(i, _swim(j, k, f + 1))
                sa_f = sc.arrays()
                t0 = time.perf_counter()
                acc.update(sa_f)
                dt = time.perf_counter() - t0
                t0 = time.perf_counter()
                acc.closest_hit(*rays)
                tr = time.perf_counter() - t0
                if f > 0:  # frame 0 makes the dolphins dynamic (first move): not timed
                    upd.append(dt)
                    mr.append(len(rays[0]) / tr / 1e6)
            for j, i in enumerate(ids):  # back to the start for the next accelerator
                sc.set_instance_matrix(i, _swim(j, k, 0))
            rows.append(_row("grid+dolphins", name, "figure2-primary", k,
                             float(np.median(mr)), 1e3 * float(np.median(upd)), build_s,
                             memory_mb(acc),
                             rebuilds=acc.stats.get("rebuilds")))
            log(f"dolphins {k:2d} {name:17s} update {rows[-1]['update_ms']:8.3f} ms  "
                f"{rows[-1]['mrays']:6.2f} Mrays/s")
            del acc
    return rows


def run_settings(settings, repeats: int, log) -> list[dict]:
    rows = []
    sc = grid()
    sa = sc.arrays()
    rays = camera_rays(sc.camera)
    for l_, n in settings:
        acc, build_s = _build("VISIBILITY_FIELD", sa, directions=l_, tiles=n)
        acc.closest_hit(*(a[:1000] for a in rays))
        mr = _mrays(acc, rays, repeats)
        extra = {"directions": acc.stats["directions"], "tiles": n,
                 "entries_per_tile": round(acc.stats["entries_per_tile"], 2)}
        rows.append(_row("grid", "VISIBILITY_FIELD", "primary", 0, mr, None, build_s,
                         memory_mb(acc), **extra))
        acc.ordered = False
        mu = _mrays(acc, rays, 1)
        rows.append(_row("grid", "VISIBILITY_FIELD", "primary-unordered", 0, mu, None,
                         build_s, memory_mb(acc), **extra))
        log(f"l={acc.stats['directions']:4d} n={n:3d}  build {build_s:6.2f} s  "
            f"{memory_mb(acc):8.1f} MB  {mr:6.2f} Mrays/s (unordered {mu:6.2f})")
        del acc
    return rows


def plot(rows: list[dict], path: Path) -> bool:
    """The paper's Figure 2, ours: update time and frame throughput against the number of
    moving objects, one curve per accelerator."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    for name in NAMES:
        rs = [r for r in rows if r["workload"] == "figure2-primary" and r["accelerator"] == name]
        if not rs:
            continue
        k = [r["dynamic_objects"] for r in rs]
        a.plot(k, [r["update_ms"] for r in rs], "o-", label=name)
        b.plot(k, [r["mrays"] for r in rs], "o-", label=name)
    a.set_xlabel("moving objects (528 triangles each)")
    a.set_ylabel("update after a move (ms)")
    a.set_yscale("log")
    b.set_xlabel("moving objects (528 triangles each)")
    b.set_ylabel("primary rays (Mrays/s)")
    a.legend()
    a.grid(alpha=0.3)
    b.grid(alpha=0.3)
    fig.suptitle("grid (102k static triangles) + moving dolphins, 640x480 primary rays")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine.bench accel")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quick", action="store_true",
                   help="a small grid only, one moved frame, 0 and 2 dolphins (for tests)")
    p.add_argument("--random", type=int, default=300_000, help="random rays per scene")
    p.add_argument("--frames", type=int, default=5, help="moved frames per dolphin count")
    p.add_argument("--repeats", type=int, default=3, help="timing runs (best)")
    p.add_argument("--directions", type=int, default=130,
                   help="visibility field l (130 in the README's tables)")
    p.add_argument("--tiles", type=int, default=32,
                   help="visibility field n (32 in the README's tables)")
    p.add_argument("--plot", default="", help="write the Figure 2 plot (PNG) here")
    p.add_argument("--parts", default="static,figure2,settings",
                   help="comma-separated parts to run (static, figure2, settings)")
    p.add_argument("--threads", type=int, default=1,
                   help="numba / Embree threads (default 1: one processor, as the paper's "
                        "Figure 2; 0: all)")
    a = p.parse_args(argv)
    import numba

    threads = numba.get_num_threads()
    if a.threads > 0:
        numba.set_num_threads(min(a.threads, numba.config.NUMBA_NUM_THREADS))
    try:
        return _main(a)
    finally:
        numba.set_num_threads(threads)


def _main(a) -> int:

    def log(msg: str) -> None:
        print(msg, file=sys.stderr if a.json else sys.stdout, flush=True)

    names = available(NAMES)
    options = {"directions": a.directions, "tiles": a.tiles}
    rows: list[dict] = []
    try:
        if a.quick:
            sc = grid(160, 120, subdivisions=2)
            sa = sc.arrays()
            rays = camera_rays(sc.camera)
            for name in names:
                acc, build_s = _build(name, sa, **options)
                rows.append(_row("grid-small", name, "primary", 0, _mrays(acc, rays, 1), None,
                                 build_s, memory_mb(acc)))
            rows += run_figure2(names, 1, (0, 2), options, log, small=True)
        else:
            parts = set(a.parts.split(","))
            if "static" in parts:
                rows += run_static(names, a.random, a.repeats, options, log)
            if "figure2" in parts:
                rows += run_figure2(names, a.frames, DYNAMIC_COUNTS, options, log)
            if "settings" in parts:
                rows += run_settings([(34, 32), (130, 16), (130, 32), (130, 64), (514, 32)],
                                     a.repeats, log)
    except AcceleratorUnavailable as e:
        print(f"accel: {e}", file=sys.stderr)
        return 1
    if a.plot:
        if not plot(rows, Path(a.plot)):
            log("matplotlib is not installed: no plot (pip install rstrace_engine[bench])")
    if a.json:
        print(json.dumps({"rows": rows}, indent=1))
    return 0
