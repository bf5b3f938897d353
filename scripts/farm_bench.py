"""Render-farm measurements on this machine (the numbers in docs/FARM.md).

    python scripts/farm_bench.py [--frames 16] [--size 320 240] [--samples 1] [--skip-cold]
                                 [--json out.json]

Every worker is a separate process started like a farm's (``scripts/bpy_render.py``, the
``blender -b`` stand-in), rendering an animation of Plate A (objects, a light and the camera
keyframed, ``tests/blender/builders.animated_three_spheres``).

* **cold**: (1) ``python -m rstrace_engine warm-cache`` on an empty ``NUMBA_CACHE_DIR``;
  (2) two workers started at the same moment on another empty cache, rendering two chunks
  of the INTERPOLANT animation: their wall time, kernels compiled and loaded, errors; then a
  third worker on that cache (what is left to compile), and the frames compared with the
  frames rendered on the warm cache (a corrupted cache would change them).
* **warm start-up**: one worker rendering one frame, three times: Python + ``import bpy``,
  the add-on, opening the file, and the first frame against a steady frame.
* **throughput**: frames per minute, start-up included, for one worker over the whole range
  against two worker processes (half the range each, one thread each, and two threads each)
  started together, in BASE and INTERPOLANT modes.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ROOT / "scripts" / "bpy_render.py"
log = logging.getLogger("farm_bench")


def make_blends(folder: Path, width: int, height: int, frames: int,
                samples: int = 1) -> dict[str, Path]:
    """base.blend (BASE) and interp.blend (INTERPOLANT, epsilon 0.02), RSTrace engine."""
    sys.path.insert(0, str(ROOT))
    import bpy

    import addon
    from tests.blender import builders

    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = builders.animated_three_spheres(width, height, frames)
    sc.rstrace.samples, sc.rstrace.max_ray_depth = samples, 3
    out = {"BASE": folder / "base.blend", "INTERPOLANT": folder / "interp.blend"}
    bpy.ops.wm.save_as_mainfile(filepath=str(out["BASE"]), copy=True)
    sc.rstrace.mode, sc.rstrace.epsilon = "INTERPOLANT", 0.02
    bpy.ops.wm.save_as_mainfile(filepath=str(out["INTERPOLANT"]), copy=True)
    return out


def start(blend: Path, out: Path, args, cache: Path | None) -> subprocess.Popen:
    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, str(RUNNER), str(blend), "-o", str(out / "frame_####"), *args]
    proc = subprocess.Popen(cmd, cwd=out, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.t0 = time.perf_counter()
    return proc


def finish(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=1800)
    wall = time.perf_counter() - proc.t0
    lines = [ln for ln in out.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(" ".join(proc.args) + "\n" + out[-2000:] + err[-4000:])
    r = json.loads(lines[-1][len("RESULT "):])
    r["wall_s"] = wall
    return r


def together(jobs) -> tuple[list[dict], float]:
    """Start every (blend, out, args, cache) at once; their results and the total wall."""
    t0 = time.perf_counter()
    procs = [start(*job) for job in jobs]
    results = [finish(p) for p in procs]
    return results, time.perf_counter() - t0


def read_frames(folder: Path):
    import numpy as np

    sys.path.insert(0, str(ROOT))
    from tests.blender.exr import read_exr, read_pass

    return {p.name: np.asarray(read_pass(read_exr(p), "Combined", components="RGB"))
            for p in sorted(folder.glob("frame_*.exr"))}


def cold(blends, work: Path, frames: int) -> dict:
    out: dict = {}
    cache = work / "cold_cache_a"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["NUMBA_CACHE_DIR"] = str(cache)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "rstrace_engine", "warm-cache", "--json"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-4000:])
    w = json.loads(proc.stdout)
    out["warm_cache_cold"] = dict(wall_s=time.perf_counter() - t0, compiled=w["compiled"],
                                  seconds=w["seconds"])
    log.info("cold warm-cache: %s", out["warm_cache_cold"])

    cache = work / "cold_cache_b"
    half = frames // 2
    jobs = [(blends["INTERPOLANT"], work / "cold" / "w1", ["-f", f"1..{half}"], cache),
            (blends["INTERPOLANT"], work / "cold" / "w2", ["-f", f"{half + 1}..{frames}"],
             cache)]
    results, wall = together(jobs)
    out["two_cold_workers"] = [dict(wall_s=r["wall_s"], cpu_s=r["cpu_s"],
                                    compiled=r["kernels"]["compiled"],
                                    loaded=r["kernels"]["loaded"], errors=r["errors"],
                                    first_frame_s=r["frames"][0]["seconds"])
                               for r in results]
    (third,), _ = together([(blends["INTERPOLANT"], work / "cold" / "w3", ["-f", "1"], cache)])
    out["third_worker_after"] = dict(compiled=third["kernels"]["compiled"], cpu_s=third["cpu_s"],
                                     loaded=third["kernels"]["loaded"],
                                     wall_s=third["wall_s"])
    leftovers = [p.name for p in cache.rglob("*") if ".tmp." in p.name]
    out["tmp_files_left"] = leftovers
    log.info("two cold workers: %s; third: %s", out["two_cold_workers"],
             out["third_worker_after"])
    return out


def cold_single(blends, work: Path) -> dict:
    """One worker alone on an empty cache, one INTERPOLANT frame, then one on the warm cache."""
    cache = work / "cold_cache_single"
    out = {}
    for name in ("cold", "warm"):
        (r,), _ = together([(blends["INTERPOLANT"], work / f"single_{name}", ["-f", "1"],
                             cache)])
        out[name] = dict(wall_s=r["wall_s"], cpu_s=r["cpu_s"], import_bpy_s=r["import_bpy_s"],
                         first_frame_s=r["frames"][0]["seconds"],
                         compiled=r["kernels"]["compiled"], loaded=r["kernels"]["loaded"])
    log.info("one worker, cold then warm: %s", out)
    return out


def warm_startup(blends, work: Path, repeats: int = 3) -> dict:
    runs = []
    for i in range(repeats):
        (r,), _ = together([(blends["BASE"], work / f"start{i}", ["-f", "1..3"], None)])
        steady = statistics.median(f["seconds"] for f in r["frames"][1:])
        first = r["frames"][0]["seconds"]
        runs.append(dict(process_wall_s=r["wall_s"], cpu_s=r["cpu_s"],
                         import_bpy_s=r["import_bpy_s"],
                         addon_s=r["addon_s"] - r["import_bpy_s"],
                         open_s=r["open_s"] - r["addon_s"], first_frame_s=first,
                         steady_frame_s=steady,
                         rstrace_startup_s=(r["addon_s"] - r["import_bpy_s"])
                         + max(first - steady, 0.0),
                         compiled=r["kernels"]["compiled"]))
    log.info("warm start-up: %s", runs)
    return {"runs": runs,
            "median_rstrace_startup_s": statistics.median(r["rstrace_startup_s"]
                                                          for r in runs),
            "median_process_overhead_s": statistics.median(
                r["process_wall_s"] - 3 * r["steady_frame_s"] for r in runs)}


def throughput(blends, work: Path, frames: int) -> dict:
    half = frames // 2
    out = {}
    for mode, blend in blends.items():
        rows = {}
        for rep in range(2):  # interleaved repeats: the machine is shared
            for name, jobs in (
                    ("1 worker", [(blend, work / f"{mode}1_{rep}", ["-s", "1", "-e",
                                                                   str(frames), "-a"],
                                   None)]),
                    ("2 workers x 1 thread",
                     [(blend, work / f"{mode}2t1_{rep}", ["-t", "1", "-f", f"1..{half}"], None),
                      (blend, work / f"{mode}2t1_{rep}", ["-t", "1", "-f",
                                                           f"{half + 1}..{frames}"], None)]),
                    ("2 workers x 2 threads",
                     [(blend, work / f"{mode}2t2_{rep}", ["-f", f"1..{half}"], None),
                      (blend, work / f"{mode}2t2_{rep}", ["-f", f"{half + 1}..{frames}"],
                       None)])):
                results, wall = together(jobs)
                rows.setdefault(name, []).append(60.0 * frames / wall)
        out[mode] = {k: sorted(v) for k, v in rows.items()}
        log.info("%s frames per minute: %s", mode, out[mode])
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--size", type=int, nargs=2, default=(320, 240))
    p.add_argument("--samples", type=int, default=1, help="samples per pixel")
    p.add_argument("--skip-cold", action="store_true")
    p.add_argument("--cold-single", action="store_true",
                   help="only: one worker on an empty cache, then on that cache warm")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    work = Path(tempfile.mkdtemp(prefix="rstrace_farm_"))
    try:
        blends = make_blends(work, args.size[0], args.size[1], args.frames, args.samples)
        result = dict(frames=args.frames, size=list(args.size), samples=args.samples,
                      cpus=os.cpu_count(),
                      loadavg_before=os.getloadavg())
        if args.cold_single:
            result["cold_single"] = cold_single(blends, work)
            sys.stdout.write(json.dumps(result, indent=2) + "\n")
            if args.json:
                Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
            return 0
        warm = subprocess.run([sys.executable, "-m", "rstrace_engine", "warm-cache", "--json"],
                              cwd=ROOT, capture_output=True, text=True, timeout=3600,
                              env={k: v for k, v in os.environ.items()
                                   if k != "NUMBA_CACHE_DIR"})
        result["warm_cache_warm_s"] = json.loads(warm.stdout)["seconds"]
        (ref,), _ = together([(blends["INTERPOLANT"], work / "reference",
                               ["-s", "1", "-e", str(args.frames), "-a"], None)])
        result["warm_startup"] = warm_startup(blends, work)
        result["throughput"] = throughput(blends, work, args.frames)
        if not args.skip_cold:
            result["cold"] = cold(blends, work, args.frames)
            import numpy as np

            reference = read_frames(work / "reference")
            cold_frames = read_frames(work / "cold" / "w1")
            cold_frames.update(read_frames(work / "cold" / "w2"))
            result["cold"]["frames_differing_from_warm"] = sorted(
                n for n in reference if not np.array_equal(reference[n], cold_frames.get(n)))
        result["loadavg_after"] = os.getloadavg()
        text = json.dumps(result, indent=2)
        sys.stdout.write(text + "\n")
        if args.json:
            Path(args.json).write_text(text + "\n")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
