"""The records' sampled-ray queries, and the samples an object edit provably leaves blocked
(BASE re-shade under soft light, issue 20 item 5).

:func:`query_samples` runs the per-pixel records' queries of the soft lights' and the
world's sampled rays (:func:`~.sample_rays.query_light_bits`, :func:`~.sample_rays.
query_world`) at the primary or the secondary nodes: per node, the lights (and the world)
whose samples an edit batch may change, and which samples. A sample that was *blocked* in
the records' frame is flagged wherever its ray may cross a place an edited object *left*
(its blocker may have been that object: the incremental frame tests it again,
:mod:`.shadow_reshade`). Where the same ray passes deep through an object the edits
*placed* -- moved, added, re-meshed or shown, in the edited scene -- it is blocked after
the edits too: its visibility, and the node's term, stay what they were. A small object
moved a little (old and new places overlapping) leaves most of its shadow's samples so, and
proving it here drops them, and the rows left with none, before the frame draws their
rays again (``studio``'s mirror ball: of the ~31,000 world rows and ~5,800 sphere-light
rows the query flags, about three quarters are proven so in the frame).

**The proof.** An object's closed surface holds a ball (:func:`~.object_rays.solid_ball`:
centre ``c``, inner radius ``r_in``, its vertices within ``r_out``, in its own space): a
segment that starts outside the outer sphere and comes within the inner radius of ``c``
meets it, by the accelerator's watertight test (:mod:`.object_rays`). In the world, under
the object's matrix ``M`` (``M^-1`` the accelerator's inverse), a point within ``r_in /
|M^-1|`` of ``M c`` is inside the object-space inner ball and one farther than ``r_out |M|``
outside its outer sphere (:func:`placed_balls`; ``|.|`` the spectral norm). The records
know a node's shadow-ray origin to within ``delta`` (its point quantised, and the spawn
offset: :meth:`~.pixel_records.PixelRecords.margin`) and a world sample's direction to
within :data:`~.tolerances.RECORD_DIR_ERROR` (the normal kept as float32); the proof holds
for every ray within those errors (:func:`_through`):

* **a world sample** (a ray from the spawn point along ``u``): the exact ray's point at
  parameter ``s`` is within ``delta + s * RECORD_DIR_ERROR`` of the recorded one's;
* **an area light's sample** (a segment to a point ``X`` on the light that does not depend
  on the shading point): the exact segment's point at the same fraction of its length is
  within ``delta`` of the recorded one's; fractions past the tracer's shortened end
  (:data:`~.tolerances.SHADOW_END_REL`) are not used;
* **a sun's sample**: its direction does not depend on the point: within ``delta``;
* **a sphere light's row**, all of whose samples were blocked (they are drawn from the
  exact point, in the cone toward the light's ball; the records draw none): every sample
  direction is within ``asin(g / e)`` of the light's centre (``g`` its bounding radius,
  ``e`` its distance, :func:`~.sample_rays._shaft_sphere`), so when that cone, widened by
  the origin's error, lies inside the cone of the placed object's inner ball, before the
  light, every sample meets the object (:func:`_cone_through`). Such a row is also dropped
  when no place an object left comes near its shaft at all (only those can unblock it).

Lengths are trusted to :data:`~.tolerances.PLACED_SLACK_REL` of the coordinates' magnitude
(the world -> object transform and these tests round far below it). Valid where a shadow
ray is blocked by any hit of that watertight float64 test (the accelerator's
:attr:`~..accel.interface.Accelerator.any_hit_by_object`: the BVH, the brute force) and
without shadow linking (an object then blocks some lights only): :meth:`~.frame_reuse.
FrameReuse.take_edits` passes no placed objects otherwise.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.edits import PART_NEW, PART_OLD
from ..geometry.scene import LIGHT_AREA, LIGHT_SUN, SceneArrays
from ..views import fields, view_type
from .light_linking import links_shadows
from .object_rays import BALLS
from .record_codes import _decode_point, _light_hit
from .sample_rays import ALL, SampleCandidates, _shaft_sphere, query_light_bits, query_world
from .soft_lights import _cosine_dir, _sample_one, row_hash, row_uv, world_row_hash


def placed_balls(sa, slots) -> tuple:
    """``(centre (k, 3), r_in (k,), r_out (k,))``: the world balls of the live objects
    ``slots`` of ``sa`` whose surface holds a ball (module doc; the others left out)."""
    cs, rin, rout = [], [], []
    for i in slots:
        if not (0 <= i < len(sa.inst_alive) and sa.inst_alive[i]):
            continue
        c, r_in, r_out = BALLS.get(sa, int(sa.inst_mesh[i]))
        if not (r_in > 0.0 and np.isfinite(r_out)):
            continue
        m = np.asarray(sa.inst_xform[i], np.float64)
        inv = np.asarray(sa.inst_inv[i], np.float64)
        stretch = float(np.linalg.norm(m[:3, :3], 2))
        shrink = float(np.linalg.norm(inv[:3, :3], 2))
        if not (np.isfinite(stretch) and np.isfinite(shrink) and shrink > 0.0):
            continue
        cs.append(m[:3, :3] @ np.asarray(c, np.float64) + m[:3, 3])
        rin.append(r_in / (shrink * (1.0 + tol.PLACED_SLACK_REL)))
        rout.append(r_out * stretch * (1.0 + tol.PLACED_SLACK_REL))
    return (np.asarray(cs, np.float64).reshape(-1, 3), np.asarray(rin, np.float64),
            np.asarray(rout, np.float64))


@njit(cache=True, nogil=True, inline="always")
def _through(px, py, pz, dx, dy, dz, tmax, delta, eps, pc, prin, prout):
    """Does every ray from within ``delta`` of p, along a unit direction within ``eps`` of
    unit d, meet a placed object (its world ball ``pc, prin, prout``, :func:`placed_balls`)
    before the parameter ``tmax``? (Module doc: it starts outside the ball's outer sphere
    and comes within its inner radius.)"""
    for k in range(pc.shape[0]):
        wx, wy, wz = pc[k, 0] - px, pc[k, 1] - py, pc[k, 2] - pz
        start = math.sqrt(wx * wx + wy * wy + wz * wz)
        s = min(max(wx * dx + wy * dy + wz * dz, 0.0), tmax)
        qx, qy, qz = wx - s * dx, wy - s * dy, wz - s * dz
        near = math.sqrt(qx * qx + qy * qy + qz * qz)
        slack = tol.PLACED_SLACK_REL * (start + s + abs(px) + abs(py) + abs(pz))
        if start - delta - slack > prout[k] and near + delta + s * eps + slack < prin[k]:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _cone_through(px, py, pz, lx, ly, lz, g, delta, pc, prin, prout):
    """Does every ray from within ``delta`` of p toward a point within ``g`` of l (a
    sphere light's samples, to its surface) meet a placed object? (Module doc.)"""
    vx, vy, vz = lx - px, ly - py, lz - pz
    e = math.sqrt(vx * vx + vy * vy + vz * vz)
    if not e - delta > g:
        return False
    spread = (math.asin(min(g / (e - delta), 1.0)) + math.asin(min(delta / e, 1.0))
              + tol.RECORD_DIR_ERROR)
    for k in range(pc.shape[0]):
        wx, wy, wz = pc[k, 0] - px, pc[k, 1] - py, pc[k, 2] - pz
        dist = math.sqrt(wx * wx + wy * wy + wz * wz)
        slack = tol.PLACED_SLACK_REL * (dist + e + abs(px) + abs(py) + abs(pz))
        if not (dist - delta - slack > prout[k]
                and dist + delta + slack < (e - delta - g) * (1.0 - tol.PLACED_SLACK_REL)):
            continue  # (p may be inside its outer sphere, or it lies past the light)
        cs = min(max((wx * vx + wy * vy + wz * vz) / (dist * e), -1.0), 1.0)
        ang = math.acos(cs) + spread + math.asin(min(delta / dist, 1.0))
        if ang < 0.5 * math.pi and (dist + delta) * math.sin(ang) + slack < prin[k]:
            return True
    return False


@njit(cache=True, nogil=True, parallel=True)
def drop_world(p_code, wnorm, seed, n, lo, step, levels, shift, old, delta, pc, prin, prout,
               bits):
    """Of :func:`~.sample_rays.query_world`'s ``bits`` (n_rays,) uint64 (changed in place),
    the samples blocked in the records' frame (their bit in ``old`` clear) whose world ray
    provably meets a placed object (:func:`_through`) cleared; rows with every bit
    (:data:`~.sample_rays.ALL`: no per-sample answer) left as they are."""
    for g in prange(bits.shape[0]):
        b = bits[g]
        if b == np.uint64(0) or b == ALL:
            continue
        sx, sy, sz = float(wnorm[g, 0]), float(wnorm[g, 1]), float(wnorm[g, 2])
        nl = math.sqrt(sx * sx + sy * sy + sz * sz)
        sx /= nl
        sy /= nl
        sz /= nl
        px, py, pz = _decode_point(p_code[g], lo, step, levels, shift)
        h = world_row_hash(seed[g])
        for s in range(n):
            bit = np.uint64(1) << np.uint64(s)
            if not b & bit or old[g] & bit:
                continue
            u, v = row_uv(h, n, s)
            dx, dy, dz = _cosine_dir(sx, sy, sz, u, v)  # (as query_world draws it)
            if _through(px, py, pz, dx, dy, dz, np.inf, delta, tol.RECORD_DIR_ERROR, pc,
                        prin, prout):
                b &= ~bit
        bits[g] = b


_DropScene = view_type("_DropScene", SceneArrays, (
    "light_cos_inner", "light_cos_outer", "light_dir", "light_ellipse", "light_half",
    "light_kind", "light_pos", "light_radius", "light_size", "light_soft",
    "light_spot_frame", "light_spot_scaled", "light_spread", "light_u", "light_v"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def drop_lights(sa, p_code, wnorm, seed, n, lo, step, levels, shift, old, lgeo, reg_lo,
                reg_hi, reg_c, reg_r, reg_tag, delta, pc, prin, prout, lights, cols, masks):
    """Of :func:`~.sample_rays.query_light_bits`' answer (``lights`` (n_rays, W) uint64
    light sets, ``masks`` the area lights' and suns' sample bits in their columns ``cols``;
    changed in place), the samples blocked in the records' frame (``old`` (n_rays, L + 1)
    uint64 clear) whose ray provably meets a placed object cleared, and a light's bit where
    none is left; a sphere light's row all of whose samples were blocked dropped where
    every sample meets one (:func:`_cone_through`) or no place an object left (``reg_tag``
    :data:`~.edits.PART_OLD`) comes near its shaft."""
    sa = _DropScene(*fields(sa, _DropScene))  # the fields its loop reads
    L = sa.light_kind.shape[0]
    k_reg = reg_lo.shape[0]
    for g in prange(lights.shape[0]):
        none = True
        for w in range(lights.shape[1]):
            none &= lights[g, w] == np.uint64(0)
        if none or not wnorm[g, 0] == wnorm[g, 0]:
            continue
        px, py, pz = _decode_point(p_code[g], lo, step, levels, shift)
        for j in range(L):
            lb = np.uint64(1) << np.uint64(j & 63)
            if not lights[g, j >> 6] & lb:
                continue
            kind = sa.light_kind[j]
            if kind == LIGHT_AREA or kind == LIGHT_SUN:
                c = cols[j]
                b = masks[g, c] if c >= 0 else np.uint64(0)
                if b == np.uint64(0):
                    continue
                h = row_hash(seed[g], j, L)
                for s in range(n):
                    bit = np.uint64(1) << np.uint64(s)
                    if not b & bit or old[g, j] & bit:
                        continue
                    u, v = row_uv(h, n, s)
                    dx, dy, dz, t, _ = _sample_one(sa, j, px, py, pz, u, v)
                    if _through(px, py, pz, dx, dy, dz, t * (1.0 - tol.SHADOW_END_REL),
                                delta, 0.0, pc, prin, prout):
                        b &= ~bit
                masks[g, c] = b
                if b == np.uint64(0):
                    lights[g, j >> 6] &= ~lb
            elif old[g, j] == np.uint64(0):
                near = False
                for q in range(k_reg):
                    if reg_tag[q] & PART_OLD and _shaft_sphere(
                            px, py, pz, j, reg_c[q, 0], reg_c[q, 1], reg_c[q, 2], reg_r[q],
                            sa.light_kind, lgeo, sa.light_dir) and _light_hit(
                                px, py, pz, j, reg_lo[q], reg_hi[q], sa.light_kind, lgeo,
                                sa.light_dir):
                        near = True
                        break
                if not near or _cone_through(px, py, pz, lgeo[j, 0], lgeo[j, 1], lgeo[j, 2],
                                             lgeo[j, 3], delta, pc, prin, prout):
                    lights[g, j >> 6] &= ~lb


def query_samples(rec, sa, combo, code, wnorm, seed, vis, is_hit, inst64, combo_traced,
                  soft, world_rays: bool, parts: tuple, pos, skip, placed=None) -> tuple:
    """The lights with an extent (``soft``: their set (W,), :mod:`.light_bits`) and the
    world's light (where ``world_rays``) whose sampled rays may cross an edited object
    (``parts``: grown boxes, spheres, tags), at the nodes ``combo``, ``code`` (the primary or the
    secondary ones of the records ``rec``) with their recorded normals, seeds and soft
    samples' visibility ``vis``, the nodes whose sample is in ``skip`` (traced again) left
    out: ``(lights (k, W) uint64, world (k,) bool, SampleCandidates)``. ``placed``: ``(balls
    (:func:`placed_balls`), delta)`` -- the samples they prove stay blocked dropped
    (module doc) -- or None."""
    k = len(combo)
    L = len(sa.light_kind)
    lights = np.zeros((k, len(soft)), np.uint64)
    world = np.zeros(k, np.bool_)
    p_lo, p_hi, p_c, p_r, p_tag = parts
    skip = np.ascontiguousarray(skip)
    # the samples' visibility in the records' frame: visible ones tested where
    # objects came, blocked ones where they went (sample_rays)
    known = vis is not None and not links_shadows(sa)
    old = np.ascontiguousarray(vis, np.uint64) if known else np.zeros((0, 0), np.uint64)
    tag = p_tag if known else np.full(len(p_tag), PART_OLD | PART_NEW, np.int8)
    prove = known and placed is not None and len(placed[0][0]) > 0 and wnorm is not None
    columns = []
    if soft.any():
        if wnorm is None:  # (no seeds recorded: the shaft tests)
            wnorm = np.full((k, 3), np.nan, np.float32)
            seed = np.zeros(k, np.uint64)
        per = [j for j in range(L) if j >> 6 < len(soft) and int(soft[j >> 6]) >> (j & 63) & 1
               and sa.light_kind[j] in (LIGHT_AREA, LIGHT_SUN)]
        cols = np.full(L, -1, np.int64)
        cols[per] = np.arange(len(per))
        masks = np.zeros((k, max(len(per), 1)), np.uint64)
        query_light_bits(sa, combo, code, inst64, combo_traced, wnorm, seed, rec.w_samples,
                         soft, rec.lo, rec.step, rec.levels, rec.shift, p_lo, p_hi, p_c, p_r,
                         tag, pos, old, skip, lights, cols, masks)
        if prove:
            drop_lights(sa, code, wnorm, seed, rec.w_samples, rec.lo, rec.step, rec.levels,
                        rec.shift, old, pos, p_lo, p_hi, p_c, p_r, tag, float(placed[1]),
                        *placed[0], lights, cols, masks)
        columns += [(j, masks[:, cols[j]]) for j in per]
    if world_rays:
        if wnorm is None:
            world = is_hit[combo.astype(np.int64)] & ~skip
        else:
            w_old = (np.ascontiguousarray(old[:, rec.w_lights]) if known
                     else np.zeros(k, np.uint64))
            w_bits = np.empty(k, np.uint64)
            query_world(combo, code, inst64, wnorm, seed, rec.w_samples, rec.lo, rec.step,
                        rec.levels, rec.shift, p_c, p_r, tag, w_old, skip, w_bits)
            if prove:
                drop_world(code, wnorm, seed, rec.w_samples, rec.lo, rec.step, rec.levels,
                           rec.shift, w_old, float(placed[1]), *placed[0], w_bits)
            world = w_bits != 0
            columns.append((L, w_bits))
    return lights, world, SampleCandidates.of(L + 1, columns)
