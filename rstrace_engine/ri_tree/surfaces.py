"""The surface arrays of interpolated hits, as the base tracer's surface kernel makes them
for traced ones (:mod:`..tracing.whitted`), so that RI_TREE frames shade both alike."""

from __future__ import annotations

from numba import njit, prange

from .. import tolerances as tol
from ..geometry.scene import SceneArrays
from ..tracing.shader import light_states
from ..tracing.shading import dot3, normalize3, spawn_offset
from ..views import fields, view_type

_InterpScene = view_type("_InterpScene", SceneArrays, (
    "light_bound", "light_cos_inner", "light_cos_outer", "light_dir", "light_ext",
    "light_half", "light_kind", "light_pos", "light_spot_frame", "light_spot_scaled",
    "mat_ior", "mat_model", "mat_roughness", "mat_transmission", "scene_extent"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def interp_surface(sa, rows, o, d, P, NS, NG, mat, surf):
    """The rows ``rows`` of ``surf`` (the level's :class:`~..tracing.whitted.Surfaces`, as
    the base tracer's surface stage makes them) for interpolated hits: points ``P``,
    shading and geometric normals ``NS``, ``NG`` and materials ``mat``, one row per
    interpolated hit. Shadow origins are moved off the surface by the normal spawn offset
    (the self-offset is applied by the shadow test)."""
    sa = _InterpScene(*fields(sa, _InterpScene))  # the fields its loop reads
    Pw, NGw, NSw, VD, ENTER, MAT, Q, sh_state = surf
    ext = sa.scene_extent
    for q in prange(rows.shape[0]):
        i = rows[q]
        ux, uy, uz, _ = normalize3(d[i, 0], d[i, 1], d[i, 2])
        VD[i, 0], VD[i, 1], VD[i, 2] = ux, uy, uz
        px, py, pz = P[q, 0], P[q, 1], P[q, 2]
        gx, gy, gz = NG[q, 0], NG[q, 1], NG[q, 2]
        sx, sy, sz = NS[q, 0], NS[q, 1], NS[q, 2]
        enter = dot3(ux, uy, uz, gx, gy, gz) < 0.0
        if not enter:
            gx, gy, gz = -gx, -gy, -gz
            sx, sy, sz = -sx, -sy, -sz
        if dot3(ux, uy, uz, sx, sy, sz) > 0.0:
            # an interpolated normal may lean past the view ray: bend it back to the view
            a = dot3(ux, uy, uz, sx, sy, sz) + tol.INTERP_NORMAL_BEND
            sx, sy, sz, _ = normalize3(sx - a * ux, sy - a * uy, sz - a * uz)
        ENTER[i] = enter
        Pw[i, 0], Pw[i, 1], Pw[i, 2] = px, py, pz
        NGw[i, 0], NGw[i, 1], NGw[i, 2] = gx, gy, gz
        NSw[i, 0], NSw[i, 1], NSw[i, 2] = sx, sy, sz
        MAT[i] = mat[q]
        off = spawn_offset(px, py, pz, ext)
        qx, qy, qz = px + gx * off, py + gy * off, pz + gz * off
        Q[i, 0], Q[i, 1], Q[i, 2] = qx, qy, qz
        light_states(sa, i, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz, mat[q],
                     sh_state)
