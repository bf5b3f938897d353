"""Per-scene ray-cast workloads through the BVH, to time and compare two checkouts.

``python scripts/raycast_ab.py OUT.npz [--scenes a,b] [--size 320x240] [--repeats N]``
traces each scene's workloads on one thread and prints rays/s (best of ``--repeats``)
per workload; ``OUT.npz`` gets every hit (t, inst, prim, u, v; any-hit flags) to compare:
``python scripts/raycast_ab.py --compare A.npz B.npz`` (0 differing rows: the same bits).
Run the first with ``PYTHONPATH`` set to each checkout (alternated: A B B A).

Workloads (the same rays on every checkout: numpy only, seeded):

* ``primary``: the camera's centre rays at ``--size``;
* ``secondary``: from each primary hit, a cosine-weighted direction about the geometric
  normal on the side the ray came from (the origin pushed off the surface by 1e-6 of the
  scene's size): diffuse and glossy bounce rays;
* ``shadow``: any-hit rays from each primary hit to each point-like light (to a point above
  the scene when it has none), ending short of the light;
* ``random``: origins uniform in the scene's box, uniform directions.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from frames_dump import compare  # scripts/ is on sys.path when run as a script

SCENES = ("three_spheres", "museum", "studio", "tori", "grid", "bezier_surface", "tomatoes",
          "rough_materials")


def workloads(scene, sa, acc, n_random: int):
    from rstrace_engine.geometry.cameras import camera_rays

    o, d, t0, t1 = camera_rays(scene.camera)
    out = {"primary": (o, d, t0, t1, False)}
    h = acc.closest_hit(o, d, t0, t1)
    hit = np.flatnonzero(h.inst >= 0)
    p = o[hit] + h.t[hit, None] * d[hit]
    box = sa.scene_aabb
    size = float(np.max(box[1] - box[0]))
    # geometric normals in world space
    tv = sa.verts[sa.tris[h.prim[hit]]]
    x = sa.inst_xform[h.inst[hit]]
    w = np.einsum("nij,nkj->nki", x[:, :3, :3], tv)
    n = np.cross(w[:, 1] - w[:, 0], w[:, 2] - w[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    n *= -np.sign(np.sum(n * d[hit], axis=1))[:, None]
    rng = np.random.default_rng(5)
    g = rng.normal(size=(len(hit), 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    sd = n + g
    sd /= np.maximum(np.linalg.norm(sd, axis=1, keepdims=True), 1e-300)
    so = p + n * (1e-6 * size)
    m = len(hit)
    out["secondary"] = (so, sd, np.zeros(m), np.full(m, np.inf), False)
    lights = [sa.light_pos[k] for k in range(len(sa.light_kind))
              if np.all(np.isfinite(sa.light_pos[k]))] or [
        np.array([0.5 * (box[0, 0] + box[1, 0]), 0.5 * (box[0, 1] + box[1, 1]),
                  box[1, 2] + size])]
    lo, ld = [], []
    for lp in lights[:2]:
        lo.append(so)
        ld.append(lp[None, :] - so)
    lo, ld = np.concatenate(lo), np.concatenate(ld)
    out["shadow"] = (lo, ld, np.zeros(len(lo)), np.full(len(lo), 1.0 - 1e-9), True)
    ro = rng.uniform(box[0], box[1], (n_random, 3))
    rd = rng.normal(size=(n_random, 3))
    rd /= np.linalg.norm(rd, axis=1, keepdims=True)
    out["random"] = (ro, rd, np.zeros(n_random), np.full(n_random, np.inf), False)
    return out


def run(out_path, scenes, size, repeats, n_random):
    import numba

    import rstrace_engine
    from rstrace_engine.accel.accelerators import create_accelerator
    from rstrace_engine.scenes import build

    numba.set_num_threads(1)
    sys.stderr.write(f"rstrace_engine from {rstrace_engine.__file__}\n")
    w, h = (int(v) for v in size.split("x"))
    saved = {}
    for name in scenes:
        scene = build(name, w, h)
        sa = scene.arrays()
        acc = create_accelerator("BVH", sa)
        for wl, (o, d, t0, t1, anyhit) in workloads(scene, sa, acc, n_random).items():
            fn = acc.any_hit if anyhit else acc.closest_hit
            res = fn(o, d, t0, t1)
            best = np.inf
            for _ in range(repeats):
                c0 = time.process_time()
                fn(o, d, t0, t1)
                best = min(best, time.process_time() - c0)
            sys.stdout.write(f"{name:<16}{wl:<10}{len(o):>9}{len(o) / best / 1e6:>9.3f} Mrays/s"
                  f"{best * 1e9 / len(o):>8.0f} ns/ray\n")
            sys.stdout.flush()
            if anyhit:
                saved[f"{name}/{wl}/hit"] = np.asarray(res)
            else:
                for f in ("t", "inst", "prim", "u", "v"):
                    saved[f"{name}/{wl}/{f}"] = np.asarray(getattr(res, f))
    if out_path:
        np.savez(out_path, **saved)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="?", default="")
    ap.add_argument("--compare", nargs=2)
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--random", type=int, default=100_000)
    args = ap.parse_args(argv)
    if args.compare:
        return compare(*args.compare)
    run(args.out, args.scenes.split(","), args.size, args.repeats, args.random)
    return 0


if __name__ == "__main__":
    sys.exit(main())
