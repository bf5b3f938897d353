"""The speed/accuracy trade of radiance interpolants, measured against the base tracer.

``python -m rstrace_engine.bench trade [--json] [--width W] [--height H]
[--scenes three_spheres,museum,tori] [--out DIR] [--quick] [--spp 1,4,16] [--caps 6,7,8]``

For each scene (default *three_spheres*, *museum* and the smooth non-convex *tori*, at
640x480, ray depth 5) the base tracer renders three cameras: the scene's camera, a step
forward by 0.5% of the scene size, and a pan of 2.5 degrees about the vertical. Then, per
setting, a fresh interpolant renderer renders the first camera (*first frame*: everything
is built), the step and the pan (each reusing the interpolants kept so far). Speedups are
base time / interpolant time of the same camera, measured in the same run (each time is the
best of ``--repeat`` runs of the whole sequence, each starting from an empty cache). The
errors compare the first frame with the base frame in display space (clamp to [0, 1], sRGB):
mean and max absolute error, the fraction of pixels whose largest channel error exceeds
epsilon, PSNR. Settings: epsilon in {0, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1} at the default
caps, and at epsilon = 0.01 a few depth caps and memory caps; ``--spp`` adds a row at
epsilon = 0.01 per count of samples per pixel (base frames with the same samples).

Writes ``DIR/trade.md`` (a markdown table) and ``DIR/trade.png`` (speedup against error, one
curve per scene; DIR defaults to ``docs``). ``--json`` prints ``{"rows": [{"scene",
"epsilon", "depth_cap", "memory_cap_mb", "spp", "first_frame_speedup",
"camera_step_speedup", "pan_speedup", "mean_error", "max_error", "frac_over_epsilon",
"n_over_epsilon" (pixels over epsilon + 1e-6), "psnr", "interpolated_fraction",
"reprojected_fraction" (share of the camera step's samples whose interpolant was found by
reprojection instead of a closest-hit ray and a walk; ``reprojected_pan_fraction`` the pan's,
``reprojected_first_fraction`` the first frame's: with several samples per pixel, the samples
after each pixel's first), "memory_mb", "first_ceiling", "step_ceiling", "pan_ceiling" (the
ceilings: the base frame's time over the time the base tracer takes for the pixels that
frame did not interpolate alone -- the speedup if every interpolated pixel were free)},
...]}``. ``--no-reproject`` turns reprojection off
(for comparison: the frames are the same). ``--light-samples N``: shadow rays per soft
light in both frames; ``--compare-fallback`` also times each camera without the measured
fallback (``first/step/pan_speedup_no_fallback``: the mode as it was before it learned where
cells do not pay); ``worst_speedup`` is the slowest of the three frames (the goal: at least
:data:`NEVER_LOSES`), ``traced_objects`` / ``deferred_cells`` what the fallback decided.
Kernel loads are not timed: the bench loads every render kernel of both modes first (as the
add-on's start-up warm-up, :mod:`..warm_kernels`) and renders a small frame of every kind
at every count of samples; a timed sequence during which numba still loaded or compiled a
kernel is run again once (``kernel_loads``: the kernels it loaded; 0 when none did).
The soft-lit scenes: ``--scenes museum_soft,studio``.
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

from .. import image, kernel_cache, scenes
from ..accel.accelerators import create_accelerator
from ..frame import CLASS_INTERPOLATED, RenderSettings
from ..geometry.cameras import camera_rays
from ..geometry.scene import Camera
from ..interpolants import fallback
from ..interpolants.render import InterpolantRenderer
from ..tracing.whitted import render

EPSILONS = (0.0, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1)
DEPTH_CAPS = (4, 8)
MEMORY_CAPS = (4.0, 0.5)
STEP_FRACTION = 0.005
PAN_DEGREES = 2.5
JSON_KEYS = ("scene", "epsilon", "depth_cap", "memory_cap_mb", "spp", "light_samples",
             "first_frame_speedup",
             "camera_step_speedup", "pan_speedup", "mean_error", "max_error",
             "frac_over_epsilon", "n_over_epsilon", "psnr", "interpolated_fraction",
             "reprojected_fraction", "reprojected_pan_fraction", "reprojected_first_fraction",
             "memory_mb", "first_ceiling", "step_ceiling", "pan_ceiling",
             "worst_speedup", "traced_objects", "deferred_cells", "first_speedup_no_fallback",
             "step_speedup_no_fallback", "pan_speedup_no_fallback", "kernel_loads")
#: the slowest an INTERPOLANT frame may be against the base frame ("never loses", issue 20)
NEVER_LOSES = 0.9
#: display-space slack of ``n_over_epsilon`` (float32 frames)
FLOAT_TOL = 1e-6


def moved_cameras(scene) -> dict[str, Camera]:
    """The scene's camera, a step forward by 0.5% of the scene size, a 2.5 degree pan."""
    cam = scene.camera
    step = cam.matrix.copy()
    fwd = -step[:3, 2] / np.linalg.norm(step[:3, 2])
    step[:3, 3] += STEP_FRACTION * scene.arrays().scene_extent * fwd
    a = math.radians(PAN_DEGREES)
    rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                   [0.0, 0.0, 1.0]])
    pan = cam.matrix.copy()
    pan[:3, :3] = rz @ pan[:3, :3]
    return {"first": cam, "step": replace(cam, matrix=step), "pan": replace(cam, matrix=pan)}


