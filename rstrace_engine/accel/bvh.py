"""Two-level bounding volume hierarchy in numba: the default ray accelerator.

* **Bottom level**: one binned-SAH BVH per *mesh*, in object space, built once and shared by
  every instance of the mesh. Meshes are keyed by a content hash of their triangles, so a new
  packing of the scene reuses every mesh whose geometry did not change; the trees are held
  once, as views of the concatenation the traversal reads (:class:`PlacedMesh`).
* **Top level**: a BVH over the instances' world bounds, rebuilt on every update (cheap: one
  primitive per instance). At an instance leaf the ray is taken to object space (direction not
  normalised, so distances stay world distances) and the mesh BVH is traversed.

This module holds the layout and the traversal; the build (in parallel, the same tree on
any thread count) is :mod:`.bvh_build` and :mod:`.bvh_mesh`. Layout (flattened,
pbrt/pynndescent style): a binary binned-SAH tree is built (:func:`.bvh_build.build_flat`)
and collapsed into a 4-wide tree (:func:`.bvh_mesh.collapse4`) whose nodes hold the boxes of
their four children, so one visit tests four boxes and pushes those hit farthest first
(front-to-back traversal with a small fixed stack).

* ``bounds`` (N, 24), struct-of-arrays over the four lanes: ``lo x[4], lo y[4], lo z[4], hi
  x[4], hi y[4], hi z[4]``: min / max of the vertex coordinates widened by one ulp
  (:func:`.bvh_mesh.pad_outward`, as the collapse reads them), then for a mesh's nodes
  rounded *outward* to float32 (:func:`.bvh_mesh.collapse4`: each box contains its float64
  one, so no ray that met the float64 box misses it; the slab test itself runs in float64).
  Half the nodes' memory, for a few percent of trace time (docs/bench-scale.md, Memory). The
  top level's boxes stay float64. An unused lane has an inverted box (``lo = +inf``) and is
  never entered.
* ``child`` (N, 4) int32: ``>= 0`` an inner node; ``< 0`` a leaf ``~(start << 3 | kind)``.
  At the top level ``kind`` (0..7) consecutive instances in leaf order (``top_inst``). In a
  mesh (:func:`.bvh_mesh.direct_leaves`) a leaf of one triangle, or of two neighbours in the
  scene's order (a quad's two halves: most leaves), *names* them (``start`` is the global
  triangle, ``kind`` 5..7 says how many and in which order); the others (``kind`` 1..4)
  list their global triangle ids at ``tri[start:start + kind]``, in leaf order.
* The leaves hold no vertices and no vertex indices: a triangle's are read from the
  scene's own triangles and vertices (:class:`SceneBVH`).

The box test is the conservative slab test of pbrt-v4 (``t_far`` scaled by
:data:`~.tolerances.BOX_TFAR_SCALE`) and the triangle test is watertight (:mod:`.triangle`),
so no ray slips through a shared edge or vertex.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import stripes
from .. import tolerances as tol
from ..geometry.footprint import MAX_TRIANGLES
from .box4 import lanes4
from .bvh_build import DEPTH_CAP, NEVER_STOP
from .bvh_mesh import (
    MeshBVH,
    direct_leaves,
    leaf_size,
    leaf_triangle,
    place_child,
    place_tri,
    used_runs,
)
from .triangle import intersect_sheared, ray_shear

log = logging.getLogger(__name__)

#: Traversal stack entries: a 4-wide visit pushes <= 4 and pops 1, the depth is <= DEPTH_CAP
#: + 31 (median splits below the cap add <= 31 levels).
STACK_SIZE = 3 * (DEPTH_CAP + 31) + 4
#: Rays per parallel work item.
CHUNK = 64


class SceneBVH(NamedTuple):
    """Everything the traversal kernel reads: both levels, concatenated (what numba takes).

    A leaf's triangles are read through the scene's own arrays (``verts`` and ``tris``: the
    :class:`~..geometry.scene.SceneArrays` arrays themselves, not copies): a leaf names
    global triangle ``t`` (or lists it in ``tri``), whose vertices are ``verts[tris[t]]``.
    The BVH's only per-triangle array is ``tri``, the listed leaves' entries (about a tenth
    of the triangles on a triangulated surface; a leaf-order copy of every triangle's
    vertex indices and ids took 16 bytes a triangle, one of the vertices 72 before that:
    docs/bench-scale.md, Memory)."""

    top_bounds: np.ndarray  # (Nt, 24) float64
    top_child: np.ndarray  # (Nt, 4) int32
    top_inst: np.ndarray  # (I,) int32, instance ids in leaf order
    bounds: np.ndarray  # (N, 24) float32, all mesh BVH nodes (rounded outward)
    child: np.ndarray  # (N, 4) int32, node and triangle indices already offset
    verts: np.ndarray  # (V, 3) float64, the scene's object-space vertices (SceneArrays')
    tris: np.ndarray  # (T, 3) int32, the scene's vertex indices (SceneArrays')
    tri: np.ndarray  # (L,) int32, GLOBAL triangle ids of the listed leaves, leaf order
    mesh_root: np.ndarray  # (M,) int32, root node of each mesh
    inst_mesh: np.ndarray  # (I,) int32
    inst_inv: np.ndarray  # (I, 4, 4) float64 world -> object


class PlacedMesh(NamedTuple):
    """A mesh's bottom-level BVH as placed in a :class:`SceneBVH`'s concatenated arrays:
    views of them, whose child codes and triangle ids carry the offsets of that placement
    (all zero for a BVH just built), so the scene holds each mesh's tree once."""

    bounds: np.ndarray  # (N, 24) float32
    child: np.ndarray  # (N, 4) int32, node indices + node_base, listing leaves' starts +
    # leaf_base, naming leaves' triangles + tri_base (:func:`.bvh_mesh.direct_leaves`)
    tri: np.ndarray  # (L,) int32, listed leaves' mesh triangle index + tri_base, leaf order
    node_base: int
    leaf_base: int
    tri_base: int
    sah_cost: float
    #: the ``(start, stop)`` runs of ``bounds``' rows that ``child``'s rows are, in order,
    #: where a tree just built leaves rows no child reaches (:func:`.bvh_mesh.used_runs`):
    #: the concatenation copies those only; () when ``bounds`` and ``child`` row up
    rows: tuple = ()

    @classmethod
    def built(cls, mb: MeshBVH) -> PlacedMesh:
        """``mb`` as built, its leaves as the traversal reads them and its unused rows
        dropped (:func:`.bvh_mesh.direct_leaves`)."""
        child = np.empty_like(mb.bvh.child)
        tri = np.empty(len(mb.tri), np.int32)
        n, r = direct_leaves(mb.bvh.child, mb.tri, child, tri)
        rows = () if r == len(child) else used_runs(mb.bvh.child)
        return cls(mb.bvh.bounds, child[:r], tri[:n].copy(), 0, 0, 0, mb.sah_cost, rows)


