"""Cameras: a Blender camera object, or a 3D viewport's view, -> :class:`Camera`.

Layer: imported by ``export`` and ``viewport`` (no session, engine or ui).
"""

from __future__ import annotations

import numpy as np

from rstrace_engine import linalg
from rstrace_engine.geometry.scene import Camera, SceneError, check_matrix

from .materials import Notes


def _matrix(m) -> np.ndarray:
    return np.array(m, dtype=np.float64)


def camera_from_object(cam_ob, width: int, height: int, render, notes: Notes) -> Camera:
    """A :class:`Camera` from an evaluated camera object. Raises :class:`SceneError`."""
    if cam_ob is None:
        raise SceneError("the scene has no active camera: add a camera and make it active "
                         "(Scene properties > Camera)")
    if cam_ob.type != "CAMERA":
        raise SceneError(f"the active camera '{cam_ob.name}' is a {cam_ob.type.lower()}, "
                         f"not a camera")
    cd = cam_ob.data
    if cd.type not in ("PERSP", "ORTHO"):
        raise SceneError(f"camera '{cam_ob.name}': {cd.type.lower()} cameras are not "
                         f"supported (use perspective or orthographic)")
    if cd.dof.use_dof:
        notes.warn("depth of field is not supported (everything is in focus)", cam_ob.name)
    if render.pixel_aspect_x != render.pixel_aspect_y:
        notes.warn("non-square pixel aspect is not supported (square pixels rendered)")
    if render.use_motion_blur:
        notes.warn("motion blur is not supported")
    if render.use_multiview:
        notes.warn("stereo and multi-view rendering are not supported: one centre view is "
                   "rendered")
    m = _matrix(cam_ob.matrix_world)
    try:
        check_matrix(cam_ob.name, m)
    except SceneError as exc:
        raise SceneError(f"camera {exc}") from None
    return Camera(matrix=m, kind=cd.type, lens=cd.lens, sensor_width=cd.sensor_width,
                  sensor_height=cd.sensor_height, sensor_fit=cd.sensor_fit,
                  shift_x=cd.shift_x, shift_y=cd.shift_y, clip_start=cd.clip_start,
                  clip_end=cd.clip_end, ortho_scale=cd.ortho_scale, width=width, height=height)


def camera_from_view(view_matrix, window_matrix, width: int, height: int) -> Camera:
    """The :class:`Camera` of a 3D viewport from its ``region_data`` matrices.

    view_matrix : (4, 4) world -> view; window_matrix : (4, 4) OpenGL projection (perspective
    or orthographic). Works for user perspective, orthographic and camera views alike (in a
    camera view Blender's window matrix already holds the camera's lens, shift and the
    view's zoom and offset). The projection's centre offset becomes the camera's shift; an
    orthographic view whose near plane lies behind the eye (Blender's default) moves the
    eye back so that the clipping range starts at 0.
    """
    view = _matrix(view_matrix)
    proj = _matrix(window_matrix)
    if view.shape != (4, 4) or proj.shape != (4, 4) or not (
            np.all(np.isfinite(view)) and np.all(np.isfinite(proj))):
        raise SceneError("viewport: view or window matrix is not a finite 4x4 matrix")
    if proj[0, 0] == 0.0 or proj[1, 1] == 0.0 or proj[2, 2] == 0.0:
        raise SceneError("viewport: degenerate projection matrix")
    try:
        cam_to_world = linalg.inv(view)  # (np.linalg.inv, no OpenBLAS threads woken)
    except np.linalg.LinAlgError:
        raise SceneError("viewport: the view matrix is singular") from None
    half_w = 1.0 / proj[0, 0]
    ortho = abs(proj[3, 3] - 1.0) < 1e-9 and abs(proj[3, 2]) < 1e-9
    if ortho:
        cx, cy = -proj[0, 3] / proj[0, 0], -proj[1, 3] / proj[1, 1]
        near = (proj[2, 3] + 1.0) / proj[2, 2]
        far = (proj[2, 3] - 1.0) / proj[2, 2]
        if near < 0.0:  # Blender centres orthographic clipping on the view: move back
            axis = cam_to_world[:3, 2] / np.linalg.norm(cam_to_world[:3, 2])
            cam_to_world = cam_to_world.copy()
            cam_to_world[:3, 3] += axis * (-near)
            far -= near
            near = 0.0
    else:
        cx, cy = proj[0, 2] / proj[0, 0], proj[1, 2] / proj[1, 1]
        near = proj[2, 3] / (proj[2, 2] - 1.0)
        far = proj[2, 3] / (proj[2, 2] + 1.0)
    check_matrix("viewport camera", cam_to_world)
    sensor = 36.0
    return Camera(matrix=cam_to_world, kind="ORTHO" if ortho else "PERSP",
                  lens=sensor / (2.0 * half_w), sensor_width=sensor, sensor_height=sensor,
                  sensor_fit="HORIZONTAL", shift_x=cx / (2.0 * half_w),
                  shift_y=cy / (2.0 * half_w), clip_start=max(float(near), 0.0),
                  clip_end=max(float(far), float(near) + 1e-6), ortho_scale=2.0 * half_w,
                  width=int(width), height=int(height))
