"""The RI-tree measured like seed 004 (Atalay & Mount, section 3), side by side with the base
tracer in the same run.

``python -m rstrace_engine.bench ritree [--json] [--scenes a,b] [--scale F] [--quick]
[--out DIR] [--clock cpu|wall] [--depth N]``

Scenes modelled after the paper's (:mod:`rstrace_engine.scenes`): ``bezier_surface`` and
``random_volumes`` at 600x600, ``tomatoes`` at 1200x900 (times ``--scale``), one sample per
pixel (no anti-aliasing), ray depth 5. Sweeps of Table 2 and Figures 5-8: distance
threshold 0.01-0.25 (angular 30, depth 28), depth constraint 22-30 (distance 0.05), angular
threshold 5-30 degrees (distance 0.05), cache size 0.128-2.048 MB (Bezier surface); the
thickness view (volume visualisation) of the random volumes at three distance thresholds;
the tomatoes at the two settings of Table 1. Every RI-tree frame starts from empty trees
(sampling included, as in the paper). ``speedup``: base tracer time / RI-tree time of the
same frame, measured in the same run (process CPU time by default, the paper's metric;
``--clock wall`` for wall time). ``mean_error``: the paper's metric, the mean L2 distance of
the pixels' RGB (display values in [0, 1]) to the base frame; ``max_error``: our largest
per-channel display error. ``traced_fraction``: pixels whose primary ray was traced (not
interpolated) over all pixels. ``memory_mb``: RI-tree memory held after the frame (pruned
to the cache size); ``peak_memory_mb`` the most it held within a query batch.
``warm_speedup``: the same against a second frame of the same camera with the trees kept
(as a session reuses them).

Writes ``DIR/ritree.md`` and ``DIR/ritree.png`` (speedup against error); ``--json`` prints
``{"rows": [{"scene", "dist_thresh", "ang_thresh", "depth", "cache_mb", "speedup",
"mean_error", "max_error", "traced_fraction", "memory_mb", ...}]}``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import image, scenes
from ..accel.accelerators import create_accelerator
from ..frame import RenderSettings
from ..ri_tree.render import RITreeRenderer, render_thickness_exact
from ..tracing.whitted import render

JSON_KEYS = ("scene", "view", "dist_thresh", "ang_thresh", "depth", "cache_mb", "speedup",
             "warm_speedup", "mean_error", "max_error", "traced_fraction", "memory_mb",
             "peak_memory_mb")
SIZES = {"bezier_surface": (600, 600), "random_volumes": (600, 600), "tomatoes": (1200, 900)}
DISTS = (0.01, 0.025, 0.05, 0.075, 0.1, 0.125, 0.15, 0.175, 0.2, 0.225, 0.25)
DEPTHS = tuple(range(22, 31))
ANGLES = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)
CACHES = (0.128, 0.256, 0.512, 1.024, 2.048)
DEFAULT_CACHE = 100.0
CLOCK = time.process_time


def grid(scene: str, quick: bool) -> list[tuple]:
    """(view, dist, ang, depth, cache MB) of the rows of ``scene``."""
    if scene == "tomatoes":
        return [("SHADED", 0.25, 30.0, 28, DEFAULT_CACHE), ("SHADED", 0.05, 10.0, 28,
                                                            DEFAULT_CACHE)]
    dists = (0.01, 0.05, 0.25) if quick else DISTS
    rows = [("SHADED", x, 30.0, 28, DEFAULT_CACHE) for x in dists]
    if not quick:
        rows += [("SHADED", 0.05, 30.0, k, DEFAULT_CACHE) for k in DEPTHS if k != 28]
        rows += [("SHADED", 0.05, a, 28, DEFAULT_CACHE) for a in ANGLES if a != 30.0]
    if scene == "bezier_surface":
        rows += [("SHADED", 0.05, 30.0, 28, c) for c in (CACHES[::2] if quick else CACHES)]
    if scene == "random_volumes":
        rows += [("THICKNESS", x, 30.0, 28, DEFAULT_CACHE) for x in (0.05, 0.15, 0.25)]
    return rows


def rgb_error(a: np.ndarray, b: np.ndarray) -> float:
    """The paper's error: mean L2 distance of display RGB (in [0, 1]) per pixel."""
    da = image.to_display(a)
    db = image.to_display(b)
    return float(np.linalg.norm(da - db, axis=-1).mean())


