"""``kernel_cache.load_cached``: a warm process loads a kernel's cached signatures into
memory without calling it (the add-on's background load before a first F12,
``addon/kernels.py``), loading only what this process's target can run and compiling
nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

from test_kernel_cache import KERNELS, ROOT

FILL = textwrap.dedent('''
    import sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    import tinykernels as k
    if sys.argv[2] == "host":
        k.axpy(np.int64(3), np.int64(4), np.int64(5))
        k.axpy(1.5, 2.0, 0.25)
        k.scaled(np.arange(4, dtype=np.float32), 0.5)
    else:  # the portable target's entry of one more signature
        k.axpy(np.float32(1), np.float32(2), np.float32(3))
''')

LOAD = textwrap.dedent('''
    import json, sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    import tinykernels as k
    from rstrace_engine import kernel_cache
    loaded = {name: kernel_cache.load_cached(getattr(k, name))
              for name in ("axpy", "scaled", "total")}
    in_memory = {name: len(getattr(k, name).signatures) for name in loaded}
    again = kernel_cache.load_cached(k.axpy)
    after_load = kernel_cache.counts("tinykernels")
    assert k.axpy(np.int64(3), np.int64(4), np.int64(5)) == 17
    assert k.axpy(1.5, 2.0, 0.25) == 3.25
    assert float(k.scaled(np.arange(4, dtype=np.float32), 0.5).sum()) == 3.0
    calls = kernel_cache.counts("tinykernels")
    print("RESULT " + json.dumps(dict(loaded=loaded, in_memory=in_memory, again=again,
                                      after_load=after_load["loaded"],
                                      compiled=after_load["compiled"],
                                      calls_loaded=calls["loaded"],
                                      calls_compiled=calls["compiled"])))
''')


def _run(script: str, folder, cache, *args, **env) -> str:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT), **env)
    env = {k: v for k, v in env.items() if v is not None}
    proc = subprocess.run([sys.executable, "-c", script, str(folder), *args], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return proc.stdout


def test_load_cached_loads_this_targets_signatures_and_compiles_nothing(tmp_path):
    folder, cache = tmp_path / "kernels", tmp_path / "cache"
    folder.mkdir()
    (folder / "tinykernels.py").write_text(KERNELS)
    host = {k: None for k in os.environ if k.startswith("NUMBA_CPU")}
    _run(FILL, folder, cache, "host", **host)
    _run(FILL, folder, cache, "generic", NUMBA_CPU_NAME="generic")
    out = _run(LOAD, folder, cache, **host)
    r = json.loads([ln for ln in out.splitlines() if ln.startswith("RESULT ")][-1][7:])
    # axpy: its two host signatures, not the generic CPU's float32 one; total: never cached
    assert r["loaded"] == {"axpy": 2, "scaled": 1, "total": 0}, r
    assert r["in_memory"] == {"axpy": 2, "scaled": 1, "total": 0}, r
    assert r["again"] == 0  # in memory already
    assert r["after_load"] == 3 and r["compiled"] == 0, r
    # the calls run what was loaded: nothing more loaded, nothing compiled
    assert r["calls_loaded"] == 3 and r["calls_compiled"] == 0, r
