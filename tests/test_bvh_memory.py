"""Memory per triangle of the BVH (issue 26): float32 node boxes rounded outward (each
contains its float64 box, so no hit is lost), leaves that read the scene's own vertices,
and a bound on the bytes held per unique triangle (counted from the arrays)."""

from __future__ import annotations

import numpy as np

from rstrace_engine.accel import bvh_build, bvh_mesh
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench import scale
from rstrace_engine.geometry import shapes

F32 = np.finfo(np.float32)
F64 = np.finfo(np.float64)


def _values() -> np.ndarray:
    """Bounds that round every way: float32-exact, halfway, subnormal in either precision,
    signed zeros, beyond float32's range, infinities; and random magnitudes."""
    rng = np.random.default_rng(11)
    special = [0.0, -0.0, 1.0, -1.0, 0.1, -0.1, 1.0 + 2.0 ** -24, 1.0 + 2.0 ** -30,
               -(1.0 + 2.0 ** -30), 1e-310, -1e-310, 5e-324, -5e-324, 1e-45, -1e-45, 2e-45,
               float(F32.tiny), -float(F32.tiny), float(F32.max), -float(F32.max),
               float(F32.max) * (1 + 2.0 ** -30), -float(F32.max) * (1 + 2.0 ** -30), 1e39,
               -1e39, float(F64.max), -float(F64.max), np.inf, -np.inf]
    rand = rng.normal(size=2000) * 10.0 ** rng.integers(-50, 50, 2000)
    with np.errstate(over="ignore"):
        near32 = rand.astype(np.float32).astype(np.float64)
    return np.concatenate([special, rand, near32[np.isfinite(near32)]])


def test_float32_boxes_contain_the_float64_ones_and_are_the_nearest_that_do():
    x = _values()
    b64 = np.resize(x, (len(x) // 24 + 1) * 24).reshape(-1, 24)
    b32 = bvh_mesh.outward_float32(b64)
    assert b32.dtype == np.float32 and b32.shape == b64.shape
    lo64, hi64 = b64[:, :12], b64[:, 12:]
    lo32, hi32 = b32[:, :12].astype(np.float64), b32[:, 12:].astype(np.float64)
    assert np.all(lo32 <= lo64) and np.all(hi32 >= hi64)  # contains (inf to inf)
    # ... and is the tightest float32 box that does: one float32 step inward leaves it
    with np.errstate(over="ignore"):
        up = np.nextafter(b32[:, :12], np.float32(np.inf)).astype(np.float64)
        down = np.nextafter(b32[:, 12:], np.float32(-np.inf)).astype(np.float64)
    fin_lo, fin_hi = np.isfinite(lo32), np.isfinite(hi32)
    assert np.all(up[fin_lo] > lo64[fin_lo]) and np.all(down[fin_hi] < hi64[fin_hi])
    # a float32-exact bound is kept exactly (infinite ones, unused lanes, included)
    with np.errstate(over="ignore"):
        exact = b64.astype(np.float32).astype(np.float64) == b64
    assert np.array_equal(b32.astype(np.float64)[exact], b64[exact])
    # a lo beyond float32's range: the largest finite float32; a hi: +inf
    big = (b64 > float(F32.max)) & np.isfinite(b64)
    assert np.all(b32[:, :12][big[:, :12]] == F32.max)
    assert np.all(np.isposinf(b32[:, 12:][big[:, 12:]]))


def test_mesh_bvh_float32_boxes_contain_the_float64_tree():
    """The built tree's float32 boxes hold its float64 boxes lane by lane (the same
    tree, the boxes only rounded outward) and so every triangle of their subtree."""
    mesh = shapes.lumpy_sphere(bvh_build.PARALLEL_MIN + 2_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), mesh.triangles
    pb = bvh_mesh.indexed_boxes(verts, tris)
    b64, child, perm, _ = bvh_build.build_flat_boxes(pb.copy())
    f64 = bvh_mesh.flatten(b64, child, perm)
    mb = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    assert np.array_equal(mb.bvh.child, f64.child) and np.array_equal(mb.tri, f64.perm)
    b32 = mb.bvh.bounds.astype(np.float64)
    assert mb.bvh.bounds.dtype == np.float32
    assert np.all(b32[:, :12] <= f64.bounds[:, :12]) and np.all(b32[:, 12:] >= f64.bounds[:, 12:])
    assert np.any(b32 != f64.bounds)  # (rounded: not the float64 values)


def test_bytes_per_unique_triangle_stay_bounded():
    """What ``bench scale`` reports, counted from the arrays held (a buffer shared by
    several counts once): the BVH's own arrays (4-wide float32 nodes, the leaf-order
    triangle ids and vertex indices, the top level) and the total with the scene model
    and the packed arrays. (230 in all before: 130 of BVH, 72 of them a float64 copy of
    the leaves' vertices, 54 the float64 nodes.)"""
    scene = scale.big_scene(20_000)
    sa = scene.arrays()
    acc = create_accelerator("BVH", sa)
    mem = scale.memory(scene, sa, acc)
    assert mem["bvh"] <= 48.0, mem
    assert mem["total"] <= 150.0, mem
    # the leaves hold no vertices: the BVH reads the scene's own (no copy), through their
    # indices in leaf order
    assert acc.sb.verts is sa.verts and np.array_equal(acc.sb.tris, sa.tris[acc.sb.tri])
    assert acc.stats["memory_mb"] * 2 ** 20 <= 48.0 * int(sa.mesh_tri_start[-1])
