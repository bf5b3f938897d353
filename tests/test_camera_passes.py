"""Depth, Normal and holdouts from a frame's camera rays (tracing.camera_passes): against
the base tracer's own frame and ray geometry."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry.cameras import camera_params, camera_rays
from rstrace_engine.tracing.camera_passes import DEPTH_BACKGROUND, camera_passes
from rstrace_engine.tracing.whitted import render


@pytest.fixture(scope="module")
def spheres():
    scene = scenes.three_spheres(40, 30, subdivisions=2)
    return scene, create_accelerator("BVH", scene.arrays())


def test_depth_is_along_the_view_axis_and_normal_faces_the_camera(spheres):
    scene, accel = spheres
    settings = RenderSettings(samples=1)
    p = camera_passes(scene, accel, settings, depth=True, normal=True)
    assert p.depth.shape == (30, 40) and p.normal.shape == (30, 40, 3)
    # the centre ray of every pixel: hit points at that distance lie on the spheres/floor
    o, d, t0, t1 = camera_rays(camera_params(scene.camera))
    hits = accel.closest_hit(o, d, t0, t1)
    hit = np.asarray(hits.inst) >= 0
    z = p.depth.reshape(-1)
    assert np.all(z[~hit] == DEPTH_BACKGROUND)
    # the hit's depth along the camera's view axis (camera-space -z), as Cycles' Z pass
    m = scene.camera.matrix
    forward = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    points = o + d * np.asarray(hits.t)[:, None]
    assert np.allclose(z[hit], (points[hit] - m[:3, 3]) @ forward, rtol=1e-6)
    assert np.all(z[hit] < np.asarray(hits.t)[hit] + 1e-9)  # never beyond the distance
    n = p.normal.reshape(-1, 3)
    assert np.all(n[~hit] == 0.0)
    assert np.allclose(np.linalg.norm(n[hit], axis=1), 1.0, atol=1e-5)
    # toward the camera (smooth-shading normals may lean past 90 degrees at silhouettes)
    assert np.mean(np.einsum("ij,ij->i", n[hit], d[hit]) < 0.0) > 0.99
    # the floor (z = 0 plane) faces up
    floor = hit & (np.abs((o + d * np.asarray(hits.t)[:, None])[:, 2]) < 1e-6)
    assert floor.sum() > 100 and np.allclose(n[floor], (0.0, 0.0, 1.0), atol=1e-6)


def test_holdout_cuts_the_material_out_of_the_frame(spheres):
    scene, accel = spheres
    settings = RenderSettings(samples=4, max_depth=2)
    frame = render(scene, settings, accel=accel)
    red = scene.material_id("red")
    p = camera_passes(scene, accel, settings, frame=frame, holdout_mats=[red])
    # every sample of a pixel on the red sphere: alpha 0, colour 0
    full = p.alpha == 0.0
    assert full.sum() > 20 and np.all(p.radiance[full] == 0.0)
    # pixels with no holdout sample keep the frame's colour bit for bit (the mirror
    # sphere still reflects the red one: only camera rays see a holdout)
    none = p.alpha == 1.0
    assert np.array_equal(p.radiance[none], frame.radiance[none])
    # partly held-out pixels: their other samples traced again, premultiplied
    part = (p.alpha > 0.0) & (p.alpha < 1.0)
    assert part.sum() > 5 and p.retraced_samples > 0
    assert p.holdout_pixels == int((~none).sum())
    # the red sphere's samples and all the others' add up to the frame: holding out every
    # other material gives the complement, pixel by pixel where no sample sees the sky
    others = [m for m in range(len(scene.materials)) if m != red]
    q = camera_passes(scene, accel, settings, frame=frame, holdout_mats=others)
    both = part & (p.alpha + q.alpha == 1.0)
    assert both.sum() > 5
    assert np.allclose(p.radiance[both] + q.radiance[both], frame.radiance[both],
                       rtol=1e-5, atol=1e-6)


def test_holdout_object_is_its_materials_held_out(spheres):
    scene, accel = spheres
    settings = RenderSettings(samples=2)
    frame = render(scene, settings, accel=accel)
    by_mat = camera_passes(scene, accel, settings, frame=frame,
                           holdout_mats=[scene.material_id("red")])
    by_obj = camera_passes(scene, accel, settings, frame=frame,
                           holdout_insts=[scene.instance_slot("RedSphere")])
    assert np.array_equal(by_mat.alpha, by_obj.alpha)
    assert np.array_equal(by_mat.radiance, by_obj.radiance)


def test_nothing_asked_nothing_traced(spheres):
    scene, accel = spheres
    p = camera_passes(scene, accel, RenderSettings())
    assert p.depth is None and p.normal is None and p.alpha is None


def test_a_cancelled_pass_returns_nothing(spheres):
    scene, accel = spheres
    settings = RenderSettings(samples=2)
    frame = render(scene, settings, accel=accel)
    p = camera_passes(scene, accel, settings, frame=frame, depth=True,
                      holdout_mats=[scene.material_id("red")], cancel=lambda: True)
    assert p.depth is None and p.alpha is None and p.radiance is None


def test_holdouts_on_rough_surfaces_trace_the_frames_glossy_samples():
    """A partly held-out pixel's other samples are traced again with the frame's own glossy
    rays (its *Glossy Samples* and the pixel's strata, tracing/glossy_strata.py): holding
    out one material and then every other gives the frame back, pixel by pixel (before, the
    re-trace took the default 16 glossy samples, each sample its own lattice)."""
    scene = scenes.rough_materials(40, 30)
    accel = create_accelerator("BVH", scene.arrays())
    settings = RenderSettings(samples=4, glossy_samples=4, max_depth=3)
    frame = render(scene, settings, accel=accel)
    red = scene.material_id("red")
    p = camera_passes(scene, accel, settings, frame=frame, holdout_mats=[red])
    others = [m for m in range(len(scene.materials)) if m != red]
    q = camera_passes(scene, accel, settings, frame=frame, holdout_mats=others)
    part = (p.alpha > 0.0) & (p.alpha < 1.0)
    both = part & (p.alpha + q.alpha == 1.0)
    assert both.sum() > 5
    assert np.allclose(p.radiance[both] + q.radiance[both], frame.radiance[both],
                       rtol=1e-5, atol=1e-6)
