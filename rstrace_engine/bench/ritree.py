"""The RI-tree measured like seed 004 (Atalay & Mount, section 3), side by side with the base
tracer in the same run.

``python -m rstrace_engine.bench ritree [--json] [--scenes a,b] [--scale F] [--quick]
[--out DIR] [--clock cpu|wall] [--depth N] [--threads N]``

Scenes modelled after the paper's (:mod:`rstrace_engine.scenes`) at the paper's sizes times
``--scale``: ``bezier_surface`` 600x600, ``tomatoes`` 1200x900, one ray per pixel; the
``random_volumes`` ray traced at 300x300 with 9 rays per pixel (anti-aliased, as the paper)
and visualised (thickness view) at 600x600 with one; ray depth 5. Sweeps of Table 2 and
Figures 5-8: distance threshold 0.01-0.25 (angular 30, depth 28), depth constraint 22-30
(distance 0.05), angular threshold 5-30 degrees (distance 0.05), cache size 0.128-2.048 MB
(Bezier surface); the thickness view at three distance thresholds; the tomatoes at the two
settings of Table 1. These rows are the paper's: the exit-ray test (``ri_probe_angle``, an
addition, :mod:`rstrace_engine.ri_tree.tree_cache`) off. Beside them, rows with the exit-ray
test at :data:`PROBES` degrees (the default settings among them), and the ``glass_horizon``
scene (issue 22: glass and a mirror before a horizon, 240x180). Every RI-tree frame starts
from empty trees (sampling included, as in the paper). ``speedup``: base tracer time /
RI-tree time of the same frame, measured in the same run (process CPU time by default, the
paper's metric; ``--clock wall`` for wall time).
``warm_speedup``: the same against a second frame of the same camera with the trees kept (as
a session reuses them). ``fallback_speedup``: the same against a frame after the fallback
(:mod:`rstrace_engine.ri_tree.fallback`) decided from the first frame's measured costs, the
objects whose trees did not pay traced (``traced_objects`` of ``ri_objects``).
``ceiling_speedup``: the same against a frame whose queries a
:class:`PerfectCache` answers exactly at no cost (per scene and view): what any tree, however
good, could give in this engine. ``mean_error``: the paper's metric, the mean L2 distance of
the pixels' RGB (display values in [0, 1]) to the base frame; ``max_error``: our largest
per-channel display error; ``p999_error``: the 99.9th percentile of the pixels' largest
channel error; ``over_01``, ``over_03``: pixels whose largest channel error passes 0.1,
0.3; ``warm_max_error``, ``warm_over_01``: the same of the warm frame; ``retraced_pixels``:
pixels the continuation check traced again (:mod:`rstrace_engine.ri_tree.recheck`; with the
exit-ray test only). ``traced_fraction``: pixels whose primary ray was traced (not
interpolated) over all pixels. ``memory_mb``: RI-tree memory held after the frame;
``peak_memory_mb`` the most it held at any time (within the cache size).

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
from ..interpolants.linetree import parameterize
from ..ri_tree.fallback import tree_pays
from ..ri_tree.patches import ST_HIT, ST_MISS
from ..ri_tree.render import RITreeRenderer, render_thickness_exact
from ..ri_tree.sampling import trace_samples
from ..ri_tree.tree_cache import QueryResult, RITreeCache
from ..tracing.whitted import render

JSON_KEYS = ("scene", "view", "dist_thresh", "ang_thresh", "depth", "cache_mb",
             "probe_angle", "speedup", "warm_speedup", "fallback_speedup", "ri_objects",
             "traced_objects", "ceiling_speedup", "mean_error", "max_error", "p999_error",
             "over_01", "over_03", "warm_max_error", "warm_over_01", "retraced_pixels",
             "traced_fraction",
             "memory_mb", "peak_memory_mb", "samples_traced", "width", "height", "spp")
#: the paper's image sizes and rays per pixel, per (scene, view): the random volumes are
#: ray traced at 300x300 with 9 rays per pixel and visualised at 600x600 with one
SIZES = {("bezier_surface", "SHADED"): (600, 600, 1), ("random_volumes", "SHADED"): (300, 300, 9),
         ("random_volumes", "THICKNESS"): (600, 600, 1), ("tomatoes", "SHADED"): (1200, 900, 1),
         ("glass_horizon", "SHADED"): (240, 180, 1)}
DISTS = (0.01, 0.025, 0.05, 0.075, 0.1, 0.125, 0.15, 0.175, 0.2, 0.225, 0.25)
DEPTHS = tuple(range(22, 31))
ANGLES = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)
CACHES = (0.128, 0.256, 0.512, 1.024, 2.048)
DEFAULT_CACHE = 100.0
#: the exit-ray test's thresholds (degrees) swept at the default distance, angle and depth
PROBES = (4.0, 2.0, 1.0, 0.5, 0.25)
DEFAULT = RenderSettings()
CLOCK = time.process_time


def grid(scene: str, quick: bool, probes=None) -> list[tuple]:
    """(view, dist, ang, depth, cache MB, exit-ray test degrees) of the rows of ``scene``:
    the paper's (test off, 0) and the exit-ray test's sweep (``probes``, default
    :data:`PROBES` and the default setting; ``quick``: the default alone), the defaults
    among it."""
    if scene == "tomatoes":
        rows = [("SHADED", 0.25, 30.0, 28, DEFAULT_CACHE, 0.0),
                ("SHADED", 0.05, 10.0, 28, DEFAULT_CACHE, 0.0)]
    else:
        dists = (0.01, 0.05, 0.25) if quick else DISTS
        rows = [("SHADED", x, 30.0, 28, DEFAULT_CACHE, 0.0) for x in dists]
        if not quick:
            rows += [("SHADED", 0.05, 30.0, k, DEFAULT_CACHE, 0.0) for k in DEPTHS if k != 28]
            rows += [("SHADED", 0.05, a, 28, DEFAULT_CACHE, 0.0) for a in ANGLES if a != 30.0]
        if scene == "bezier_surface":
            rows += [("SHADED", 0.05, 30.0, 28, c, 0.0) for c in (CACHES[::2] if quick
                                                                 else CACHES)]
    d = DEFAULT
    if probes is None:
        probes = (d.ri_probe_angle,) if quick else (*PROBES, d.ri_probe_angle)
    probes = sorted({float(p) for p in probes if p > 0}, reverse=True)
    rows += [("SHADED", d.ri_dist_thresh, d.ri_ang_thresh, d.ri_depth, d.ri_cache_mb, p)
             for p in probes]
    if scene == "random_volumes":
        rows += [("THICKNESS", x, 30.0, 28, DEFAULT_CACHE, 0.0) for x in (0.05, 0.15, 0.25)]
    return rows


class PerfectCache(RITreeCache):
    """The ceiling: a "tree" that answers every query exactly, by tracing the query's own
    line as a sample; the time it spends doing so is kept in ``spent`` and left out, so a
    frame's time minus ``spent`` is what an RI_TREE frame would cost with a perfect tree
    that were free to build and to query."""

    spent = 0.0

    def query(self, inst, origins, directions) -> QueryResult:
        t0 = CLOCK()
        inst = np.ascontiguousarray(inst, np.int32)
        o = np.ascontiguousarray(origins, np.float64)
        d = np.ascontiguousarray(directions, np.float64)
        n = len(inst)
        face = np.empty(n, np.int8)
        abcd = np.empty((n, 4))
        parameterize(self.box, inst, o, d, face, abcd)
        s = trace_samples(self.sa, self.accel, self.tri_class, self.box, inst, face, abcd,
                          self.thickness)
        hit = s.cls >= 0
        t = np.full(n, np.inf)
        t[hit] = np.einsum("ij,ij->i", s.P[hit] - o[hit], d[hit]) / np.einsum(
            "ij,ij->i", d[hit], d[hit])
        res = QueryResult(np.where(hit, ST_HIT, ST_MISS).astype(np.int8), t, s.P, s.NS, s.NG,
                          s.OP, s.OD, s.gain, s.nint, s.mat, s.thick, np.full(n, np.inf),
                          np.full(n, -1, np.int32), np.zeros(n), np.zeros(n), s.RP, s.RD,
                          s.rgain)
        self.spent += CLOCK() - t0
        return res


def perfect_tree_time(sc, st: RenderSettings, accel, repeat: int = 2) -> float:
    """Best time of an RI_TREE frame answered by a :class:`PerfectCache` (its own tracing
    left out)."""
    r = RITreeRenderer()
    r.auto_fallback = False
    r.recheck = False  # (exact answers: nothing to check)
    r.render(sc, st, accel)
    cache = r.caches[bool(st.thickness_view)]
    cache.__class__ = PerfectCache
    best = math.inf
    for _ in range(repeat):
        cache.spent = 0.0
        t0 = CLOCK()
        r.render(sc, st, accel)
        best = min(best, CLOCK() - t0 - cache.spent)
    return best


def rgb_error(a: np.ndarray, b: np.ndarray) -> float:
    """The paper's error: mean L2 distance of display RGB (in [0, 1]) per pixel."""
    da = image.to_display(a)
    db = image.to_display(b)
    return float(np.linalg.norm(da - db, axis=-1).mean())


