"""rough_materials at equal CPU time against Mitsuba, over seeds (issue 24, session 34): the
bench row (``bench frame --scenes rough_materials``) renders Mitsuba once, seed 0, at the
spp its time search lands on, which moved its error by 20-30% between runs; this takes
rstrace's mean ``rel`` over ``--seeds`` frames (seeds 100...) at its median CPU time, and
Mitsuba's mean ``rel`` over 6 seeds at the spp of that CPU time (from a 64 spp render's
time per sample), both against one Mitsuba reference of ``--ref-spp``.

Reproduce: ``DRJIT_LIBLLVM_PATH=<libLLVM.so >= 16> NUMBA_NUM_THREADS=1 PYTHONPATH=.
python scripts/rough_equal_time.py 1:16 8:1 4:4 4:2`` (pixel samples : glossy samples).

``--own-reference`` (session 35) separates the models' bias from the sampling error. rstrace
follows Cycles' model (multiscatter GGX, Schlick-to-white metal, no light on a rough
interface's far side), Mitsuba its own (single-scattering GGX), so one Mitsuba reference
counts the models' difference against rstrace only. Every ``rel`` is the bench row's mean
relative luminance error (:func:`rstrace_engine.bench.frame_rough.error_stats`'s
``rel_mean``), over all pixels and without the pixels that see the glass ball
(``_no_glass``: the ball's mask from the rstrace reference's pixel samples, cover > 0.5):

* ``own``: the sampling error at equal CPU time. rstrace's frames (seeds 100...) against
  rstrace's own converged frame (``--rstrace-ref S:G``, default 64:64, seed 7: disjoint from
  the test seeds; cached in ``--cache``), Mitsuba's against its ``--ref-spp`` reference
  (seed 1). ``ratio_own`` = rstrace's mean / Mitsuba's.
* ``mitsuba_ref``: today's measure, both against Mitsuba's reference (the goal sentence as
  the bench row reads it); ``ratio_mitsuba_ref``.
* ``bias``: rstrace's converged frame against Mitsuba's converged frame (printed once): the
  floor under rstrace's ``mitsuba_ref`` error that no sampling removes.

Mitsuba's error at a CPU time is read from power-law curves ``rel = c spp^k`` fitted over
12-96 spp, one per seed (seeds 10..15: disjoint from the reference's), at the spp of
rstrace's median CPU time (Mitsuba's CPU time per sample: the median of three 64 spp
renders); its mean and standard error are over the 6 seeds' curves, rstrace's over its
``--seeds`` frames, a ratio's by first-order propagation of both. Both references carry noise
of their own (rstrace's 64 x 64: 256 times the glossy rays of 1 x 16; Mitsuba's 4096 spp:
70-120 times its equal-time frames' 35-60 spp), which slightly raises every ``own`` error
(session 35: under 2%) and is part of the ``bias`` row (there about a fifth: docs/glossy.md,
"session 35 (ownref)").

``--ref-noise`` renders a second reference of each (rstrace seed 8, Mitsuba seed 2) and
prints ``rstrace_ref_seeds`` / ``mitsuba_ref_seeds`` (one reference against the other of the
same renderer: about sqrt 2 times one reference's noise, as mean relative errors add
roughly in quadrature) and ``bias_of_means`` (the two references' means against each other:
half the noise of either reference in the bias row).
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
from rstrace_engine.tracing.whitted import render


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("allocations", nargs="+", help="S:G (pixel samples : glossy samples)")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--own-reference", action="store_true",
                    help="each renderer against its own converged reference too (docstring)")
    ap.add_argument("--rstrace-ref", default="64:64", help="S:G of rstrace's own reference")
    ap.add_argument("--ref-noise", action="store_true",
                    help="with --own-reference: a second reference of each (docstring)")
    ap.add_argument("--cache", default="/tmp/ownref-cache", help="where the references are kept")
    a = ap.parse_args()
    if a.own_reference:
        return own_reference(a)
    scene = scenes.rough_materials(a.width, a.height)
    acc = create_accelerator("BVH", scene.arrays())
    mi, ms = fr.mitsuba_rough(scene, a.width, a.height)
    ref, _ = fr._mitsuba_render(mi, ms, a.ref_spp, seed=1)
    lr = fr._luminance(ref)

    def rel(img):
        return float(np.mean(np.abs(fr._luminance(img) - lr) / (lr + fr.REL_EPS)))

    t0 = time.process_time()
    fr._mitsuba_render(mi, ms, 64, seed=99)
    per_spp = (time.process_time() - t0) / 64
    for al in a.allocations:
        s, g = map(int, al.split(":"))
        st = RenderSettings(max_depth=5, samples=s, glossy_samples=g).validated()
        render(scenes.rough_materials(16, 12), st)  # compiles
        rr, ts = [], []
        for k in range(a.seeds):
            c = time.process_time()
            f = render(scene, replace(st, seed=100 + k), accel=acc)
            ts.append(time.process_time() - c)
            rr.append(rel(f.radiance.astype(np.float64)))
        t = float(np.median(ts))
        spp = max(1, round(t / per_spp))
        mr, mt = [], []
        for k in range(6):
            img, secs = fr._mitsuba_render(mi, ms, spp, seed=k, clock=time.process_time)
            mr.append(rel(img))
            mt.append(secs)
        sys.stdout.write(json.dumps(dict(
            samples=s, glossy=g, cpu_s=round(t, 4), rel=round(float(np.mean(rr)), 5),
            rel_se=round(float(np.std(rr, ddof=1) / np.sqrt(len(rr))), 5), mitsuba_spp=spp,
            mitsuba_cpu_s=round(float(np.median(mt)), 4), mitsuba_rel=round(float(np.mean(mr)), 5),
            mitsuba_rel_se=round(float(np.std(mr, ddof=1) / np.sqrt(6)), 5),
            ratio=round(float(np.mean(rr) / np.mean(mr)), 3))) + "\n")
        sys.stdout.flush()


def power_fit(spps, errs) -> tuple[float, float]:
    """``(k, log c)`` of the least-squares line of ``log err`` on ``log spp``: err = c spp^k."""
    k, icpt = np.polyfit(np.log(np.asarray(spps, np.float64)),
                         np.log(np.asarray(errs, np.float64)), 1)
    return float(k), float(icpt)


def power_at(fit: tuple[float, float], spp: float) -> float:
    """The fitted error of :func:`power_fit`'s ``fit`` at ``spp`` samples per pixel."""
    return float(np.exp(fit[1] + fit[0] * np.log(spp)))


