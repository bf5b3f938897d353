"""Scenes built to break the interpolants' error bound (tests/test_interpolant_bound.py):
a fine image texture, spot lights with blend 0 and 0.3, a partial (non-convex) occluder,
glass and a mirror; each from a perspective or an orthographic camera."""

from __future__ import annotations

import math

import numpy as np

from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene

W, H = 64, 48


def _camera(kind: str, eye, target, ortho_scale: float) -> Camera:
    return Camera(matrix=shapes.look_at(eye, target), kind=kind, lens=35.0,
                  ortho_scale=ortho_scale, width=W, height=H)


def grid_texture(n: int = 128, period: int = 8, dark: float = 0.05) -> np.ndarray:
    """A white image with a dark grid line every ``period`` texels: detail far finer than a
    cell's test lines."""
    t = np.full((n, n, 3), 0.9, np.float32)
    t[::period, :] = dark
    t[:, ::period] = dark
    t[3::period, 5::period] = (0.9, 0.2, 0.1)  # and coloured dots between the lines
    return t


def textured_floor(kind: str) -> Scene:
    s = Scene()
    tex = s.add_material(Material("tiles", diffuse=(1.0, 1.0, 1.0), texture=grid_texture()))
    red = s.add_material(Material("red", diffuse=(0.7, 0.15, 0.1), specular=(0.2,) * 3,
                                  roughness=0.2))
    s.add_instance(s.add_mesh(shapes.plane(8.0, name="floor")), np.eye(4), [tex], "Floor")
    s.add_instance(s.add_mesh(shapes.icosphere(2, name="ball")),
                   shapes.transform((0.8, 0.5, 0.7), 0.7), [red], "Ball")
    s.add_light(Light("Lamp", "POINT", power=900.0, position=(-2.0, -1.5, 4.0)))
    s.set_world_color((0.05, 0.05, 0.06), lights=False)
    s.set_camera(_camera(kind, (0.0, -5.5, 4.5), (0.0, 0.3, 0.0), 7.0))
    return s


def spot_floor(kind: str) -> Scene:
    """A spot with blend 0 (its cone edge is a step) making a small pool of light on a
    floor, and a wide one, blend 0.3, making a soft one."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(10.0, name="floor")), np.eye(4), [grey], "Floor")
    s.add_light(Light("Hard", "SPOT", power=400.0, position=(0.7, 0.3, 3.0),
                      direction=(0.0, 0.0, -1.0), spot_size=math.radians(9.0),
                      spot_blend=0.0))
    s.add_light(Light("Soft", "SPOT", power=600.0, position=(-1.5, 0.5, 4.0),
                      direction=(0.2, 0.0, -1.0), spot_size=math.radians(40.0),
                      spot_blend=0.3))
    s.add_light(Light("Fill", "POINT", power=150.0, position=(0.0, -3.0, 5.0)))
    s.set_camera(_camera(kind, (0.0, -6.0, 5.0), (0.0, 0.0, 0.0), 8.0))
    return s


def gallery(kind: str) -> Scene:
    """A polished floor (a partial mirror reflecting the scene), a torus over it (a
    non-convex, partial occluder: light leaks through its hole), a glass sphere seen
    against the sky, a diffuse box."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.45, 0.45, 0.42), mirror=(0.35,) * 3))
    bronze = s.add_material(Material("bronze", diffuse=(0.35, 0.22, 0.1),
                                     specular=(0.35, 0.3, 0.2), roughness=0.2))
    glass = s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(0.95,) * 3,
                                    ior=1.45))
    s.add_instance(s.add_mesh(shapes.plane(12.0, name="floor")), np.eye(4), [floor], "Floor")
    s.add_instance(s.add_mesh(shapes.torus(0.9, 0.25, 32, 16, name="ring")),
                   shapes.transform((-1.2, 0.6, 1.2), rotate_x_deg=15.0), [bronze], "Ring")
    s.add_instance(s.add_mesh(shapes.icosphere(3, name="ball")),
                   shapes.transform((1.3, 0.8, 2.4), 1.1), [glass], "Glass")
    cube = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="cube"))
    s.add_instance(cube, shapes.transform((0.4, -1.6, 0.4), 0.8), [bronze], "Box")
    s.add_light(Light("Key", "POINT", power=1500.0, position=(-2.0, -0.5, 6.0)))
    s.add_light(Light("Sun", "SUN", power=1.5, direction=(0.3, 0.5, -1.0)))
    s.set_world_color((0.3, 0.35, 0.45), lights=False)
    s.set_camera(_camera(kind, (0.5, -7.0, 2.5), (0.0, 0.4, 1.2), 8.0))
    return s