def _base_frame(sc, st: RenderSettings, accel):
    if st.thickness_view:
        return render_thickness_exact(sc, replace(st, mode="BASE"), accel)
    return render(sc, replace(st, mode="BASE"), accel=accel)


def run_scene(name: str, scale: float, depth: int, quick: bool, log, probes=None
              ) -> list[dict]:
    base_st = RenderSettings(max_depth=depth)
    # compile / cache load first (not timed)
    warm = scenes.build(name, 32, 24)
    wacc = create_accelerator("BVH", warm.arrays())
    for view in (False, True):
        RITreeRenderer().render(warm, replace(base_st, mode="RI_TREE", thickness_view=view),
                                wacc)
        perfect_tree_time(warm, replace(base_st, mode="RI_TREE", thickness_view=view), wacc, 1)
    render(warm, base_st, accel=wacc)
    render_thickness_exact(warm, replace(base_st, thickness_view=True), wacc)
    rows = []
    grid_rows = grid(name, quick, probes)
    for view in dict.fromkeys(g[0] for g in grid_rows):
        thick = view == "THICKNESS"
        w0, h0, spp = SIZES.get((name, view), (600, 600, 1))
        w, h = max(8, int(w0 * scale)), max(8, int(h0 * scale))
        sc = scenes.build(name, w, h)
        accel = create_accelerator("BVH", sc.arrays())
        st0 = replace(base_st, samples=spp, thickness_view=thick)
        t0 = CLOCK()
        base = _base_frame(sc, st0, accel)
        t_base = CLOCK() - t0
        # the ceiling: an RI_TREE frame with a perfect tree, free to build and to query
        t_perfect = perfect_tree_time(sc, replace(st0, mode="RI_TREE"), accel)
        t0 = CLOCK()
        _base_frame(sc, st0, accel)
        t_base = min(t_base, CLOCK() - t0)
        ceiling = t_base / t_perfect
        log(f"{name} {view.lower()} {w}x{h} spp {spp}: base {t_base:.2f} s, perfect tree "
            f"{t_perfect:.2f} s (ceiling {ceiling:.2f}x)")
        for _, dist, ang, dep, cache, probe in (g for g in grid_rows if g[0] == view):
            st = replace(st0, mode="RI_TREE", ri_dist_thresh=dist, ri_ang_thresh=ang,
                         ri_depth=dep, ri_cache_mb=cache, ri_probe_angle=probe)
            # the base frame is re-timed next to each row (the machine's load drifts)
            t0 = CLOCK()
            _base_frame(sc, st0, accel)
            tb = min(CLOCK() - t0, t_base)
            r = RITreeRenderer()
            r.auto_fallback = False  # decided below, after the warm frame
            t0 = CLOCK()
            f = r.render(sc, st, accel)
            t_ri = CLOCK() - t0
            costs = r.last_costs
            # a second frame of the same camera with the trees kept (what a session reuses)
            t0 = CLOCK()
            f2 = r.render(sc, st, accel)
            t_warm = CLOCK() - t0
            # the fallback (ri_tree.fallback) as decided from the first frame's costs, and
            # a frame with the objects whose trees did not pay traced
            ri = r.ri[thick]
            n_ri = len(ri)
            out = ri[~tree_pays(costs)[ri]] if costs is not None and n_ri else ri[:0]
            t_fb = t_warm
            if len(out):
                r.fall_back(thick, out, sc, costs)
                t0 = CLOCK()
                r.render(sc, st, accel)
                t_fb = CLOCK() - t0
            m = image.compare(f.radiance, base.radiance, 0.02)
            px, px2 = (np.abs(image.to_display(g.radiance)
                              - image.to_display(base.radiance)).max(axis=-1) for g in (f, f2))
            row = dict(scene=name, view=view, dist_thresh=dist, ang_thresh=ang, depth=dep,
                       cache_mb=cache, probe_angle=probe,
                       speedup=tb / t_ri, warm_speedup=tb / t_warm,
                       fallback_speedup=tb / t_fb, ri_objects=n_ri, traced_objects=len(out),
                       ceiling_speedup=ceiling,
                       mean_error=rgb_error(f.radiance, base.radiance),
                       max_error=m["max_error"], p999_error=float(np.quantile(px, 0.999)),
                       over_01=int(np.count_nonzero(px > 0.1)),
                       over_03=int(np.count_nonzero(px > 0.3)),
                       warm_max_error=float(px2.max()),
                       warm_over_01=int(np.count_nonzero(px2 > 0.1)),
                       retraced_pixels=int(f.stats.get("retraced_pixels", 0)),
                       traced_fraction=f.stats["traced_fraction"],
                       interpolated_fraction=f.stats["interpolated_fraction"],
                       memory_mb=f.stats["memory_mb"],
                       peak_memory_mb=f.stats["peak_memory_mb"],
                       mean_display_error=m["mean_error"], psnr=m["psnr"], base_s=tb,
                       ri_s=t_ri, samples_traced=f.stats["samples_traced"], width=w, height=h,
                       spp=spp)
            rows.append(row)
            log(f"{name} {view} d={dist:g} a={ang:g} depth={dep} cache={cache:g} "
                f"probe={probe:g}: "
                f"{row['speedup']:.2f}x (warm {row['warm_speedup']:.2f}x, fallback "
                f"{row['fallback_speedup']:.2f}x, {len(out)}/{n_ri} traced) "
                f"err {row['mean_error']:.5f} max {row['max_error']:.3f} "
                f"p99.9 {row['p999_error']:.3f} >0.1 {row['over_01']} "
                f"warm max {row['warm_max_error']:.3f} >0.1 {row['warm_over_01']} "
                f"re-traced {row['retraced_pixels']} px "
                f"traced {100 * row['traced_fraction']:.1f}% mem {row['memory_mb']:.2f} MB "
                f"(peak {row['peak_memory_mb']:.2f}) samples {row['samples_traced']}")
    return rows


