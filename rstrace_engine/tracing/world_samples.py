"""The world's term of an INTERPOLANT frame's interpolated samples, kept for world edits.

While the world lights, an interpolated sample's radiance is its interpolated part ``R'``
(which leaves the world's term at its root out, :mod:`~..interpolants.world_term`) plus its
own world term ``W``, traced at its hit: ``W = c * world_light`` with ``c`` the shade
kernel's world term over the world's radiance. ``R'`` does not change with the world's
colour or strength (a cell whose ray trees show the world below the root is invalidated by
such an edit, one whose trees hit a surface below the root never passes while the world
lights), and ``c`` does not either (its samples and shadow rays are seeded by the sample,
:func:`~.soft_lights.row_hash`). So a world colour or strength edit that keeps the world lighting
recombines such a sample as ``R' + c * world_light'`` -- the float64 operations the frame
performed, on the same operands -- instead of rendering it again
(:meth:`~.light_records.LightRecords.recombine`).

Kept as part of the per-light records, under their cap: 4 bytes per sample of the frame (the
row of its kept term, -1: none) and 48 per interpolated sample (``c`` and ``R'``, float64
RGB); rows of samples rendered again are dropped when they outnumber the live ones.
"""

from __future__ import annotations

import numpy as np


class WorldSamples:
    """Per sample of a frame: the row of its kept ``coef`` and ``rest`` (-1: not an
    interpolated sample with its world term kept)."""

    def __init__(self, n_rays: int) -> None:
        self.row = np.full(int(n_rays), -1, np.int32)
        self.coef = np.zeros((0, 3))
        self.rest = np.zeros((0, 3))
        self.n = 0  # rows in use (live or stale)
        self.stale = 0  # rows whose sample was rendered again

    @property
    def ok(self) -> np.ndarray:
        """(n_rays,) bool: the samples with their world term kept."""
        return self.row >= 0

    @property
    def nbytes(self) -> int:
        return self.row.nbytes + self.coef.nbytes + self.rest.nbytes

    def set(self, rays: np.ndarray, on: np.ndarray, coef: np.ndarray,
            rest: np.ndarray) -> None:
        """Samples ``rays`` were rendered again; of them ``on`` keep ``coef``, ``rest``
        ((k, 3) each); the others are not (or no longer) rescalable."""
        rays = np.asarray(rays, np.int64)
        on = np.asarray(on, np.int64)
        self.stale += int(np.count_nonzero(self.row[rays] >= 0))
        self.row[rays] = -1
        k = len(on)
        if self.n + k > len(self.coef):
            cap = max(2 * len(self.coef), self.n + k, 1024)
            self.coef = np.concatenate([self.coef[:self.n], np.zeros((cap - self.n, 3))])
            self.rest = np.concatenate([self.rest[:self.n], np.zeros((cap - self.n, 3))])
        self.coef[self.n:self.n + k] = coef
        self.rest[self.n:self.n + k] = rest
        self.row[on] = self.n + np.arange(k, dtype=np.int32)
        self.n += k
        if self.stale > self.n - self.stale:
            self._compact()

    def forget(self, rays: np.ndarray) -> None:
        """Samples ``rays`` were rendered again without their world term kept."""
        self.set(rays, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))

    def _compact(self) -> None:
        live = np.flatnonzero(self.row >= 0)
        r = self.row[live]
        self.coef, self.rest = self.coef[r], self.rest[r]
        self.row[live] = np.arange(len(live), dtype=np.int32)
        self.n, self.stale = len(live), 0

    def apply(self, rad: np.ndarray, world_light: np.ndarray) -> None:
        """The kept samples' radiance in ``rad`` (n_rays, 3) for the world's radiance
        ``world_light`` (3,): ``rest + coef * world_light``, as the frame summed it."""
        g = np.flatnonzero(self.row >= 0)
        r = self.row[g]
        rad[g] = self.rest[r] + self.coef[r] * np.asarray(world_light, np.float64)[None, :]


class TermSamples:
    """Per sample of a frame: a kept RGB term (the row of its value, -1: none) -- an
    INTERPOLANT frame's interpolated samples' sampled terms of lights with an extent
    (:func:`~..interpolants.sampled_term.add_sampled_terms`), which depend on the sample's
    hit and seeds, the lights with an extent and the geometry alone: a pixel rendered
    again after an edit of none of them (a hard light's power, colour or addition, the
    world) takes them instead of tracing their samples again. Dropped by the edits that
    may change them (:meth:`~.frame_reuse.FrameReuse.take_edits`)."""

    def __init__(self, n_rays: int) -> None:
        self.row = np.full(int(n_rays), -1, np.int32)
        self.value = np.zeros((0, 3))
        self.n = 0

    @property
    def nbytes(self) -> int:
        return self.row.nbytes + self.value.nbytes

    def get(self, rays: np.ndarray):
        """``(have (k,) bool, value (k, 3))`` of samples ``rays`` (value 0 where not kept)."""
        r = self.row[np.asarray(rays, np.int64)]
        have = r >= 0
        value = np.zeros((len(r), 3))
        value[have] = self.value[r[have]]
        return have, value

    def set(self, rays: np.ndarray, value: np.ndarray) -> None:
        """Keep ``value`` (k, 3) for samples ``rays`` (their earlier rows left unused; the
        store is rebuilt when they outnumber the live ones)."""
        rays = np.asarray(rays, np.int64)
        k = len(rays)
        if self.n + k > len(self.value):
            live = np.flatnonzero(self.row >= 0)
            old = self.value[self.row[live]]
            self.value = np.zeros((max(2 * (len(live) + k), 1024), 3))
            self.value[:len(live)] = old
            self.row[live] = np.arange(len(live), dtype=np.int32)
            self.n = len(live)
        self.value[self.n:self.n + k] = value
        self.row[rays] = self.n + np.arange(k, dtype=np.int32)
        self.n += k

    def forget(self, rays: np.ndarray) -> None:
        self.row[np.asarray(rays, np.int64)] = -1