SCENES = dict(texture=textured_floor, spot=spot_floor, gallery=gallery)


# ----------------------------------------------------------------------------- soft light
# (issue 20 item 3: lights with an extent are interpolated where a cell proves them fully
# visible and their value is the closed form; all Lambertian unless said otherwise)


def soft_penumbra(kind: str) -> Scene:
    """A box floating under a small rectangle light: its penumbra on the floor spans many
    cells (umbra, penumbra and lit floor side by side), and a sphere light just above the
    floor (its light changes fast close to it)."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6)))
    box = s.add_material(Material("box", diffuse=(0.4, 0.5, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(12.0, name="floor")), np.eye(4), [grey], "Floor")
    s.add_instance(s.add_mesh(shapes.box((0.6, 0.6, 0.6), name="cube")),
                   shapes.transform((-0.8, 0.3, 0.9)), [box], "Blocker")
    s.add_light(Light("Area", "AREA", power=350.0, position=(-0.6, 0.4, 2.2),
                      direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(0.9, 0.5)))
    s.add_light(Light("Near", "POINT", power=25.0, position=(1.6, -0.8, 0.3), radius=0.2,
                      soft_falloff=False))
    s.set_camera(_camera(kind, (0.0, -4.5, 5.0), (0.0, 0.0, 0.0), 6.0))
    return s


def soft_sun(kind: str) -> Scene:
    """A sun with a wide angle behind a post: its soft shadow edge across the floor, a
    glossy ball (its highlight is sampled: traced) and a sphere light with Blender's soft
    falloff."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.55, 0.55, 0.5)))
    gloss = s.add_material(Material("gloss", diffuse=(0.5, 0.1, 0.1), specular=(0.3,) * 3,
                                    roughness=0.3))
    s.add_instance(s.add_mesh(shapes.plane(12.0, name="floor")), np.eye(4), [grey], "Floor")
    s.add_instance(s.add_mesh(shapes.box((0.3, 0.3, 2.0), name="post")),
                   shapes.transform((-0.5, 0.5, 1.0)), [grey], "Post")
    s.add_instance(s.add_mesh(shapes.icosphere(2, name="ball")),
                   shapes.transform((1.2, 0.8, 0.5), 0.5), [gloss], "Ball")
    s.add_light(Light("Sun", "SUN", power=2.0, direction=(0.6, -0.3, -0.7), angle=0.25))
    s.add_light(Light("Soft", "POINT", power=120.0, position=(-2.0, -1.5, 1.5),
                      radius=0.4))
    s.set_camera(_camera(kind, (0.0, -5.0, 5.0), (0.0, 0.2, 0.0), 7.0))
    return s


def soft_studio(kind: str) -> Scene:
    """Objects on a floor under one large area light and a sphere light (a studio): soft
    contact shadows."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.7, 0.7, 0.68)))
    clay = s.add_material(Material("clay", diffuse=(0.65, 0.45, 0.3)))
    s.add_instance(s.add_mesh(shapes.plane(12.0, name="floor")), np.eye(4), [floor], "Floor")
    s.add_instance(s.add_mesh(shapes.box((0.8, 0.8, 0.8), name="cube")),
                   shapes.transform((-1.0, 0.4, 0.4), rotate_z_deg=25.0), [clay], "Cube")
    s.add_instance(s.add_mesh(shapes.icosphere(2, name="ball")),
                   shapes.transform((0.9, 0.2, 0.5), 0.5), [clay], "Ball")
    s.add_light(Light("Softbox", "AREA", power=600.0, position=(0.0, -0.5, 3.0),
                      direction=(0.0, 0.2, -1.0), shape="SQUARE", size=(2.0, 2.0)))
    s.add_light(Light("Bulb", "POINT", power=200.0, position=(2.5, -2.0, 2.0), radius=0.5))
    s.set_camera(_camera(kind, (0.0, -5.5, 3.5), (0.0, 0.3, 0.3), 6.0))
    return s


SOFT_SCENES = dict(soft_penumbra=soft_penumbra, soft_sun=soft_sun, soft_studio=soft_studio)