def concat_meshes(meshes: list[PlacedMesh], mesh_tri_start: np.ndarray):
    """Concatenate mesh BVHs (mesh ``k`` owns global triangles from ``mesh_tri_start[k]``).

    Returns ``bounds, child, tri (global), mesh_root`` and the meshes placed there
    (views: keep those, not the arguments, so nothing is held twice).
    """
    node_base = np.cumsum([0] + [len(m.child) for m in meshes])
    leaf_base = np.cumsum([0] + [len(m.tri) for m in meshes])
    # (a Scene refuses such meshes before anything is built: .footprint.check_count)
    if max(leaf_base[-1], int(mesh_tri_start[-1])) > MAX_TRIANGLES:
        raise OverflowError("BVH: too many triangles for 32-bit leaf codes")
    child = np.empty((int(node_base[-1]), 4), np.int32)
    tri = np.empty(int(leaf_base[-1]), np.int32)
    for k, (m, nb, lb) in enumerate(zip(meshes, node_base[:-1], leaf_base[:-1], strict=True)):
        # node indices and leaf starts moved to this placement, in one pass each
        place_child(m.child, child, int(nb), int(nb) - m.node_base, int(lb) - m.leaf_base,
                    int(mesh_tri_start[k]) - m.tri_base)
        place_tri(m.tri, tri, int(lb), int(mesh_tri_start[k]) - m.tri_base)
    bounds = np.ascontiguousarray(np.concatenate(
        [m.bounds[a:b] for m in meshes for a, b in (m.rows or ((0, len(m.bounds)),))]),
        np.float32)
    placed = [PlacedMesh(bounds[nb:ne], child[nb:ne], tri[lb:le], int(nb), int(lb),
                         int(mesh_tri_start[k]), m.sah_cost)
              for k, (m, nb, ne, lb, le) in enumerate(zip(meshes, node_base[:-1],
                                                          node_base[1:], leaf_base[:-1],
                                                          leaf_base[1:], strict=True))]
    return bounds, child, tri, node_base[:-1].astype(np.int32), placed


