"""The RI-tree's display error and speed against its thresholds (docs/RI_TREE.md, issue 22):
one scene, one base frame, then per setting an RI_TREE frame from empty trees (*cold*) and a
second one with the trees kept (*warm*), the fallback off (the trees are measured, not its
decision). Prints one JSON line per setting: largest display error per pixel (largest
channel, display values) against the base frame (``max``, ``p999``, pixels over 0.1 and 0.3;
``wmax``, ``wp999``, ``wover01`` of the warm frame), pixels the continuation check traced
again (``redo``, ``wredo``: :mod:`rstrace_engine.ri_tree.recheck`), speed as base CPU
time / RI-tree CPU time in the same process (the base frame re-timed before each setting,
best kept), samples traced.

``PYTHONPATH=. python scripts/ritree_probe_sweep.py SCENE WIDTH HEIGHT SPP
DIST:ANG:PROBE[:RECHECK][,...]`` (the checkout's package; ``RECHECK`` 0 turns the
continuation check off, default 1), e.g. ``random_volumes 150 150 9
0.05:30:0,0.05:30:0.1,0.05:30:0.1:0``."""

import json
import sys
import time
from dataclasses import replace

import numpy as np

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.ri_tree.render import RITreeRenderer
from rstrace_engine.tracing.whitted import render


def errors(frame, base) -> np.ndarray:
    return np.abs(image.to_display(frame.radiance)
                  - image.to_display(base.radiance)).max(axis=-1)


def main(name: str, w: int, h: int, spp: int, combos: list[tuple[float, ...]]):
    sc = scenes.build(name, w, h)
    accel = create_accelerator("BVH", sc.arrays())
    st0 = RenderSettings(max_depth=5, samples=spp)
    t = time.process_time()
    base = render(sc, st0, accel=accel)
    tb = time.process_time() - t
    for dist, ang, probe, *rest in combos:
        t = time.process_time()
        render(sc, st0, accel=accel)
        tb = min(tb, time.process_time() - t)
        r = RITreeRenderer()
        r.auto_fallback = False
        r.recheck = bool(rest[0]) if rest else True
        st = replace(st0, mode="RI_TREE", ri_probe_angle=probe, ri_dist_thresh=dist,
                     ri_ang_thresh=ang)
        t = time.process_time()
        f = r.render(sc, st, accel)
        tr = time.process_time() - t
        t = time.process_time()
        f2 = r.render(sc, st, accel)
        tw = time.process_time() - t
        px, px2 = errors(f, base), errors(f2, base)
        sys.stdout.write(json.dumps(dict(
            scene=name, size=f"{w}x{h}" + (f" x{spp}" if spp > 1 else ""), dist=dist,
            ang=ang, probe=probe, recheck=r.recheck, max=float(px.max()),
            p999=float(np.quantile(px, 0.999)),
            over01=int((px > 0.1).sum()), over03=int((px > 0.3).sum()),
            wmax=float(px2.max()), wp999=float(np.quantile(px2, 0.999)),
            wover01=int((px2 > 0.1).sum()), redo=int(f.stats["retraced_pixels"]),
            wredo=int(f2.stats["retraced_pixels"]), cold=tb / tr, warm=tb / tw,
            samples=int(f.stats["samples_traced"]))) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]),
         [tuple(float(v) for v in c.split(":")) for c in sys.argv[5].split(",")])
