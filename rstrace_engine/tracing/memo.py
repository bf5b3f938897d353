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
        self._kept: tuple | None = None  # (weak references to the arrays, value): one slot

    def get(self, sa):
        arrays = [getattr(sa, f) for f in self._fields]
        kept = self._kept  # read once: another thread may replace it (never change it)
        if kept is not None and all(r() is a for r, a in zip(kept[0], arrays, strict=True)):
            return kept[1]
        value = self._compute(sa)
        try:
            self._kept = (tuple(weakref.ref(a) for a in arrays), value)
        except TypeError:  # not an array (a list, a scalar): computed every time
            self._kept = None
        return value
