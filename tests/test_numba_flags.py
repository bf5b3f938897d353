"""numba's compile flags compared and hashed without a property call per option
(rstrace_engine/numba_flags.py): the same answers as numba's own methods."""

from __future__ import annotations

import itertools
import textwrap

from numba.core import cpu
from numba.core.compiler import Flags
from numba.core.targetconfig import TargetConfig

import rstrace_engine  # noqa: F401  (installs the quick methods)
from rstrace_engine import numba_flags


def _numbas():
    """numba's own methods, compiled from the source text numba_flags relies on."""
    ns = {"TargetConfig": TargetConfig}
    for src in numba_flags._NUMBA_SOURCE.values():
        exec(textwrap.dedent(src), ns)  # noqa: S102
    return ns["values"], ns["__hash__"], ns["__eq__"]


def _variants():
    out = [Flags()]
    a = Flags()
    a.nrt = True
    out.append(a)
    b = Flags(copy_from=a)
    b.error_model = "numpy"
    out.append(b)
    c = Flags(copy_from=b)
    c.fastmath = cpu.FastMathOptions(True)
    out.append(c)
    d = Flags()
    d.nrt = False  # set to its default: equal to Flags() by value
    out.append(d)
    e = Flags(copy_from=a)
    e.forceinline = True
    out.append(e)
    return out


def test_installed_and_the_same_answers_as_numbas_methods():
    assert numba_flags.installed()
    values, hash_, eq = _numbas()
    flags = _variants()
    for f in flags:
        assert f.values() == values(f)
        assert list(f.values()) == list(values(f))  # the same order
        assert hash(f) == hash_(f)
    for f, g in itertools.product(flags, flags):
        assert (f == g) == eq(f, g), (f, g)
    assert flags[0] == flags[4] and flags[0] != flags[1]
    assert (flags[0] == 3) is False  # not a TargetConfig: NotImplemented, then identity


def test_hash_and_equality_read_no_option_one_by_one(monkeypatch):
    """numba's build ``values()`` from every option's property (~30 Python calls per
    hash or comparison, ~110 000 of them typing the error predicate's chain)."""
    calls = []
    prop = Flags.__dict__.get("nrt") or TargetConfig.__dict__.get("nrt")
    owner = Flags if "nrt" in Flags.__dict__ else TargetConfig
    monkeypatch.setattr(owner, "nrt", property(lambda self: calls.append(1) or prop.fget(self),
                                               prop.fset, prop.fdel))
    a, b = Flags(), Flags()
    a.nrt = b.nrt = True
    calls.clear()
    hash(a)
    assert a == b
    assert calls == []
