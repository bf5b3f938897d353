"""Where a cold compile goes: run a command, list numba's compiles by kernel.

    python scripts/compile_profile.py [--out DIR] [--top N] -- COMMAND...

e.g. ``NUMBA_CACHE_DIR=/tmp/empty python scripts/compile_profile.py -- python -m
rstrace_engine warm-cache --modes BASE INTERPOLANT --accelerators BVH --no-soft-light``.

Every Python process the command starts (``warm-cache``'s parts too: they inherit
``PYTHONPATH``) imports a ``sitecustomize`` that listens to numba's ``numba:compile``
events and writes, at exit, one JSON file per process into ``DIR``: each compile's kernel,
signature, start time, wall and CPU time *exclusive* of the compiles nested in it (a callee
compiled while its caller is typed), its nesting depth, the CPU time of it spent in LLVM
(llvmlite's C calls: optimising, linking and machine code; the rest is numba's Python
passes) and how many call sites numba inlined into it (``inline="always"`` callees,
counted at every level of nesting). The report sums them by kernel (docs/KERNELS.md,
*Cutting the cold compile*; docs/first-render.md). A process killed before it exits writes
nothing (SIGTERM is an exit: it writes). Loads from the cache are not compiles and are not listed.
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import os
import subprocess
import sys
import tempfile
import time

SITECUSTOMIZE = '''
import os
if os.environ.get("RSTRACE_COMPILE_PROFILE"):
    import atexit, json, sys, time
    from numba.core import event
    _stack, _rows = [], []
    _t0w, _t0c, _t0abs = time.perf_counter(), time.process_time(), time.time()
    # [start wall, start CPU, nested wall, nested CPU, LLVM CPU, inlined call sites]
    try:  # LLVM's share: every llvmlite C call, timed (a few microseconds each)
        from llvmlite.binding import ffi as _ffi
        _call = _ffi._lib_fn_wrapper.__call__

        def _timed(self, *a, **k):
            if not _stack:
                return _call(self, *a, **k)
            t = time.process_time()
            try:
                return _call(self, *a, **k)
            finally:
                _stack[-1][4] += time.process_time() - t
        _ffi._lib_fn_wrapper.__call__ = _timed
    except (ImportError, AttributeError):
        pass
    try:
        from numba.core import inline_closurecall as _icc
        _inline = _icc.InlineWorker.inline_function

        def _counted(self, *a, **k):
            if _stack:
                _stack[-1][5] += 1
            return _inline(self, *a, **k)
        _icc.InlineWorker.inline_function = _counted
    except (ImportError, AttributeError):
        pass

    class _Listener(event.Listener):
        def on_start(self, ev):
            _stack.append([time.perf_counter(), time.process_time(), 0.0, 0.0, 0.0, 0])

        def on_end(self, ev):
            s = _stack.pop()
            w, c = time.perf_counter() - s[0], time.process_time() - s[1]
            if _stack:
                _stack[-1][2] += w
                _stack[-1][3] += c
            d = (ev.data or {}).get("dispatcher")
            name = (f"{d.py_func.__module__}.{d.py_func.__qualname__}" if d is not None
                    else "?")
            par = bool(d.targetoptions.get("parallel")) if d is not None else False
            args = (ev.data or {}).get("args") or ()
            nrt = d.targetoptions.get("_nrt", True) is not False if d is not None else True
            _rows.append(dict(kernel=name, parallel=par, wall=w - s[2], cpu=c - s[3],
                              llvm=s[4], inlined=s[5], nrt=nrt,
                              depth=len(_stack), at=s[0] - _t0w,
                              signature=", ".join(str(a) for a in args)))

    event.register("numba:compile", _Listener())
    import signal
    # a process stopped by SIGTERM (make demo's background warm-up) writes its file too
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(143))

    def _dump():
        path = os.path.join(os.environ["RSTRACE_COMPILE_PROFILE"], f"{os.getpid()}.json")
        kc = sys.modules.get("rstrace_engine.kernel_cache")  # waits for others' compiles
        waits = [[n, t - _t0abs, s] for n, t, s in getattr(kc, "CLAIM_WAITS", ())]
        with open(path, "w") as f:
            json.dump(dict(argv=sys.argv, wall=time.perf_counter() - _t0w,
                           cpu=time.process_time() - _t0c, started=_t0abs,
                           compiles=_rows, waits=waits), f)

    atexit.register(_dump)
'''


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")


def report(folder: str, top: int) -> None:
    # kernel: [CPU, signatures, parallel, LLVM CPU, inlined sites, NRT]
    by_kernel = collections.defaultdict(lambda: [0.0, 0, False, 0.0, 0, True])
    total = llvm = 0.0
    for path in sorted(glob.glob(os.path.join(folder, "*.json"))):
        with open(path) as f:
            d = json.load(f)
        mine = sum(r["cpu"] for r in d["compiles"])
        total += mine
        waits = d.get("waits", [])
        _say(f"process {' '.join(d['argv'])[:90]}: wall {d['wall']:.1f} s, CPU "
              f"{d['cpu']:.1f} s, compiling {mine:.1f} s ({len(d['compiles'])} compiles), "
              f"waiting {sum(w[2] for w in waits):.1f} s for {len(waits)} of other "
              "processes' compiles")
        for r in d["compiles"]:
            k = by_kernel[r["kernel"]]
            k[0] += r["cpu"]
            k[1] += 1
            k[2] = r["parallel"]
            k[3] += r.get("llvm", 0.0)
            k[4] += r.get("inlined", 0)
            k[5] = r.get("nrt", True)
            llvm += r.get("llvm", 0.0)
    _say(f"compile CPU {total:.1f} s ({llvm:.1f} s in LLVM) in "
         f"{sum(k[1] for k in by_kernel.values())} signatures of {len(by_kernel)} functions; "
         "the largest (P: parallel, N: reference counting off; inl: call sites inlined):")
    for name, (cpu, n, par, ll, inl, nrt) in sorted(by_kernel.items(),
                                                    key=lambda x: -x[1][0])[:top]:
        _say(f"  {cpu:7.1f} s  llvm {ll:5.1f}  {n:2d} sig  inl {inl:3d}  "
             f"{'P' if par else ' '}{' ' if nrt else 'N'}  {name}")


def main(argv: list[str]) -> int:
    if "--" not in argv:
        _say(__doc__)
        return 2
    cut = argv.index("--")
    p = argparse.ArgumentParser(description="numba compile time by kernel")
    p.add_argument("--out", default=None, help="folder for the per-process JSON files")
    p.add_argument("--top", type=int, default=30)
    a = p.parse_args(argv[:cut])
    command = argv[cut + 1:]
    out = a.out or tempfile.mkdtemp(prefix="compile-profile-")
    os.makedirs(out, exist_ok=True)
    site = tempfile.mkdtemp(prefix="compile-profile-site-")
    with open(os.path.join(site, "sitecustomize.py"), "w") as f:
        f.write(SITECUSTOMIZE)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = [root, site] + [x for x in os.environ.get("PYTHONPATH", "").split(os.pathsep) if x]
    env = dict(os.environ, RSTRACE_COMPILE_PROFILE=out, PYTHONPATH=os.pathsep.join(path))
    t0 = time.perf_counter()
    rc = subprocess.call(command, env=env)
    _say(f"command: rc {rc}, {time.perf_counter() - t0:.1f} s wall; profiles in {out}")
    report(out, a.top)
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
