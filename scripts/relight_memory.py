"""Memory of the per-light records (docs/RELIGHT.md): museum BASE full frames at WIDTH x
HEIGHT with N lights (N <= 6: the first N of museum's own; more: museum's six and point
lights on a ceiling grid), the light terms kept under an unlimited cap; prints nodes,
terms, the parts' bytes, the dense layout's ``177 + 25 (L + 2)`` bytes per node it
replaced (``L`` the light slots) and what the default cap
(``RenderSettings.relight_memory_mb``) does.
``python scripts/relight_memory.py WIDTH HEIGHT N [N ...]``."""

import sys
import time

import numpy as np

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry.scene import Light
from rstrace_engine.session import Session


def museum_with(width: int, height: int, n: int):
    s = scenes.museum(width, height)
    for j in range(len(s.lights) - 1, n - 1, -1):
        s.delete_light(j)
    extra = n - sum(li is not None for li in s.lights)
    cols = int(np.ceil(np.sqrt(extra * 4 / 3))) if extra > 0 else 0
    for k in range(max(extra, 0)):
        x = -18.0 + 36.0 * ((k % cols) + 0.5) / cols
        y = -13.0 + 26.0 * ((k // cols) + 0.5) / max(1, int(np.ceil(extra / cols)))
        s.add_light(Light(f"Grid{k:03d}", "POINT", power=6000.0 / n, position=(x, y, 7.4)))
    return s


def main(width: int, height: int, counts: list) -> None:
    default_cap = RenderSettings().relight_memory_mb
    for n in counts:
        sess = Session(museum_with(width, height, n),
                       RenderSettings(mode="BASE", max_depth=5, relight_memory_mb=1e6))
        sess.light_terms = True
        t0 = time.perf_counter()
        sess.render()
        dt = time.perf_counter() - t0
        lr = sess.reuse.light_records
        p, s = lr.p, lr.s
        nodes = len(p) + len(s)
        entries = len(p.slot) + len(s.slot)
        hits = int(p.hit.sum() + s.hit.sum())
        geo = p.geo_bytes + s.geo_bytes
        total = lr.nbytes
        dense = nodes * (177 + 25 * (lr.L + 2))
        cap = 1e6 * default_cap
        tier = ("all kept" if total <= cap else "geometry dropped (moves re-trace)"
                if total - geo <= cap else "dropped (every light edit re-traces)")
        sys.stdout.write(
            f"lights {n}: nodes {nodes} (surface {hits}), terms {entries} "
            f"({entries / nodes:.2f} per node), records {total / 1e6:.1f} MB "
            f"(geometry {geo / 1e6:.1f}, terms {entries * 25 / 1e6:.1f}), "
            f"{total / nodes:.0f} B/node; dense layout {dense / 1e6:.1f} MB "
            f"({dense / nodes:.0f} B/node); default cap {default_cap:.0f} MB: {tier}; "
            f"frame {dt:.1f} s\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), [int(a) for a in sys.argv[3:]])
