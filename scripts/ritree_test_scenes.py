"""The RI-tree's test scenes measured (docs/RI_TREE.md, "The continuation check"): the scenes
of tests/test_ri_tree_bounds.py and tests/test_ri_tree_recheck.py with the cost rule's counts
lowered as those tests lower them (4 / 16), the fallback off, per setting a cold frame (empty
trees) and a warm one (trees kept), the continuation check off and on. Prints one JSON line
per row: largest display error per pixel against the base frame (``max``, ``p999``, pixels
over 0.1), pixels the check traced again (``redo``), the primary pixels interpolated
(``interp``, a fraction of the frame) and speed (base CPU time / RI-tree CPU time, the base
frame timed in the same process).

``PYTHONPATH=. NUMBA_NUM_THREADS=1 python scripts/ritree_test_scenes.py``"""

import json
import sys
import time
from dataclasses import replace

import numpy as np

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.ri_tree import tree_cache as ri_cache
from rstrace_engine.ri_tree.render import RITreeRenderer
from rstrace_engine.tracing.whitted import render

ROWS = [("glass_horizon", 160, 120, 1, 0.025), ("tomatoes", 200, 150, 1, 0.025),
        ("random_volumes", 100, 100, 4, 0.025), ("random_volumes", 100, 100, 4, 0.1)]


def main() -> None:
    ri_cache.SPLIT_QUERIES = 4
    ri_cache.SPLIT_QUERIES_MIXED = 16
    for name, w, h, spp, probe in ROWS:
        sc = scenes.build(name, w, h)
        accel = create_accelerator("BVH", sc.arrays())
        st = RenderSettings(max_depth=5, samples=spp)
        render(sc, st, accel=accel)  # (kernels loaded)
        for check in (False, True):
            t = time.process_time()
            base = render(sc, st, accel=accel)
            tb = time.process_time() - t
            r = RITreeRenderer()
            r.auto_fallback = False
            r.recheck = check
            row = dict(scene=name, size=f"{w}x{h}" + (f" x{spp}" if spp > 1 else ""),
                       probe=probe, recheck=check)
            for tag in ("cold", "warm"):
                t = time.process_time()
                f = r.render(sc, replace(st, mode="RI_TREE", ri_probe_angle=probe), accel)
                dt = time.process_time() - t
                px = np.abs(image.to_display(f.radiance)
                            - image.to_display(base.radiance)).max(axis=-1)
                row[tag] = dict(max=float(px.max()), p999=float(np.quantile(px, 0.999)),
                                over01=int((px > 0.1).sum()), redo=f.stats["retraced_pixels"],
                                interp=float((f.pixel_class == CLASS_INTERPOLATED).mean()),
                                speed=tb / dt)
            sys.stdout.write(json.dumps(row) + "\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
