"""Mesh trees of other build parameters on the dumped rays: visits per ray, and time.

``python scripts/tree_variants.py count|time RAYS.npz VARIANTS SCENE:GROUP[,...]
[--rounds 7]`` with ``RAYS.npz`` from ``scripts/trace_rays.py dump``; ``VARIANTS`` a
comma-separated list of ``_``-joined parameters of the small meshes' binary build
(:func:`rstrace_engine.accel.bvh_mesh._binary`): ``t2`` SAH node cost 2, ``leaf3`` leaves
of at most 3, ``b48`` 48 bins, ``nocheap`` no cheap rule (:data:`.bvh_bins.CHEAP_MAX` 0);
``default`` is ``bvh_build``'s defaults, ``current`` the checkout's own small-mesh build.

``count``: per closest-hit ray, top-level node visits, instances entered, mesh node visits,
leaves entered and triangles tested (a counting copy of :func:`.bvh._trace_ray` /
:func:`.bvh._trace_mesh`: the same order and culls; its hit distances checked against the
accelerator's). ``time``: every variant's tree alternated, ``--rounds`` rounds of best of 5,
process CPU, one thread; ns a ray and the ratio to the first variant per round (median and
range). Session 42 (tree), docs/bench-raycast.md.
"""

from __future__ import annotations

import argparse
import sys
import time

import numba
import numpy as np
from numba import njit
from trace_rays import _sets  # scripts/ is on sys.path when run as a script

from rstrace_engine import scenes
from rstrace_engine.accel import bvh_build, bvh_mesh
from rstrace_engine.accel.accelerators import _skip_only, check_rays, create_accelerator
from rstrace_engine.accel.bvh import STACK_SIZE, _cull, _inv_dir, _near, _visit, ray_to_object
from rstrace_engine.accel.bvh_mesh import leaf_size, leaf_triangle
from rstrace_engine.accel.triangle import intersect_sheared, ray_shear

_CURRENT = bvh_mesh._binary


def _params(name):
    kw = {}
    for part in name.split("_"):
        if part in ("default", "current"):
            continue
        if part == "nocheap":
            kw["cheap_max"] = 0
        elif part.startswith("leaf"):
            kw["max_leaf"] = int(part[4:])
        elif part.startswith("b"):
            kw["nbins"] = int(part[1:])
        elif part.startswith("t"):
            kw["trav_cost"] = float(part[1:])
        else:
            raise ValueError(part)
    return kw


def _use(name):
    """Make the small meshes' binary build the variant's."""
    if name == "current":
        bvh_mesh._binary = _CURRENT
        return
    kw = _params(name)

    def binary(pb, grain, stop):
        return bvh_build.build_flat_boxes(pb, grain=grain, stop=stop, packed=False, **kw)

    bvh_mesh._binary = binary


@njit(cache=True)
def _mesh(bounds, child, verts, tris, tri, root, ox, oy, oz, dx, dy, dz, t0, best, st_node,
          st_t, cnt):
    kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
    okx = ox if kx == 0 else (oy if kx == 1 else oz)
    oky = ox if ky == 0 else (oy if ky == 1 else oz)
    okz = ox if kz == 0 else (oy if kz == 1 else oz)
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    found, bp = False, -1
    st_node[0], st_t[0] = root, t0
    sp = 1
    while sp > 0:
        sp -= 1
        if st_t[sp] > _cull(best):
            continue
        c = st_node[sp]
        if c >= 0:
            cnt[2] += 1
            sp = _visit(bounds, child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, _cull(best),
                        st_node, st_t, sp)
            continue
        s, k = (~c) >> 3, (~c) & 7
        cnt[3] += 1
        for i in range(leaf_size(k)):
            g = leaf_triangle(tri, s, k, i)
            a, b, e = tris[g, 0], tris[g, 1], tris[g, 2]
            cnt[4] += 1
            hit, t, _, _ = intersect_sheared(
                verts[a, kx], verts[a, ky], verts[a, kz], verts[b, kx], verts[b, ky],
                verts[b, kz], verts[e, kx], verts[e, ky], verts[e, kz], okx, oky, okz, sx, sy,
                sz, t0, best)
            if hit and (t < best or g > bp):
                found, best, bp = True, t, g
    return found, best