# ----------------------------------------------------------------------------- traversal


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def ray_to_object(inv, i, ox, oy, oz, dx, dy, dz):
    """World ray -> object space of instance ``i`` with ``inv`` (I, 4, 4) float64.

    The direction is transformed without normalisation, so a distance ``t`` along the
    object-space ray is the same ``t`` along the world ray.
    """
    # element indexing only: a view (inv[i]) would cost a reference count in the hot loop
    return (inv[i, 0, 0] * ox + inv[i, 0, 1] * oy + inv[i, 0, 2] * oz + inv[i, 0, 3],
            inv[i, 1, 0] * ox + inv[i, 1, 1] * oy + inv[i, 1, 2] * oz + inv[i, 1, 3],
            inv[i, 2, 0] * ox + inv[i, 2, 1] * oy + inv[i, 2, 2] * oz + inv[i, 2, 3],
            inv[i, 0, 0] * dx + inv[i, 0, 1] * dy + inv[i, 0, 2] * dz,
            inv[i, 1, 0] * dx + inv[i, 1, 1] * dy + inv[i, 1, 2] * dz,
            inv[i, 2, 0] * dx + inv[i, 2, 1] * dy + inv[i, 2, 2] * dz)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _u(i):
    """``i`` as an unsigned index: numba then emits no wrap-around of negative indices (a
    select per access) for the node rows and stack slots, which are never negative."""
    return np.uint64(i)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _ascending(ta, tb, tc, td, ca, cb, cc, cd):
    """Four entry distances and their children, sorted by distance (a sorting network;
    :func:`_visit`'s and :func:`.bvh_occlusion._push_hit`'s)."""
    if tb < ta:
        ta, tb, ca, cb = tb, ta, cb, ca
    if td < tc:
        tc, td, cc, cd = td, tc, cd, cc
    if tc < ta:
        ta, tc, ca, cc = tc, ta, cc, ca
    if td < tb:
        tb, td, cb, cd = td, tb, cd, cb
    if tc < tb:
        tb, tc, cb, cc = tc, tb, cc, cb
    return ta, tb, tc, td, ca, cb, cc, cd


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _visit(bounds, child, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1, st_node, st_t, sp):
    """Test the four children of ``node`` (all four boxes at once, :func:`.box4.lanes4`);
    push those hit, farthest first. Returns ``sp``."""
    ta, tb, tc, td = lanes4(bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1)
    un = _u(node)
    ta, tb, tc, td, ca, cb, cc, cd = _ascending(
        ta, tb, tc, td, child[un, _u(0)], child[un, _u(1)], child[un, _u(2)],
        child[un, _u(3)])
    if td < np.inf:
        st_node[_u(sp)], st_t[_u(sp)] = cd, td
        sp += 1
    if tc < np.inf:
        st_node[_u(sp)], st_t[_u(sp)] = cc, tc
        sp += 1
    if tb < np.inf:
        st_node[_u(sp)], st_t[_u(sp)] = cb, tb
        sp += 1
    if ta < np.inf:
        st_node[_u(sp)], st_t[_u(sp)] = ca, ta
        sp += 1
    return sp


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _inv_dir(x):
    # tiny or zero components get a huge finite reciprocal: (b - o) * inv stays NaN-free.
    # Selects, not branches on the sign (a coin toss on incoherent rays, three per ray and
    # three per instance it enters); the same value for every x, -0.0 and NaN included.
    # (never a division by zero: callers compiled with the Python error model do not raise)
    tiny = abs(x) < 1e-300
    r = 1.0 / (1.0 if tiny else x)
    return (1e300 if x >= 0.0 else -1e300) if tiny else r


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _near(ix, iy, iz):
    """Offsets of the near planes of each axis in a node's SoA bounds."""
    return 0 if ix >= 0.0 else 12, 4 if iy >= 0.0 else 16, 8 if iz >= 0.0 else 20


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cull(best):
    """Nodes entered beyond this are skipped: ``best`` plus
    :data:`~.tolerances.BVH_CULL_REL` of it (a box entry and a triangle distance round
    differently; a node culled by an ulp lost a hit tying within an ulp, and which of the two
    won then depended on the traversal order, i.e. on the other objects)."""
    return best + abs(best) * tol.BVH_CULL_REL


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _trace_mesh(bounds, child, verts, tris, tri, root, ox, oy, oz, dx, dy, dz, t0, best,
                anyhit, st_node, st_t):
    """Closest (or any) hit in one mesh BVH; the ray is in object space. A leaf's
    triangles (:func:`.bvh_mesh.leaf_triangle`) are rows of ``tris`` (global vertex indices
    into ``verts``).

    Returns ``(found, t, triangle, u, v)`` with ``t <= best`` (the global triangle).
    """
    kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
    ux, uy, uz = _u(kx), _u(ky), _u(kz)  # (indices never negative: no wrap-around code)
    okx = ox if kx == 0 else (oy if kx == 1 else oz)
    oky = ox if ky == 0 else (oy if ky == 1 else oz)
    okz = ox if kz == 0 else (oy if kz == 1 else oz)
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    found = False
    bp, bu, bv = -1, 0.0, 0.0
    st_node[0], st_t[0] = root, t0  # one _visit call site: it is inlined, keep it small
    sp = 1
    while sp > 0:
        sp -= 1
        if st_t[sp] > _cull(best):
            continue
        c = st_node[sp]
        if c >= 0:
            sp = _visit(bounds, child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, _cull(best),
                        st_node, st_t, sp)
            continue
        code = ~c
        s, k = code >> 3, code & 7
        for i in range(leaf_size(k)):
            g = leaf_triangle(tri, s, k, i)
            ug = _u(g)
            a, b, c = _u(tris[ug, _u(0)]), _u(tris[ug, _u(1)]), _u(tris[ug, _u(2)])
            hit, t, u, v = intersect_sheared(
                verts[a, ux], verts[a, uy], verts[a, uz], verts[b, ux], verts[b, uy],
                verts[b, uz], verts[c, ux], verts[c, uy], verts[c, uz], okx, oky, okz, sx, sy,
                sz, t0, best)
            # t <= best; an equal distance goes to the highest triangle id, whichever the
            # tree tested first (every triangle at t == best is tested: nodes are culled
            # only past _cull(best)), so ties resolve the same in any tree, as the oracle
            # (triangles in id order) resolves them
            if hit and (t < best or g > bp):
                found, best, bp, bu, bv = True, t, g, u, v
                if anyhit:
                    return found, best, bp, bu, bv
    return found, best, bp, bu, bv


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _trace_ray(sb, ox, oy, oz, dx, dy, dz, t0, best, anyhit, only, st_node, st_t, st2_node,
               st2_t):
    """One world ray through both levels (or only instance ``only`` when ``only >= 0``;
    every instance but ``-2 - only`` when ``only <= -2``).

    Returns ``(inst, t, triangle, u, v)``. Each inlined helper has a single call site (the
    instance range ``q..q_end`` of a top-level leaf, or ``only``, is drained before the next
    pop), which keeps the kernel's compile time reasonable.
    """
    bi, bp, bu, bv = -1, -1, 0.0, 0.0
    bounds, child, top_inst = sb.top_bounds, sb.top_child, sb.top_inst
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    sp = 0
    q, q_end = 0, 0
    if only >= 0:
        q_end = 1
    else:
        st_node[0], st_t[0] = 0, t0
        sp = 1
    while True:
        if q < q_end:
            i = only if only >= 0 else top_inst[q]
            q += 1
            if i == -2 - only:
                continue  # (the one instance this ray leaves out)
            lx, ly, lz, ex, ey, ez = ray_to_object(sb.inst_inv, i, ox, oy, oz, dx, dy, dz)
            found, t, p, u, v = _trace_mesh(sb.bounds, sb.child, sb.verts, sb.tris, sb.tri,
                                            sb.mesh_root[sb.inst_mesh[i]], lx, ly, lz,
                                            ex, ey, ez, t0, best, anyhit, st2_node, st2_t)
            # t <= best; an equal distance goes to the highest instance id (the oracle's
            # rule), not to whichever instance the top level happened to visit last
            if found and (t < best or i > bi):
                bi, best, bp, bu, bv = i, t, p, u, v
                if anyhit:
                    break
            continue
        if sp == 0:
            break
        sp -= 1
        if st_t[sp] > _cull(best):
            continue
        c = st_node[sp]
        if c >= 0:
            sp = _visit(bounds, child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, _cull(best),
                        st_node, st_t, sp)
        else:
            q = (~c) >> 3
            q_end = q + ((~c) & 7)
    return bi, best, bp, bu, bv


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def trace_kernel(sb, o, d, tmin, tmax, only, anyhit, out_t, out_inst, out_prim, out_u, out_v,
                 stop, stacks_node, stacks_t, first, step):
    """Closest (``anyhit=False``) or any hit of each ray through a :class:`SceneBVH`.

    o, d : (n, 3) float64; tmin, tmax : (n,) float64; only : (n,) int32, ``>= 0`` restricts
    a ray to that instance, ``<= -2`` leaves instance ``-2 - only`` out of it (-1: every
    instance). Outputs (n,): t float64 (inf on miss), inst int32, prim int32
    (global triangle), u, v float64; rows that miss are left untouched (callers pre-fill
    them). Work items are :data:`CHUNK` consecutive rays, this call's those numbered
    ``first, first + step, ...`` (threads taking the chunks in turn balance the cost per
    ray, which varies a lot across an image): one thread's stripe (:func:`trace` runs
    ``step`` of them with :func:`~rstrace_engine.stripes.run`). stacks_node (step, 2,
    STACK_SIZE) int32 and stacks_t (step, 2, STACK_SIZE) float64: each stripe's two
    traversal stacks (row ``first``), so that the kernel allocates nothing.

    Serial and without numba's reference counting (``_nrt=False``), not ``prange``: its
    compile is a third of the parallel kernel's, and it casts rays as fast (within a few %,
    docs/KERNELS.md); with reference counting a serial loop paid an atomic increment and
    decrement per array per ray (the scene's eleven arrays passed to the inlined traversal),
    30-60 % of the time of a ray, which a parfor's hoisting avoided.

    stop : (1,) int32, read before every work item: once it is non-zero the remaining
    work items are skipped (their rows left as misses) and the result is incomplete, for
    the caller to discard (:mod:`rstrace_engine.cancel`); zero, every ray is traced.
    """
    n = o.shape[0]
    chunks = (n + CHUNK - 1) // CHUNK
    st_node, st2_node = stacks_node[first, 0], stacks_node[first, 1]
    st_t, st2_t = stacks_t[first, 0], stacks_t[first, 1]
    for c in range(first, chunks, step):
        if stop[0] != 0:
            continue
        for r in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if not tmin[r] <= tmax[r]:
                continue
            bi, t, p, u, v = _trace_ray(sb, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1],
                                        d[r, 2], tmin[r], tmax[r], anyhit, only[r], st_node,
                                        st_t, st2_node, st2_t)
            if bi >= 0:
                out_t[r] = t
                out_inst[r] = bi
                out_prim[r] = p
                out_u[r] = u
                out_v[r] = v


def trace(sb: SceneBVH, o, d, tmin, tmax, only, anyhit: bool, hits,
          stop: np.ndarray = NEVER_STOP) -> None:
    """Run :func:`trace_kernel` on the calling thread's numba thread count
    (:func:`~rstrace_engine.stripes.run`) into ``hits`` (t, inst, prim, u, v); ``stop``: its
    stop flag (a :class:`~rstrace_engine.cancel.CancelFlag`'s ``array``)."""
    chunks = (len(o) + CHUNK - 1) // CHUNK
    k = stripes.threads_for(chunks)
    stacks_node = np.empty((k, 2, STACK_SIZE), np.int32)
    stacks_t = np.empty((k, 2, STACK_SIZE))
    stripes.run(trace_kernel, chunks, sb, o, d, tmin, tmax, only,
                anyhit, *hits, stop, stacks_node, stacks_t)
