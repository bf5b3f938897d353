"""Per-scene values the tracer asks for at every depth level, computed once per set of arrays.

A :class:`Memo` holds one value, computed from the named fields of the last scene arrays
(:class:`~..geometry.scene.SceneArrays`, or an accelerator's geometry) it was asked about,
and those arrays weakly, as :class:`~.object_rays.SolidBalls` holds a packing's: an edit
hands the tracer new arrays (a scene's arrays are never written in place), and the value
is computed again the first time another array object of those fields is asked about.
The values are the tracer's own: callers read them and never write into them.
"""

from __future__ import annotations

import weakref


class Memo:
    """``compute(sa)`` for the last ``sa`` asked about, kept while ``sa``'s ``fields`` are
    the same array objects (held weakly)."""

    def __init__(self, fields: tuple, compute) -> None:
        self._fields = tuple(fields)
        self._compute = compute
        self._of: tuple | None = None
        self._value = None

    def get(self, sa):
        arrays = [getattr(sa, f) for f in self._fields]
        of = self._of
        if of is None or any(r() is not a for r, a in zip(of, arrays, strict=True)):
            value = self._compute(sa)
            try:
                self._of = tuple(weakref.ref(a) for a in arrays)
            except TypeError:  # not an array (a list, a scalar): computed every time
                self._of = None
                return value
            self._value = value
        return self._value
