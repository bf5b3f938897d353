"""Lights with an extent over a cell's slab: where the tracer's value is its closed form.

The interpolant predicate (:mod:`.predicate`, "Soft light") passes a light with an extent
over a cell only where every shadow sample is proven unoccluded *and* the tracer's value is
then exact: the ratio estimator (:mod:`..tracing.soft_lights`) gives the closed form times
the visibility ratio, which is exactly 1 when every sample is visible, wherever the closed
form exists -- the whole extent above the horizon of the point's geometric and shading
normal, in front of an area light. :func:`soft_slab` proves that (or that the light is off)
for one slab polygon; docs/INTERPOLANTS.md has the argument.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.attributes import corner_normals
from ..geometry.scene import LIGHT_AREA, LIGHT_SUN


@njit(cache=True, nogil=True)
def _unit_normals(qs, inst, gt, nx, ny, nz, N):
    """World unit normals of global triangle ``gt`` (object-space geometric normal n) on
    instance ``inst``: row 0 the geometric normal, rows 1-3 the corners' shading normals
    (0 where too short to normalise: the tracer's interpolated normal then falls back to
    the geometric one, :func:`~..tracing.shading.shading_normal`, or gets no share of it)."""
    nm = qs.inst_nmat[inst]
    c = corner_normals(qs, qs.inst_mesh[inst], gt)
    for r in range(4):
        if r == 0:
            ox, oy, oz = nx, ny, nz
        else:
            ox, oy, oz = c[3 * r - 3], c[3 * r - 2], c[3 * r - 1]
        wx = nm[0, 0] * ox + nm[0, 1] * oy + nm[0, 2] * oz
        wy = nm[1, 0] * ox + nm[1, 1] * oy + nm[1, 2] * oz
        wz = nm[2, 0] * ox + nm[2, 1] * oy + nm[2, 2] * oz
        ln = math.sqrt(wx * wx + wy * wy + wz * wz)
        if ln > tol.NORMAL_MIN_LENGTH:
            N[r, 0] = wx / ln
            N[r, 1] = wy / ln
            N[r, 2] = wz / ln
        else:
            N[r, 0] = 0.0
            N[r, 1] = 0.0
            N[r, 2] = 0.0


#: Closed-form conditions of :func:`soft_slab` hold with this margin on unit cosines.
_COS_MARGIN = 1e-9


@njit(cache=True, nogil=True)
def soft_slab(qs, inst, gt, nx, ny, nz, j, W, nv, quiet, behind):
    """Light ``j`` (an extent) over one slab polygon ``W[:nv]`` (world) of global triangle
    ``gt``: clears ``quiet[j]`` unless at every point of the polygon, for the geometric
    normal and every shading normal the triangle can interpolate, the light lies wholly
    above the horizon -- so the tracer takes its closed form (``soft_lights._row_exact``:
    a sun's or a sphere's cone, a rectangle in front of the point), and every sample has a
    positive weight -- and clears ``behind[j]`` unless the polygon is behind area light
    j's emitting side (every sample 0).

    The shading normal at a point is the normalised barycentric mix of the corners' normals
    ``w_i``: when ``w_i . X >= mu >= 0`` for every corner, the unit mix also has ``s . X >=
    mu`` (the mix is no longer than the mix of lengths); ``X`` is affine in the point, so
    its polygon's vertices bound it (the clipped polygon holds every slab crossing on the
    triangle). The shadow origin lies ``spawn_offset`` (far below the shaft slack) off the
    surface: the margins include twice the slack."""
    if nv == 0:
        return
    N = np.empty((4, 3))
    _unit_normals(qs, inst, gt, nx, ny, nz, N)
    if N[0, 0] == 0.0 and N[0, 1] == 0.0 and N[0, 2] == 0.0:
        quiet[j] = False
        behind[j] = False
        return
    kind = qs.light_kind[j]
    margin = 2.0 * qs.slack
    cx, cy, cz = qs.light_pos[j, 0], qs.light_pos[j, 1], qs.light_pos[j, 2]
    if kind == LIGHT_AREA:
        dx, dy, dz = qs.light_dir[j, 0], qs.light_dir[j, 1], qs.light_dir[j, 2]
        for v in range(nv):
            f = (W[v, 0] - cx) * dx + (W[v, 1] - cy) * dy + (W[v, 2] - cz) * dz
            if not f < -margin:
                behind[j] = False
            if not f > margin:
                quiet[j] = False
    if not quiet[j]:
        return
    if kind == LIGHT_SUN:
        lim = math.sin(qs.light_half[j]) + _COS_MARGIN
        for r in range(4):
            if r > 0 and N[r, 0] == 0.0 and N[r, 1] == 0.0 and N[r, 2] == 0.0:
                continue
            if not -(N[r, 0] * qs.light_dir[j, 0] + N[r, 1] * qs.light_dir[j, 1]
                     + N[r, 2] * qs.light_dir[j, 2]) >= lim:
                quiet[j] = False
                return
        return
    for r in range(4):
        if r > 0 and N[r, 0] == 0.0 and N[r, 1] == 0.0 and N[r, 2] == 0.0:
            continue
        for v in range(nv):
            if kind == LIGHT_AREA:
                for k in range(4):
                    a = 0.5 * qs.light_size[j, 0] * (1.0 if k & 1 else -1.0)
                    b = 0.5 * qs.light_size[j, 1] * (1.0 if k & 2 else -1.0)
                    xx = cx + a * qs.light_u[j, 0] + b * qs.light_v[j, 0] - W[v, 0]
                    yy = cy + a * qs.light_u[j, 1] + b * qs.light_v[j, 1] - W[v, 1]
                    zz = cz + a * qs.light_u[j, 2] + b * qs.light_v[j, 2] - W[v, 2]
                    if not N[r, 0] * xx + N[r, 1] * yy + N[r, 2] * zz > margin + _COS_MARGIN \
                            * math.sqrt(xx * xx + yy * yy + zz * zz):
                        quiet[j] = False
                        return
            else:  # a sphere: its ball above the tangent plane (the cone of sine r / d)
                xx = cx - W[v, 0]
                yy = cy - W[v, 1]
                zz = cz - W[v, 2]
                if not N[r, 0] * xx + N[r, 1] * yy + N[r, 2] * zz > qs.light_radius[j] \
                        + margin + _COS_MARGIN * math.sqrt(xx * xx + yy * yy + zz * zz):
                    quiet[j] = False
                    return