def run_scene(name: str, scale: float, depth: int, quick: bool, log) -> list[dict]:
    w0, h0 = SIZES.get(name, (600, 600))
    w, h = max(8, int(w0 * scale)), max(8, int(h0 * scale))
    sc = scenes.build(name, w, h)
    accel = create_accelerator("BVH", sc.arrays())
    base_st = RenderSettings(max_depth=depth)
    # compile / cache load first (not timed)
    warm = scenes.build(name, 32, 24)
    wacc = create_accelerator("BVH", warm.arrays())
    for view in (False, True):
        RITreeRenderer().render(warm, replace(base_st, mode="RI_TREE", thickness_view=view),
                                wacc)
    render(warm, base_st, accel=wacc)
    render_thickness_exact(warm, replace(base_st, thickness_view=True), wacc)
    t0 = CLOCK()
    base = render(sc, base_st, accel=accel)
    t_base = CLOCK() - t0
    t0 = CLOCK()
    base_thick = render_thickness_exact(sc, replace(base_st, thickness_view=True), accel)
    t_base_thick = CLOCK() - t0
    log(f"{name} {w}x{h}: base {t_base:.2f} s, thickness base {t_base_thick:.2f} s")
    rows = []
    for view, dist, ang, dep, cache in grid(name, quick):
        thick = view == "THICKNESS"
        st = replace(base_st, mode="RI_TREE", ri_dist_thresh=dist, ri_ang_thresh=ang,
                     ri_depth=dep, ri_cache_mb=cache, thickness_view=thick)
        # the base frame is re-timed next to each row (the machine's load drifts)
        t0 = CLOCK()
        if thick:
            render_thickness_exact(sc, st, accel)
        else:
            render(sc, base_st, accel=accel)
        tb = min(CLOCK() - t0, t_base_thick if thick else t_base)
        r = RITreeRenderer()
        t0 = CLOCK()
        f = r.render(sc, st, accel)
        t_ri = CLOCK() - t0
        # a second frame of the same camera with the trees kept (what a session reuses)
        t0 = CLOCK()
        r.render(sc, st, accel)
        t_warm = CLOCK() - t0
        ref = base_thick if thick else base
        m = image.compare(f.radiance, ref.radiance, 0.02)
        row = dict(scene=name, view=view, dist_thresh=dist, ang_thresh=ang, depth=dep,
                   cache_mb=cache, speedup=tb / t_ri, warm_speedup=tb / t_warm,
                   mean_error=rgb_error(f.radiance, ref.radiance),
                   max_error=m["max_error"], traced_fraction=f.stats["traced_fraction"],
                   interpolated_fraction=f.stats["interpolated_fraction"],
                   memory_mb=f.stats["memory_mb"], peak_memory_mb=f.stats["peak_memory_mb"],
                   mean_display_error=m["mean_error"], psnr=m["psnr"], base_s=tb, ri_s=t_ri,
                   samples_traced=f.stats["samples_traced"], width=w, height=h)
        rows.append(row)
        log(f"{name} {view} d={dist:g} a={ang:g} depth={dep} cache={cache:g}: "
            f"{row['speedup']:.2f}x (warm {row['warm_speedup']:.2f}x) "
            f"err {row['mean_error']:.5f} max {row['max_error']:.3f} "
            f"traced {100 * row['traced_fraction']:.1f}% mem {row['memory_mb']:.2f} MB "
            f"(peak {row['peak_memory_mb']:.2f})")
    return rows


def markdown(rows: list[dict], note: str) -> str:
    head = ("| scene | view | size | dist | ang | depth | cache MB | speedup | warm | "
            "mean RGB err | max err | PSNR dB | traced % | memory MB | peak MB | base s | "
            "RI-tree s |")
    lines = [f"RI-tree against the base tracer (`python -m rstrace_engine.bench ritree`). "
             f"{note}", "", head, "|" + "---|" * 17]
    for r in rows:
        lines.append("| " + " | ".join([
            r["scene"], r["view"].lower(), f"{r['width']}x{r['height']}",
            f"{r['dist_thresh']:g}",
            f"{r['ang_thresh']:g}", str(r["depth"]), f"{r['cache_mb']:g}",
            f"{r['speedup']:.2f}x", f"{r['warm_speedup']:.2f}x", f"{r['mean_error']:.5f}",
            f"{r['max_error']:.3f}",
            f"{r['psnr']:.1f}" if math.isfinite(r["psnr"]) else "inf",
            f"{100 * r['traced_fraction']:.1f}", f"{r['memory_mb']:.3f}",
            f"{r['peak_memory_mb']:.3f}", f"{r['base_s']:.2f}", f"{r['ri_s']:.2f}"]) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key in dict.fromkeys((r["scene"], r["view"]) for r in rows):
        sel = [r for r in rows if (r["scene"], r["view"]) == key and r["ang_thresh"] == 30.0
               and r["depth"] == 28 and r["cache_mb"] == DEFAULT_CACHE] or \
              [r for r in rows if (r["scene"], r["view"]) == key]
        sel.sort(key=lambda r: r["dist_thresh"])
        ax.plot([r["mean_error"] for r in sel], [r["speedup"] for r in sel], marker="o",
                label=f"{key[0]} ({key[1].lower()})")
    ax.axhline(1.0, color="grey", lw=0.8, ls="--")
    ax.axvspan(0.004, 0.019, color="green", alpha=0.08, label="paper's error range")
    ax.set_xlabel("mean RGB error vs base frame (distance threshold sweep)")
    ax.set_ylabel("CPU-time speedup over the base tracer")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine.bench ritree")
    p.add_argument("--json", action="store_true")
    p.add_argument("--scenes", default="bezier_surface,random_volumes,tomatoes")
    p.add_argument("--scale", type=float, default=1.0, help="resolution factor")
    p.add_argument("--depth", type=int, default=5, help="ray depth of both tracers")
    p.add_argument("--quick", action="store_true", help="three distance thresholds only")
    p.add_argument("--out", default="docs")
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    args = p.parse_args(argv)
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    rows = []
    for name in args.scenes.split(","):
        rows += run_scene(name.strip(), args.scale, args.depth, args.quick, log)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    note = (f"Timing: {'process CPU time' if args.clock == 'cpu' else 'wall time'}; ray "
            f"depth {args.depth}; one sample per pixel; each RI-tree frame from empty trees.")
    (out / "ritree.md").write_text(markdown(rows, note))
    if not plot(rows, out / "ritree.png"):
        log("matplotlib is not installed: no ritree.png")
    if args.json:
        clean = [{k: (None if isinstance(r[k], float) and not math.isfinite(r[k]) else r[k])
                  for k in JSON_KEYS} for r in rows]
        print(json.dumps({"rows": clean}, indent=1))
    else:
        print(markdown(rows, note))
    return 0
