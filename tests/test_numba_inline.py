"""numba's inliner copying a callee's IR once (rstrace_engine/numba_inline.py): installed on
this numba, the copy linear in the callee's size, and the compiled code the same as numba's
own inlining gives."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from numba.core import ir

import rstrace_engine  # noqa: F401  (installs it)
from rstrace_engine import numba_inline

ROOT = Path(__file__).resolve().parents[1]

# a callee of many blocks and variables, inlined at two call sites, itself inlining another
KERNELS = '''
import numpy as np
from numba import njit


@njit(inline="always")
def _leaf(a, b):
    if a > b:
        return a - b
    return b - a


@njit(inline="always")
def _branchy(x, n):
    s = 0.0
    t = 1.0
    for i in range(n):
        v = x[i]
        if v > 0.5:
            s += v * t
        elif v > 0.25:
            s -= _leaf(v, t)
        elif v > 0.125:
            t *= 1.5
        else:
            t = 0.5 * t + v
        if s > 100.0:
            s = 0.0
        u = s + t
        w = u * u - s
        if w < 0.0:
            s = -s
    return s, t


@njit
def kernel(x, n):
    a, b = _branchy(x, n)
    c, d = _branchy(x[::-1].copy(), n)
    return a + b + c + d
'''


def test_installed_on_this_numba():
    assert numba_inline.installed()


def test_a_callee_is_copied_once_not_once_per_block(monkeypatch):
    """Inlining copies the callee's variables a bounded number of times, not once per block
    of the callee (numba's own copy: every block's copy held all the callee's variables)."""
    namespace = {}
    exec(compile(KERNELS, "<kernels>", "exec"), namespace)  # noqa: S102  (fresh functions)
    copies = [0]
    deepcopy = ir.Var.__deepcopy__

    def counted(self, memo):
        copies[0] += 1
        return deepcopy(self, memo)

    monkeypatch.setattr(ir.Var, "__deepcopy__", counted)
    x = np.linspace(0.0, 1.0, 16)
    assert np.isfinite(namespace["kernel"](x, 16))
    from numba.core.compiler import run_frontend

    body = run_frontend(namespace["_branchy"].py_func)
    blocks, variables = len(body.blocks), len(body.blocks[min(body.blocks)].scope.localvars)
    assert blocks >= 10 and variables >= 20
    # two call sites of _branchy (each inlining _leaf), each copied twice (the callee and
    # numba's unmutated original): once per copy is ~4 x (variables of both) at most
    assert copies[0] <= 8 * (variables + 10), (copies[0], blocks, variables)


def _llvm(inline: str) -> str:
    code = (KERNELS + "\nimport numpy as np\nimport rstrace_engine\n"
            "from rstrace_engine import numba_inline\n"
            "kernel(np.linspace(0.0, 1.0, 16), 16)\n"
            "print('INSTALLED', numba_inline.installed())\n"
            "print(kernel.inspect_llvm(kernel.signatures[0]))\n")
    env = dict(os.environ, RSTRACE_NUMBA_INLINE=inline, PYTHONHASHSEED="0",
               PYTHONPATH=os.pathsep.join([str(ROOT)] + sys.path))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, timeout=300).stdout
    assert f"INSTALLED {inline == '1'}" in out
    # (names that hold a memory address differ between any two processes)
    return re.sub(r"0x[0-9a-f]+", "", out.split("\n", 1)[1])


def test_the_compiled_code_is_numbas_own():
    """The kernel's LLVM IR with this copy is the one numba's own inlining gives."""
    assert _llvm("1") == _llvm("0")
