"""What a new user does, timed: install the extension zip into a fresh Blender profile, F12.

    python scripts/first_render.py dist/rstrace-<version>-linux_x64.zip [--json out.json]
                                   [--width 96 --height 72]

A fresh ``BLENDER_USER_RESOURCES`` (a temporary folder), then in one process (``bpy`` as a
module stands in for Blender; the repository is hidden so ``rstrace_engine`` comes from the
zip's wheel): install the zip and enable it, build a small scene (a floor, three spheres one
of them a mirror, a point light, a camera), select RSTrace and press F12 in BASE, then in
INTERPOLANT, then in RI_TREE; then a *second* process on the same profile presses F12 in
BASE. For each F12: the wall time and the process's CPU time (all threads, and finished
child processes), the kernels compiled and loaded during it, and which compiled kernels
ship (``runtime.shipped_status``). The machine may be shared: the CPU times say how much
work each step was, whatever else ran.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from small_scene import SOURCE as SCENE_SOURCE  # (scripts/ is the script's sys.path[0])

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = SCENE_SOURCE + textwrap.dedent('''
    import json, os, resource, sys, time

    zip_path, repo, phase, width, height = (sys.argv[1], os.path.realpath(sys.argv[2]),
                                            sys.argv[3], int(sys.argv[4]), int(sys.argv[5]))
    sys.path[:] = [p for p in sys.path if os.path.realpath(p or ".") != repo]
    sys.meta_path[:] = [f for f in sys.meta_path
                        if not getattr(f, "__module__", "").startswith("__editable__")]
    t_start = time.perf_counter()
    import bpy

    def cpu():
        s = resource.getrusage(resource.RUSAGE_SELF)
        c = resource.getrusage(resource.RUSAGE_CHILDREN)
        return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime

    out = {"phase": phase, "bpy_import_s": time.perf_counter() - t_start}
    if phase == "first":
        t0, c0 = time.perf_counter(), cpu()
        bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                 enable_on_install=True)
        bpy.ops.wm.save_userpref()
        out["install_s"], out["install_cpu_s"] = time.perf_counter() - t0, cpu() - c0
    mod = sys.modules.get("bl_ext.user_default.rstrace")
    if mod is None:  # bpy as a module does not enable the saved add-ons as Blender does
        import addon_utils

        t0, c0 = time.perf_counter(), cpu()
        addon_utils.enable("bl_ext.user_default.rstrace", default_set=True)
        out["enable_s"], out["enable_cpu_s"] = time.perf_counter() - t0, cpu() - c0
        mod = sys.modules.get("bl_ext.user_default.rstrace")
    out["enabled"] = mod is not None
    runtime = mod.runtime
    out["shipped"] = runtime.shipped_status() or "used"
    out["kernel_target"] = runtime.kernel_target()
    import numba
    out["numba_cpu"] = numba.config.CPU_NAME or "host"
    from rstrace_engine import kernel_cache

    sc = build_small_scene(bpy, width, height)

    modes = ["BASE", "INTERPOLANT", "RI_TREE"] if phase == "first" else ["BASE"]
    renders = []
    for mode in modes:
        sc.rstrace.mode = mode
        since = kernel_cache.mark()
        t0, c0 = time.perf_counter(), cpu()
        bpy.ops.render.render()
        k = kernel_cache.counts(since=since)
        stats = mod.last_render_stats(sc)
        renders.append(dict(mode=mode, wall_s=time.perf_counter() - t0, cpu_s=cpu() - c0,
                            compiled=k["compiled"], loaded=k["loaded"],
                            render_s=stats.get("render_seconds"),
                            ok=bool(stats) and stats.get("mode") == mode))
    out["renders"] = renders
    out["process_s"] = time.perf_counter() - t_start
    out["process_cpu_s"] = cpu()
    mod.kernels.stop()
    print("RESULT " + json.dumps(out))
''')


def run_phase(script: Path, zip_path: Path, user: Path, phase: str, w: int, h: int) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR") and not k.startswith("NUMBA_CPU")}
    env["BLENDER_USER_RESOURCES"] = str(user)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, str(script), str(zip_path), str(ROOT), phase,
                           str(w), str(h)], cwd=script.parent, env=env, capture_output=True,
                          text=True, timeout=1800)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"{phase} process failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    result = json.loads(lines[-1][len("RESULT "):])
    result["wall_with_start_s"] = time.perf_counter() - t0
    sys.stderr.write(json.dumps(result) + "\n")  # each phase as soon as it is done
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zip", type=Path)
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=72)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="rstrace-first-") as tmp:
        tmp = Path(tmp)
        user = tmp / "blender_user"
        user.mkdir()
        script = tmp / "new_user.py"
        script.write_text(SCRIPT)
        results = [run_phase(script, args.zip.resolve(), user, phase, args.width, args.height)
                   for phase in ("first", "second")]
    lines = [f"zip {args.zip.name} ({args.zip.stat().st_size / 2**20:.1f} MiB); shipped "
             f"kernels: {results[0]['shipped']}; numba CPU: {results[0]['numba_cpu']}",
             f"install: {results[0]['install_s']:.1f} s wall, "
             f"{results[0]['install_cpu_s']:.1f} s CPU"]
    for r in results:
        for f in r["renders"]:
            lines.append(f"{r['phase']} process F12 {f['mode']:<12} {f['wall_s']:6.2f} s wall "
                         f"{f['cpu_s']:6.2f} s CPU  ({f['compiled']} compiled, {f['loaded']} "
                         f"loaded{'' if f['ok'] else ', NO IMAGE'})")
        lines.append(f"{r['phase']} process: bpy import {r['bpy_import_s']:.1f} s, whole "
                     f"process {r['wall_with_start_s']:.1f} s wall, {r['process_cpu_s']:.1f} s "
                     "CPU")
    sys.stdout.write("\n".join(lines) + "\n")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
