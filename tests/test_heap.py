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

# a soft-lit tile's arrays (session 34): 240 MB in all, two of them past glibc's 32 MiB mmap
# threshold, as 2.2M soft shadow samples' origins, directions and the rays traced of them;
# numpy's huge-page advice off, so that the faults count pages (not 2 MiB huge pages)
SOFT_CHILD = r"""
import ctypes, json, resource
import numpy as np
from rstrace_engine import heap
try:
    np.core.multiarray._set_madvise_hugepage(False)
except AttributeError:
    pass
# no transparent huge pages for this process (PR_SET_THP_DISABLE): systems that back the heap
# with them ('always', or glibc.malloc.hugetlb) count 2 MiB faults, not pages
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)
kept = heap.keep()
def tile():
    big = [np.ones((2_200_000, 3)) for _ in range(2)]            # 50 MiB each
    small = [np.ones(2_200_000) for _ in range(8)]               # 17 MiB each
    return sum(float(a[-1].sum()) for a in big + small)
faults = []
for _ in range(4):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    tile()
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
print(json.dumps({"kept": kept, "faults": faults}))
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


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heap (Linux)")
def test_heap_keeps_a_soft_tiles_arrays():
    """A soft-lit tile's 240 MB of arrays (past TOP_PAD, two past the mmap threshold) land on
    pages already touched once the heap has grown to them: it is not trimmed between tiles
    (before session 34, glibc's 128 KiB trim threshold gave it back after every tile: every
    round faulted on 43,773 pages, as museum_soft's 100,000 faults a frame). The second round
    still grows the heap (the first round's two large blocks came from mmap, the second's
    from the heap's top, measured 25,781 faults); the rounds after it take none."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for k in ("MALLOC_TOP_PAD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_",
              "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES"):
        env.pop(k, None)
    out = subprocess.run([sys.executable, "-c", SOFT_CHILD], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    if not r["kept"]:
        pytest.skip("not glibc: the heap's thresholds are the C library's")
    pages = (2 * 2_200_000 * 3 + 8 * 2_200_000) * 8 // 4096  # one round: 60,000 pages
    assert r["faults"][0] > pages // 2, r  # (the first round does touch fresh pages)
    assert max(r["faults"][2:]) < pages // 20, r
