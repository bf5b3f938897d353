"""The extension's shipped kernels (issue 25): used only when they fit this Blender (numba,
llvmlite, Python and engine versions, this platform); otherwise the reason is kept and the
kernels compile on first use, never a crash. Each case runs in a fresh process: choosing the
portable CPU target changes numba's state for the whole process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

CHECK = textwrap.dedent('''
    import importlib.util, json, os, sys
    # addon/runtime.py alone, as the add-on's __init__ runs it: before any kernel module
    spec = importlib.util.spec_from_file_location("runtime", sys.argv[3])
    runtime = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(runtime)
    import numba
    numba.config.CACHE_DIR = sys.argv[2]  # as runtime.configure does
    why = runtime._use_shipped(sys.argv[1], sys.argv[2])
    numba.core.config.reload_config()  # as numba does before each compile
    print("RESULT " + json.dumps(dict(why=why, target=runtime.kernel_target(),
                                      cpu=numba.config.CPU_NAME,
                                      env=os.environ.get("NUMBA_CPU_NAME"),
                                      cache_dir=numba.config.CACHE_DIR,
                                      stamp=runtime._state["manifest_stamp"])))
''')


def _check(shipped: Path, cache: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    env["PYTHONPATH"] = str(ROOT)
    proc = subprocess.run([sys.executable, "-c", CHECK, str(shipped), str(cache),
                           str(ROOT / "addon" / "runtime.py")], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=300)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stdout[-2000:] + proc.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT "):])


def _manifest(folder: Path, **changes) -> Path:
    from rstrace_engine import shipped_kernels

    folder.mkdir(parents=True, exist_ok=True)
    m = shipped_kernels.build_manifest("linux-x64", True)
    m.update(cpu="generic", **changes)
    (folder / shipped_kernels.MANIFEST).write_text(json.dumps(m))
    return folder


@pytest.mark.parametrize("case, words", [
    ("missing", "no compiled kernels ship"),
    ("other_platform", "cannot compile for windows-x64"),
    ("other_numba", "another numba 0.0.1"),
    ("other_version", "another version 0.0.0"),
    ("corrupt", "unreadable")])
def test_unusable_shipped_kernels_say_why_and_compile_on_first_use(tmp_path, case, words):
    shipped = tmp_path / "kernel_cache"
    if case == "other_platform":
        _manifest(shipped, shipped=False, platform="windows-x64",
                  reason="built on linux-x64, which cannot compile for windows-x64")
    elif case == "other_numba":
        _manifest(shipped, numba="0.0.1")
    elif case == "other_version":
        _manifest(shipped, version="0.0.0")
    elif case == "corrupt":
        shipped.mkdir()
        (shipped / "rstrace-kernels.json").write_text("{not json")
    r = _check(shipped, tmp_path / "cache")
    assert words in r["why"], r
    assert r["target"] is None and r["cpu"] is None and r["env"] is None  # host, as before


def test_usable_shipped_kernels_then_this_cpus_after_a_background_compile(tmp_path):
    from addon import runtime

    shipped = _manifest(tmp_path / "kernel_cache")
    cache = tmp_path / "cache"
    cache.mkdir()
    r = _check(shipped, cache)
    assert r["why"] == "" and r["target"] == "generic"
    assert r["cpu"] == "generic" and r["env"] is None  # config only (see use_portable_target)
    assert r["cache_dir"] == str(cache)  # not dropped by numba re-reading its environment
    # what the background compile writes when it has compiled every kernel for this CPU
    import llvmlite.binding as ll

    (cache / runtime.HOST_MARKER).write_text(f"{ll.get_host_cpu_name()}\n{r['stamp']}")
    host = _check(shipped, cache)
    assert host["target"] == "host" and host["cpu"] is None and host["env"] is None
    # a marker of another build (another manifest) does not count
    (cache / runtime.HOST_MARKER).write_text(f"{ll.get_host_cpu_name()}\nother")
    assert _check(shipped, cache)["target"] == "generic"
