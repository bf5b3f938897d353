"""Views of a struct of arrays: a NamedTuple of some of its fields, for parallel kernels.

Why: numba lowers a ``prange`` loop into a function that takes every variable the loop body
reads, and a NamedTuple among them is passed field by field (numba 0.68,
``parfor_lowering``: "Convert tuples to individual parameters"); the parfor passes then
work on every field. A parallel kernel whose loop reads the scene (:class:`SceneArrays`, 58
fields) compiled for seconds even where its body is ten lines: a synthetic ``prange`` loop
reading 3 fields of a 60-field NamedTuple compiles in 3.9 s, in 0.75 s when it reads them
from a 3-field view made before the loop. So a parallel kernel makes, before its ``prange``,
a view holding only the fields its loop body (and the functions it hands the struct to)
reads, and the loop reads the view::

    _ShadowScene = view_type("_ShadowScene", SceneArrays, ("light_kind", "light_pos"))

    @njit(parallel=True)
    def kernel(sa, ...):
        sa = _ShadowScene(*fields(sa, _ShadowScene))  # the fields, shared (no copy)
        for i in prange(n):
            ... sa.light_pos[j, 0] ...

The view is made by calling its class, bound at module level to a global of the class's own
name (rebinding the parameter is fine: numba gives each binding its own type): numba's
parfor lowering rebuilds the NamedTuple inside the loop's function by that
name, from the global the call names (a view made any other way fails to compile there).

The view's fields are the struct's own objects (arrays shared, not copied), in the struct's
types: the same code, the same machine arithmetic, so the same results bit for bit. A field
the view lacks is a typing error at compile time naming the view and the field, never a
wrong value.

Views are for reading. (Seen with numba 0.68: a ``prange`` loop that *writes* into an array
field of a NamedTuple, view or not, ``s.b[i] = x``, left the caller's array unchanged; the
kernels unpack their output structs into plain variables before the loop.)
"""

from __future__ import annotations

from typing import NamedTuple

from numba.core import types
from numba.extending import intrinsic


def view_type(name: str, struct: type, fields, module: str | None = None) -> type:
    """A NamedTuple class ``name`` with ``fields`` of the NamedTuple class ``struct`` (their
    annotations kept), in the struct's field order. ``module``: the module the class is
    said to live in (the caller's, so that it pickles by reference; the caller binds it to
    ``name`` at module level)."""
    fields = set(fields)
    unknown = sorted(fields - set(struct._fields))
    if unknown:
        raise ValueError(f"view {name}: {struct.__name__} has no field {', '.join(unknown)}")
    ann = struct.__annotations__
    cls = NamedTuple(name, [(f, ann[f]) for f in struct._fields if f in fields])
    if module is not None:
        cls.__module__ = module
    return cls


@intrinsic
def fields(typingctx, struct, cls):
    """``tuple(struct.<f> for f in cls._fields)``: the fields of the NamedTuple ``struct``
    that the view class ``cls`` (:func:`view_type`) holds, shared, as a tuple."""
    if not isinstance(struct, types.BaseNamedTuple) or not isinstance(
            cls, types.NamedTupleClass):
        return None
    names = cls.instance_class._fields
    src = struct.instance_class._fields
    missing = [f for f in names if f not in src]
    if missing:
        raise TypeError(f"view {cls.instance_class.__name__}: "
                        f"{struct.instance_class.__name__} has no field {', '.join(missing)}")
    at = [src.index(f) for f in names]
    out = types.Tuple([struct.types[i] for i in at])
    sig = out(struct, cls)

    def codegen(context, builder, signature, args):
        value = context.get_constant_undef(out)
        for k, i in enumerate(at):
            member = builder.extract_value(args[0], i)
            if context.enable_nrt:  # (a kernel compiled with _nrt=False counts no references)
                context.nrt.incref(builder, struct.types[i], member)  # the view holds one
            value = builder.insert_value(value, member, k)
        return value

    return sig, codegen
