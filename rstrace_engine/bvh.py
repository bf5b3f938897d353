"""Two-level bounding volume hierarchy in numba (placeholder for the ray transform helper)."""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, inline="always")
def ray_to_object(inv, i, ox, oy, oz, dx, dy, dz):
    """World ray -> object space of instance ``i`` with ``inv`` (I, 4, 4) float64.

    The direction is transformed without normalisation, so a distance ``t`` along the
    object-space ray is the same ``t`` along the world ray.
    """
    m = inv[i]
    return (m[0, 0] * ox + m[0, 1] * oy + m[0, 2] * oz + m[0, 3],
            m[1, 0] * ox + m[1, 1] * oy + m[1, 2] * oz + m[1, 3],
            m[2, 0] * ox + m[2, 1] * oy + m[2, 2] * oz + m[2, 3],
            m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz,
            m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz,
            m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz)
