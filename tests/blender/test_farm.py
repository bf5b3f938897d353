"""Render farms: frames split over worker processes render exactly as in one process.

An animation (two objects, a light and the camera keyframed) is saved as two .blend files:
one saved with another engine and rendered with ``-E RSTRACE`` in BASE mode, one saved as an
RSTrace .blend in INTERPOLANT mode. Each is rendered the way a farm does it, one command
line per process (``scripts/bpy_render.py`` stands in for ``blender -b``): once as a
single process over the whole range, and again as two chunks in two workers started
together, the later chunk first, one of them rendering its frames backwards (``-f 2,1``).
So frame N of a chunk never follows frame N-1 in its process. BASE frames must be
bit-identical; INTERPOLANT frames must be within epsilon (display space, max over pixels)
of the BASE frame. The workers share the checkout's kernel cache, warmed first with
``python -m rstrace_engine warm-cache`` (the documented farm step): no worker compiles.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest

from rstrace_engine.frame import CLASS_COLORS, CLASS_INTERPOLATED
from rstrace_engine.image import to_display

from . import builders as b
from .exr import read_exr, read_pass

ROOT = Path(__file__).resolve().parents[2]
RUNNER = ROOT / "scripts" / "bpy_render.py"
FRAMES = (1, 2, 3, 4)
EPSILON = 0.02


@pytest.fixture(scope="module")
def warm_cache():
    """The farm's 'warm the cache once' step, on the cache the workers use."""
    proc = subprocess.run([sys.executable, "-m", "rstrace_engine", "warm-cache", "--json"],
                          cwd=ROOT, capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return json.loads(proc.stdout)


def _start(blend: Path, out: Path, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, str(RUNNER), str(blend), "-o", str(out / "frame_####"), *args]
    return subprocess.Popen(cmd, cwd=out.parent, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _finish(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=600)
    lines = [ln for ln in out.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, (" ".join(proc.args) + "\n" + out[-2000:]
                                           + err[-4000:])
    return json.loads(lines[-1][len("RESULT "):])


def _frames(folder: Path) -> dict[int, dict[str, np.ndarray]]:
    out = {}
    for path in sorted(folder.glob("frame_*.exr")):
        channels = read_exr(path)
        out[int(path.stem.split("_")[1])] = {
            "combined": read_pass(channels, "Combined", components="RGB"),
            "classes": read_pass(channels, "Interpolation", components="RGB")}
    return out


def test_chunked_workers_render_the_same_frames_as_one_process(tmp_path, warm_cache):
    sc = b.animated_three_spheres(160, 120, FRAMES[-1])  # big enough to interpolate
    sc.rstrace.samples, sc.rstrace.max_ray_depth = 1, 2
    sc.render.engine = "CYCLES"  # saved with another engine: rendered with -E RSTRACE
    base_blend = tmp_path / "base.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(base_blend), copy=True)
    sc.render.engine = "RSTRACE"  # an RSTrace .blend: no -E needed
    sc.rstrace.mode = "INTERPOLANT"
    sc.rstrace.epsilon = EPSILON
    # cells, to test them (saved in the .blend): here they do not pay, and the measured
    # fallback would trace (tests/blender/test_interpolant_mode.py, the note at its top)
    sc.rstrace.interpolant_fallback = False
    interp_blend = tmp_path / "interp.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(interp_blend), copy=True)

    runs = {}
    for mode, blend, extra in (("base", base_blend, ("-E", "RSTRACE")),
                               ("interp", interp_blend, ())):
        for name in ("single", "chunks"):
            (tmp_path / mode / name).mkdir(parents=True)
        # one process, the whole range, Blender's -s/-e/-a
        runs[mode, "single"] = [_start(blend, tmp_path / mode / "single", *extra,
                                       "-s", str(FRAMES[0]), "-e", str(FRAMES[-1]), "-a")]
        # two workers started together, the later chunk first (Flamenco's --render-frame),
        # the other chunk backwards: frame N never follows frame N-1 in its process
        chunks = tmp_path / mode / "chunks"
        runs[mode, "chunks"] = [_start(blend, chunks, *extra, "--render-frame", "3..4"),
                                _start(blend, chunks, *extra, "-f", "2,1")]
    results = {key: [_finish(p) for p in procs] for key, procs in runs.items()}

    for key, rs in results.items():
        for r in rs:
            assert r["errors"] == [] and r["engine"] == "RSTRACE", (key, r)
            assert r["kernels"]["compiled"] == 0, (key, r["kernels"])  # warm shared cache
    assert [f["frame"] for f in results["base", "chunks"][0]["frames"]] == [3, 4]
    assert [f["frame"] for f in results["base", "chunks"][1]["frames"]] == [2, 1]
    assert {r["mode"] for r in results["interp", "single"]} == {"INTERPOLANT"}
    starts = [r["frames"][0]["at_s"] - r["frames"][0]["seconds"]
              for rs in results.values() for r in rs]
    print(f"worker start-up before the first frame: {min(starts):.2f}-{max(starts):.2f} s")

    frames = {(mode, name): _frames(tmp_path / mode / name)
              for mode in ("base", "interp") for name in ("single", "chunks")}
    for key, fs in frames.items():
        assert sorted(fs) == list(FRAMES), (key, sorted(fs))

    base, base_chunks = frames["base", "single"], frames["base", "chunks"]
    for f in FRAMES[1:]:  # the animation moves: consecutive frames differ
        assert np.abs(base[f]["combined"] - base[f - 1]["combined"]).max() > 0.05
    differing = [f for f in FRAMES
                 if not np.array_equal(base[f]["combined"], base_chunks[f]["combined"])]
    assert differing == [], f"BASE frames {differing} differ between one process and chunks"

    worst, interpolated = {}, []
    for name in ("single", "chunks"):
        for f in FRAMES:
            img = frames["interp", name][f]
            err = np.abs(to_display(img["combined"]) - to_display(base[f]["combined"]))
            worst[name, f] = float(err.max())
            green = np.all(np.isclose(img["classes"], CLASS_COLORS[CLASS_INTERPOLATED]), -1)
            interpolated.append(float(green.mean()))
    print("INTERPOLANT max display error vs BASE:",
          {f"{n}:{f}": round(e, 5) for (n, f), e in worst.items()},
          f"interpolated {min(interpolated):.1%}-{max(interpolated):.1%}")
    assert max(interpolated) > 0.05, "the INTERPOLANT frames interpolated (almost) nothing"
    assert max(worst.values()) <= EPSILON, worst
    single_vs_chunks = max(float(np.abs(frames["interp", "single"][f]["combined"]
                                        - frames["interp", "chunks"][f]["combined"]).max())
                           for f in FRAMES)
    print(f"INTERPOLANT one process vs chunks, max linear difference {single_vs_chunks:.5f}")
    assert os.path.exists(base_blend)


def test_warm_cache_operator_compiles_nothing_on_a_warm_cache(warm_cache):
    """``bpy.ops.rstrace.warm_cache()``: the command-line warm-up step inside Blender."""
    import addon

    assert addon.operators._render_menu in bpy.types.TOPBAR_MT_render.draw._draw_funcs
    assert bpy.ops.rstrace.warm_cache() == {"FINISHED"}
    result = addon.runtime.warm_cache()
    assert result["compiled"] == 0, result["compiled_kernels"]  # the cache is warm
    assert set(result["modes"]) >= {"BASE", "INTERPOLANT"}
    assert addon.runtime.kernel_status() is None  # kernels are in memory now
    # counts are the warm-up's own (kernel_cache.mark): this second warm-up finds every
    # kernel in memory and loads nothing; kernels compiled by earlier tests in this process
    # (a partly warm cache: the old flake) are not counted as the operator's
    assert result["loaded"] == 0 and result["used"] > 20 and warm_cache["loaded"] > 0
