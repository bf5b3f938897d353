"""The C heap a frame leaves kept (rstrace_engine/heap.py, issue 20): after a BASE or an
INTERPOLANT frame, a batch's worth of arrays allocated, touched and freed again lands on
pages already touched -- glibc's default gives them back after every batch, and the
INTERPOLANT frames paid 5,000-26,000 page faults a frame for it (0.80x of the BASE frame's
CPU time with nothing interpolated). Counted in a fresh process: the heap's state is
the process's history."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# a frame (the mode's entry point), then four rounds of a batch's arrays (12 x 1.9 MB, as a
# 37,800-ray batch's shadow rays and surface points): the minor page faults of each round
CHILD = r"""
import json, resource, sys
import numpy as np
from rstrace_engine import heap, scenes
from rstrace_engine.frame import RenderSettings
sc = scenes.three_spheres(16, 12, subdivisions=1)
if sys.argv[1] == "base":
    from rstrace_engine.tracing.whitted import render
    render(sc, RenderSettings())
else:
    from rstrace_engine.accel.accelerators import create_accelerator
    from rstrace_engine.interpolants.render import InterpolantRenderer
    InterpolantRenderer().render(sc, RenderSettings(mode="INTERPOLANT", epsilon=0.01),
                                 create_accelerator("BVH", sc.arrays()))
def batch():
    arrs = [np.ones((80000, 3)) for _ in range(12)]
    return sum(float(a[-1, 0]) for a in arrs)
faults = []
for _ in range(4):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    batch()
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
print(json.dumps({"kept": heap.keep(), "faults": faults}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heap (Linux)")
@pytest.mark.parametrize("mode", ["base", "interpolant"])
def test_frame_keeps_heap(mode):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for k in ("MALLOC_TOP_PAD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_"):
        env.pop(k, None)
    out = subprocess.run([sys.executable, "-c", CHILD, mode], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    if not r["kept"]:
        pytest.skip("not glibc: the heap's thresholds are the C library's")
    pages = 12 * 80000 * 3 * 8 // 4096  # what one round touches: 5,625 pages
    # the rounds after the first reuse the heap's pages (without the frame keeping it:
    # every round faults on all of them, measured 5,600-5,700)
    assert max(r["faults"][1:]) < pages // 10, r
