"""The glossy rays of a rough root, traced per pixel (issue 24, the decomposition).

A rough surface's reflected and refracted rays are a Monte Carlo estimate (glossy rays,
docs/glossy.md): not a function of the line that cells may interpolate. Default Blender
materials are rough (Principled, roughness 0.5), so failing every cell that meets one would
leave nothing to interpolate. Interpolants therefore hold a rough root's *own* light
(emission, direct and world light: ``trace(roots="own")``) and every interpolated pixel
whose visible surface is rough adds what its glossy rays bring, traced here from its own
hit with the base tracer's stages, seeds and sample counts (``trace(roots="below")``). So
that part is exactly the base tracer's for that pixel sample, noise included, and the
pixel's error is that of the interpolated part alone, as with the world's term
(:mod:`.world_term`). A rough surface deeper in a line's tree (a rough floor in a mirror)
still fails its cell (``R_GLOSSY``).

The glossy rays' segments go to the pixel records, so an edit they cross dirties the pixel
(the interpolant's own ray trees hold the root's segments and shadow rays).
"""

from __future__ import annotations

import numpy as np

from ..accel.accelerators import Hits
from ..tracing.glossy_rays import glossy_materials
from ..tracing.glossy_strata import draws_glossy
from ..tracing.soft_lights import sample_seeds
from ..tracing.whitted import trace
from .samples import hit_materials


def rough_roots(sa, hits: Hits, max_depth: int) -> np.ndarray:
    """(n,) bool: the hits on rough surfaces whose glossy rays the tracer draws (ray depth
    above 0)."""
    n = len(hits.inst)
    if not draws_glossy(sa, max_depth):
        return np.zeros(n, np.bool_)
    m = hit_materials(sa, hits.inst, hits.prim)
    return (m >= 0) & glossy_materials(sa)[np.maximum(m, 0)]


def rough_objects(sa) -> np.ndarray:
    """(n_instances,) bool: the objects with a rough material in one of their slots."""
    starts = np.asarray(sa.inst_mat_start, np.int64)
    owner = np.repeat(np.arange(len(starts) - 1), np.diff(starts))  # each slot's object
    out = np.zeros(len(starts) - 1, np.bool_)
    out[owner[glossy_materials(sa)[sa.inst_mat]]] = True
    return out


def glossy_term(sa, accel, o, d, tmin, tmax, hits: Hits, gids: np.ndarray, seed: int,
                max_depth: int, light_samples: int, glossy_samples: int,
                counters: dict | None = None, segments: list | None = None,
                cancel=None, strata=None) -> np.ndarray:
    """(n, 3) float64: what the rays spawned at rough root hits ``hits`` of pixel samples
    ``gids`` (rays ``o, d`` within ``tmin, tmax``) bring: :func:`~..tracing.whitted.trace`'s
    radiance of those samples less the roots' own light, the same rays and seeds.
    ``segments``: their ray trees' levels for the pixel records (the roots' without shadow
    rays); ``strata``: their :class:`~..tracing.glossy_strata.Strata`."""
    rad, _ = trace(sa, accel, o, d, tmin, tmax, max_depth, primary=hits, counters=counters,
                   segments=segments, cancel=cancel, seeds=sample_seeds(gids, int(seed)),
                   light_samples=int(light_samples), glossy_samples=int(glossy_samples),
                   roots="below", strata=strata)
    return rad