@njit(cache=True)
def _count(sb, o, d, tmin, tmax, only, cnt):
    """Closest-hit distances (inf: a miss), ``cnt`` (5,) += the visits (module doc)."""
    st_node, st2_node = np.empty(STACK_SIZE, np.int32), np.empty(STACK_SIZE, np.int32)
    st_t, st2_t = np.empty(STACK_SIZE), np.empty(STACK_SIZE)
    out = np.full(o.shape[0], np.inf)
    for r in range(o.shape[0]):
        if not tmin[r] <= tmax[r]:
            continue
        ox, oy, oz, dx, dy, dz = o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2]
        t0, best, on = tmin[r], tmax[r], only[r]
        bi = -1
        ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
        nx, ny, nz = _near(ix, iy, iz)
        sp, q, q_end = 0, 0, 0
        if on >= 0:
            q_end = 1
        else:
            st_node[0], st_t[0] = 0, t0
            sp = 1
        while True:
            if q < q_end:
                i = on if on >= 0 else sb.top_inst[q]
                q += 1
                if i == -2 - on:
                    continue
                cnt[1] += 1
                lx, ly, lz, ex, ey, ez = ray_to_object(sb.inst_inv, i, ox, oy, oz, dx, dy, dz)
                found, t = _mesh(sb.bounds, sb.child, sb.verts, sb.tris, sb.tri,
                                 sb.mesh_root[sb.inst_mesh[i]], lx, ly, lz, ex, ey, ez, t0,
                                 best, st2_node, st2_t, cnt)
                if found and (t < best or i > bi):
                    bi, best = i, t
                continue
            if sp == 0:
                break
            sp -= 1
            if st_t[sp] > _cull(best):
                continue
            c = st_node[sp]
            if c >= 0:
                cnt[0] += 1
                sp = _visit(sb.top_bounds, sb.top_child, c, nx, ny, nz, ox, oy, oz, ix, iy,
                            iz, t0, _cull(best), st_node, st_t, sp)
            else:
                q, q_end = (~c) >> 3, ((~c) >> 3) + ((~c) & 7)
        if bi >= 0:
            out[r] = best
    return out


def _queries(qs):
    for o, d, t0, t1, sk in qs:
        yield o, d, t0, t1, None if np.all(sk == -1) else sk


def count(sets, names, specs):
    for spec in specs:
        scene, group = spec.split(":")
        sa = scenes.build(scene, 160, 120).arrays()
        for name in names:
            _use(name)
            acc = create_accelerator("BVH", sa)
            cnt, n = np.zeros(5, np.int64), 0
            for o, d, t0, t1, sk in _queries(sets[(scene, group)]):
                oo, dd, lo, hi = check_rays(o, d, t0, t1)
                only = _skip_only(sk, len(o))
                only = np.full(len(o), -1, np.int32) if only is None else only
                got = _count(acc.sb, oo, dd, lo, hi, only, cnt)
                ref = acc.closest_hit(o, d, t0, t1, sk)
                assert np.array_equal(got, np.where(ref.inst >= 0, ref.t, np.inf)), name
                n += len(o)
            c = cnt / n
            sys.stdout.write(f"{scene} {group} {name:<14} a ray: top nodes {c[0]:.2f}, "
                             f"instances {c[1]:.2f}, mesh nodes {c[2]:.2f}, leaves "
                             f"{c[3]:.2f}, triangles {c[4]:.2f} (4-wide nodes "
                             f"{acc.stats['nodes']})\n")


def timing(sets, names, specs, rounds):
    for spec in specs:
        scene, group = spec.split(":")
        qs = list(_queries(sets[(scene, group)]))
        n = sum(len(q[0]) for q in qs)
        sa = scenes.build(scene, 160, 120).arrays()
        accs, ref = {}, None
        for name in names:
            _use(name)
            acc = accs[name] = create_accelerator("BVH", sa)
            hits = [acc.closest_hit(*q) for q in qs]
            key = b"".join(np.asarray(getattr(h, f)).tobytes() for h in hits
                           for f in ("t", "inst", "prim", "u", "v"))
            ref = key if ref is None else ref
            assert key == ref, f"{name}: other hits"
        ns = {k: [] for k in names}
        for r in range(rounds):
            for name in names if r % 2 == 0 else names[::-1]:
                best = np.inf
                for _ in range(5):
                    c0 = time.process_time()
                    for q in qs:
                        accs[name].closest_hit(*q)
                    best = min(best, time.process_time() - c0)
                ns[name].append(best * 1e9 / n)
        base = np.array(ns[names[0]])
        for name in names:
            ratio = np.array(ns[name]) / base
            sys.stdout.write(f"{scene} {group} {name:<14} {np.median(ns[name]):6.1f} ns a "
                             f"ray, ratio {np.median(ratio):.3f} ({ratio.min():.3f}-"
                             f"{ratio.max():.3f}); hits identical\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("count", "time"))
    ap.add_argument("rays")
    ap.add_argument("variants")
    ap.add_argument("sets")
    ap.add_argument("--rounds", type=int, default=7)
    a = ap.parse_args(argv)
    numba.set_num_threads(1)
    sets = _sets(np.load(a.rays))
    names, specs = a.variants.split(","), a.sets.split(",")
    if a.mode == "count":
        count(sets, names, specs)
    else:
        timing(sets, names, specs, a.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