#: the clock the timings use (``--clock``): wall time, or this process's CPU time (robust to
#: other processes on a shared machine; run with ``--threads 1`` then)
CLOCK = time.perf_counter


def _timed(fn, repeat: int):
    best, out = math.inf, None
    for _ in range(max(repeat, 1)):
        t0 = CLOCK()
        out = fn()
        best = min(best, CLOCK() - t0)
    return best, out


def settings_grid(quick: bool = False, spps=(1,), caps=(),
                  epsilons=None) -> list[tuple[float, int, float, int]]:
    """(epsilon, depth cap, memory cap MB, samples per pixel) of every row: the sweeps at 1
    sample per pixel, and epsilon 0.01 at the default caps for every other count of
    ``spps``; ``caps``: epsilon 0.01 at each of these depth caps, for every count of
    ``spps``; ``epsilons``: the sweep's epsilons (default: all, or three with ``quick``;
    given, no cap sweep)."""
    d = RenderSettings()
    eps = ((0.0, 0.01, 0.1) if quick else EPSILONS) if epsilons is None else tuple(epsilons)
    rows = [(e, d.depth_cap, d.memory_cap_mb, 1) for e in eps]
    if not quick and epsilons is None:
        rows += [(0.01, c, d.memory_cap_mb, 1) for c in DEPTH_CAPS]
        rows += [(0.01, d.depth_cap, m, 1) for m in MEMORY_CAPS]
    rows += [(0.01, d.depth_cap, d.memory_cap_mb, int(k)) for k in spps if int(k) != 1]
    rows += [(0.01, int(c), d.memory_cap_mb, int(k)) for c in caps for k in spps
             if (0.01, int(c), d.memory_cap_mb, int(k)) not in rows]
    return rows


