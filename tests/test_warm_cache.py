"""``python -m rstrace_engine warm-cache``: the command's counts, its parallel parts (their
reports read whatever their size, one per usable core, none outliving a killed parent).
The cache the parts share is :mod:`test_kernel_cache`'s subject."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_warm_cache_command_reports_compiled_and_loaded_kernels():
    """``python -m rstrace_engine warm-cache`` twice: the second run compiles nothing.

    Uses this checkout's default cache (beside the sources), which the other tests share: a
    cold checkout pays the compile once here instead of in the first test that renders.
    """
    cmd = [sys.executable, "-m", "rstrace_engine", "warm-cache", "--json"]
    # (and the machine's own thread count: with NUMBA_NUM_THREADS=1 the BVH build never
    # calls its parallel collapse, so the warm-up leaves those kernels unreached)
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "NUMBA_NUM_THREADS")}
    runs = []
    for _ in range(2):
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                              timeout=900)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
        runs.append(json.loads(proc.stdout))
    warm = runs[1]
    print({k: warm[k] for k in ("kernels", "compiled", "loaded", "seconds", "unreached")})
    assert warm["compiled"] == 0 and warm["loaded"] > 20
    assert set(warm["modes"]) >= {"BASE", "INTERPOLANT"}
    # what the warm-up does not reach is no render kernel: the brute-force reference
    # accelerator (tests only) and linetree helpers used by the tests, not by renders
    assert set(warm["unreached"]) <= {
        "rstrace_engine.accel.accelerators._brute_kernel",
        "rstrace_engine.interpolants.linetree.descend",
        "rstrace_engine.interpolants.linetree.local_coords",
        "rstrace_engine.interpolants.linetree.parameterize",
        # the visibility field's batch direction look-up (directions.lookup): tests and
        # tools only; the tracing kernel inlines nearest_direction
        "rstrace_engine.accel.directions.nearest_directions",
        # the visibility field's parallel rasteriser: only for l x triangles >= 2M (a big
        # scene's build), compiled by the first such build
        "rstrace_engine.accel.tiles.raster_parallel",
        # the rough glass albedo's quadrature: scripts/ggx_glass_tables.py and tests (the
        # shader reads the tables it wrote)
        "rstrace_engine.tracing.glass_albedo.ggx_glass_albedo_quadrature",
        # GGX's whole-sample functions, which that quadrature and the tests call: the
        # glossy rays take their halves (ggx_sample_frame/_at, ggx_weight_lo; session 42)
        "rstrace_engine.tracing.ggx_sampling.ggx_vndf",
        "rstrace_engine.tracing.ggx_sampling.ggx_sample_normal",
        "rstrace_engine.tracing.ggx_sampling.ggx_weight",
        # the binary boxes' ulp padding as a pass of its own: tests only (a mesh's collapse
        # pads each box as it reads it, bvh_collapse.collapse4's ``pad``)
        "rstrace_engine.accel.bvh_collapse.pad_outward",
        # the Principled BRDF and GGX's albedo as whole functions: the bench's Mitsuba
        # tables and the tests (renders call principled_brdf_z and read dielectric_albedos'
        # quadrature); in the suite the tests before this one compile them into the shared
        # cache, so the list passed there while a cold run of this test alone failed
        "rstrace_engine.tracing.shading.principled_brdf",
        "rstrace_engine.tracing.shading.ggx_albedo",
        }  # the BVH build's parallel kernels are reached: warm_kernels._warm_large_bvh


def test_parallel_warm_up_reads_parts_whose_report_outgrows_a_pipe(tmp_path, monkeypatch):
    """A part's JSON report lists every signature it compiled: from a cold cache it grew past
    a pipe's 64 KiB, and the parent, which read nothing until every part had ended, waited on
    a part blocked writing it (the cold warm-cache test timing out). Each part here reports
    200 KiB; the warm-up must finish and sum the parts."""
    import signal

    from rstrace_engine import child_python, warm_kernels

    report = {"compiled": 3, "loaded": 2,
              "compiled_kernels": {f"k{i}": ["x" * 200] for i in range(1000)}}
    part = tmp_path / "part.py"
    part.write_text(f"import json, sys\nsys.stderr.write('w' * 200000)\n"
                    f"print(json.dumps({report!r}))\n")
    exe = tmp_path / "python-part"  # stands for the Python that runs `-m rstrace_engine ...`
    exe.write_text(f"#!/bin/sh\nexec {sys.executable} {part}\n")
    exe.chmod(0o755)
    monkeypatch.setattr(child_python, "python", lambda: str(exe))

    def hang(*_):
        raise TimeoutError("the warm-up waited on parts blocked on their output")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(60)
    try:
        out = warm_kernels.warm_parallel(jobs=2, modes=["BASE"], accelerators=["BVH"],
                                         report_unreached=False, poll_s=0.05)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    assert out["jobs"] == 2 and out["compiled"] == 6 and out["loaded"] == 4
    assert len(out["compiled_kernels"]["k0"]) == 2


def test_usable_cores_follow_the_affinity(monkeypatch):
    """warm-cache starts one process per CPU this process may run on (a container's or
    taskset's limit), not per CPU of the machine."""
    from rstrace_engine import kernel_cache

    monkeypatch.setattr(os, "cpu_count", lambda: 16)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    assert kernel_cache.usable_cores() == 1
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)  # (macOS, Windows)
    assert kernel_cache.usable_cores() == 16


def _children(pid: int) -> list[int]:
    """The live processes whose parent is ``pid`` (Linux ``/proc``)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after the command's name
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2:].split()[0] != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_parts_of_a_killed_warm_up_end_with_it(tmp_path):
    """A parallel ``warm-cache`` killed outright (SIGKILL: no clean-up runs, as when a
    test's timeout or a crash ends it) leaves no part compiling on: each part watches its
    parent and ends within seconds. On an empty cache a part compiles for minutes, so a part
    still alive 30 s after its parent died is one that does not watch."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    parent = subprocess.Popen([sys.executable, "-m", "rstrace_engine", "warm-cache", "--json",
                               "--jobs", "2", "--modes", "BASE", "--accelerators", "BVH"],
                              cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        parts = []
        while len(parts) < 2 and time.monotonic() < deadline and parent.poll() is None:
            time.sleep(0.2)
            parts = _children(parent.pid)
        assert len(parts) == 2, f"the warm-up started {len(parts)} parts"
        # killed at once: the parts are still importing (orphaned before they look)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in parts) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p for p in parts if _alive(p)]
    for p in left:
        os.kill(p, 9)
    assert not left, f"parts {left} still compiling after their parent was killed"
