"""The thickness view (seed 004, section 3.7: volume visualisation): how far a ray travels
inside the objects it crosses.

Objects are treated as semi-transparent and non-refracting (an x-ray): a pixel's value is
``exp(-length / distance)`` grey, ``length`` the summed length of its camera ray inside
objects and ``distance`` the setting ``thickness_distance`` (0: a tenth of the scene
diagonal). Only closed meshes have an inside (an open one -- a ground plane -- adds
nothing). Inside is decided by the winding of the crossings: a ray entering through a
front face goes in, one leaving through a back face goes out, one that starts inside an
object counts from its origin; the length is ``sum(exits t) - sum(entries t)`` over the
crossings, so every closed object adds its own chords and overlapping objects add up (the
RI-tree's per-object lengths add up alike). (One in/out counter over all objects once made
an open ground plane's "entry" swallow the chord of a sphere sunk into it, and counted
overlaps once where the RI-tree counted them twice: the two modes disagreed by up to 0.37.)

:func:`walk` computes lengths exactly by stepping from crossing to crossing (BASE mode, the
RI-tree's samples, and rays the RI-tree traces); :mod:`.render` interpolates them from the
RI-tree where its tests pass.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..frame import CLASS_BACKGROUND, Frame, RenderSettings
from ..geometry.cameras import camera_params, camera_rays
from ..geometry.mesh_topology import mesh_topology_cached
from ..tracing.batches import TILE_RAYS, accumulate, frame_batches
from ..tracing.shading import geometric_normal

#: At most this many crossings are followed along one ray.
MAX_CROSSINGS = 64


@njit(cache=True, nogil=True)
def _step(sa, closed, o, d, idx, t, inst, prim, depth, length, tlast, tcur, step):
    """Account the crossings ``(t, inst, prim)`` of the still-walking rays ``idx``:
    ``length`` gains ``t`` at an exit and loses it at an entry of a closed mesh, ``depth``
    counts entries less exits.

    Returns how many rays keep walking (moved to the front of ``idx``)."""
    k = 0
    for q in range(idx.shape[0]):
        r = idx[q]
        if inst[q] < 0:
            continue
        th = t[q]
        if closed[inst[q]]:
            gx, gy, gz = geometric_normal(sa.verts, sa.tris, sa.inst_nmat[inst[q]], prim[q])
            if d[r, 0] * gx + d[r, 1] * gy + d[r, 2] * gz < 0.0:  # entering
                depth[r] += 1
                length[r] -= th
            else:
                depth[r] -= 1
                length[r] += th
            tlast[r] = th
        tcur[r] = th + step[r]
        idx[k] = r
        k += 1
    return k


def walk(sa, trace_fn, origins, directions, tmin, tmax) -> np.ndarray:
    """Length inside objects of each ray (world units): (n,) float64.

    trace_fn(o, d, tmin, tmax, rows) -> Hits: closest hits of rays ``rows`` (e.g. the whole
    scene's ``closest_hit``, or ``intersect_object`` of one instance per row).
    """
    o = np.ascontiguousarray(origins, np.float64)
    d = np.ascontiguousarray(directions, np.float64)
    n = len(o)
    t0 = np.ascontiguousarray(np.broadcast_to(np.asarray(tmin, np.float64), (n,))).copy()
    t1 = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, np.float64), (n,)))
    dl = np.linalg.norm(d, axis=1)
    # step past a crossing: relative to the coordinate magnitude along the ray
    mag = np.abs(o).max(axis=1) + dl * np.minimum(np.abs(t1), sa.scene_extent * 10 / np.maximum(
        dl, 1e-300))
    step = (tol.THICKNESS_STEP_REL * np.maximum(mag, sa.scene_extent)
            / np.maximum(dl, 1e-300))
    depth = np.zeros(n, np.int32)
    length = np.zeros(n)
    tlast = t0.copy()
    tcur = t0.copy()
    closed = np.ascontiguousarray(mesh_topology_cached(sa).mesh_closed[sa.inst_mesh])
    idx = np.arange(n, dtype=np.int64)
    for _ in range(MAX_CROSSINGS):
        if len(idx) == 0:
            break
        h = trace_fn(o[idx], d[idx], tcur[idx], t1[idx], idx)
        k = _step(sa, closed, o, d, idx, np.ascontiguousarray(h.t, np.float64),
                  np.ascontiguousarray(h.inst, np.int32), np.ascontiguousarray(h.prim, np.int32),
                  depth, length, tlast, tcur, step)
        idx = idx[:k].copy()
    # more exits than entries: the ray started inside (counts from its origin); more
    # entries: it was cut short inside (by MAX_CROSSINGS or tmax: counts to the last crossing)
    length += np.where(depth < 0, t0, tlast) * depth
    return np.maximum(length, 0.0) * dl


def display(length: np.ndarray, distance: float) -> np.ndarray:
    """Grey radiance of lengths ``length`` (n,): ``exp(-length / distance)``, (n, 3)."""
    v = np.exp(-np.asarray(length, np.float64) / max(float(distance), 1e-300))
    return np.repeat(v[:, None], 3, axis=1)


def auto_distance(sa, distance: float) -> float:
    """The 1/e distance of the thickness view: the setting, or a tenth of the scene size."""
    d = float(distance)
    return d if d > 0.0 and math.isfinite(d) else 0.1 * float(sa.scene_extent)


def render_thickness_exact(scene, settings: RenderSettings, accel, progress=None,
                           cancel=None) -> Frame:
    """The thickness view traced exactly (BASE mode): every crossing walked."""
    settings = settings.validated()
    t_start = time.perf_counter()
    sa = scene.arrays()
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    spp = int(settings.samples)
    rows_per_tile = max(1, TILE_RAYS // max(1, w * spp))
    image = np.zeros((h * w, 3), np.float32)
    pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
    dist = auto_distance(sa, settings.thickness_distance)
    cancelled = False

    def through(oo, dd, lo, hi, rows):
        return accel.closest_hit(oo, dd, lo, hi)

    for pix, jitter, y1 in frame_batches(w, h, spp, int(settings.seed), rows_per_tile,
                                         None):
        if cancel is not None and cancel():
            cancelled = True
            break
        rows = slice(int(pix[0]), int(pix[-1]) + 1)
        o, dr, tmin, tmax = camera_rays(cp, np.tile(pix, spp), jitter.reshape(-1, 2))
        length = walk(sa, through, o, dr, tmin, tmax)
        inst = np.where(length > 0, 0, -1).astype(np.int32)
        accumulate(display(length, dist), inst, spp, image[rows], pclass[rows])
        if progress is not None:
            progress(y1 / h, f"thickness {y1}/{h} rows")
    stats = dict(mode=settings.mode, view="THICKNESS", time_s=time.perf_counter() - t_start,
                 width=w, height=h, samples=spp, cancelled=cancelled,
                 thickness_distance=dist)
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats)