def run_scene(name: str, width: int, height: int, depth: int, grid, repeat: int = 3,
              log=None, light_samples: int | None = None,
              compare_fallback: bool = False) -> list[dict]:
    """Measure every setting of ``grid`` on scene ``name``; returns the rows.
    ``light_samples``: shadow rays per soft light (base and interpolant frames alike; None:
    the default); ``compare_fallback``: each camera also gets a frame of an interpolant
    renderer without the measured fallback (``*_no_fallback``: the mode as it was)."""
    ls = RenderSettings().light_samples if light_samples is None else int(light_samples)
    sc = scenes.build(name, width, height)
    accel = create_accelerator("BVH", sc.arrays())
    cams = moved_cameras(sc)
    base_settings = RenderSettings(max_depth=depth, light_samples=ls)
    # numba compile / cache load is not timed: a small frame of every kind first, at every
    # count of samples the grid times (``main`` loads every render kernel before, as the
    # add-on does at start-up: a 48x36 frame builds no valid cell, and the kernels of
    # tunnels and reprojection loaded in the first timed frame, 0.94 -> 0.87x on museum);
    # a timed sequence that still loads a kernel is run again (``kernel_loads``)
    warm = scenes.build(name, 48, 36)
    wacc = create_accelerator("BVH", warm.arrays())
    for spp in sorted({int(g[3]) for g in grid}):
        wr = InterpolantRenderer()
        wr.auto_fallback = False  # (cells wherever they may be: the mode's kernels load)
        ws = replace(base_settings, samples=spp)
        for cam in moved_cameras(warm).values():
            warm.set_camera(cam)
            render(warm, ws, accel=wacc)
            wr.render(warm, replace(ws, mode="INTERPOLANT"), wacc)
    sc.set_camera(cams["first"])
    # the floor of any frame that finds its visible surfaces with one ray per pixel
    rays = camera_rays(sc.camera)
    t_vis, _ = _timed(lambda: accel.closest_hit(*rays), repeat + 1)
    rows = []
    base_frames: dict = {}
    for eps, cap, mem, spp in grid:
        base_settings = RenderSettings(max_depth=depth, samples=spp, light_samples=ls)
        if spp not in base_frames:
            sc.set_camera(cams["first"])
            base_frames[spp] = _timed(lambda bs=base_settings: render(sc, bs, accel=accel),
                                      repeat + 1 if spp == 1 else 1)
        t_base, base_frame = base_frames[spp]
        st = RenderSettings(mode="INTERPOLANT", epsilon=eps, depth_cap=cap, memory_cap_mb=mem,
                            max_depth=depth, samples=spp, light_samples=ls)
        # the whole sequence (first frame from an empty cache, step, pan) is repeated; each
        # interpolant frame is timed right after a base frame of the same camera (the
        # machine's load drifts), and each keeps its best time
        times = dict.fromkeys(cams, math.inf)
        rep = dict.fromkeys(cams, 0.0)
        btimes = dict.fromkeys(cams, math.inf)
        rest = dict.fromkeys(cams, math.inf)
        off = dict.fromkeys(cams, math.inf)
        runs, loads = 0, 0
        while runs < max(repeat, 1):
            since = kernel_cache.mark()
            r = InterpolantRenderer()
            r_off = InterpolantRenderer()
            r_off.auto_fallback = False
            took: dict = {}
            for key, cam in cams.items():
                sc.set_camera(cam)
                t0 = CLOCK()
                bframe = render(sc, base_settings, accel=accel)
                took["b", key] = CLOCK() - t0
                t0 = CLOCK()
                frame = r.render(sc, st, accel)
                took["i", key] = CLOCK() - t0
                if compare_fallback:
                    t0 = CLOCK()
                    r_off.render(sc, st, accel)
                    took["o", key] = CLOCK() - t0
                fbs = frame.stats.get("fallback", {})
                if key == "first":
                    f_first = frame
                    memory = r.cache.memory_bytes / 1e6
                    deferred = fbs.get("deferred_cells", 0)
                traced_objects = fbs.get("traced_objects", 0)
                rep[key] = frame.stats.get("reprojected_fraction", 0.0)
                took["r", key] = _rest_time(sc, base_settings, accel, bframe, frame)
            c = kernel_cache.counts(since=since)
            if c["loaded"] + c["compiled"] and not loads:
                loads = c["loaded"] + c["compiled"]  # (once: a kernel that loads every time
                continue  # is the mode's cost)
            runs += 1
            for (who, key), t in took.items():
                best = {"b": btimes, "i": times, "o": off, "r": rest}[who]
                best[key] = min(best[key], t)
        t_first = times["first"]
        m = image.compare(f_first.radiance, base_frame.radiance, eps)
        err = np.abs(image.to_display(f_first.radiance)
                     - image.to_display(base_frame.radiance)).max(axis=-1)
        row = dict(
            scene=name, epsilon=eps, depth_cap=cap, memory_cap_mb=mem, spp=spp,
            light_samples=ls, traced_objects=traced_objects, deferred_cells=deferred,
            kernel_loads=loads,
            first_speedup_no_fallback=(btimes["first"] / off["first"] if compare_fallback
                                   else math.nan),
            step_speedup_no_fallback=(btimes["step"] / off["step"] if compare_fallback
                                   else math.nan),
            pan_speedup_no_fallback=(btimes["pan"] / off["pan"] if compare_fallback
                                   else math.nan),
            n_over_epsilon=int(np.count_nonzero(err > eps + FLOAT_TOL)),
            reprojected_fraction=float(rep["step"]),
            reprojected_pan_fraction=float(rep["pan"]),
            reprojected_first_fraction=float(rep["first"]),
            first_frame_speedup=btimes["first"] / t_first,
            camera_step_speedup=btimes["step"] / times["step"],
            pan_speedup=btimes["pan"] / times["pan"],
            mean_error=m["mean_error"], max_error=m["max_error"],
            frac_over_epsilon=m["frac_over"], psnr=m["psnr"],
            interpolated_fraction=f_first.stats["interpolated_fraction"], memory_mb=memory,
            base_s=btimes["first"], first_s=t_first, step_s=times["step"],
            pan_s=times["pan"], cells_built=f_first.stats["cells_built"],
            visibility_bound=t_base / (t_vis * spp),
            first_ceiling=btimes["first"] / rest["first"],
            step_ceiling=btimes["step"] / rest["step"],
            pan_ceiling=btimes["pan"] / rest["pan"],
        )
        row["worst_speedup"] = min(row["first_frame_speedup"], row["camera_step_speedup"],
                                   row["pan_speedup"])
        rows.append(row)
        if log is not None:
            log(f"{name} eps={eps:g} cap={cap} mem={mem:g} spp={spp}: "
                f"first {row['first_frame_speedup']:.2f}x "
                f"step {row['camera_step_speedup']:.2f}x pan {row['pan_speedup']:.2f}x "
                f"interp {100 * row['interpolated_fraction']:.1f}% "
                f"reprojected {100 * row['reprojected_fraction']:.1f}% "
                f"ceiling {row['first_ceiling']:.2f}/{row['step_ceiling']:.2f}/"
                f"{row['pan_ceiling']:.2f}x "
                f"over-eps {100 * row['frac_over_epsilon']:.3f}% "
                f"traced objects {traced_objects} deferred {deferred} "
                f"without fallback {row['first_speedup_no_fallback']:.2f}/"
                f"{row['step_speedup_no_fallback']:.2f}/{row['pan_speedup_no_fallback']:.2f}x "
                f"base {row['base_s']:.2f} s memory {memory:.1f} MB")
    sc.set_camera(cams["first"])
    return rows


