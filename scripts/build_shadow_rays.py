"""What any-hit shadow rays would save in the cell builds of radiance interpolants (issue 8,
"use any-hit rays where the occluder's identity is not needed").

::

    python scripts/build_shadow_rays.py museum_1999 [--width 640 --height 480]

Renders the scene's first INTERPOLANT frame (epsilon 0.01, one thread) through an
accelerator that records every batch of shadow rays the builds trace with ``closest_hit``
(the ray trees name each occluder), then times the same batches with ``closest_hit`` and
with ``any_hit`` (best of 3) and prints the share of those rays that are occluded and what
any-hit would save, against the frame's build time and the frame. Only an upper bound: an
any-hit ray cannot name the occluder the predicate and the membership index need.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rstrace_engine import scenes  # noqa: E402
from rstrace_engine.accel.accelerators import create_accelerator  # noqa: E402
from rstrace_engine.frame import RenderSettings  # noqa: E402
from rstrace_engine.interpolants.render import InterpolantRenderer  # noqa: E402


class ShadowRecorder:
    """An accelerator that keeps the batches of shadow rays ``whitted.trace`` casts with
    ``closest_hit`` (recorded ray trees) and passes everything else through."""

    def __init__(self, accel):
        self._accel = accel
        self.batches: list = []

    def __getattr__(self, name):
        return getattr(self._accel, name)

    def closest_hit(self, o, d, tmin, tmax):
        caller = sys._getframe(1)
        if caller.f_code.co_name == "trace" and caller.f_locals.get("zero") is tmin:
            self.batches.append((o.copy(), d.copy(), tmin.copy(), tmax.copy()))
        return self._accel.closest_hit(o, d, tmin, tmax)


def _best(fn, repeat=3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("scene", nargs="?", default="museum_1999")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    args = p.parse_args(argv)
    import numba

    numba.set_num_threads(1)
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.01)
    warm = scenes.build(args.scene, 48, 36)  # compiles / loads the kernels, not timed
    InterpolantRenderer().render(warm, st, create_accelerator("BVH", warm.arrays()))
    sc = scenes.build(args.scene, args.width, args.height)
    accel = create_accelerator("BVH", sc.arrays())
    rec = ShadowRecorder(accel)
    t0 = time.process_time()
    frame = InterpolantRenderer().render(sc, st, rec)
    t_frame = time.process_time() - t0
    n = sum(len(b[0]) for b in rec.batches)
    occluded = sum(int(np.count_nonzero(accel.closest_hit(*b).inst >= 0)) for b in rec.batches)
    t_closest = _best(lambda: [accel.closest_hit(*b) for b in rec.batches])
    t_any = _best(lambda: [accel.any_hit(*b) for b in rec.batches])
    saved = t_closest - t_any
    t_build = frame.stats["build_s"]
    sys.stdout.write(
        f"{args.scene}: first frame {t_frame:.3f} s, builds {t_build:.3f} s; {n} build shadow "
        f"rays in {len(rec.batches)} batches, {occluded / max(n, 1):.1%} occluded; closest-hit "
        f"{1e3 * t_closest:.1f} ms, any-hit {1e3 * t_any:.1f} ms: any-hit would save "
        f"{1e3 * saved:.1f} ms ({saved / t_build:.1%} of the builds, {saved / t_frame:.1%} of "
        f"the frame)\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