def mean_se(xs) -> tuple[float, float]:
    """Mean and its standard error (sample standard deviation / sqrt n; 0 for one value)."""
    x = np.asarray(xs, np.float64)
    se = float(np.std(x, ddof=1) / np.sqrt(x.size)) if x.size > 1 else 0.0
    return float(np.mean(x)), se


def ratio_se(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    """``a / b`` of two independent (mean, standard error) pairs and its standard error to
    first order: r sqrt((se_a / a)^2 + (se_b / b)^2)."""
    r = a[0] / b[0]
    return r, abs(r) * float(np.hypot(a[1] / a[0], b[1] / b[0]))


def _cached(path: str, make):
    if os.path.exists(path):
        return np.load(path)
    img = make()
    os.makedirs(os.path.dirname(path), exist_ok=True)
    np.save(path, img)
    return img


def own_reference(a) -> None:
    """``--own-reference``: the module docstring says what each number measures."""
    say(dict(load=os.getloadavg()))
    scene = scenes.rough_materials(a.width, a.height)
    acc = create_accelerator("BVH", scene.arrays())
    mi, ms = fr.mitsuba_rough(scene, a.width, a.height)
    tag = f"{a.width}x{a.height}"
    mref = _cached(f"{a.cache}/mitsuba_{tag}_{a.ref_spp}.npy",
                   lambda: fr._mitsuba_render(mi, ms, a.ref_spp, seed=1)[0])
    rs, rg = map(int, a.rstrace_ref.split(":"))
    rst = RenderSettings(max_depth=5, samples=rs, glossy_samples=rg, seed=7).validated()
    rref = _cached(f"{a.cache}/rstrace_{tag}_{rs}x{rg}.npy",
                   lambda: render(scene, rst, accel=acc).radiance.astype(np.float64))
    glass = fr.material_pixels(scene, "glass", rst, acc)
    masks = {"": None, "_no_glass": glass}

    def rel(img, ref, skip):
        return fr.error_stats(img, ref, skip)["rel_mean"]

    say(dict(glass_pixels=int(glass.sum()), rstrace_ref=a.rstrace_ref, ref_spp=a.ref_spp,
             **{"bias" + m: round(rel(rref, mref, k), 5) for m, k in masks.items()}))
    if a.ref_noise:
        rref2 = _cached(f"{a.cache}/rstrace_{tag}_{rs}x{rg}_seed8.npy", lambda: render(
            scene, replace(rst, seed=8), accel=acc).radiance.astype(np.float64))
        mref2 = _cached(f"{a.cache}/mitsuba_{tag}_{a.ref_spp}_seed2.npy",
                        lambda: fr._mitsuba_render(mi, ms, a.ref_spp, seed=2)[0])
        rm, mm = (rref + rref2) / 2, (mref + mref2) / 2
        say({k + m: round(v, 5) for m, sk in masks.items() for k, v in (
            ("rstrace_ref_seeds", rel(rref2, rref, sk)),
            ("mitsuba_ref_seeds", rel(mref2, mref, sk)),
            ("bias_of_means", rel(rm, mm, sk)))})
    per_spp = fr.mitsuba_cpu_per_spp(mi, ms)
    spps = (12, 16, 24, 32, 48, 64, 96)
    errs = {m: np.zeros((6, len(spps))) for m in masks}
    for i, spp in enumerate(spps):
        for k in range(6):
            img = fr._mitsuba_render(mi, ms, spp, seed=10 + k)[0]
            for m, sk in masks.items():
                errs[m][k, i] = rel(img, mref, sk)
    fits = {m: [power_fit(spps, e[k]) for k in range(6)] for m, e in errs.items()}
    say(dict(mitsuba_per_spp_cpu_s=round(per_spp, 6), slopes={
        m: round(float(np.mean([f[0] for f in fs])), 3) for m, fs in fits.items()}))
    for al in a.allocations:
        s, g = map(int, al.split(":"))
        st = RenderSettings(max_depth=5, samples=s, glossy_samples=g).validated()
        render(scenes.rough_materials(16, 12), st)  # compiles
        ts, own, mref_err = [], {m: [] for m in masks}, {m: [] for m in masks}
        for k in range(a.seeds):
            c = time.process_time()
            f = render(scene, replace(st, seed=100 + k), accel=acc)
            ts.append(time.process_time() - c)
            img = f.radiance.astype(np.float64)
            for m, sk in masks.items():
                own[m].append(rel(img, rref, sk))
                mref_err[m].append(rel(img, mref, sk))
        t = float(np.median(ts))
        spp = t / per_spp
        row = dict(alloc=al, cpu_s=round(t, 4), mitsuba_spp=round(spp, 1))
        for m in masks:
            mit = mean_se([power_at(f, spp) for f in fits[m]])
            for name, vals in (("own", own[m]), ("mitsuba_ref", mref_err[m])):
                r = mean_se(vals)
                q = ratio_se(r, mit)
                row[f"{name}{m}"] = dict(rstrace=_r(r), mitsuba=_r(mit), ratio=_r(q, 3))
        row["load"] = os.getloadavg()
        say(row)


def _r(pair, n: int = 5) -> list:
    return [round(pair[0], n), round(pair[1], n)]


def say(d: dict) -> None:
    sys.stdout.write(json.dumps(d) + "\n")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
