"""What a frame's camera rays hit, as Cycles writes it into its data passes, and holdouts.

One more pass of camera rays over the frame, with the jitter a BASE frame gives each pixel
(:func:`~.batches.frame_batches`, from the seed alone), whatever mode rendered its colours:

* **Depth** (Blender's "Z" pass): sample 0's hit point's depth along the camera's view
  axis (its camera-space -z), as Cycles' ``camera_z_depth`` writes it at sample 0 only
  (perspective and orthographic cameras alike); ``DEPTH_BACKGROUND`` (Cycles' 1e10) where
  sample 0 hits nothing or a holdout (Cycles ends that path before its data passes).
* **Normal**: the world-space shading normal turned toward the camera (Cycles' ``sd->N``
  after its back-facing flip), summed over the samples and divided by their number (a miss
  or a holdout adds 0), as Cycles accumulates it.
* **Holdout** (a hit on a material in ``holdout_mats`` or an object in ``holdout_insts``):
  Cycles ends such a camera path with no light and counts it transparent, so a pixel's
  Combined colour is the sum of its other samples' radiance over all samples
  (premultiplied) and its alpha the share of those samples. Pixels all of whose samples
  hit holdouts become (0, 0, 0, 0); pixels with some are traced again, their other samples
  only, with the frame's seeds (so in BASE mode the result is bit for bit what those
  samples gave the frame).

Only camera rays see a holdout: reflections, refractions and shadows see the surface's
material as usual (a Holdout *shader* is black there: the caller gives it a black material).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import tolerances as tol
from ..cancel import bound, cancelled
from ..frame import Frame, RenderSettings
from ..geometry.cameras import camera_params, camera_rays
from ..geometry.scene import Scene
from .batches import TILE_RAYS, frame_batches, threads_for
from .whitted import surfaces, trace_pixels

#: Cycles' depth where a camera ray hits nothing (``film_get_pass_pixel_depth``).
DEPTH_BACKGROUND = 1e10


class CameraPasses(NamedTuple):
    """Per-pixel results of :func:`camera_passes`, rows bottom-up like :class:`Frame`."""

    depth: np.ndarray | None  # (h, w) float32
    normal: np.ndarray | None  # (h, w, 3) float32
    alpha: np.ndarray | None  # (h, w) float32 1 - share of samples that hit a holdout
    radiance: np.ndarray | None  # (h, w, 3) float32 the frame's colours with holdouts cut
    holdout_pixels: int  # pixels with at least one holdout sample
    retraced_samples: int  # samples of partly held-out pixels traced again


def camera_passes(scene: Scene, accel, settings: RenderSettings, frame: Frame | None = None,
                  holdout_mats=(), holdout_insts=(), depth: bool = False,
                  normal: bool = False, cancel=None) -> CameraPasses:
    """The Depth and Normal passes (when asked) and, when ``holdout_mats`` (material ids)
    or ``holdout_insts`` (instance slots: holdout objects) is not empty, the frame's colours
    and alpha with those held out (``frame``: the rendered frame of the same camera and
    settings). ``accel``: an accelerator over ``scene.arrays()`` (the session's).
    ``cancel() -> bool`` is polled between tiles: once it says stop, nothing is returned
    (every field None: the caller writes the frame as it is)."""
    settings = settings.validated()
    sa = scene.arrays()
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    spp = int(settings.samples)
    seed = int(settings.seed)
    is_holdout = np.zeros(max(len(sa.mat_diffuse), 1), np.bool_)
    for m in holdout_mats:
        if 0 <= int(m) < len(is_holdout):
            is_holdout[int(m)] = True
    inst_holdout = np.zeros(max(len(sa.inst_mesh), 1), np.bool_)
    for i in holdout_insts:
        if 0 <= int(i) < len(inst_holdout):
            inst_holdout[int(i)] = True
    any_holdout = bool(is_holdout.any() or inst_holdout.any())
    holdouts = any_holdout and frame is not None
    z = np.full(h * w, DEPTH_BACKGROUND, np.float32) if depth else None
    nsum = np.zeros((h * w, 3)) if normal else None
    held = np.zeros(h * w, np.int32) if holdouts else None
    if not (depth or normal or holdouts):
        return CameraPasses(None, None, None, None, 0, 0)  # (nothing asked)
    m = np.asarray(scene.camera.matrix, np.float64)
    eye, forward = m[:3, 3], -m[:3, 2] / np.linalg.norm(m[:3, 2])
    held_mask = []  # per tile: (pix, (spp, k) bool holdout samples)
    rows_per_tile = max(1, TILE_RAYS // max(1, w * spp))
    nothing = CameraPasses(None, None, None, None, 0, 0)
    for pix, jitter, _ in frame_batches(w, h, spp, seed, rows_per_tile, None):
        if cancelled(cancel):
            return nothing
        k = len(pix)
        with threads_for(k * spp), bound(accel, cancel):
            o, d, tmin, tmax = camera_rays(cp, np.tile(pix, spp), jitter.reshape(-1, 2))
            hits = accel.closest_hit(o, d, tmin, tmax)
            surf = surfaces(sa, o, d, tmax, hits) if normal or any_holdout else None
        hit = np.asarray(hits.inst) >= 0
        hs = np.zeros(k * spp, np.bool_)
        if any_holdout:
            inst = np.maximum(np.asarray(hits.inst), 0)
            hs = hit & (is_holdout[np.maximum(surf.mat, 0)] | inst_holdout[inst])
        # Cycles ends a held-out camera path before it writes the data passes
        live = hit & ~hs
        if depth:
            first = live[:k]
            p = o[:k][first] + np.asarray(hits.t)[:k][first, None] * d[:k][first]
            z[pix[first]] = ((p - eye) @ forward).astype(np.float32)
        if normal:
            ns = np.where(live[:, None], surf.NS, 0.0).reshape(spp, k, 3)
            nsum[pix] = ns.sum(axis=0)
        if holdouts:
            hs = hs.reshape(spp, k)
            held[pix] = hs.sum(axis=0)
            if hs.any():
                held_mask.append((pix, hs, jitter))
    alpha = radiance = None
    retraced = 0
    n_held = 0
    if holdouts:
        alpha = (1.0 - held / spp).astype(np.float32)
        radiance = frame.radiance.reshape(h * w, 3).copy()
        radiance[held == spp] = 0.0
        n_held = int(np.count_nonzero(held))
        for pix, hs, jitter in held_mask:
            part = (hs.sum(axis=0) > 0) & (hs.sum(axis=0) < spp)
            if not part.any():
                continue
            keep = ~hs[:, part]  # (spp, kp) samples to trace again
            s_idx, p_idx = np.nonzero(keep)
            ppix = pix[part][p_idx]
            jit = jitter[:, part][s_idx, p_idx]
            gids = s_idx.astype(np.int64) * (w * h) + ppix
            rad, _ = trace_pixels(sa, accel, cp, ppix, np.ascontiguousarray(jit),
                                  int(settings.max_depth), cancel, gids=gids, seed=seed,
                                  light_samples=int(settings.light_samples),
                                  glossy_samples=int(settings.glossy_samples), spp=spp)
            if cancelled(cancel):
                return nothing
            good = np.all(np.abs(rad) <= tol.RADIANCE_MAX, axis=1)
            acc = np.zeros((int(part.sum()), 3))
            np.add.at(acc, p_idx[good], rad[good])
            radiance[pix[part]] = (acc / spp).astype(np.float32)
            retraced += len(ppix)
        radiance = radiance.reshape(h, w, 3)
        alpha = alpha.reshape(h, w)
    return CameraPasses(
        z.reshape(h, w) if depth else None,
        (nsum / spp).astype(np.float32).reshape(h, w, 3) if normal else None,
        alpha, radiance, n_held, retraced)


__all__ = ["DEPTH_BACKGROUND", "CameraPasses", "camera_passes"]