def markdown(rows: list[dict], note: str) -> str:
    head = ("| scene | view | size | dist | ang | depth | cache MB | exit-ray test | speedup | "
            "warm | fallback (traced objects) | ceiling | mean RGB err | max err | "
            "99.9% err | px > 0.1 | px > 0.3 | warm max err | warm px > 0.1 | re-traced px | "
            "PSNR dB | traced % | memory MB | peak MB | base s | RI-tree s |")
    lines = [f"RI-tree against the base tracer (`python -m rstrace_engine.bench ritree`). "
             f"{note}", "", head, "|" + "---|" * 26]
    for r in rows:
        lines.append("| " + " | ".join([
            r["scene"], r["view"].lower(),
            f"{r['width']}x{r['height']}" + (f" x{r['spp']}" if r["spp"] > 1 else ""),
            f"{r['dist_thresh']:g}",
            f"{r['ang_thresh']:g}", str(r["depth"]), f"{r['cache_mb']:g}",
            f"{r['probe_angle']:g}°" if r["probe_angle"] > 0 else "off (paper)",
            f"{r['speedup']:.2f}x", f"{r['warm_speedup']:.2f}x",
            f"{r['fallback_speedup']:.2f}x ({r['traced_objects']}/{r['ri_objects']})",
            f"{r['ceiling_speedup']:.2f}x", f"{r['mean_error']:.5f}",
            f"{r['max_error']:.3f}", f"{r['p999_error']:.3f}", str(r["over_01"]),
            str(r["over_03"]), f"{r['warm_max_error']:.3f}", str(r["warm_over_01"]),
            str(r["retraced_pixels"]),
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
               and r["depth"] == 28 and r["cache_mb"] == DEFAULT_CACHE
               and r["probe_angle"] == 0.0] or \
              [r for r in rows if (r["scene"], r["view"]) == key]
        sel.sort(key=lambda r: r["dist_thresh"])
        (line,) = ax.plot([r["mean_error"] for r in sel], [r["speedup"] for r in sel],
                          marker="o", label=f"{key[0]} ({key[1].lower()})")
        if sel and "ceiling_speedup" in sel[0]:  # a perfect tree, free: dotted
            ax.axhline(sel[0]["ceiling_speedup"], color=line.get_color(), lw=1.0, ls=":")
    ax.axhline(1.0, color="grey", lw=0.8, ls="--")
    ax.axvspan(0.004, 0.019, color="green", alpha=0.08, label="paper's error range")
    ax.set_xlabel("mean RGB error vs base frame (distance threshold sweep)")
    ax.set_ylabel("CPU-time speedup over the base tracer\n(dotted: with a perfect, free tree)")
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
    p.add_argument("--scenes", default="bezier_surface,random_volumes,tomatoes,glass_horizon")
    p.add_argument("--scale", type=float, default=1.0, help="resolution factor")
    p.add_argument("--depth", type=int, default=5, help="ray depth of both tracers")
    p.add_argument("--quick", action="store_true", help="three distance thresholds only")
    p.add_argument("--probes", default="",
                   help="exit-ray test thresholds (degrees, comma separated) of the rows at "
                        "the default settings; default: the sweep (--quick: the default)")
    p.add_argument("--out", default="docs")
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    p.add_argument("--threads", type=int, default=0,
                   help="numba threads (0: all); 1 keeps idle threads' spinning out of the "
                        "CPU time on a loaded machine")
    args = p.parse_args(argv)
    if args.threads > 0:
        import numba

        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    rows = []
    for name in args.scenes.split(","):
        rows += run_scene(name.strip(), args.scale, args.depth, args.quick, log,
                          [float(x) for x in args.probes.split(",")] if args.probes else None)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    note = (f"Timing: {'process CPU time' if args.clock == 'cpu' else 'wall time'}"
            f"{f', {args.threads} numba thread(s)' if args.threads > 0 else ''}; scale "
            f"{args.scale:g} of the paper's sizes; ray depth {args.depth}; each RI-tree frame "
            f"from empty trees; *warm*: a second frame with the trees kept; *fallback*: a frame "
            f"after the first frame's fallback decision (objects whose tree did not pay "
            f"traced / objects with a tree); *ceiling*: a frame "
            f"with a perfect tree, free to build and to query.")
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
