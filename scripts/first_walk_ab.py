"""The first-walk A/B driver (docs/bench-trade-first-frames.md, "Session 42 (neverlose)"):
per process one scene; the bench's 48x36 warm-up, one untimed sequence, then ROUNDS
sequences of a fresh renderer: first, step, pan, and 'reprobe' (the first camera again after
the whole-frame fallback's wait: frames_all set to REPROBE_FRAMES where the whole frame was
judged not to pay), each INTERPOLANT frame right after or before the base frame of its
camera (alternated); process CPU (run with NUMBA_NUM_THREADS=1), epsilon 0.01. One JSON
line a sequence on stdout. Alternate the trees by PYTHONPATH, one process at a time:
``PYTHONPATH=TREE python scripts/first_walk_ab.py SCENE W H SPP ROUNDS TAG``."""
import json
import sys
import time

import numpy as np

from rstrace_engine import kernel_cache, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.trade import moved_cameras
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants import fallback
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.whitted import render

name, tag = sys.argv[1], sys.argv[6]
w, h, spp, rounds = (int(x) for x in sys.argv[2:6])
CLOCK = time.process_time
sc = scenes.build(name, w, h)
accel = create_accelerator("BVH", sc.arrays())
cams = moved_cameras(sc)
bs = RenderSettings(samples=spp)
st = RenderSettings(mode="INTERPOLANT", epsilon=0.01, samples=spp)
warm = scenes.build(name, 48, 36)
wacc = create_accelerator("BVH", warm.arrays())
wr = InterpolantRenderer()
wr.auto_fallback = False
for cam in moved_cameras(warm).values():
    warm.set_camera(cam)
    render(warm, bs, accel=wacc)
    wr.render(warm, st, wacc)
seq = [("first", "first"), ("step", "step"), ("pan", "pan"), ("reprobe", "first")]
for rnd in range(rounds + 1):
    since = kernel_cache.mark()
    r = InterpolantRenderer()
    out = []
    for i, (kind, cam) in enumerate(seq):
        sc.set_camera(cams[cam])
        if kind == "reprobe":
            fb = r.cache.fallback
            if fb.all_traced:
                fb.frames_all = fallback.REPROBE_FRAMES
        empty = r.cache is None or r.cache.pool.n_live == 0
        order = (rnd + i) % 2  # base first or interpolant first, alternated
        t = {}
        for who in ((0, 1) if order == 0 else (1, 0)):
            t0 = CLOCK()
            if who == 0:
                bf = render(sc, bs, accel=accel)
            else:
                f = r.render(sc, st, accel)
            t[who] = CLOCK() - t0
        s = f.stats.get("fallback", {})
        d = float(np.abs(f.radiance - bf.radiance).max())  # (classes: background alike)
        same = bool(d == 0.0 and np.array_equal(f.pixel_class == 0, bf.pixel_class == 0))
        out.append(dict(kind=kind, base=t[0], interp=t[1], ratio=t[0] / t[1],
                        empty=bool(empty), walked=s.get("walked_rays", 0),
                        added_ms=1e3 * s.get("added_s", 0.0), declined=s.get("declined"),
                        first_walk=s.get("first_walk"), all_traced=s.get("all_traced"),
                        interp_pct=100 * f.stats.get("interpolated_fraction", 0.0),
                        maxdiff=d, same=same, notes=f.stats.get("fallback_notes")))
    c = kernel_cache.counts(since=since)
    rec = dict(tag=tag, scene=name, size=f"{w}x{h}", spp=spp, round=rnd,
               loads=c["loaded"] + c["compiled"], frames=out)
    sys.stdout.write(json.dumps(rec if rnd else dict(rec, untimed=True)) + "\n")
    sys.stdout.flush()
