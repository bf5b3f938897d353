"""One kernel's cold compile, callees included, with LLVM's phases timed.

    NUMBA_CACHE_DIR=<warm cache> python scripts/compile_one.py sigs MODULE KERNEL FILE
    NUMBA_CACHE_DIR=<empty dir>  python scripts/compile_one.py compile MODULE KERNEL FILE

``sigs`` writes (pickle) the signatures a warm cache's index holds for the kernel (the
index of the cache current for these sources: run it where the kernel was compiled);
``compile`` compiles each of them in this process (an empty cache: every callee compiles
too) and prints the process CPU of it and, summed over every code library finalised
(numba's own overloads too), the CPU of LLVM's function passes, of the module passes on the
library's final module (its callees' modules linked in), of machine code (MCJIT's
``finalize_object``), and the megabytes of LLVM IR text each of the last two were given,
then the libraries with the most machine-code CPU. e.g. the error predicate's chain:
``rstrace_engine.interpolants.predicate _check_cells`` (docs/first-render.md, session 32).
"""

from __future__ import annotations

import collections
import importlib
import pickle
import sys
import time


def _timed(cls, meth, key, totals, counts, by_lib, size=None):
    f = getattr(cls, meth)

    def g(self, *a, **k):
        if size is not None:
            totals[size] += len(str(self._final_module)) / 1e6
        t = time.process_time()
        try:
            return f(self, *a, **k)
        finally:
            dt = time.process_time() - t
            totals[key] += dt
            counts[key] += 1
            by_lib[key][self.name] += dt
    setattr(cls, meth, g)


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")


def main(argv: list[str]) -> None:
    what, module, name, path = argv
    from rstrace_engine import kernel_cache
    kernel_cache.install()
    from numba.core import codegen as cg
    kernel = getattr(importlib.import_module(module), name)
    if what == "sigs":
        sigs = [key[0] for key in kernel._cache._cache_file._load_index()]
        with open(path, "wb") as f:
            pickle.dump(sigs, f)
        _say(f"{name}: {len(sigs)} signature(s) written to {path}")
        return
    totals, counts = collections.defaultdict(float), collections.Counter()
    by_lib = collections.defaultdict(lambda: collections.defaultdict(float))
    _timed(cg.CPUCodeLibrary, "_optimize_functions", "function passes", totals, counts,
           by_lib)
    _timed(cg.CPUCodeLibrary, "_optimize_final_module", "module passes (callees linked)",
           totals, counts, by_lib, size="IR MB through module passes")
    _timed(cg.JITCodeLibrary, "_finalize_specific", "machine code", totals, counts, by_lib,
           size="IR MB to machine code")
    with open(path, "rb") as f:
        sigs = pickle.load(f)
    t = time.process_time()
    for sig in sigs:
        kernel.compile(sig)
    _say(f"{name}: compile CPU {time.process_time() - t:.2f} s "
          f"({counts['machine code']} libraries)")
    for key in sorted(totals, key=totals.get, reverse=True):
        _say(f"  {key:32s} {totals[key]:7.2f}" + (" s" if "MB" not in key else ""))
    lib = by_lib["machine code"]
    for k in sorted(lib, key=lib.get, reverse=True)[:10]:
        _say(f"    machine code {lib[k]:6.2f} s  {k[:80]}")


if __name__ == "__main__":
    main(sys.argv[1:])
