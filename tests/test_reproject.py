"""Reprojected visibility (interpolants/reproject.py): frames whose pixels found their
interpolant by reprojection must be the frames a closest-hit ray per sample gives -- exactly,
since the proof makes the reprojected hit the closest one.

Small images (160 x 120, cells built from 12 rays on); each comparison renders the same
camera sequence with reprojection on and off.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.interpolants import interpolant_cache, reproject
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing import whitted

EPS = 0.01
FLOAT_TOL = 1e-6


@pytest.fixture(autouse=True)
def small_cells(monkeypatch):
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 12)
    # frames with and without reprojection are compared: the measured fallback (decided
    # from timings, tests/test_interpolant_fallback.py) would make them differ
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)


def _sequence(scene, cams, spp=1, enabled=True, monkeypatch=None):
    accel = create_accelerator("BVH", scene.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, samples=spp)
    r = InterpolantRenderer()
    frames = []
    monkeypatch.setattr(reproject, "ENABLED", enabled)
    for cam in cams:
        scene.set_camera(cam)
        frames.append(r.render(scene, st, accel))
    return frames, accel


def _moves(cam, step):
    m = cam.matrix.copy()
    fwd = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    m[:3, 3] += step * fwd
    a = np.radians(2.5)
    rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    pan = cam.matrix.copy()
    pan[:3, :3] = rz @ pan[:3, :3]
    return [cam, replace(cam, matrix=m), replace(cam, matrix=pan)]


def _assert_same(on, off):
    for a, b in zip(on, off, strict=True):
        assert np.array_equal(a.radiance, b.radiance)
        assert np.array_equal(a.pixel_class, b.pixel_class)
        assert np.array_equal(a.pixel_interpolant, b.pixel_interpolant)


@pytest.mark.parametrize("spp", [1, 4])
def test_reprojected_frames_are_the_traced_visibility_frames(monkeypatch, spp):
    sc = scenes.museum_1999(160, 120)
    cams = _moves(sc.camera, 0.005 * sc.arrays().scene_extent)
    on, accel = _sequence(sc, cams, spp, True, monkeypatch)
    off, _ = _sequence(sc, cams, spp, False, monkeypatch)
    _assert_same(on, off)
    rep = [f.stats["reprojected_fraction"] for f in on]
    assert all(f.stats["reprojected_fraction"] == 0.0 for f in off)
    # the camera moves reproject a good share; at several samples per pixel the first
    # frame too (the samples of a pixel after its first)
    assert rep[1] > 0.05 and rep[2] > 0.05
    assert (rep[0] > 0.05) if spp > 1 else rep[0] == 0.0
    assert max(rep) <= max(f.stats["interpolated_fraction"] for f in on) + 1e-9
    # and the bound holds on the moved frames
    for f, cam in zip(on[1:], cams[1:], strict=True):
        sc.set_camera(cam)
        base = whitted.render(sc, RenderSettings(samples=spp), accel=accel)
        err = np.abs(image.to_display(f.radiance) - image.to_display(base.radiance)).max()
        assert err <= EPS + FLOAT_TOL


def _floor_and_pillar():
    """A lit floor, and a pillar that a sideways camera move brings in front of it."""
    s = Scene()
    grey = s.add_material(Material(diffuse=(0.7, 0.7, 0.7)))
    red = s.add_material(Material(diffuse=(0.8, 0.2, 0.1)))
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="floor")), np.eye(4), [grey],
                   name="Floor")
    s.add_instance(s.add_mesh(shapes.box((0.4, 0.4, 3.0), name="pillar")),
                   shapes.transform(translate=(-2.6, 1.0, 1.5)), [red], name="Pillar")
    s.add_light(Light(kind="POINT", position=(0.0, 0.0, 6.0), power=3000.0))
    cam = Camera(matrix=shapes.look_at((0.0, -6.0, 4.0), (0.0, 2.0, 0.0)), width=120,
                 height=90)
    s.set_camera(cam)
    return s, cam


def test_an_object_moving_into_view_is_never_reprojected_away(monkeypatch):
    sc, cam = _floor_and_pillar()
    moved = []
    for dx in (0.0, -0.6, -1.2):
        m = cam.matrix.copy()
        m[0, 3] += dx
        moved.append(replace(cam, matrix=m))
    on, _ = _sequence(sc, moved, 1, True, monkeypatch)
    off, _ = _sequence(sc, moved, 1, False, monkeypatch)
    _assert_same(on, off)
    assert on[1].stats["reprojected_fraction"] > 0.05
    # the pillar is seen in the later frames (it was not in the first)
    red = (on[2].radiance[..., 0] > 2.0 * on[2].radiance[..., 2] + 1e-3)
    assert np.count_nonzero(red) > 20


def test_orthographic_cameras_and_edits_do_not_reproject(monkeypatch):
    sc, cam = _floor_and_pillar()
    ortho = Camera(matrix=shapes.look_at((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), up=(0, 1, 0)),
                   kind="ORTHO", ortho_scale=8.0, width=80, height=60)
    m = ortho.matrix.copy()
    m[0, 3] += 0.1
    on, _ = _sequence(sc, [ortho, replace(ortho, matrix=m)], 1, True, monkeypatch)
    assert on[1].stats["reprojected_fraction"] == 0.0
    # an edit drops what the previous frame left
    r = InterpolantRenderer()
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS)
    sc.set_camera(cam)
    r.render(sc, st, create_accelerator("BVH", sc.arrays()))
    assert r.cache.view is not None
    r.cache.invalidate(np.zeros((0, 2, 3)), objects=[1])
    assert r.cache.view is None


@pytest.mark.parametrize("name", ["spot_floor", "gallery", "tori"])
def test_random_camera_moves_reproject_exactly(monkeypatch, name):
    """Random small moves and turns on a spot light with a hard cone edge, a gallery with
    a torus occluder, glass and a polished floor, and smooth non-convex tori."""
    import bound_scenes

    sc = scenes.tori(96, 72) if name == "tori" else getattr(bound_scenes, name)("PERSP")
    rng = np.random.default_rng(3)
    cams = [sc.camera]
    m = sc.camera.matrix.copy()
    for _ in range(3):
        m = m.copy()
        m[:3, 3] += rng.normal(size=3) * 0.01 * sc.arrays().scene_extent
        a = np.radians(rng.normal() * 3.0)
        m[:3, :3] = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0],
                              [0.0, 0.0, 1.0]]) @ m[:3, :3]
        cams.append(replace(sc.camera, matrix=m))
    on, _ = _sequence(sc, cams, 2, True, monkeypatch)
    off, _ = _sequence(sc, cams, 2, False, monkeypatch)
    _assert_same(on, off)
    assert max(f.stats["reprojected_fraction"] for f in on) > 0.0


def test_a_session_reprojects_after_a_camera_move_and_edits_stay_exact(monkeypatch):
    """Session frames keep pixel records: reprojected samples record a view segment to the
    far end of their slab (longer than to their hit: it can only make more pixels dirty).
    An edit after a reprojected frame gives the frame a fresh session gives, within the
    bound of the base frame."""
    from rstrace_engine.geometry.edits import CameraChange, ObjectTransform
    from rstrace_engine.session import Session

    def run(enabled):
        monkeypatch.setattr(reproject, "ENABLED", enabled)
        sc = scenes.three_spheres(120, 90, subdivisions=2)
        st = RenderSettings(mode="INTERPOLANT", epsilon=EPS)
        sess = Session(sc, st)
        sess.render()
        cam = _moves(sc.camera, 0.1)[1]
        sc.set_camera(cam)
        sess.apply([CameraChange(cam)])
        moved = sess.render()
        edit = ObjectTransform("RedSphere", shapes.transform((-1.4, 0.5, 1.0)))
        sess.apply([edit])
        edited = sess.render()
        return moved, edited, sess

    moved, edited, sess = run(True)
    moved_off, edited_off, _ = run(False)
    assert moved.stats["reprojected_fraction"] > 0.02
    assert np.array_equal(moved.radiance, moved_off.radiance)
    assert not np.array_equal(edited.radiance, moved.radiance)  # the edit is seen
    base = whitted.render(sess.scene, RenderSettings(), accel=sess.accel)
    for f in (edited, edited_off):
        err = np.abs(image.to_display(f.radiance) - image.to_display(base.radiance)).max()
        assert err <= EPS + FLOAT_TOL
