"""numba's compile flags compared and hashed without a property call per option.

Why: numba keys the implementation it builds for every ``@overload`` call it types
(``_OverloadFunctionTemplate._get_impl``'s ``_impl_cache``: ``np.empty``, ``min``, a
tuple's ``len`` ...) on the compile flags of the kernel being compiled, a
``numba.core.targetconfig.TargetConfig``; every lookup hashes the flags and compares them
with the key it finds, and both go through ``TargetConfig.values()``: a dict built by
calling each option's property (~30 options), each a Python function call: 5-9 us a
hash or comparison. Compiling the error predicate's chain makes ~163 000 of them (~1.2 s
of its ~60 s), the traversal and the shade stage ~29 000 (~0.2 s of ~16 s)
(docs/first-render.md, *session 36 (compile)*): 1-2 % of a cold compile.

What: :func:`install` (called by ``rstrace_engine/__init__.py`` before any kernel
compiles) replaces ``TargetConfig.values``, ``__hash__`` and ``__eq__`` with versions
that give the same results: ``values()`` is the class's defaults (read once per class
from its ``Option`` objects, which the properties return when an option is unset) updated
with the options set (``_values``: only the setters write it), in the same order;
``__hash__`` is numba's ``hash(tuple(sorted(self.values())))``, which sorts the dict's
*keys*, i.e. the option names, the same for every instance of a class: computed once per
class; ``__eq__`` is numba's (``values() == other.values()``), answered at once when both
are of one class and set the same options to the same values. No compiled code changes
(the flags compiled with are the same objects; only the time to compare them does).

What it relies on: the exact source text of those three methods in numba's
``numba/core/targetconfig.py`` (numba 0.54 to 0.68 at least); :func:`install` changes
nothing unless they are found verbatim. ``RSTRACE_NUMBA_FLAGS=0`` in the environment
leaves numba alone (to compare).
"""

from __future__ import annotations

import inspect
import logging
import os
import textwrap

log = logging.getLogger(__name__)

#: numba's methods, as this module expects to find them (TargetConfig, numba 0.54-0.68)
_NUMBA_SOURCE = {
    "values": '''\
def values(self):
    """Returns a dict of all the values
    """
    return {k: getattr(self, k) for k in self.options}
''',
    "__hash__": '''\
def __hash__(self):
    return hash(tuple(sorted(self.values())))
''',
    "__eq__": '''\
def __eq__(self, other):
    if isinstance(other, TargetConfig):
        return self.values() == other.values()
    else:
        return NotImplemented
''',
}

_STATE = {"installed": False}
_DEFAULTS: dict = {}  # TargetConfig subclass -> {option name: default}, in option order
_HASHES: dict = {}  # TargetConfig subclass -> numba's hash of its instances


def installed() -> bool:
    """Whether numba's flags compare and hash the quick way in this process."""
    return _STATE["installed"]


def _defaults(cls) -> dict:
    d = _DEFAULTS.get(cls)
    if d is None:
        d = _DEFAULTS[cls] = {k: opt.default for k, opt in cls.options.items()}
    return d


def install() -> bool:
    """Replace ``TargetConfig.values``, ``__hash__`` and ``__eq__`` (module doc). Returns
    whether they are replaced (False: numba's code is not the text this relies on, or
    ``RSTRACE_NUMBA_FLAGS=0``)."""
    if _STATE["installed"]:
        return True
    if os.environ.get("RSTRACE_NUMBA_FLAGS", "1") == "0":
        return False
    try:
        from numba.core.targetconfig import TargetConfig

        found = {name: textwrap.dedent(inspect.getsource(getattr(TargetConfig, name)))
                 for name in _NUMBA_SOURCE}
    except (ImportError, AttributeError, OSError, TypeError) as exc:
        log.debug("numba's flags left as they are: %s", exc)
        return False
    if found != _NUMBA_SOURCE:
        log.debug("numba's flags left as they are: TargetConfig is not the code "
                  "numba_flags relies on")
        return False
    numba_values = TargetConfig.values

    def values(self):
        d = dict(_defaults(type(self)))
        n = len(d)
        d.update(self._values)
        if len(d) != n:  # a value of an option this class lacks: numba's own answer
            return numba_values(self)
        return d

    def __hash__(self):
        cls = type(self)
        h = _HASHES.get(cls)
        if h is None:
            h = _HASHES[cls] = hash(tuple(sorted(self.values())))
        return h

    def __eq__(self, other):
        if isinstance(other, TargetConfig):
            if type(self) is type(other) and self._values == other._values:
                return True
            return self.values() == other.values()
        return NotImplemented

    TargetConfig.values = values
    TargetConfig.__hash__ = __hash__
    TargetConfig.__eq__ = __eq__
    _STATE["installed"] = True
    return True
