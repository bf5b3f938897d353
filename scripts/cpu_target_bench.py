"""Portable kernels against host kernels, in one run: is numba's generic CPU slower?

The extension ships kernels compiled for numba's portable CPU (``NUMBA_CPU_NAME=generic``,
no CPU features). This compares them with kernels compiled for this machine's CPU on the
two speed benchmarks, ``bench raycast`` (BVH traversal, Mrays/s) and ``bench frame`` (a
whole base-tracer frame, s), alternating the two targets round by round (a noisy machine
moves both alike), each run a fresh process on one shared cache (both targets are entries
of the same index files, keyed on the CPU). The first round compiles and is not counted.

    python scripts/cpu_target_bench.py [--rounds 3] [--cache DIR] [--json out.json]

Prints the median of each measure per target and the ratio generic / host (> 1: the
portable code is slower for times, < 1 for rates), and the CPU time of each run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ("host", "generic")


def say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _run(target: str, args: list[str], cache: str) -> tuple[dict, float, float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    env.update(NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
    if target == "generic":
        env.update(NUMBA_CPU_NAME="generic", NUMBA_CPU_FEATURES="")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "rstrace_engine.bench", *args, "--json"],
                          cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return json.loads(proc.stdout), wall, cpu


def _measures(raycast: dict, frame: dict) -> dict[str, float]:
    out = {f"raycast {w['name']} Mrays/s": w["numba_mrays"] for w in raycast["workloads"]}
    out.update({f"frame {f['scene']} s": f["time_s"] for f in frame["frames"]})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cache", default=None, help="numba cache (default: a temporary one)")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--json", default=None, help="write the results here too")
    args = ap.parse_args(argv)
    cache = args.cache or tempfile.mkdtemp(prefix="rstrace-cpu-bench-")
    frame_args = ["frame", "--no-mitsuba", "--width", str(args.width), "--height",
                  str(args.height)]
    samples: dict[str, dict[str, list[float]]] = {t: {} for t in TARGETS}
    cpu: dict[str, list[float]] = {t: [] for t in TARGETS}
    for rnd in range(args.rounds + 1):
        for target in TARGETS:
            ray, w1, c1 = _run(target, ["raycast"], cache)
            frame, w2, c2 = _run(target, frame_args, cache)
            say(f"round {rnd}{' (compiles, not counted)' if rnd == 0 else ''} {target}: "
                f"wall {w1 + w2:.1f} s, CPU {c1 + c2:.1f} s")
            if rnd == 0:
                continue
            cpu[target].append(c1 + c2)
            for k, v in _measures(ray, frame).items():
                samples[target].setdefault(k, []).append(v)
    result = {"host_cpu": _host_cpu(), "rounds": args.rounds, "measures": {}}
    say(f"\nhost CPU: {result['host_cpu']}; medians of {args.rounds} rounds")
    say(f"{'measure':<42}{'host':>10}{'generic':>10}{'generic/host':>14}")
    for k in samples["host"]:
        h, g = (statistics.median(samples[t][k]) for t in TARGETS)
        result["measures"][k] = dict(host=h, generic=g, ratio=g / h if h else None)
        say(f"{k:<42}{h:>10.3f}{g:>10.3f}{g / h if h else float('nan'):>14.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


def _host_cpu() -> str:
    import llvmlite.binding as ll

    return ll.get_host_cpu_name()


if __name__ == "__main__":
    sys.exit(main())
