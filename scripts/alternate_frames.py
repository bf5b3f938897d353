"""Frame time of this checkout against another (an older commit's worktree), alternating.

``python scripts/alternate_frames.py --base DIR [--scenes three_spheres,museum] [--pairs 12]
[--width 320] [--height 240] [--depth 5] [--samples S] [--glossy-samples G]``

Two warm worker processes, one importing ``rstrace_engine`` from ``DIR`` (e.g. ``git -C
/work/main worktree add --detach DIR <commit>``) and one from this checkout, render the same
base-tracer frame (BVH, default settings at ``--depth``, and ``--samples`` pixel samples and
``--glossy-samples`` where given) in turn, ``--pairs`` times per scene
(the order swapped every pair), so that both see the same load on a shared machine. Prints per
scene the median frame times, the median of the per-pair ratios (this / base: wall and process
CPU time) with its quartiles, and whether the two frames are bit-identical with the same ray
counts. Used for issue 24's "a scene without rough surfaces renders as fast as today"
(docs/bench-frame.md).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

WORKER = r"""
import hashlib, sys, time
from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing.whitted import render

W, H, DEPTH, S, G = map(int, sys.argv[1:6])
st = RenderSettings(max_depth=DEPTH, **({"samples": S} if S > 0 else {}),
                    **({"glossy_samples": G} if G > 0 else {}))
cache = {}
print("ready", flush=True)
for line in sys.stdin:
    name = line.strip()
    if name not in cache:
        sc = scenes.build(name, W, H)
        acc = create_accelerator("BVH", sc.arrays())
        render(sc, st, accel=acc)  # compiles / loads the kernels
        cache[name] = (sc, acc)
        print("built", flush=True)
        continue
    sc, acc = cache[name]
    t0, c0 = time.perf_counter(), time.process_time()
    f = render(sc, st, accel=acc)
    t, c = time.perf_counter() - t0, time.process_time() - c0
    digest = hashlib.sha1(f.radiance.tobytes()).hexdigest()[:12]
    print(t, c, digest, f.stats["rays_traced"], flush=True)
"""


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--base", type=Path, required=True, help="the other checkout")
    p.add_argument("--scenes", default="three_spheres,museum,glass_horizon,tori")
    p.add_argument("--pairs", type=int, default=12)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    p.add_argument("--depth", type=int, default=5)
    p.add_argument("--samples", type=int, default=0, help="pixel samples (0: the default)")
    p.add_argument("--glossy-samples", type=int, default=0, help="(0: the default)")
    a = p.parse_args(argv)
    here = Path(__file__).resolve().parent.parent
    args = [sys.executable, "-c", WORKER, str(a.width), str(a.height), str(a.depth),
            str(a.samples), str(a.glossy_samples)]
    env = dict(os.environ)
    workers = {k: subprocess.Popen(args, cwd=d, env=env, stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE, text=True)
               for k, d in (("base", a.base.resolve()), ("this", here))}

    def ask(k, name):
        workers[k].stdin.write(name + "\n")
        workers[k].stdin.flush()
        return workers[k].stdout.readline().split()

    try:
        for w in workers.values():
            if w.stdout.readline().strip() != "ready":
                raise SystemExit("a worker failed to start")
        for name in [s for s in a.scenes.split(",") if s]:
            for k in workers:
                ask(k, name)
            times = {k: [] for k in workers}
            cpu_s = {k: [] for k in workers}
            digests = {k: set() for k in workers}
            rays = {}
            wall, cpu = [], []
            for i in range(a.pairs):
                order = ("base", "this") if i % 2 == 0 else ("this", "base")
                got = {k: ask(k, name) for k in order}
                for k in workers:
                    times[k].append(float(got[k][0]))
                    cpu_s[k].append(float(got[k][1]))
                    digests[k].add(got[k][2])
                    rays[k] = int(got[k][3])
                wall.append(float(got["this"][0]) / float(got["base"][0]))
                cpu.append(float(got["this"][1]) / float(got["base"][1]))
            q = statistics.quantiles(wall, n=4)
            qc = statistics.quantiles(cpu, n=4)
            sys.stdout.write(
                f"{name}: {a.width}x{a.height} depth {a.depth} samples {a.samples or 'default'}"
                f" x {a.glossy_samples or 'default'}, {a.pairs} pairs: base "
                f"{statistics.median(times['base']):.3f} s, this "
                f"{statistics.median(times['this']):.3f} s; this/base wall "
                f"{statistics.median(wall):.3f} (quartiles {q[0]:.3f}-{q[2]:.3f}), cpu "
                f"{statistics.median(cpu):.3f} (quartiles {qc[0]:.3f}-{qc[2]:.3f}, base "
                f"{statistics.median(cpu_s['base']):.3f} s, this "
                f"{statistics.median(cpu_s['this']):.3f} s); images identical "
                f"{digests['base'] == digests['this']}, rays {rays['base']:,} / "
                f"{rays['this']:,}\n")
            sys.stdout.flush()
    finally:
        for w in workers.values():
            w.stdin.close()
            w.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
