"""Closest-hit rays of real frames, dumped once, then timed through the BVH and Embree.

``python scripts/trace_rays.py dump RAYS.npz [--size 160x120] [--frames 4:4,1:16]``
renders rough_materials (BASE, BVH) at each ``SAMPLES:GLOSSY`` and records every
``closest_hit`` query the frame makes (camera rays and each level's secondary rays, with
their ``tmin``, ``tmax`` and ``skip``), plus the closest-hit workloads of
``scripts/raycast_ab.py`` (primary, secondary, random) of its scenes.

``python scripts/trace_rays.py time RAYS.npz [OUT.npz] [--embree] [--repeats 3]`` traces
each dumped set on one thread (process CPU, best of ``--repeats``) and prints Mrays/s and
ns a ray; ``--embree`` also times Embree's closest hit on the same rays. ``OUT.npz`` gets
the BVH's hits (t, inst, prim, u, v) to compare two checkouts bit for bit:
``python scripts/raycast_ab.py --compare A.npz B.npz``. Run ``time`` with ``PYTHONPATH`` set
to each checkout, alternated (A B B A); the rays are the same file.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

ROUGH = "rough_materials"
AB_SCENES = ("three_spheres", "museum", "rough_materials")


def dump(out, size, frames):
    from raycast_ab import workloads  # scripts/ is on sys.path when run as a script

    from rstrace_engine import scenes
    from rstrace_engine.accel.accelerators import create_accelerator
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.tracing import whitted

    w, h = (int(v) for v in size.split("x"))
    saved = {}
    for spec in frames:
        s, g = (int(v) for v in spec.split(":"))
        scene = scenes.build(ROUGH, w, h)
        st = RenderSettings(samples=s, glossy_samples=g).validated()
        acc = create_accelerator("BVH", scene.arrays(), **st.accelerator_options())
        got = []
        inner = acc.closest_hit

        def rec(o, d, t0, t1, skip=None, inner=inner, got=got):
            n = len(o)
            sk = np.full(n, -1, np.int32) if skip is None else np.asarray(skip, np.int32)
            got.append((np.array(o, np.float64), np.array(d, np.float64),
                        np.broadcast_to(np.asarray(t0, np.float64), (n,)).copy(),
                        np.broadcast_to(np.asarray(t1, np.float64), (n,)).copy(), sk))
            return inner(o, d, t0, t1, skip)

        acc.closest_hit = rec
        whitted.render(scene, st, accel=acc)
        for k, arrays in enumerate(got):
            key = f"{ROUGH}/{s}x{g}/q{k:02d}"
            for name, a in zip(("o", "d", "t0", "t1", "skip"), arrays, strict=True):
                saved[f"{key}/{name}"] = a
        sys.stderr.write(f"{ROUGH} {s}x{g}: {len(got)} queries, "
                         f"{sum(len(a[0]) for a in got)} rays\n")
    for name in AB_SCENES:
        scene = scenes.build(name, 320, 240)
        sa = scene.arrays()
        acc = create_accelerator("BVH", sa)
        for wl, (o, d, t0, t1, anyhit) in workloads(scene, sa, acc, 100_000).items():
            if anyhit:
                continue
            key = f"{name}/ab/{wl}"
            for nm, a in zip(("o", "d", "t0", "t1"), (o, d, t0, t1), strict=True):
                saved[f"{key}/{nm}"] = np.asarray(a, np.float64)
            saved[f"{key}/skip"] = np.full(len(o), -1, np.int32)
    np.savez(out, **saved)


def _sets(z):
    """``{(scene, group): [(o, d, t0, t1, skip), ...]}``: a frame's queries as one group."""
    out: dict = {}
    keys = sorted({k.rsplit("/", 1)[0] for k in z.files})
    for k in keys:
        scene, group = k.split("/")[:2]
        if group == "ab":
            group = k.split("/")[2]
        out.setdefault((scene, group), []).append(
            tuple(z[f"{k}/{n}"] for n in ("o", "d", "t0", "t1", "skip")))
    return out


def timing(path, out, embree, repeats):
    import numba

    import rstrace_engine
    from rstrace_engine import scenes
    from rstrace_engine.accel.accelerators import create_accelerator

    numba.set_num_threads(1)
    sys.stderr.write(f"rstrace_engine from {rstrace_engine.__file__}\n")
    z = np.load(path)
    saved = {}
    accs: dict = {}
    for (scene, group), qs in _sets(z).items():
        if scene not in accs:
            sa = scenes.build(scene, 160, 120).arrays()
            accs[scene] = [("bvh", create_accelerator("BVH", sa))]
            if embree:
                accs[scene].append(("embree", create_accelerator("EMBREE", sa)))
        n = sum(len(q[0]) for q in qs)
        row = f"{scene:<16}{group:<10}{n:>8}"
        for kind, acc in accs[scene]:
            def go(acc=acc, qs=qs):
                return [acc.closest_hit(o, d, t0, t1, None if np.all(sk == -1) else sk)
                        for o, d, t0, t1, sk in qs]
            res = go()
            best = np.inf
            for _ in range(repeats):
                c0 = time.process_time()
                go()
                best = min(best, time.process_time() - c0)
            row += f"  {kind} {n / best / 1e6:6.3f} Mrays/s {best * 1e9 / n:5.0f} ns"
            if kind == "bvh":
                for f in ("t", "inst", "prim", "u", "v"):
                    saved[f"{scene}/{group}/{f}"] = np.concatenate(
                        [np.asarray(getattr(h, f)) for h in res])
        sys.stdout.write(row + "\n")
        sys.stdout.flush()
    if out:
        np.savez(out, **saved)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("dump", "time"))
    ap.add_argument("rays")
    ap.add_argument("out", nargs="?", default="")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--frames", default="4:4,1:16")
    ap.add_argument("--embree", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    if a.mode == "dump":
        dump(a.rays, a.size, a.frames.split(","))
    else:
        timing(a.rays, a.out, a.embree, a.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
