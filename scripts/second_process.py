"""A second Blender process: F12 on a warm kernel cache, timed (issue 25's "second process").

    python scripts/second_process.py [--repo PATH ...] [--rounds 3] [--json out.json]

Each round starts a fresh process (``bpy`` as a module stands in for Blender) that registers
the add-on of ``--repo`` (default: this repository; several repositories alternate round by
round, for a comparison in one run), builds the small scene of ``scripts/first_render.py``
(a floor, three spheres one a mirror, a point light; 96x72) and presses F12 in BASE. The
numba cache is ``NUMBA_CACHE_DIR`` as inherited; a first round per repository fills it (and
Python's bytecode caches) and is not counted. Reported per F12: wall and CPU time (the
process's, all threads and finished child processes), kernels compiled and loaded, and the
load average before and after (the machine may be shared: CPU times say how much work it was).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

from small_scene import SOURCE as SCENE_SOURCE  # (scripts/ is the script's sys.path[0])

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = SCENE_SOURCE + textwrap.dedent('''
    import json, os, resource, sys, time
    t_start = time.perf_counter()
    sys.path.insert(0, os.path.realpath(sys.argv[1]))

    def cpu():
        s = resource.getrusage(resource.RUSAGE_SELF)
        c = resource.getrusage(resource.RUSAGE_CHILDREN)
        return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime

    import bpy
    out = {"bpy_import_s": time.perf_counter() - t_start}
    t0, c0 = time.perf_counter(), cpu()
    import addon
    addon.register()
    out["enable_s"], out["enable_cpu_s"] = time.perf_counter() - t0, cpu() - c0
    sc = build_small_scene(bpy, 96, 72)
    from rstrace_engine import kernel_cache
    sc.rstrace.mode = "BASE"
    since = kernel_cache.mark()
    t0, c0 = time.perf_counter(), cpu()
    bpy.ops.render.render()
    k = kernel_cache.counts(since=since)
    out.update(f12_s=time.perf_counter() - t0, f12_cpu_s=cpu() - c0, compiled=k["compiled"],
               loaded=k["loaded"], ok=addon.last_render_stats(sc).get("mode") == "BASE",
               process_s=time.perf_counter() - t_start, process_cpu_s=cpu())
    addon.kernels.stop()
    print("RESULT " + json.dumps(out))
''')


def run_once(script: Path, repo: Path) -> dict:
    load0 = os.getloadavg()[0]
    proc = subprocess.run([sys.executable, str(script), str(repo)], cwd=script.parent,
                          capture_output=True, text=True, timeout=1800)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"process failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return dict(json.loads(lines[-1][len("RESULT "):]), repo=str(repo), load_before=load0,
                load_after=os.getloadavg()[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repo", type=Path, nargs="+", default=[ROOT])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rstrace-second-") as tmp:
        script = Path(tmp) / "second.py"
        script.write_text(SCRIPT)
        for repo in args.repo:
            run_once(script, repo.resolve())  # fills the caches, not counted
        for i in range(args.rounds):
            for repo in args.repo:
                r = dict(run_once(script, repo.resolve()), round=i)
                rows.append(r)
                sys.stderr.write(f"{repo}: F12 {r['f12_s']:.2f} s wall {r['f12_cpu_s']:.2f} s "
                                 f"CPU ({r['compiled']} compiled, {r['loaded']} loaded), "
                                 f"enable {r['enable_cpu_s']:.2f} s CPU, load "
                                 f"{r['load_before']:.1f}-{r['load_after']:.1f}\n")
    for repo in args.repo:
        mine = [r for r in rows if r["repo"] == str(repo.resolve())]
        med = {k: statistics.median(r[k] for r in mine)
               for k in ("f12_s", "f12_cpu_s", "enable_s", "enable_cpu_s", "process_cpu_s")}
        sys.stdout.write(
            f"{repo}: median of {len(mine)}: F12 {med['f12_s']:.2f} s wall, "
            f"{med['f12_cpu_s']:.2f} s CPU; enable {med['enable_s']:.2f} s wall, "
            f"{med['enable_cpu_s']:.2f} s CPU; whole process {med['process_cpu_s']:.2f} s CPU\n")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
