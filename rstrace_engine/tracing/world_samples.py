"""The world's term of an INTERPOLANT frame's interpolated samples, kept for world edits.

While the world lights, an interpolated sample's radiance is its interpolated part ``R'``
(which leaves the world's term at its root out, :mod:`~..interpolants.world_term`) plus its
own world term ``W``, traced at its hit: ``W = c * world_light`` with ``c`` the shade
kernel's world term over the world's radiance. ``R'`` does not change with the world's
colour or strength (a cell whose ray trees show the world below the root is invalidated by
such an edit, one whose trees hit a surface below the root never passes while the world
lights), and ``c`` does not either (its samples and shadow rays are seeded by the sample and
the number of light slots). So a world colour or strength edit that keeps the world lighting
recombines such a sample as ``R' + c * world_light'`` -- the float64 operations the frame
performed, on the same operands -- instead of rendering it again
(:meth:`~.light_records.LightRecords.recombine`).

Kept per sample of the frame (dense, 49 bytes a sample, allocated at the first such sample),
as part of the per-light records and under their cap.
"""

from __future__ import annotations

import numpy as np


class WorldSamples:
    """Per sample of a frame: whether it is an interpolated sample with its world term kept
    (``ok``), the interpolated part ``rest`` and the world term's coefficient ``coef``."""

    def __init__(self, n_rays: int) -> None:
        self.ok = np.zeros(int(n_rays), np.bool_)
        self.coef = np.zeros((int(n_rays), 3))
        self.rest = np.zeros((int(n_rays), 3))

    @property
    def nbytes(self) -> int:
        return self.ok.nbytes + self.coef.nbytes + self.rest.nbytes

    def set(self, rays: np.ndarray, on: np.ndarray, coef: np.ndarray,
            rest: np.ndarray) -> None:
        """Samples ``rays`` were rendered again; of them ``on`` keep ``coef``, ``rest``
        ((k, 3) each); the others are not (or no longer) rescalable."""
        self.ok[np.asarray(rays, np.int64)] = False
        on = np.asarray(on, np.int64)
        self.ok[on] = True
        self.coef[on] = coef
        self.rest[on] = rest

    def apply(self, rad: np.ndarray, world_light: np.ndarray) -> None:
        """The kept samples' radiance in ``rad`` (n_rays, 3) for the world's radiance
        ``world_light`` (3,): ``rest + coef * world_light``, as the frame summed it."""
        on = self.ok
        rad[on] = self.rest[on] + self.coef[on] * np.asarray(world_light,
                                                             np.float64)[None, :]
