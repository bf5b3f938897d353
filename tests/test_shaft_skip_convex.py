"""The shaft skips' own-instance proof (tracing/shaft_skip.py ``own_clear``): a mesh's
convexity certificate (tracing/object_rays.py ``convexity``) lets a group of points on a
convex instance, seen from outside, skip its own triangles -- proving exactly the rows the
per-triangle test proves -- and nothing else does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_params, camera_rays
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.tracing import object_rays, shaft_skip, whitted
from rstrace_engine.tracing.soft_lights import SH_SOFT


def _arrays(mesh):
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64)


@pytest.mark.parametrize("mesh", [shapes.icosphere(3, 0.5), shapes.uv_sphere(24, 12, 0.3),
                                  shapes.box((0.6, 0.2, 1.0))])
def test_closed_convex_meshes_are_certified_outward_only(mesh):
    out, inn, r = object_rays.convexity(*_arrays(mesh))
    assert out <= 1e-10 * r  # (every vertex behind or on every plane, to rounding)
    assert inn == np.inf  # seen from inside, the far side is in front
    assert r > 0.0


def test_flat_meshes_are_certified_both_sides():
    out, inn, _ = object_rays.convexity(*_arrays(shapes.plane(2.0, divisions=3)))
    assert out < np.inf and inn < np.inf


@pytest.mark.parametrize("mesh", [
    shapes.torus(0.5, 0.18, 24, 12),
    shapes.revolve([0.0, 0.4, 0.15, 0.4, 0.0], [0.0, 0.05, 0.5, 0.9, 0.9], 16),  # waisted
])
def test_non_convex_meshes_have_no_certificate(mesh):
    out, inn, _ = object_rays.convexity(*_arrays(mesh))
    assert out == np.inf and inn == np.inf


def test_one_dent_breaks_the_certificate():
    """A sphere with one vertex pushed in by 2% (deeper than the surface bulges between
    neighbouring vertices): no certificate."""
    verts, tris = _arrays(shapes.icosphere(3, 0.5))
    assert object_rays.convexity(verts, tris)[0] < np.inf
    verts = verts.copy()
    verts[7] *= 0.98
    assert object_rays.convexity(verts, tris)[0] == np.inf


def _scene(mesh, xf, camera_at=(0.0, -4.0, 1.0), target=(0.0, 0.0, 1.0), w=48, h=36):
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(12.0, divisions=2, name="floor")), np.eye(4),
                   [grey], name="Floor")
    s.add_instance(s.add_mesh(mesh), xf, [grey], name="Obj")
    s.add_light(Light("Bulb", "POINT", power=150.0, position=(-1.0, -2.0, 3.0), radius=0.3))
    s.add_light(Light("Panel", "AREA", power=80.0, position=(1.0, -1.0, 3.5),
                      direction=(0.0, 0.0, -1.0), axis=(1.0, 0.0, 0.0), shape="SQUARE",
                      size=1.0))
    s.set_camera(Camera(matrix=shapes.look_at(camera_at, target), lens=30.0, width=w,
                        height=h))
    return s


def _prove(scene, with_prim):
    sa = scene.arrays()
    accel = create_accelerator("BVH", sa)
    cp = camera_params(scene.camera)
    pixels = np.arange(cp.width * cp.height, dtype=np.int64)
    o, d, _, tmax = camera_rays(cp, pixels, np.full((len(pixels), 2), 0.5))
    hits = accel.closest_hit(o, d, np.zeros(len(pixels)), tmax)
    surf = whitted.surfaces(sa, o, d, tmax, hits)
    counters: dict = {}
    proven = shaft_skip.proven_rows(sa, accel, surf, hits.inst,
                                    shaft_skip.tile_keys(pixels, cp.width), counters,
                                    hits.prim if with_prim else None)
    soft = (surf.sh_state.reshape(len(pixels), -1) == SH_SOFT).any(axis=1)
    return proven, counters, hits, soft


BALL = shapes.icosphere(3, 0.8, name="ball")
CASES = {
    "plain": shapes.transform((0.0, 0.0, 1.0)),
    # non-uniform scale, mirrored, rotated: the certificate is the mesh's, the bound the
    # instance's
    "mirrored": shapes.transform((0.2, 0.3, 1.0), (1.3, -0.7, 0.9), 35.0, 20.0),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_convex_ball_skips_its_own_triangles_and_proves_the_same_rows(case):
    proven, counters, hits, soft = _prove(_scene(BALL, CASES[case]), True)
    ref, ref_counters, _, _ = _prove(_scene(BALL, CASES[case]), False)
    assert np.array_equal(proven, ref)  # the same rows, bit for bit
    assert proven.sum() > 0
    on_ball = int(np.count_nonzero((hits.inst == 1) & soft))
    assert on_ball > 50
    # every point on the ball soft-lit by something (all seen from outside) holds; the
    # floor's few triangles are not offered the skip (OWN_MIN_TRIS)
    assert counters["skip_own"] == on_ball
    assert ref_counters["skip_own"] == 0


def test_without_a_certificate_nothing_is_skipped(monkeypatch):
    monkeypatch.setattr(object_rays.CONVEX, "get", lambda sa, m: (np.inf, np.inf, 1.0))
    proven, counters, _, _ = _prove(_scene(BALL, CASES["plain"]), True)
    assert counters["skip_own"] == 0
    monkeypatch.undo()
    ref, counters, _, _ = _prove(_scene(BALL, CASES["plain"]), True)
    assert np.array_equal(proven, ref) and counters["skip_own"] > 0


def test_a_torus_skips_nothing_of_its_own():
    torus = shapes.torus(0.8, 0.3, 32, 16, name="torus")
    xf = shapes.transform((0.0, 0.0, 1.0), 1.0, 0.0, 60.0)
    proven, counters, hits, _ = _prove(_scene(torus, xf), True)
    ref, _, _, _ = _prove(_scene(torus, xf), False)
    assert np.count_nonzero(hits.inst == 1) > 100
    assert np.array_equal(proven, ref)
    # no torus point may skip its own instance
    own = np.zeros(len(hits.inst), bool)
    shaft_skip.own_clear(_scene(torus, xf).arrays(), np.ascontiguousarray(
        _scene(torus, xf).arrays().inst_xform, np.float64), *_points(torus, xf), own)
    assert not own[hits.inst == 1].any()
    assert counters["skip_own"] == int(own.sum())


def _points(mesh, xf):
    _, _, hits, _ = _prove(_scene(mesh, xf), True)
    sa = _scene(mesh, xf).arrays()
    surf = whitted.surfaces(sa, *_camera(sa, _scene(mesh, xf)), hits)
    pts = np.flatnonzero(hits.inst >= 0)
    return (surf.Q, surf.NG, hits.inst.astype(np.int64), hits.prim.astype(np.int64), pts)


def _camera(sa, scene):
    cp = camera_params(scene.camera)
    pixels = np.arange(cp.width * cp.height, dtype=np.int64)
    o, d, _, tmax = camera_rays(cp, pixels, np.full((len(pixels), 2), 0.5))
    return o, d, tmax


def test_points_seen_from_inside_a_ball_are_not_skipped():
    """The camera inside a closed convex ball: every point's normal faces the centre, the
    rest of the ball is in front of its plane -- no certificate on that side."""
    big = shapes.icosphere(3, 3.0, name="big")
    xf = shapes.transform((0.0, 0.0, 1.0))
    scene = _scene(big, xf, camera_at=(0.0, -0.5, 1.0), target=(0.3, 1.0, 0.8))
    scene.add_light(Light("In", "POINT", power=50.0, position=(0.5, 0.5, 1.5), radius=0.2))
    proven, counters, hits, _ = _prove(scene, True)
    ref, _, _, _ = _prove(scene, False)
    assert np.array_equal(proven, ref)
    on_ball = hits.inst == 1
    assert on_ball.sum() > 100
    sa = scene.arrays()
    own = np.zeros(len(hits.inst), bool)
    surf = whitted.surfaces(sa, *_camera(sa, scene), hits)
    shaft_skip.own_clear(sa, np.ascontiguousarray(sa.inst_xform, np.float64), surf.Q,
                         surf.NG, hits.inst.astype(np.int64), hits.prim.astype(np.int64),
                         np.flatnonzero(hits.inst >= 0), own)
    assert not own[on_ball].any()
    assert math.isfinite(object_rays.convexity(*_arrays(big))[0])
