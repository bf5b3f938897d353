"""numba's ``inline="always"`` inliner made linear in the size of the callee.

Why: to inline a callee, numba 0.68 copies the callee's IR (``InlineWorker.inline_ir``'s
nested ``copy_ir``) block by block, a ``copy.deepcopy`` per block. Each block's variables
refer to the callee's one ``Scope``, which holds every variable of the callee, so every
block's copy copies the whole scope again: blocks x variables objects per inlined call site,
twice (the IR is copied again as the "unmutated original" it returns). For the BVH
traversal (30 inlined call sites, some of them large) this was half the compile: 12.0 ->
5.0 s of CPU (docs/first-render.md, *Where the compile goes, kernel by kernel*). The
problem is known upstream (numba/numba#8989, open; numba-cuda#688).

What: :func:`install` (called by ``kernel_cache.install()``, before any kernel compiles)
replaces the loop with one ``copy.deepcopy`` of the blocks together
(one memo: the scope, its variables and the blocks' statements copied once each). The
copy is the same IR (the same statements and variable names; the blocks share one copy of
the scope instead of each holding its own, and the inliner sets every inlined block's scope
to the caller's right after), so the compiled code is the same: ``tests/test_numba_inline.py``
compares the LLVM IR of kernels compiled with and without it (hence no kernel's cache key
depends on this file).

What it relies on: the exact source text of ``copy_ir`` in numba's
``numba/core/inline_closurecall.py`` (numba 0.56 to 0.68 at least). :func:`install`
changes nothing unless that text is found verbatim (another numba: inlining as numba does
it, only slower); ``RSTRACE_NUMBA_INLINE=0`` in the environment leaves numba alone too (to
compare).
"""

from __future__ import annotations

import inspect
import logging
import os
import textwrap

log = logging.getLogger(__name__)

_BLOCK_BY_BLOCK = """\
    kernel_copy.blocks = {}
    for block_label, block in the_ir.blocks.items():
        new_block = copy.deepcopy(the_ir.blocks[block_label])
        kernel_copy.blocks[block_label] = new_block
"""
_ALL_AT_ONCE = """\
    kernel_copy.blocks = copy.deepcopy(the_ir.blocks)  # rstrace: one memo (numba_inline.py)
"""

_STATE = {"installed": False}


def installed() -> bool:
    """Whether numba's inliner copies a callee's blocks at once in this process."""
    return _STATE["installed"]


def install() -> bool:
    """Make numba's ``copy_ir`` copy a callee's blocks at once (module doc). Returns
    whether it is (False: numba's code is not the text this relies on, or the environment
    says ``RSTRACE_NUMBA_INLINE=0``)."""
    if _STATE["installed"]:
        return True
    if os.environ.get("RSTRACE_NUMBA_INLINE", "1") == "0":
        return False
    try:
        from numba.core import inline_closurecall as icc

        source = textwrap.dedent(inspect.getsource(icc.InlineWorker.inline_ir))
    except (ImportError, AttributeError, OSError, TypeError) as exc:
        log.debug("numba's inliner left as it is: %s", exc)
        return False
    old = textwrap.indent(_BLOCK_BY_BLOCK, "    ")
    if source.count(old) != 1:
        log.debug("numba's inliner left as it is: copy_ir is not the code numba_inline "
                  "relies on")
        return False
    namespace = dict(vars(icc))
    code = compile(source.replace(old, textwrap.indent(_ALL_AT_ONCE, "    ")),
                   icc.__file__, "exec")
    exec(code, namespace)  # noqa: S102  (numba's own function, one statement changed)
    icc.InlineWorker.inline_ir = namespace["inline_ir"]
    _STATE["installed"] = True
    return True
