"""rough_materials at equal CPU time, a ``glossy_rays`` module switch off and on in one process
(issue 24, session 35): per seed (100...) the two frames rendered in alternating order, CPU
time, rays, the bench row's ``rel`` against a Mitsuba reference (4096 spp, cached in
``/tmp/glass-w``); Mitsuba's ``rel`` from one power-law fit over 12-96 spp (6 seeds each) at
the spp of each side's median time. One curve for both sides: ``scripts/rough_equal_time.py``
times Mitsuba once per process, which moved its ratios by 10-15% between runs.

Reproduce: ``DRJIT_LIBLLVM_PATH=<libLLVM.so >= 16> NUMBA_NUM_THREADS=1 PYTHONPATH=.
python scripts/rough_switch_ab.py 1:16 4:4 4:2 [--switch ROULETTE]`` (session 35 ran it with
``FIRST_CHOICE``, the switch of commit ``dd71928``, dropped: docs/glossy.md).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace

import numpy as np

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench import frame_rough as fr
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import glossy_rays
from rstrace_engine.tracing.whitted import render

REF = "/tmp/glass-w/ref4096.npy"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("allocations", nargs="+", help="S:G (pixel samples : glossy samples)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--switch", default="ROULETTE", help="a glossy_rays module switch")
    a = ap.parse_args()
    w, h = 160, 120
    scene = scenes.rough_materials(w, h)
    acc = create_accelerator("BVH", scene.arrays())
    mi, ms = fr.mitsuba_rough(scene, w, h)
    os.makedirs(os.path.dirname(REF), exist_ok=True)
    if os.path.exists(REF):
        ref = np.load(REF)
    else:
        ref, _ = fr._mitsuba_render(mi, ms, 4096, seed=1)
        np.save(REF, ref)
    lr = fr._luminance(ref)

    def rel(img):
        return float(np.mean(np.abs(fr._luminance(img) - lr) / (lr + fr.REL_EPS)))

    per_spp = fr.mitsuba_cpu_per_spp(mi, ms)
    curve = [(spp, float(np.mean([rel(fr._mitsuba_render(mi, ms, spp, seed=k)[0])
                                  for k in range(6)])))
             for spp in (12, 16, 24, 32, 48, 64, 96)]
    slope, icpt = np.polyfit(np.log([c[0] for c in curve]), np.log([c[1] for c in curve]), 1)
    say(dict(mitsuba_curve=curve, slope=round(float(slope), 3), per_spp=per_spp))
    modes = ("off", "on")
    for al in a.allocations:
        s, g = map(int, al.split(":"))
        st = RenderSettings(max_depth=5, samples=s, glossy_samples=g).validated()
        for m in modes:  # compiles
            setattr(glossy_rays, a.switch, m == "on")
            render(scenes.rough_materials(16, 12), st)
        res = {m: ([], [], []) for m in modes}
        for k in range(a.seeds):
            for m in (modes if k % 2 == 0 else modes[::-1]):
                setattr(glossy_rays, a.switch, m == "on")
                c = time.process_time()
                f = render(scene, replace(st, seed=100 + k), accel=acc)
                res[m][0].append(time.process_time() - c)
                res[m][1].append(rel(f.radiance.astype(np.float64)))
                res[m][2].append(f.stats["secondary_rays"] + f.stats["shadow_rays"])
        for m in modes:
            ts, rr, rays = res[m]
            spp = float(np.median(ts)) / per_spp
            mr = float(np.exp(icpt + slope * np.log(spp)))
            say(dict(alloc=al, switch=m, cpu_s=round(float(np.median(ts)), 4),
                     rays=int(np.mean(rays)), rel=round(float(np.mean(rr)), 5),
                     rel_se=round(float(np.std(rr, ddof=1) / np.sqrt(len(rr))), 5),
                     mitsuba_spp=round(spp, 1), mitsuba_rel=round(mr, 5),
                     ratio=round(float(np.mean(rr)) / mr, 3)))


def say(d: dict) -> None:
    sys.stdout.write(json.dumps(d) + "\n")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
