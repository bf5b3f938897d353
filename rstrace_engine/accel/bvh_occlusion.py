"""Occlusion of shadow rays: a frame's sampled ones straight from the arrays they were
drawn in, and hard lights' one ray a row (:func:`occluded_rays`).

A soft light's and the world's samples (:func:`~..tracing.soft_lights.soft_rays`: ``n``
a (point, light) row, 16 by default) were traced through the accelerator's general
any-hit query: the samples that carry light gathered into new arrays (``np.take`` of the
origins, directions and bounds), validated and copied again (:func:`.interface.check_rays`),
per-ray instance codes built, five output arrays filled and the instance array compared.
On a world-lit frame that was a quarter of the shadow rays' time (``studio_world``,
docs/bench-frame.md "Session 41 (rays)"). :func:`occluded_kernel` reads the samples where
they lie, row by row, skips those without weight and the rows proven visible, and writes
each sample's visibility.

Its traversal is the any-hit query of :func:`.bvh.trace_kernel` less what only a closest
hit needs: no box distances kept on the stack nor culled against on the way back (a ray
stops at its first hit, any order finds one when there is one), no distance or
barycentrics carried. A node's children are visited farthest entry first: a shadow ray
leaves a surface, and the boxes it enters first hold that surface and its neighbours,
which it has just left; what blocks it lies farther on (session 42: blocked rays 25%
cheaper on rough_materials than in lane order, visible ones ~4% dearer). Whether a
ray is blocked -- a triangle met at ``0 <= t <= tmax`` by the same watertight float64 test
on the same boxes -- is the any-hit query's answer bit for bit: a node is entered, as there,
when the ray enters its box no farther than :func:`.bvh._cull` of ``tmax`` (``tmax`` itself
lost hits at ``t == tmax`` to a box entry rounded past it; the shadow re-shade's per-object
test, :meth:`~.interface.Accelerator.occludes_object`, culls so too), so images are
unchanged.

Hard lights' shadow rays (a point, a spot, a sun without an angle, a light radius of 0:
one ray a (point, light) row, :func:`~..tracing.whitted.shadow_rays`) are the same plain
query: :func:`occluded_rays` traces them with :func:`occluded_kernel`, each ray a row of
one sample, instead of :func:`.bvh.trace_kernel`'s any hit (its box sort and distance
stack, its five outputs).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import stripes
from .box4 import lanes4
from .bvh import STACK_SIZE, SceneBVH, _ascending, _cull, _inv_dir, _near, _u, ray_to_object
from .bvh_build import NEVER_STOP
from .bvh_mesh import leaf_size, leaf_triangle
from .triangle import intersect_sheared, ray_shear

#: The largest float64: a box entry no greater is a box entered (a miss is inf).
_FINITE = np.finfo(np.float64).max


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _push_hit(bounds, child, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, tc, st, sp):
    """Push the children of ``node`` whose box the ray enters within ``[t0, tc]`` (``tc``:
    :func:`.bvh._cull` of the ray's ``tmax``; :func:`.bvh._visit` pushes a box entered up to
    ``tc`` times the slab test's far scale, and its pop skips those entered past ``tc``),
    the farthest entry popped first (module doc; any order finds a hit, so the answer is
    the same). Returns ``sp``."""
    ta, tb, tc4, td = lanes4(bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, tc)
    lim = min(tc, _FINITE)  # (a miss is inf)
    un = _u(node)
    ta, tb, tc4, td, ca, cb, cc, cd = _ascending(
        ta, tb, tc4, td, child[un, _u(0)], child[un, _u(1)], child[un, _u(2)],
        child[un, _u(3)])
    if ta <= lim:
        st[_u(sp)] = ca
        sp += 1
    if tb <= lim:
        st[_u(sp)] = cb
        sp += 1
    if tc4 <= lim:
        st[_u(sp)] = cc
        sp += 1
    if td <= lim:
        st[_u(sp)] = cd
        sp += 1
    return sp


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _mesh_blocks(bounds, child, verts, tris, tri, root, ox, oy, oz, dx, dy, dz, t0, t1, st):
    """Whether the object-space ray meets a triangle of the mesh tree at ``root`` within
    ``[t0, t1]`` (:func:`.bvh._trace_mesh`'s any hit; its boxes to ``_cull(t1)``)."""
    kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
    okx = ox if kx == 0 else (oy if kx == 1 else oz)
    oky = ox if ky == 0 else (oy if ky == 1 else oz)
    okz = ox if kz == 0 else (oy if kz == 1 else oz)
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    tc = _cull(t1)
    st[0] = root
    sp = 1
    while sp > 0:
        sp -= 1
        c = st[_u(sp)]
        if c >= 0:
            sp = _push_hit(bounds, child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, tc, st, sp)
            continue
        code = ~c
        s, k = code >> 3, code & 7
        for i in range(leaf_size(k)):
            g = leaf_triangle(tri, s, k, i)
            a, b, e = tris[g, 0], tris[g, 1], tris[g, 2]
            hit, _, _, _ = intersect_sheared(
                verts[a, kx], verts[a, ky], verts[a, kz], verts[b, kx], verts[b, ky],
                verts[b, kz], verts[e, kx], verts[e, ky], verts[e, kz], okx, oky, okz, sx, sy,
                sz, t0, t1)
            if hit:
                return True
    return False


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _blocked(sb, ox, oy, oz, dx, dy, dz, t0, t1, skip, st, st2):
    """Whether the world ray meets a triangle within ``[t0, t1]`` of any instance but
    ``skip`` (-1: none). One call site per inlined helper, as in :func:`.bvh._trace_ray`."""
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    st[0] = 0
    sp = 1
    q, q_end = 0, 0
    while True:
        if q < q_end:
            i = sb.top_inst[q]
            q += 1
            if i == skip:
                continue
            lx, ly, lz, ex, ey, ez = ray_to_object(sb.inst_inv, i, ox, oy, oz, dx, dy, dz)
            if _mesh_blocks(sb.bounds, sb.child, sb.verts, sb.tris, sb.tri,
                            sb.mesh_root[sb.inst_mesh[i]], lx, ly, lz, ex, ey, ez, t0, t1, st2):
                return True
            continue
        if sp == 0:
            return False
        sp -= 1
        c = st[_u(sp)]
        if c >= 0:
            sp = _push_hit(sb.top_bounds, sb.top_child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz,
                           t0, _cull(t1), st, sp)
        else:
            q = (~c) >> 3
            q_end = q + ((~c) & 7)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def occluded_kernel(sb, o, d, tmax, w, n, row_skip, row_proven, vis, stop, counts, stacks,
                    first, step):
    """The visibility of sampled shadow rays, ``n`` a row: sample ``k`` of row ``r = k //
    n`` is traced (from ``o[k]`` along ``d[k]``, ``0 <= t <= tmax[k]``, leaving instance
    ``row_skip[r]`` out, -1: none) when ``w[k] > 0`` and the row is not ``row_proven[r]``
    (visible without a ray); ``vis[k]``: True where it was not blocked or its row is proven,
    False where ``w[k] <= 0`` (no ray). Rows are dealt in blocks (:mod:`~rstrace_engine.
    stripes`); ``counts[first]`` (int64) receives the rays traced, the proven samples, the
    rays that left an instance out and the rays whose origin or direction is not finite
    or whose bound is NaN (traced all the same: the caller raises). ``stop``:
    :func:`.bvh.trace_kernel`'s (a stopped kernel leaves later blocks' ``vis`` False: the
    caller discards them).
    ``stacks`` (step, 2, STACK_SIZE) int32."""
    m = row_skip.shape[0]
    st, st2 = stacks[first, 0], stacks[first, 1]
    traced, proven, own, bad = 0, 0, 0, 0
    block = -1
    for q in range(stripes.stripe_len(m, first, step)):
        r = stripes.stripe_item(q, first, step)
        if r >= m:
            break
        if r // stripes.BLOCK != block:
            block = r // stripes.BLOCK
            if stop[0] != 0:
                break
        skip = row_skip[r]
        pr = row_proven[r]
        for k in range(r * n, (r + 1) * n):
            if not w[k] > 0.0:
                vis[k] = False
                continue
            if pr:
                vis[k] = True
                proven += 1
                continue
            ox, oy, oz, dx, dy, dz = o[k, 0], o[k, 1], o[k, 2], d[k, 0], d[k, 1], d[k, 2]
            if not (np.isfinite(ox) and np.isfinite(oy) and np.isfinite(oz)
                    and np.isfinite(dx) and np.isfinite(dy) and np.isfinite(dz)):
                bad += 1
            t1 = tmax[k]
            if t1 != t1:
                bad += 1
            traced += 1
            if skip >= 0:
                own += 1
            vis[k] = not (0.0 <= t1 and _blocked(sb, ox, oy, oz, dx, dy, dz, 0.0, t1, skip,
                                                  st, st2))
    counts[first, 0] = traced
    counts[first, 1] = proven
    counts[first, 2] = own
    counts[first, 3] = bad


def occluded_samples(sb: SceneBVH, o, d, tmax, w, n: int, row_skip, row_proven,
                     stop: np.ndarray = NEVER_STOP):
    """Run :func:`occluded_kernel` on the calling thread's numba thread count over the
    rows' samples. Returns ``(vis (k,) bool, counts (4,) int64)``; raises ``ValueError``
    as :func:`.interface.check_rays` does when a traced ray is not finite."""
    m = len(row_skip)
    vis = np.zeros(m * n, np.bool_)
    k = stripes.threads_for(stripes.blocks_of(m))
    counts = np.zeros((k, 4), np.int64)
    stacks = np.empty((k, 2, STACK_SIZE), np.int32)
    stripes.run(occluded_kernel, stripes.blocks_of(m), sb, o, d, tmax, w, int(n),
                np.ascontiguousarray(row_skip, np.int32),
                np.ascontiguousarray(row_proven, np.bool_), vis, stop, counts, stacks)
    total = counts.sum(axis=0)
    if total[3]:
        raise ValueError("rays: NaN or infinite origin or direction")
    return vis, total


def occluded_rays(sb: SceneBVH, o, d, tmax, skip=None, stop: np.ndarray = NEVER_STOP):
    """Whether each ray ``o[r] + t d[r]``, ``0 <= t <= tmax[r]``, meets a triangle
    (leaving instance ``skip[r]`` out, -1: none; None: none left out): what
    :func:`.bvh.trace_kernel`'s any hit from ``tmin = 0`` answers, bit for bit, by
    :func:`occluded_kernel` (a row of one sample per ray; no new signature). Returns
    ``(blocked (n,) bool, counts (4,) int64)`` as :func:`occluded_samples`."""
    n = len(tmax)
    o = np.ascontiguousarray(o, np.float64).reshape(n, 3)
    d = np.ascontiguousarray(d, np.float64).reshape(n, 3)
    tmax = np.ascontiguousarray(tmax, np.float64)
    skip = np.full(n, -1, np.int32) if skip is None else skip
    vis, counts = occluded_samples(sb, o, d, tmax, np.ones(n), 1, skip, np.zeros(n, np.bool_),
                                   stop)
    return ~vis, counts