def _rest_time(sc, settings: RenderSettings, accel, base_frame, frame) -> float:
    """The time the base tracer takes for the pixels ``frame`` did not interpolate alone
    (every sample of a pixel any of whose samples was traced, its primary rays included),
    copied over ``base_frame`` (that camera's base frame): what a frame would still cost if
    its interpolated pixels were free -- no visibility ray, walk, look-up or cell build. The
    base frame's time over it is the most the interpolants' coverage of that frame allows."""
    todo = (frame.pixel_class != CLASS_INTERPOLATED).reshape(-1)
    t0 = CLOCK()
    render(sc, settings, accel=accel, pixels=todo, base=base_frame)
    return max(CLOCK() - t0, 1e-9)


def _fmt(x, nd=3):
    if isinstance(x, float):
        if math.isinf(x):
            return "inf"
        return f"{x:.{nd}f}"
    return str(x)


def markdown(rows: list[dict], width: int, height: int, note: str = "") -> str:
    head = ("| scene | eps | depth cap | mem cap MB | spp | first frame | camera step | pan | "
            "mean err | max err | >eps px | PSNR dB | interp % | "
            "reprojected % (first / step / pan) | memory MB | "
            "base s | first s | step s | pan s | base / primary rays | "
            "ceiling (first / step / pan) | light samples | traced objects / deferred cells "
            "| no fallback (first / step / pan) |")
    lines = [f"Interpolant speed/accuracy trade at {width}x{height}, ray depth 5 "
             f"(`python -m rstrace_engine.bench trade`). Speedups are base tracer time / "
             f"interpolant time of the same frame in the same run; errors compare the "
             f"first frame with the base frame in display space. The last column is the "
             f"base frame time over the time of its primary rays alone: the most any frame "
             f"that casts one visibility ray per pixel could gain; the *ceiling* is the base "
             f"frame time over the time of tracing only the pixels that frame did not "
             f"interpolate: the speedup if every interpolated pixel were free. {note}", "",
             head, "|" + "---|" * 24]
    for r in rows:
        lines.append("| " + " | ".join([
            r["scene"], f"{r['epsilon']:g}", str(r["depth_cap"]), f"{r['memory_cap_mb']:g}",
            str(r["spp"]),
            f"{r['first_frame_speedup']:.2f}x", f"{r['camera_step_speedup']:.2f}x",
            f"{r['pan_speedup']:.2f}x", f"{r['mean_error']:.5f}", f"{r['max_error']:.4f}",
            str(r["n_over_epsilon"]), _fmt(r["psnr"], 1),
            f"{100 * r['interpolated_fraction']:.1f}",
            f"{100 * r['reprojected_first_fraction']:.1f} / "
            f"{100 * r['reprojected_fraction']:.1f} / {100 * r['reprojected_pan_fraction']:.1f}",
            f"{r['memory_mb']:.1f}",
            f"{r['base_s']:.3f}", f"{r['first_s']:.3f}", f"{r['step_s']:.3f}",
            f"{r['pan_s']:.3f}", f"{r['visibility_bound']:.1f}x",
            f"{r['first_ceiling']:.2f} / {r['step_ceiling']:.2f} / {r['pan_ceiling']:.2f}x",
            str(r["light_samples"]), f"{r['traced_objects']} / {r['deferred_cells']}",
            (f"{r['first_speedup_no_fallback']:.2f} / {r['step_speedup_no_fallback']:.2f} / "
             f"{r['pan_speedup_no_fallback']:.2f}x"
             if math.isfinite(r["pan_speedup_no_fallback"]) else "-")])
            + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> bool:
    """Speedup against mean display error, one curve per scene (epsilon sweep rows)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    d = RenderSettings()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), sharey=False)
    keys = (("first_frame_speedup", "first_ceiling", "first frame"),
            ("camera_step_speedup", "step_ceiling", "camera step"),
            ("pan_speedup", "pan_ceiling", "pan 2.5 deg"))
    for ax, (key, ceil_key, title) in zip(axes, keys, strict=True):
        for name in dict.fromkeys(r["scene"] for r in rows):
            sel = [r for r in rows if r["scene"] == name and r["depth_cap"] == d.depth_cap
                   and r["memory_cap_mb"] == d.memory_cap_mb and r["spp"] == 1]
            sel.sort(key=lambda r: r["epsilon"])
            x = [max(r["mean_error"], 1e-6) for r in sel]
            y = [r[key] for r in sel]
            line, = ax.plot(x, y, marker="o", label=name)
            if sel and ceil_key in sel[0]:  # the frame if its interpolated pixels were free
                ax.plot(x, [r[ceil_key] for r in sel], color=line.get_color(), lw=1.0, ls=":",
                        label=f"{name}: ceiling")
            for r, xi, yi in zip(sel, x, y, strict=True):
                ax.annotate(f"{r['epsilon']:g}", (xi, yi), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        ax.set_xscale("log")
        ax.axhline(1.0, color="grey", lw=0.8, ls="--")
        ax.set_xlabel("mean display error vs base frame (labels: epsilon)")
        ax.set_ylabel(f"{title} speedup over the base tracer\n(dotted: interpolated pixels free)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine.bench trade")
    p.add_argument("--json", action="store_true")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--depth", type=int, default=5)
    p.add_argument("--scenes", default="three_spheres,museum,tori")
    p.add_argument("--out", default="docs", help="directory for trade.md and trade.png")
    p.add_argument("--repeat", type=int, default=3, help="timing runs per frame (best)")
    p.add_argument("--quick", action="store_true", help="three epsilons, no cap sweep")
    p.add_argument("--epsilons", default="", help="the sweep's epsilons, comma separated "
                                                 "(no cap sweep; e.g. 0.01)")
    p.add_argument("--spp", default="1", help="samples per pixel, comma separated (counts "
                                              "other than 1: one row each at epsilon 0.01)")
    p.add_argument("--caps", default="", help="depth caps, comma separated: one row each at "
                                             "epsilon 0.01 per count of --spp")
    p.add_argument("--threads", type=int, default=0, help="numba threads (0: all)")
    p.add_argument("--light-samples", type=int, default=None,
                   help="shadow rays per soft light, base and interpolant frames alike "
                        "(default: RenderSettings')")
    p.add_argument("--compare-fallback", action="store_true",
                   help="also time each camera without the measured fallback")
    p.add_argument("--no-reproject", action="store_true",
                   help="find every sample's visible surface with a closest-hit ray")
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                   help="wall time, or this process's CPU time (with --threads 1 on a "
                        "shared machine)")
    args = p.parse_args(argv)
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    # the mode's fallback measures what the bench measures (on a shared machine the wall
    # clock counts other processes' time too)
    fallback.CLOCK = CLOCK
    if args.threads > 0:
        import numba

        numba.set_num_threads(args.threads)
    if args.no_reproject:
        from ..interpolants import reproject

        reproject.ENABLED = False
    grid = settings_grid(args.quick, [int(k) for k in args.spp.split(",")],
                         [int(c) for c in args.caps.split(",") if c.strip()],
                         [float(e) for e in args.epsilons.split(",")] if args.epsilons
                         else None)
    rows = []

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    # every render kernel of the two modes loaded (compiled where the cache lacks it) before
    # anything is timed, as the add-on's start-up warm-up does (warm_kernels.py)
    from ..warm_kernels import warm

    warm(modes=("BASE", "INTERPOLANT"), accelerators=("BVH",), report_unreached=False)
    for name in args.scenes.split(","):
        rows += run_scene(name.strip(), args.width, args.height, args.depth, grid,
                          repeat=args.repeat, log=log, light_samples=args.light_samples,
                          compare_fallback=args.compare_fallback)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    note = (f"Timing: {'process CPU time' if args.clock == 'cpu' else 'wall time'}, "
            f"{args.threads or 'all'} numba thread(s), best of {args.repeat}.")
    (out / "trade.md").write_text(markdown(rows, args.width, args.height, note))
    plotted = plot(rows, out / "trade.png")
    if not plotted:
        log("matplotlib is not installed: no trade.png (pip install rstrace_engine[bench])")
    if args.json:
        clean = [{k: (None if isinstance(r[k], float) and not math.isfinite(r[k]) else r[k])
                  for k in JSON_KEYS} for r in rows]
        print(json.dumps({"rows": clean}, indent=1))
    else:
        print(markdown(rows, args.width, args.height, note))
    return 0
