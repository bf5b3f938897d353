"""Some pixels of a frame recombined from the per-light records (BASE re-shade, issue 20
item 5).

An object edit under soft light shades some lights (or the world) again at a few kept nodes
(:mod:`.shadow_reshade`); every other node keeps its terms. A pixel none of whose samples'
nodes was shaded again recombines to the value it has: the recombination is the tracer's
own sums in its order (:meth:`~.light_records.LightRecords.recombine`, bit for bit the
traced value, which every incremental frame checked against a fresh one relies on), and
its operands did not change. So the frame recombines just the pixels whose samples shade
something again -- the same kernels' arithmetic on the same operands, the samples averaged
by the tracer's :func:`~.batches.accumulate` -- and keeps the others' values
(:func:`recombine_pixels`; :meth:`~.frame_reuse.FrameReuse.relight`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .batches import accumulate, threads_for
from .edit_kernels import register
from .light_records import _node_light, light_weights


@njit(cache=True, nogil=True)
def _recombine_rows(rows, hit, start, slot, val, use, scale, dj, d_on, d_val, world, rad):
    """:func:`~.light_records._recombine_primary` at the primary nodes ``rows`` only,
    into ``rad[r]`` for ``rows[r]``."""
    for r in range(rows.shape[0]):
        g = rows[r]
        if hit[g]:
            x, y, z = _node_light(g, start, slot, val, use, scale, dj, d_on, d_val)
            rad[r, 0] = 0.0 + 1.0 * x
            rad[r, 1] = 0.0 + 1.0 * y
            rad[r, 2] = 0.0 + 1.0 * z
        else:
            rad[r, 0] = 0.0 + 1.0 * (1.0 * world[0])
            rad[r, 1] = 0.0 + 1.0 * (1.0 * world[1])
            rad[r, 2] = 0.0 + 1.0 * (1.0 * world[2])


@njit(cache=True, nogil=True)
def _recombine_nodes(nodes, at, hit, start, slot, val, w, use, scale, dj, d_on, d_val,
                     world, rad):
    """:func:`~.light_records._recombine_secondary` over the secondary nodes ``nodes`` (in
    the records' order) only, each added to ``rad[at[i]]``."""
    for i in range(nodes.shape[0]):
        k = nodes[i]
        if hit[k]:
            x, y, z = _node_light(k, start, slot, val, use, scale, dj, d_on, d_val)
        else:
            x, y, z = 1.0 * world[0], 1.0 * world[1], 1.0 * world[2]
        g = at[i]
        rad[g, 0] += w[k, 0] * x
        rad[g, 1] += w[k, 1] * y
        rad[g, 2] += w[k, 2] * z


def recombine_pixels(lr, sa, s_ray: np.ndarray, spp: int, n_pixels: int,
                     pixels: np.ndarray) -> np.ndarray:
    """(len pixels, 3) float32: the pixels ``pixels`` (sorted, int64) of the frame that the
    per-light records ``lr`` recombine to (:meth:`~.light_records.LightRecords.recombine`
    with no world rescale and nothing extra), the lights of ``sa``; ``s_ray`` the
    secondary nodes' samples."""
    use, scale, world = light_weights(sa)
    m = len(pixels)
    rows = (np.arange(spp, dtype=np.int64)[:, None] * n_pixels + pixels[None, :]).reshape(-1)
    rad = np.empty((len(rows), 3))
    p, s = lr.p, lr.s
    out = np.empty((m, 3), np.float32)
    with threads_for(0):  # (a few thousand nodes: one thread)
        _recombine_rows(rows, p.hit, p.start, p.slot, p.val, use, scale, *p.detached(),
                        world, rad)
        if len(s):
            # the secondary nodes of those samples (``rows`` is sorted), in the records'
            # order
            at = np.minimum(np.searchsorted(rows, s_ray), max(len(rows) - 1, 0))
            nodes = np.flatnonzero(rows[at] == s_ray) if len(rows) else at[:0]
            _recombine_nodes(nodes, np.ascontiguousarray(at[nodes], np.int64), s.hit,
                             s.start, s.slot, s.val, s.weight, use, scale, *s.detached(),
                             world, rad)
        accumulate(rad, np.where(p.hit[rows], 0, -1).astype(np.int32), spp, out,
                   np.empty(m, np.uint8))
    return out


def load_kernels(records, sa, camera=None) -> None:
    """Load (or compile) :func:`recombine_pixels`' kernels after the first frame that keeps
    light terms (:data:`~.edit_kernels.LOADERS`), so that the first object edit under
    soft light does not."""
    recombine_pixels(records.light, sa, np.zeros(1, np.int64), 1, 1, np.zeros(0, np.int64))


register("recombine_pixels", load_kernels,
         lambda records, sa: records.light.p is not None and len(sa.light_kind) > 0)
