"""Base-mode shaft skips (docs/SOFT_LIGHT.md): ``python scripts/shaft_skip_numbers.py
[width height [tiles]]``.

Per scene, BASE frames (1 spp, max depth 5, 16 light samples, 1 thread) with the skips on
and off alternated in one run, CPU time (``time.process_time``) best of ``REPS`` each: the
ratio, shadow rays per pixel traced with and without, the samples skipped, the share of
(point, light) rows of lights with an extent proven fully visible, the proofs' own time,
and whether the two images are identical bit for bit. Then the tile size (``tiles``,
default 4,8,16,32) on the soft scenes.
"""

from __future__ import annotations

import sys
import time

import numba
import numpy as np

from rstrace_engine import scenes
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import shaft_skip
from rstrace_engine.tracing.whitted import render

REPS = 3
SCENES = {"studio": scenes.studio, "museum_soft": scenes.museum_soft,
          "soft_room": SOAK_SCENES["soft_room"], "museum_1999": scenes.museum_1999}


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def frames(scene, st, reps=REPS):
    """Best CPU time and last frame with the skips on and off, alternated."""
    best = {True: np.inf, False: np.inf}
    last = {}
    for _ in range(reps):
        for on in (True, False):
            shaft_skip.SHAFT_SKIP = on
            t = time.process_time()
            last[on] = render(scene, st)
            best[on] = min(best[on], time.process_time() - t)
    shaft_skip.SHAFT_SKIP = True
    return best, last


def main(w=320, h=240, tiles=(4, 8, 16, 32)):
    numba.set_num_threads(1)
    st = RenderSettings(mode="BASE", samples=1, max_depth=5, light_samples=16)
    px = w * h
    out(f"## BASE {w}x{h}, 1 spp, max depth 5, 16 light samples, 1 thread, CPU s best of "
        f"{REPS}, tile {shaft_skip.SKIP_TILE}")
    out("| scene | skips on | off | speed-up | shadow rays/px on, off | skipped/px | rows "
        "proven | proofs | identical |")
    out("|---|---|---|---|---|---|---|---|---|")
    for name, build in SCENES.items():
        scene = build(w, h)
        render(scene, st)  # compile / load
        best, f = frames(scene, st)
        on, off = f[True].stats, f[False].stats
        same = np.array_equal(f[True].radiance, f[False].radiance)
        rows = on["skip_rows_proven"] / max(1, on["skip_rows"])
        out(f"| {name} | {best[True]:.3f} s | {best[False]:.3f} s | "
            f"{best[False] / best[True]:.2f}x | {on['shadow_rays'] / px:.1f}, "
            f"{off['shadow_rays'] / px:.1f} | {on['shadow_rays_skipped'] / px:.1f} | "
            f"{rows:.1%} | {on['skip_s']:.3f} s | {same} |")
    out("")
    out("| tile | scene | skips on | off | speed-up | skipped/px | rows proven | proofs |")
    out("|---|---|---|---|---|---|---|---|")
    for tile in tiles:
        shaft_skip.SKIP_TILE = tile
        for name in ("studio", "museum_soft"):
            scene = SCENES[name](w, h)
            best, f = frames(scene, st, 2)
            on = f[True].stats
            rows = on["skip_rows_proven"] / max(1, on["skip_rows"])
            out(f"| {tile} | {name} | {best[True]:.3f} s | {best[False]:.3f} s | "
                f"{best[False] / best[True]:.2f}x | {on['shadow_rays_skipped'] / px:.1f} | "
                f"{rows:.1%} | {on['skip_s']:.3f} s |")


if __name__ == "__main__":
    args = sys.argv[1:]
    tiles = tuple(int(t) for t in args[2].split(",")) if len(args) > 2 else (4, 8, 16, 32)
    main(*(int(a) for a in args[:2]), tiles=tiles)
