"""Why each pixel of a radiance-interpolant frame was or was not interpolated (diagnostics).

::

    python scripts/interpolant_outcomes.py museum_1999 --epsilon 0.01 --depth-cap 6 \\
        --out docs/outcomes_museum_1999.png

Renders the scene's camera in INTERPOLANT mode (one sample per pixel, from an empty cache)
with :attr:`~rstrace_engine.interpolants.interpolant_cache.InterpolantCache.outcome_log`
on, then finds
each pixel's linetree leaf again (the frame's own rays) and names the outcome of the deepest
cell built above it: a predicate reason (:data:`~rstrace_engine.interpolants.predicate.
REASONS`: ``light_change`` = the corners disagree on a light's state (lit, occluded by which
object, not facing / outside a spot cone), ``spot_cone``, ``light_shaft`` ...), ``radiance``
(the radiance test), ``box_miss``; ``valid`` when the cell is valid but the pixel's hit is
not the slab crossing it certifies; ``never built`` when no cell above the pixel held
``MIN_PIXELS`` rays. Prints the share of the pixels per outcome (``--json``: one object) and
writes a false-colour PNG (green: interpolated, dark grey: background; the legend is
printed) and, with ``--corner-spread``, the median world-space spread of the corner hits of
the failed cells per depth (how much surface one cell's lines cover).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rstrace_engine import image, scenes  # noqa: E402
from rstrace_engine.accel.accelerators import create_accelerator  # noqa: E402
from rstrace_engine.frame import (  # noqa: E402
    CLASS_BACKGROUND,
    CLASS_INTERPOLATED,
    RenderSettings,
)
from rstrace_engine.geometry.cameras import camera_params, camera_rays  # noqa: E402
from rstrace_engine.interpolants.interpolant_cache import OUTCOMES  # noqa: E402
from rstrace_engine.interpolants.linetree import EMPTY, descend  # noqa: E402
from rstrace_engine.interpolants.render import InterpolantRenderer  # noqa: E402
from rstrace_engine.tracing.batches import TILE_RAYS, frame_batches  # noqa: E402

#: pixel outcomes: the cell outcomes, then these
EXTRA = ("never built", "interpolated", "background")
COLOURS = {
    "interpolated": (0, 150, 0), "background": (40, 40, 40), "never built": (150, 150, 150),
    "light_change": (230, 40, 40), "spot_cone": (250, 220, 0), "light_shaft": (255, 140, 0),
    "radiance": (40, 110, 255), "corner_miss": (255, 0, 255), "class_change": (190, 80, 255),
    "box_miss": (120, 40, 160), "tree_change": (0, 230, 230), "valid": (255, 255, 255),
    "slab": (140, 90, 40), "partial_occluder": (255, 160, 160),
}


def pixel_outcomes(name: str, epsilon: float, depth_cap: int, width: int, height: int,
                   fallback: bool = True, world: bool = True, by_object: bool = False):
    """(h, w) int array of indices into ``OUTCOMES + EXTRA``, the frame's stats; with
    ``by_object`` also the (h, w) instance seen (-1: none) and the instances' names.
    ``fallback=False`` builds cells wherever they may be (no build budget);
    ``world=False`` keeps the world's colour as a background only (no world light)."""
    sc = scenes.build(name, width, height)
    if not world:
        sc.set_world_color(tuple(sc.world_color), lights=False)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=epsilon, depth_cap=depth_cap).validated()
    r = InterpolantRenderer()
    r.auto_fallback = fallback
    cache, _ = r.prepare(sc.arrays(), st, accel)
    cache.outcome_log = []
    frame = r.render(sc, st, accel)
    cell = {}
    for tree, depth, coord, outcome in cache.outcome_log:
        for q in range(len(tree)):
            cell[(int(tree[q]), int(depth[q]), tuple(int(x) for x in coord[q]))] = int(outcome[q])
    # the frame's rays again (as render_frame draws them, one sample per pixel)
    cp = camera_params(sc.camera)
    parts = list(frame_batches(cp.width, cp.height, 1, int(st.seed),
                               max(1, TILE_RAYS // cp.width), None))
    pix = np.concatenate([q for q, _, _ in parts])
    jitter = np.concatenate([j for _, j, _ in parts], axis=1)
    o, d, tmin, tmax = camera_rays(cp, pix, jitter[0])
    hits = accel.closest_hit(o, d, tmin, tmax)
    face, abcd, _, _ = cache.pixel_lines(hits, o, d)
    pclass = frame.pixel_class.reshape(-1)[pix]
    out = np.full(len(pix), OUTCOMES.index("valid"), np.int64)
    nb = len(OUTCOMES)
    out[pclass == CLASS_INTERPOLATED] = nb + 1
    out[(pclass == CLASS_BACKGROUND) | (hits.inst < 0)] = nb + 2
    todo = np.flatnonzero(out == OUTCOMES.index("valid"))
    roots = cache.trees.get_roots(hits.inst[todo], face[todo])
    leaf = np.empty(len(todo), np.int32)
    descend(cache.trees.arrays, roots, abcd[todo], leaf, np.full(len(todo), EMPTY, np.int32))
    a = cache.trees.arrays
    for k, nd in enumerate(leaf):
        tr, dp, co = int(a.tree[nd]), int(a.depth[nd]), a.coord[nd].astype(np.int64)
        res = nb  # never built
        for up in range(dp + 1):
            key = (tr, dp - up, tuple(int(x) for x in co >> up))
            if key in cell:
                res = cell[key]
                break
        out[todo[k]] = res
    grid = np.empty(cp.width * cp.height, np.int64)
    grid[pix] = out
    grid = grid.reshape(cp.height, cp.width)
    if not by_object:
        return grid, frame.stats
    seen = np.full(cp.width * cp.height, -1, np.int64)
    seen[pix] = hits.inst
    names = [(i or {}).get("name", "?") for i in sc.instances]
    return grid, frame.stats, seen.reshape(cp.height, cp.width), names


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scene")
    p.add_argument("--epsilon", type=float, default=0.01)
    p.add_argument("--depth-cap", type=int, default=RenderSettings().depth_cap)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--out", default="", help="PNG of the per-pixel outcome")
    p.add_argument("--json", action="store_true")
    p.add_argument("--no-fallback", action="store_true",
                   help="build cells wherever they may be (no build budget, nothing traced "
                        "by the measured fallback)")
    p.add_argument("--no-world", action="store_true",
                   help="the world's colour as a background only (the world does not light)")
    p.add_argument("--no-split", action="store_true",
                   help="the lights' sampled terms not split off (interpolants.sampled_term."
                        "PER_PIXEL off: their cells fail with soft_sampled, as before)")
    p.add_argument("--by-object", action="store_true",
                   help="also the outcomes' shares per object seen (by the object's name)")
    args = p.parse_args(argv)
    if args.no_split:
        from rstrace_engine.interpolants import sampled_term
        sampled_term.PER_PIXEL = False
    res = pixel_outcomes(args.scene, args.epsilon, args.depth_cap, args.width, args.height,
                         fallback=not args.no_fallback, world=not args.no_world,
                         by_object=args.by_object)
    grid, stats = res[0], res[1]
    names = (*OUTCOMES, *EXTRA)
    n = np.bincount(grid.reshape(-1), minlength=len(names)) / grid.size
    shares = {names[i]: round(float(n[i]), 4) for i in np.argsort(-n) if n[i] > 0}
    objects = {}
    if args.by_object:
        seen, inst_names = res[2], res[3]
        for i in np.unique(seen):
            if i < 0:
                continue
            m = seen == i
            c = np.bincount(grid[m], minlength=len(names)) / grid.size
            objects[inst_names[i]] = {names[q]: round(float(c[q]), 4)
                                      for q in np.argsort(-c) if c[q] > 0}
    timing = {k: round(float(stats.get(k, 0.0)), 3) for k in (
        "time_s", "visibility_s", "resolve_s", "build_s", "world_s", "sampled_s", "trace_s")}
    counts = {k: int(stats.get(k, 0)) for k in (
        "traced_rays", "shadow_rays", "secondary_rays", "rough_interpolated",
        "cells_built", "cells_valid")}
    if args.json:
        sys.stdout.write(json.dumps(dict(scene=args.scene, epsilon=args.epsilon,
                                         depth_cap=args.depth_cap, world=not args.no_world,
                                         fallback=not args.no_fallback,
                                         split=not args.no_split, shares=shares,
                                         cell_outcomes=stats["cell_outcomes"],
                                         objects=objects, timing=timing,
                                         counts=counts)) + "\n")
    else:
        for k, v in shares.items():
            sys.stdout.write(f"{k:18s} {100 * v:5.1f}%  colour "
                             f"{COLOURS.get(k, (255, 255, 255))}\n")
    if args.out:
        pal = np.array([COLOURS.get(k, (255, 255, 255)) for k in names], np.uint8)
        image.write_png(args.out, pal[grid], bottom_up=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
