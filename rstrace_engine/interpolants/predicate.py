"""The error predicate of radiance interpolants, cell by cell.

What a valid cell guarantees (see docs/INTERPOLANTS.md for the argument):

* **Geometry (all meshes, convex or not).** The cell's lines all cross the plane slab
  ``z_lo <= depth <= z_hi`` inside the *slab shaft* ``S'`` (the hexahedron swept by the
  cell's lines between those depths). Every triangle of the object that meets ``S'`` belongs
  to the surface class ``C`` of the 16 corner hits and faces every line of the cell (its
  normal against all 16 corner directions; line directions are affine in ``(a, b, c, d)``,
  so the corners bound them), no boundary edge of the mesh meets ``S'``, and no triangle
  meets the two end rectangles of ``S'``. A winding-number argument then shows that every line
  of the cell crosses the object exactly once inside the slab, entering class ``C``: a pixel
  whose visible hit on the object lies in the slab is that crossing, whatever the viewpoint.
* **Lights.** The 16 corners (and the test lines) agree on every light's state: contributes,
  occluded by the same object, or not facing / outside the cone. For a contributing light, a
  shaft from the slab's box to the light meets no triangle of any other object, and every
  triangle of the object itself inside it faces the light with no boundary edge inside it;
  then no interior point is shadowed (a shadow ray would have to enter the object through a
  triangle facing away from the light). For an occluded light, the shaft meets nothing but
  the object and the named occluder, and the occluder must cover every shadow segment
  (:func:`.occluders.occluder_covers`). A light off at every corner must be behind every slab
  triangle, or outside its spot cone over the whole slab (or, if in front of all of them,
  its shaft must be empty as for a lit light). A spot cone edge with blend 0 (a step) may not
  cross the slab (:func:`.shafts.cone_state`).
* **Soft light** (a light with an extent: a sphere, a sun with an angle, an area light;
  :func:`_soft_light`). Sampled at the corners (``OCC_SOFT``): the light must be *fully
  visible* over the cell -- the shaft from the slab surface's box to the light's whole
  extent (the ball, the rectangle's box, the sun's cone as a far box grown by its chord)
  meets no other object, and every triangle of the object in it faces every point of the
  extent (the point-light winding argument, shadow ray by shadow ray) -- and the tracer's
  value must then be exact: the ratio estimator's closed form, which it takes where the
  whole extent is above the horizon of the geometric and every interpolable shading normal
  (:func:`.soft_slab.soft_slab`), on a material without a glossy lobe (whose soft samples
  would be a Monte Carlo estimate). Then every shadow sample is unoccluded, the visibility ratio is
  exactly 1 and the pixel's value is the closed form: smooth, deterministic, interpolable.
  While the sampled terms are traced per pixel (:mod:`.sampled_term`, the default), the
  cache's query scene lifts the last two conditions (``light_closed`` for every light with
  an extent, no ``mat_glossy``): what the tracer samples is added per pixel from its own
  samples, and the horizon conditions are proven for every light with an extent.
  Otherwise ``light_shaft`` (penumbra or umbra: not proven), ``self_shadow`` or
  ``soft_sampled`` (a spot with a radius, a disk, an ellipse, a spread, a glossy surface, a
  light crossing the horizon). Not facing at the corners (``-2``): off everywhere when the
  whole extent is behind every slab triangle or the slab is behind an area light. Below the
  root a light with an extent fails the cell (``tunnel_light``).
* **The world's light** is not interpolated: samples store their radiance without the
  world's term at the root, and every interpolated pixel traces its own
  (:mod:`.world_term`, the base tracer's samples). A cell whose ray trees hit a surface
  below the root fails while the world lights (``world_light``): the world's term there
  would be sampled noise in what is interpolated.
* **Textures** are applied per pixel: samples keep ``R + texel * D`` apart
  (:func:`.samples.texture_split`) and the radiance test checks the texel range.
* **Reflection / refraction tunnels** (ray-tree nodes below the root): the shaft between the
  padded boxes of the 16 parent points and the 16 node points, and each node's light shafts,
  meet no other object than those the tree names. Secondary hit points of interior lines are
  not bounded exactly (curved mirrors), so this part is conservative only up to the padding
  :data:`~.tolerances.TUNNEL_MARGIN_REL`: tested, not guaranteed.

Surface classes and boundary edges come from :mod:`.mesh_topology`; shafts and triangle
queries from :mod:`.shafts`.
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import image, stripes
from .. import tolerances as tol
from ..frame import CLASS_FAIL_SHADOW, CLASS_FAIL_SILHOUETTE
from ..geometry.attributes import slot_of
from ..geometry.scene import LIGHT_AREA, LIGHT_SUN
from ..tracing.soft_lights import OCC_SOFT
from .linetree import corner_weights, face_frame, line_points
from .occluders import occluder_covers, sun_umbra
from .shafts import (
    CONE_OFF,
    CONE_STEP,
    MAX_PLANES,
    boundary_edge_in,
    clip_polygon,
    cone_state,
    extent_side,
    hexa_planes,
    hw_shaft,
    light_box,
    load_tri,
    mesh_candidates,
    other_geometry,
    to_object,
    tri_normal,
)
from .soft_slab import soft_slab

log = logging.getLogger(__name__)

#: Predicate outcome of a cell that passed (otherwise a CLASS_FAIL_* code).
VALID = 0
_SIL = CLASS_FAIL_SILHOUETTE
_SHD = CLASS_FAIL_SHADOW
#: Why a cell failed, finer than its pixel class (``check_cells``'s ``detail`` output).
REASONS = ("valid", "corner_miss", "class_change", "light_change", "tree_change", "slab",
           "light_facing", "light_shaft", "self_shadow", "tunnel", "tunnel_light", "spot_cone",
           "self_tunnel", "partial_occluder", "soft_sampled", "world_light", "glossy")
(R_VALID, R_MISS, R_CLASS, R_LIGHT, R_TREE, R_SLAB, R_FACING, R_SHAFT, R_SELF, R_TUNNEL,
 R_TUNNEL_LIGHT, R_CONE, R_SELF_TUNNEL, R_PARTIAL, R_SOFT, R_WORLD,
 R_GLOSSY) = range(len(REASONS))
#: Slab depth margin: half the corners' depth range plus this fraction of the cell's width.
SLAB_WIDTH_MARGIN = 0.25
#: Triangles a self query may collect before the cell fails (conservatively).
MAX_CANDIDATES = 4096

#: Test lines in local cell coordinates: the centre, the 8 facet centres and 4 lines on the
#: diagonals a = c, b = d (where the lines of distant viewpoints run) ...
TEST_BASE = np.array([[.5, .5, .5, .5],
                      [.5, .5, .5, 0], [.5, .5, .5, 1], [.5, .5, 0, .5], [.5, .5, 1, .5],
                      [.5, 0, .5, .5], [.5, 1, .5, .5], [0, .5, .5, .5], [1, .5, .5, .5],
                      [.25, .25, .25, .25], [.75, .75, .75, .75],
                      [.25, .75, .25, .75], [.75, .25, .75, .25]])
#: ... and 4 more interior lines for non-convex meshes.
TEST_EXTRA = np.array([[.25, .5, .25, .5], [.75, .5, .75, .5],
                       [.5, .25, .5, .25], [.5, .75, .5, .75]])
TEST_POINTS = np.concatenate([TEST_BASE, TEST_EXTRA])
N_TEST_BASE = len(TEST_BASE)
N_TEST_ALL = len(TEST_POINTS)
_TEST_WEIGHTS = corner_weights(TEST_POINTS)  # (17, 16)

#: The radiance test asks for this fraction of epsilon at the test lines (the error between
#: them is not bounded by the samples).
TEST_EPS_FRAC = 0.5
#: Slope of the sRGB curve at 1 (d sRGB / dx at x = 1).
_SRGB_SLOPE_AT_1 = 1.055 / 2.4


def extended_display(linear: np.ndarray) -> np.ndarray:
    """The display transform (:func:`.image.to_display`) continued linearly above 1.

    The radiance test compares samples here: clamping at 1 would let corners that are all
    saturated vouch for the inside of a cell where the true radiance dips below 1 (the ring
    around a light's bright spot). Below 1 it is exactly the display transform.
    """
    x = np.nan_to_num(np.asarray(linear, np.float64), nan=0.0)
    over = np.maximum(x - 1.0, 0.0)
    return image.to_display(x) + _SRGB_SLOPE_AT_1 * over

def radiance_ok(rad: np.ndarray, cell_samples: np.ndarray, nsamp: np.ndarray,
                epsilon: float, tex=None, tex_max=None) -> np.ndarray:
    """The radiance test of cells (m of them): quadrilinear interpolation of the 16 corner
    samples within ``TEST_EPS_FRAC * epsilon`` of every traced test line, in the extended
    display space; non-finite radiance fails.

    rad (S, 3) sample radiance; cell_samples (m, 16 + N_TEST_ALL) sample ids (corners, then
    test lines in :data:`TEST_POINTS` order); nsamp (m,) how many are used. Returns (m,) bool.

    Textures (:func:`.samples.texture_split`): with ``tex = (D, texel, flag)`` per sample,
    ``rad`` is R and a line's radiance ``R + texel * D``; a pixel gets the interpolated R
    and D with its own texel. So at every test line the interpolated and the traced
    radiance are compared for its own texel and for texels ``0, 1/4, ... 1`` times
    ``tex_max`` (3,) (the texel range: a pixel's texel can be any of them). A cell with a
    flagged sample (a texture below the root, a failed split) fails.
    """
    corners = rad[cell_samples[:, :16]]  # (m, 16, 3)
    tid = np.maximum(cell_samples[:, 16:], 0)
    tests = rad[tid]  # (m, T, 3)
    interp = np.einsum("tk,mkc->mtc", _TEST_WEIGHTS, corners)
    used = np.arange(N_TEST_ALL)[None, :] < (nsamp - 16)[:, None]
    finite = np.isfinite(corners).all(axis=(1, 2)) & np.isfinite(
        np.where(used[:, :, None], tests, 0.0)).all(axis=(1, 2))
    err = np.abs(extended_display(interp) - extended_display(tests)).max(axis=2)
    if tex is not None:
        dif, texel, flag = tex
        ids = np.where(np.arange(cell_samples.shape[1])[None, :] < nsamp[:, None],
                       cell_samples, cell_samples[:, :1])
        finite &= (flag[ids] == 0).all(axis=1)
        dc = dif[cell_samples[:, :16]]
        if np.any(dc != 0.0):
            dt = dif[tid]
            idif = np.einsum("tk,mkc->mtc", _TEST_WEIGHTS, dc)
            tmax = np.ones(3) if tex_max is None else np.asarray(tex_max, np.float64)
            for t in [texel[tid]] + [f * tmax for f in (0.0, 0.25, 0.5, 0.75, 1.0)]:
                e = np.abs(extended_display(interp + t * idif)
                           - extended_display(tests + t * dt)).max(axis=2)
                err = np.maximum(err, e)
    err = np.where(used, err, 0.0)
    return finite & (err.max(axis=1) <= TEST_EPS_FRAC * epsilon)


# ----------------------------------------------------------------------------- per cell


class SampleArrays(NamedTuple):
    """Traced lines (corner and test samples) and their ray trees, for the kernels."""

    rad: np.ndarray  # (S, 3) float64 radiance
    inst: np.ndarray  # (S,) int32 instance of the slab crossing, -1 when none
    cls: np.ndarray  # (S,) int32 surface class of the crossing
    depth: np.ndarray  # (S,) float64 depth of the crossing below the front face
    node_start: np.ndarray  # (S,) int64 first ray-tree node (the root) in the node arrays
    node_count: np.ndarray  # (S,) int32
    node_path: np.ndarray  # (Nn,) int64 root 1, reflect 2p, refract 2p + 1
    node_inst: np.ndarray  # (Nn,) int32, -1 miss
    node_cls: np.ndarray  # (Nn,) int32, -1 miss
    node_occ: np.ndarray  # (Nn, L) int32 occluder per light (-1 none, -2 not facing)
    node_point: np.ndarray  # (Nn, 3) float64


#: Vertices of the slab polygons kept for the occluder proof (more: the box's corners).
MAX_HULL_POINTS = 64


@njit(cache=True, nogil=True)
def _box_corners(lo, hi, out):
    for c in range(8):
        out[c, 0] = hi[0] if c & 1 else lo[0]
        out[c, 1] = hi[1] if c & 2 else lo[1]
        out[c, 2] = hi[2] if c & 4 else lo[2]


@njit(cache=True, nogil=True)
def _same_tree(sm, s, r):
    """R_VALID when samples s and r have the same position-independent ray tree, else
    R_CLASS (the root differs), R_LIGHT (a light's state differs) or R_TREE."""
    n = sm.node_count[s]
    if sm.node_count[r] != n:
        return R_TREE
    a = sm.node_start[s]
    b = sm.node_start[r]
    L = sm.node_occ.shape[1]
    for q in range(n):
        if sm.node_path[a + q] != sm.node_path[b + q] or sm.node_inst[a + q] \
                != sm.node_inst[b + q] or sm.node_cls[a + q] != sm.node_cls[b + q]:
            return R_CLASS if q == 0 else R_TREE
        for j in range(L):
            if sm.node_occ[a + q, j] != sm.node_occ[b + q, j]:
                return R_LIGHT
    return R_VALID


@njit(cache=True, nogil=True)
def _points_box(sm, ids, ns, q, margin_rel, slack, lo, hi):
    """Box of node ``q``'s points over samples ``ids[:ns]``, padded."""
    for k in range(3):
        lo[k] = np.inf
        hi[k] = -np.inf
    for u in range(ns):
        row = sm.node_start[ids[u]] + q
        for k in range(3):
            lo[k] = min(lo[k], sm.node_point[row, k])
            hi[k] = max(hi[k], sm.node_point[row, k])
    pad = margin_rel * math.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2
                                 + (hi[2] - lo[2]) ** 2) + slack
    for k in range(3):
        lo[k] -= pad
        hi[k] += pad


@njit(cache=True, nogil=True)
def _slab(box, inst, face, depth, coord, zmin, zmax, V):
    """Slab shaft of a cell around depths [zmin, zmax]: its 8 vertices in ``V``; returns
    (z_lo, z_hi)."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    s = 1.0 / (1 << depth)
    a0 = li + coord[0] * s * wi
    a1 = li + (coord[0] + 1) * s * wi
    b0 = lj + coord[1] * s * wj
    b1 = lj + (coord[1] + 1) * s * wj
    c0 = li + coord[2] * s * wi
    c1 = li + (coord[2] + 1) * s * wi
    d0 = lj + coord[3] * s * wj
    d1 = lj + (coord[3] + 1) * s * wj
    zm = 0.5 * (zmin + zmax) / L
    w = max((1 - zm) * (a1 - a0) + zm * (c1 - c0), (1 - zm) * (b1 - b0) + zm * (d1 - d0))
    margin = 0.5 * (zmax - zmin) + SLAB_WIDTH_MARGIN * w + tol.SLAB_DEPTH_PAD_REL * L
    zlo = max(zmin - margin, 0.0)
    zhi = min(zmax + margin, L)
    for v in range(8):
        z = zhi if v & 4 else zlo
        f = z / L
        x = (1 - f) * (a1 if v & 1 else a0) + f * (c1 if v & 1 else c0)
        y = (1 - f) * (b1 if v & 2 else b0) + f * (d1 if v & 2 else d0)
        V[v, k] = front - z if neg else front + z
        V[v, i] = x
        V[v, j] = y
    return zlo, zhi


@njit(cache=True, nogil=True, inline="always")
def _self_slab(qs, inst, cls, dirs, pl, bb, cand, P, Q, fac, bfac, quiet, behind, hb, hv,
               nhv):
    """Geometry test of the slab shaft ``pl`` (6 planes, world) against the object itself.

    dirs (16, 3) world corner directions. Sets per light ``fac[j]`` / ``bfac[j]`` when some
    slab triangle faces / faces away from light j (for a light with an extent: from some
    point of it, :func:`.shafts.extent_side`), and ``hb`` (6,) to the world box of the
    object's surface inside the slab (which holds every slab crossing), and ``hv[:nhv[0]]``
    to the vertices of those clipped polygons (``nhv[0] = -1`` when more than ``hv`` holds).
    Lights with an extent (:func:`.soft_slab.soft_slab`): clears ``quiet[j]`` unless the
    tracer's value of light j is its closed form wherever the light is fully visible on the
    slab, and ``behind[j]`` unless the whole slab is behind area light j's emitting side.
    Returns True when the cell passes.
    """
    xf = qs.inst_xform[inst]
    inv = qs.inst_inv[inst]
    plo = np.empty((6, 4))
    bbo = np.empty(6)
    six = np.int64(6)  # (not a literal 6: a constant argument compiles its callee again)
    to_object(xf, inv, pl, six, bb, plo, bbo)
    m = qs.inst_mesh[inst]
    nc = mesh_candidates(qs, m, plo, six, bbo, cand, P, Q)
    if nc < 0:
        return False
    if nc == 0:
        for j in range(quiet.shape[0]):
            quiet[j] = False  # nothing to prove the soft lights' flags on
            behind[j] = False
    do = np.empty((16, 3))
    for c in range(16):
        for k in range(3):
            do[c, k] = inv[k, 0] * dirs[c, 0] + inv[k, 1] * dirs[c, 1] + inv[k, 2] * dirs[c, 2]
    L = qs.light_kind.shape[0]
    for k in range(3):
        hb[k] = np.inf
        hb[3 + k] = -np.inf
    W = np.empty((P.shape[0], 3))
    s0 = qs.inst_mat_start[inst]
    nslot = qs.inst_mat_start[inst + 1] - s0
    for q in range(nc):
        t = cand[q]
        gt = qs.tri[t]
        if qs.tri_class[gt] != cls:
            return False
        if nslot > 0 and qs.mat_glossy[qs.inst_mat[
                s0 + min(slot_of(qs, qs.inst_mesh[inst], gt), nslot - 1)]]:
            for j in range(L):
                quiet[j] = False  # a glossy lobe: the soft samples estimate it (noise)
        load_tri(qs, t, P)
        nv = clip_polygon(plo, 0, six, P, 3, Q)
        for v in range(nv):
            m_ = nhv[0]
            if m_ >= hv.shape[0]:
                nhv[0] = -1
            for k in range(3):
                w = xf[k, 0] * P[v, 0] + xf[k, 1] * P[v, 1] + xf[k, 2] * P[v, 2] + xf[k, 3]
                W[v, k] = w
                hb[k] = min(hb[k], w)
                hb[3 + k] = max(hb[3 + k], w)
                if 0 <= m_ < hv.shape[0]:
                    hv[m_, k] = w
            if 0 <= m_ < hv.shape[0]:
                nhv[0] = m_ + 1
        nx, ny, nz = tri_normal(qs, t)
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        for c in range(16):
            s = nx * do[c, 0] + ny * do[c, 1] + nz * do[c, 2]
            dl = math.sqrt(do[c, 0] ** 2 + do[c, 1] ** 2 + do[c, 2] ** 2)
            if not s < -tol.FACING_EPS_REL * ln * dl:
                return False
        if boundary_edge_in(qs, t, plo, six):
            return False
        # the end rectangles: clip by the four side planes, then look for a crossing of the
        # z-lo / z-hi planes
        load_tri(qs, t, P)
        n = clip_polygon(plo, 0, np.int64(4), P, 3, Q)
        for e in range(4, 6):
            lo_s = np.inf
            hi_s = -np.inf
            for v in range(n):
                s = plo[e, 0] * P[v, 0] + plo[e, 1] * P[v, 1] + plo[e, 2] * P[v, 2] \
                    + plo[e, 3] - qs.slack
                lo_s = min(lo_s, s)
                hi_s = max(hi_s, s)
            if n > 0 and lo_s <= qs.slack and hi_s >= -qs.slack:
                return False
        for j in range(L):
            side = extent_side(qs, xf, inv, t, j, nx, ny, nz)
            if side >= 0:
                fac[j] = True
            if side <= 0:
                bfac[j] = True
            if qs.light_ext[j] and qs.light_kind[j] >= 0:
                soft_slab(qs, inst, gt, nx, ny, nz, j, W, nv, quiet, behind)
    return True


@njit(cache=True, nogil=True)
def _self_shadow(qs, inst, j, pl, npl, bb, cand, P, Q):
    """Every triangle of the object inside light j's shaft faces the light (every point of
    its extent, :func:`.shafts.extent_side`), and no boundary edge of it is inside the
    shaft."""
    xf = qs.inst_xform[inst]
    inv = qs.inst_inv[inst]
    plo = np.empty((MAX_PLANES, 4))
    bbo = np.empty(6)
    to_object(xf, inv, pl, npl, bb, plo, bbo)
    nc = mesh_candidates(qs, qs.inst_mesh[inst], plo, npl, bbo, cand, P, Q)
    if nc < 0:
        return False
    for q in range(nc):
        t = cand[q]
        nx, ny, nz = tri_normal(qs, t)
        if extent_side(qs, xf, inv, t, j, nx, ny, nz) != 1:
            return False
        if boundary_edge_in(qs, t, plo, npl):
            return False
    return True


@njit(cache=True, nogil=True)
def _light_shafts(qs, sm, s0, row, inst, lo, hi, self_ok, fac, bfac, quiet, behind, cand, P,
                  Q, pl, bb, plo, bbo, named, pts, npts):
    """Light tests of one ray-tree node (row offset ``row`` in sample ``s0``) whose points
    lie in box (lo, hi) on instance ``inst``. ``self_ok``: run the self-shadow test (root
    level, where the slab facing flags ``fac``/``bfac`` and the soft-light flags ``quiet``,
    ``behind`` of :func:`_self_slab` are known). Returns R_VALID or the reason (R_FACING,
    R_SHAFT, R_SELF, R_SOFT; the caller maps these below the root). ``pts[:npts]``: world
    points whose convex hull holds the node's points (for the occluder proof)."""
    L = qs.light_kind.shape[0]
    blo = np.empty(3)
    bhi = np.empty(3)
    for j in range(L):
        if qs.light_kind[j] < 0:
            # a deleted light's slot (LIGHT_NONE): no light. Its stale position once made
            # the facing and shaft tests fail cells everywhere (no pixel of a room was
            # interpolated after a light was deleted)
            continue
        occ = sm.node_occ[sm.node_start[s0] + row, j]
        if qs.light_ext[j]:
            r = _soft_light(qs, inst, j, occ, lo, hi, self_ok, fac, bfac, quiet, behind, cand,
                            P, Q, pl, bb, plo, bbo, named, pts, npts)
            if r != R_VALID:
                return r
            continue
        lit = occ == -1
        # the spot cone over the points' box: a step inside the cell fails it; a cell the
        # cone leaves entirely dark is off for every line
        cone = cone_state(qs, j, lo, hi)
        if cone == CONE_STEP or (cone == CONE_OFF and occ != -2):
            return R_CONE
        if occ == -2 and cone == CONE_OFF:
            continue
        if occ == -2:
            if not self_ok:
                continue  # below the root: tested only
            if bfac[j] and not fac[j]:
                continue  # behind every slab triangle: off for every line
            if bfac[j]:
                return R_FACING  # the light's facing changes inside the cell
            lit = True  # facing every slab triangle: may contribute inside, treat as lit
        light_box(qs, j, lo, hi, blo, bhi)
        npl = hw_shaft(lo, hi, blo, bhi, qs.slack, pl, bb)
        named[0] = inst
        n_named = 1
        if not lit:
            named[1] = occ
            n_named = 2
        if other_geometry(qs, pl, npl, bb, named, n_named, plo, bbo, P, Q):
            return R_SHAFT
        if not lit and not occluder_covers(qs, occ, j, pts, npts, pl, npl, bb, cand, P, Q):
            return R_PARTIAL  # the occluder may let light through between the test lines
        if lit and self_ok:
            if bfac[j] or not _self_shadow(qs, inst, j, pl, npl, bb, cand, P, Q):
                return R_SELF
    return R_VALID


@njit(cache=True, nogil=True, inline="always")
def _soft_light(qs, inst, j, occ, lo, hi, self_ok, fac, bfac, quiet, behind, cand, P, Q, pl,
                bb, plo, bbo, named, pts, npts):
    """Light ``j`` with an extent at a ray-tree node whose points lie in box (lo, hi) on
    instance ``inst`` (see the module doc, "Soft light"). At the root:

    * not facing at the corners (``-2``): every sample of every line is 0 when the whole
      extent is behind every slab triangle's plane, or the slab is behind an area light's
      emitting side; else ``R_FACING``;
    * sampled (``OCC_SOFT``): the tracer's value must be its closed form wherever the light
      is fully visible (``quiet``, else ``R_SOFT``), and the light fully visible over the
      cell: the Haines-Wallace shaft from the slab surface's box to the light's extent
      (:func:`.shafts.light_box`) holds no other object's triangle (``R_SHAFT``), and every
      triangle of the object in it faces every point of the extent, with no boundary edge
      in it (``R_SELF``);
    * or, for a sun, off over the whole cell: an umbra -- a closed convex object in the
      shaft blocks every direction of its cone from every point of the cell's surface
      (:func:`.occluders.sun_umbra`, from the hull ``pts[:npts]``), so every shadow sample
      of every line is blocked and the light's value is 0.

    Below the root a light with an extent is not proven: ``R_SHAFT`` (the caller's
    ``tunnel_light``)."""
    if not self_ok:
        return R_SHAFT
    if occ == -2:
        if (bfac[j] and not fac[j]) or behind[j]:
            return R_VALID
        return R_FACING
    if occ != OCC_SOFT:
        return R_LIGHT  # (a sampled light never names an occluder)
    sun = qs.light_kind[j] == LIGHT_SUN
    if not sun:
        if not quiet[j]:
            return R_SOFT
        if bfac[j]:
            return R_SELF
    blo = np.empty(3)
    bhi = np.empty(3)
    light_box(qs, j, lo, hi, blo, bhi)
    npl = hw_shaft(lo, hi, blo, bhi, qs.slack, pl, bb)
    named[0] = inst
    r = R_VALID
    if not quiet[j]:
        r = R_SOFT
    elif bfac[j]:
        r = R_SELF
    elif other_geometry(qs, pl, npl, bb, named, np.int64(1), plo, bbo, P, Q):
        r = R_SHAFT
    if r != R_VALID:
        if sun and sun_umbra(qs, j, pl, npl, bb, cand, P, Q, plo, bbo, named, pts, npts):
            return R_VALID
        return r
    if not _self_shadow(qs, inst, j, pl, npl, bb, cand, P, Q):
        return R_SELF
    return R_VALID


@njit(cache=True, nogil=True)
def corner_trees(sm, corners, out):
    """The ray-tree test of :func:`check_cells` on the 16 corners alone (corners (m, 16)
    sample ids): ``out[c]`` is R_VALID or the reason :func:`check_cells` would give the cell
    (it compares the corners first, in this order; the slab crossings' instance and class
    are tested before shading). Cells that fail here need no test lines shaded."""
    for c in range(corners.shape[0]):
        r = R_VALID
        for u in range(1, 16):
            r = _same_tree(sm, corners[c, 0], corners[c, u])
            if r != R_VALID:
                break
        out[c] = r


def check_cells(qs, box, sm, cell_inst, cell_face, cell_depth, cell_coord, cell_samples,
                cell_nsamp, status, detail, zlo_out, zhi_out, cls_out):
    """Geometric part of the error predicate for a batch of cells.

    cell_samples (nc, S) int32 sample ids: the 16 corners (bit order of
    :func:`~.linetree.corner_weight`) then the test lines; cell_nsamp (nc,) how many.
    Outputs: status (nc,) int32 VALID or a CLASS_FAIL_* code, detail (nc,) int8 an index
    into :data:`REASONS`; the slab (zlo, zhi) and the surface class of valid cells.
    Cells dealt in turn to numba's thread count (``stripes.run`` of :func:`_check_cells`).
    """
    stripes.run(_check_cells, len(cell_inst), qs, box, sm, cell_inst, cell_face, cell_depth,
                cell_coord, cell_samples, cell_nsamp, status, detail, zlo_out, zhi_out,
                cls_out)


@njit(cache=True, nogil=True, error_model="numpy")
def _check_cells(qs, box, sm, cell_inst, cell_face, cell_depth, cell_coord, cell_samples,
                 cell_nsamp, status, detail, zlo_out, zhi_out, cls_out, first, step):
    """:func:`check_cells` for cells ``first, first + step, ...``: serial (stripes.py; NRT
    kept: _check_one allocates). _check_one, _self_slab, _soft_light (one call site each)
    are inlined: a level compiled alone re-optimises and re-emits its callees' chain."""
    L = qs.light_kind.shape[0]
    for c in range(first, cell_inst.shape[0], step):
        r = _check_one(qs, box, sm, cell_inst[c], cell_face[c], cell_depth[c], cell_coord[c],
                       cell_samples[c], cell_nsamp[c], L, zlo_out, zhi_out, cls_out, np.int64(c))
        detail[c] = r
        status[c] = VALID if r == R_VALID else (
            _SIL if r == R_MISS or r == R_CLASS or r == R_SLAB else _SHD)


@njit(cache=True, nogil=True, inline="always")
def _check_one(qs, box, sm, inst, face, depth, coord, ids, ns, L, zlo_out, zhi_out, cls_out,
               c):
    s0 = ids[0]
    cls = sm.cls[s0]
    for u in range(ns):
        s = ids[u]
        if sm.inst[s] != inst:
            return R_MISS
        if sm.cls[s] != cls:
            return R_CLASS
    for u in range(1, ns):
        r = _same_tree(sm, s0, ids[u])
        if r != R_VALID:
            return r
    if qs.world_light:
        # the world's term at the root is left out of the samples and traced per pixel
        # (world_term.py); below the root it would be sampled noise in what is
        # interpolated: a reflection or refraction that hits a surface fails the cell
        for q in range(1, sm.node_count[s0]):
            if sm.node_inst[sm.node_start[s0] + q] >= 0:
                return R_WORLD
    zmin = np.inf
    zmax = -np.inf
    for u in range(ns):
        zmin = min(zmin, sm.depth[ids[u]])
        zmax = max(zmax, sm.depth[ids[u]])
    V = np.empty((8, 3))
    zlo, zhi = _slab(box, inst, face, depth, coord, zmin, zmax, V)
    pl = np.empty((MAX_PLANES, 4))
    hexa_planes(V, qs.slack, pl)
    bb = np.empty(6)
    for k in range(3):
        bb[k] = np.inf
        bb[3 + k] = -np.inf
        for v in range(8):
            bb[k] = min(bb[k], V[v, k])
            bb[3 + k] = max(bb[3 + k], V[v, k])
    # corner directions
    dirs = np.empty((16, 3))
    F = np.empty(3)
    B = np.empty(3)
    sc = 1.0 / (1 << depth)
    for q in range(16):
        line_points(box, inst, face, (coord[0] + (q & 1)) * sc,
                    (coord[1] + ((q >> 1) & 1)) * sc, (coord[2] + ((q >> 2) & 1)) * sc,
                    (coord[3] + ((q >> 3) & 1)) * sc, F, B)
        for m in range(3):
            dirs[q, m] = B[m] - F[m]
    cand = np.empty(MAX_CANDIDATES, np.int32)
    P = np.empty((MAX_PLANES + 8, 3))
    Q = np.empty((MAX_PLANES + 8, 3))
    fac = np.zeros(max(L, 1), np.bool_)
    bfac = np.zeros(max(L, 1), np.bool_)
    quiet = np.zeros(max(L, 1), np.bool_)
    behind = np.zeros(max(L, 1), np.bool_)
    for j in range(L):
        quiet[j] = qs.light_closed[j]
        behind[j] = qs.light_kind[j] == LIGHT_AREA
    hb = np.empty(6)
    hv = np.empty((MAX_HULL_POINTS, 3))
    nhv = np.zeros(1, np.int64)
    if not _self_slab(qs, inst, cls, dirs, pl, bb, cand, P, Q, fac, bfac, quiet, behind, hb,
                      hv, nhv):
        return R_SLAB
    # the light shafts and the first tunnels start from the surface inside the slab
    if hb[0] > hb[3]:
        hb[:] = bb
    lo = np.empty(3)
    hi = np.empty(3)
    for k in range(3):
        hb[k] -= qs.slack
        hb[3 + k] += qs.slack
        lo[k] = hb[k]
        hi[k] = hb[3 + k]
    spl = np.empty((MAX_PLANES, 4))
    sbb = np.empty(6)
    plo = np.empty((MAX_PLANES, 4))
    bbo = np.empty(6)
    named = np.empty(2, np.int32)
    if nhv[0] <= 0:  # too many polygon vertices: the box's corners
        _box_corners(lo, hi, hv)
        nhv[0] = 8
    # (the row, the flag and the count as variables: constant arguments compile the
    # callees once more, for their literal values)
    r = _light_shafts(qs, sm, s0, np.int64(0), inst, lo, hi, np.bool_(True), fac, bfac, quiet,
                      behind, cand, P, Q, spl, sbb, plo, bbo, named, hv, nhv[0])
    if r != R_VALID:
        return r
    # reflection / refraction tunnels and their lights
    nn = sm.node_count[s0]
    base = sm.node_start[s0]
    plo_ = np.empty(3)
    phi_ = np.empty(3)
    for q in range(1, nn):
        ppath = sm.node_path[base + q] >> 1
        pq = 0
        for x in range(q):
            if sm.node_path[base + x] == ppath:
                pq = x
        if pq == 0:
            for k in range(3):
                plo_[k] = hb[k]
                phi_[k] = hb[3 + k]
        else:
            _points_box(sm, ids, ns, pq, tol.TUNNEL_MARGIN_REL, qs.slack, plo_, phi_)
        _points_box(sm, ids, ns, q, tol.TUNNEL_MARGIN_REL, qs.slack, lo, hi)
        npl = hw_shaft(plo_, phi_, lo, hi, qs.slack, spl, sbb)
        named[0] = sm.node_inst[base + pq]
        named[1] = sm.node_inst[base + q]
        if named[0] == named[1] and named[0] >= 0 and not qs.mesh_convex[
                qs.inst_mesh[named[0]]]:
            # reflection / refraction into the same non-convex object: its own geometry
            # could cut interior lines' segments (for a convex one it cannot)
            return R_SELF_TUNNEL
        if other_geometry(qs, spl, npl, sbb, named, np.int64(2), plo, bbo, P, Q):
            return R_TUNNEL
        if sm.node_inst[base + q] >= 0:
            _box_corners(lo, hi, hv)
            r = _light_shafts(qs, sm, s0, q, sm.node_inst[base + q], lo, hi, np.bool_(False),
                              fac, bfac, quiet, behind, cand, P, Q, spl, sbb, plo, bbo, named,
                              hv, np.int64(8))
            if r == R_CONE or r == R_PARTIAL:
                return r
            if r != R_VALID:
                return R_TUNNEL_LIGHT
    zlo_out[c] = zlo
    zhi_out[c] = zhi
    cls_out[c] = cls
    return R_VALID
