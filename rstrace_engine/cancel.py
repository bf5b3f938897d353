"""Cancelling a frame in progress, down to the kernels.

A host that must stop a frame quickly (the viewport: an edit or a camera move interrupts
the frame within tens of milliseconds) passes a :class:`CancelFlag` as the renderers'
``cancel`` argument. It is an ordinary ``cancel() -> bool`` callable, polled between tiles
and between the stages of a frame, and it also carries :attr:`CancelFlag.array`, a (1,)
int32 array that numba kernels read inside their loops: the BVH traversal
(:func:`~rstrace_engine.accel.bvh.trace_kernel`) checks it before every work item of a few
dozen rays, so a 32k-ray query stops within a few milliseconds instead of finishing.

A kernel that sees the flag leaves its output incomplete; whoever bound the flag polls
``cancel()`` after the query and throws that output away (a renderer never stores a tile,
a record or an image part computed after the flag was set). Only the renderers' own
per-frame queries are bound (:meth:`~rstrace_engine.accel.accelerators.Accelerator.
cancellable`); work whose result persists across frames (interpolant cells, RI-trees)
never sees the flag, so a cancel can never corrupt a cache. The BVH build polls it too
(between levels and subtrees of a mesh's tree, and between meshes) but stores nothing
until it is complete: a stopped build raises :class:`Cancelled` and the accelerator, and
the session that asked for it, stay as they were.

Any other callable still works as ``cancel`` (polled between tiles only).
"""

from __future__ import annotations

import contextlib

import numpy as np


class Cancelled(Exception):
    """A cancellable build stopped at the flag; nothing it would have stored was stored."""


class CancelFlag:
    """A cancel request visible to Python (``flag()``) and to numba kernels (``array``)."""

    __slots__ = ("array",)

    def __init__(self) -> None:
        self.array = np.zeros(1, np.int32)

    def set(self) -> None:
        self.array[0] = 1

    def clear(self) -> None:
        self.array[0] = 0

    def __call__(self) -> bool:
        return bool(self.array[0])


def kernel_flag(cancel) -> np.ndarray | None:
    """The (1,) int32 array kernels poll for ``cancel`` (None: it has none)."""
    return cancel.array if isinstance(cancel, CancelFlag) else None


def cancelled(cancel) -> bool:
    """``cancel()``, False for None."""
    return cancel is not None and bool(cancel())


def bound(accel, cancel):
    """``accel.cancellable(cancel)``: a context in which ``accel``'s kernels poll ``cancel``;
    a null context for an accelerator without that method (any object with the query
    methods serves as one) or a ``cancel`` that is not a :class:`CancelFlag`."""
    method = getattr(accel, "cancellable", None)
    if method is None or kernel_flag(cancel) is None:
        return contextlib.nullcontext(accel)
    return method(cancel)
