"""What the error bound of a frame's interpolants rests on: proven, or only tested.

The predicate (:mod:`.predicate`) proves the geometry of a cell's own object, the state of
every light at the root of the ray trees (shafts, self shadow, the spot cone, a named
occluder's coverage: :mod:`.occluders`), and it applies textures per pixel
(:mod:`.samples`). Reflections and refractions are certified only up to the tunnel padding
(docs/INTERPOLANTS.md, "What is guaranteed, and what is only tested"); a frame that
interpolated pixels from such interpolants says so in ``stats["bound_notes"]``, which the
Blender add-on shows as messages.
"""

from __future__ import annotations

import numpy as np

from ..tracing.soft_lights import has_soft_light, world_lights

#: The notes, one per scene class whose bound is tested rather than proven.
NOTE_SECONDARY = ("epsilon is tested, not proven, for interpolated pixels whose radiance "
                  "includes reflections or refractions (secondary hit points are bounded "
                  "only up to the tunnel padding)")


#: Lights with an extent: what is interpolated under them, and what is traced.
NOTE_SOFT = ("lights with an extent (area, sphere, sun with an angle) are interpolated only "
             "where a cell proves them fully visible (an empty shaft to the whole extent) "
             "or off (facing away, or a sun hidden by one convex object); there their "
             "closed-form diffuse part is interpolated, and what the "
             "tracer samples -- a glossy surface's highlight, a spot with a radius, a disk, "
             "an ellipse, a spread -- is added per pixel from the base tracer's own samples "
             "(no shadow ray: the proof says each is visible); penumbrae are traced, exactly "
             "as the base tracer")
#: The world's light: traced per pixel, the other lights interpolated.
NOTE_WORLD = ("the world's light is traced per pixel: every interpolated pixel adds the "
              "world's term at its own hit, from the base tracer's own samples (occlusion "
              "included), to the interpolated rest; cells whose reflections or refractions "
              "hit a surface are traced while the world lights. " + NOTE_SOFT[0].upper()
              + NOTE_SOFT[1:])


def bound_notes(cache, used: np.ndarray) -> list[str]:
    """The notes that apply to interpolants ``used`` (ids, -1 for none) of ``cache``."""
    if world_lights(cache.sa):
        soft = [NOTE_WORLD]
    else:
        soft = [NOTE_SOFT] if has_soft_light(cache.sa) else []
    q = np.unique(used[used >= 0])
    if len(q) == 0:
        return soft
    sm = cache.samples.view()
    s0 = cache.pool.samples[q, 0]
    s0 = s0[(s0 >= 0) & (s0 < len(sm.node_count))]
    notes = soft
    if len(s0) == 0:
        return notes
    if np.any(sm.node_count[s0] > 1):
        notes.append(NOTE_SECONDARY)
    return notes
