"""Built-in benchmark scenes, built with the core API.

* ``three_spheres`` — the paper's Plate A: three spheres (one a mirror) on a plane, two lights.
* ``museum`` — a room with 1,000+ objects (pedestals and sculptures), a mirror wall, several
  lights, 100k+ triangles.
* ``museum_1999`` — like seed 000's museum: a room, four sculptures of ~1,100 primitives, a
  mirror, two lights and a spot (most pixels large smooth surfaces, as in the paper).
* ``grid`` — 20 icospheres on a plane, ~100k triangles (the ray-cast benchmark).
* ``torus_knot`` — smooth non-convex objects (tori) on a plane, for interpolant tests.
* ``museum_soft`` — ``museum_1999`` lit as a Blender user lights it (issue 20): two
  rectangular area lights at the ceiling, a sun with a 3 degree angle through a skylight, a
  spot with a radius and a grey world that lights (through the skylight).
* ``studio`` — objects on a floor under one large area light, a sphere light and a grey
  world that lights: the studio set-up of product shots.
* ``glass_horizon`` — a glass sphere, a glass torus and a chrome ball before a horizon (the
  RI-tree's exit rays, issue 22).
* ``rough_materials`` — a rough metal, a rough glass and a default plastic sphere on a floor
  under one point light, the world a background only: what ``bench frame`` renders with
  Mitsuba 3 too (issue 24).
"""

from __future__ import annotations

import math

import numpy as np

from .geometry import shapes
from .geometry.elements import Mesh
from .geometry.principled import principled_material
from .geometry.scene import Camera, Light, Material, Scene


def _camera(eye, target, width, height, lens=35.0) -> Camera:
    return Camera(matrix=shapes.look_at(eye, target), lens=lens, width=width, height=height)


def three_spheres(width: int = 640, height: int = 480, subdivisions: int = 4) -> Scene:
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.55, 0.55, 0.5), specular=(0.1,) * 3,
                                    roughness=0.25))
    red = s.add_material(Material("red", diffuse=(0.7, 0.12, 0.1), specular=(0.25,) * 3,
                                  roughness=0.15))
    blue = s.add_material(Material("blue", diffuse=(0.1, 0.2, 0.65), specular=(0.2,) * 3,
                                   roughness=0.3))
    mirror = s.add_material(Material("mirror", diffuse=(0.05,) * 3, mirror=(0.9,) * 3))
    sphere = s.add_mesh(shapes.icosphere(subdivisions, name="sphere"))
    ground = s.add_mesh(shapes.plane(12.0, name="ground"))
    s.add_instance(ground, np.eye(4), [floor], name="Ground")
    s.add_instance(sphere, shapes.transform((-1.6, 0.4, 1.0)), [red], name="RedSphere")
    s.add_instance(sphere, shapes.transform((0.6, -0.9, 1.0)), [mirror], name="MirrorSphere")
    s.add_instance(sphere, shapes.transform((1.5, 1.6, 0.8), 0.8), [blue], name="BlueSphere")
    s.add_light(Light("Key", "POINT", power=1500.0, position=(-3.0, -4.0, 6.0)))
    s.add_light(Light("Fill", "POINT", color=(0.9, 0.95, 1.0), power=500.0,
                      position=(4.0, -2.0, 3.5)))
    s.set_world_color((0.05, 0.06, 0.08), lights=False)  # a background only
    s.set_camera(_camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8), width, height))
    return s


def grid(width: int = 640, height: int = 480, subdivisions: int = 4) -> Scene:
    """20 icospheres (5,120 triangles each) on a plane: ~102k triangles."""
    s = Scene()
    mat = s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6), specular=(0.2,) * 3))
    floor = s.add_material(Material("floor", diffuse=(0.4, 0.45, 0.4)))
    sphere = s.add_mesh(shapes.icosphere(subdivisions, name="ico"))
    ground = s.add_mesh(shapes.plane(30.0, divisions=8, name="ground"))
    s.add_instance(ground, np.eye(4), [floor], name="Ground")
    for k in range(20):
        i, j = divmod(k, 5)
        s.add_instance(sphere, shapes.transform((-6.0 + 3.0 * j, -4.5 + 3.0 * i, 1.0)),
                       [mat], name=f"Ico{k:02d}")
    s.add_light(Light("Sun", "SUN", power=3.0, direction=(-0.3, 0.4, -1.0)))
    s.add_light(Light("Lamp", "POINT", power=3000.0, position=(0.0, -6.0, 8.0)))
    s.set_world_color((0.1, 0.1, 0.12), lights=False)  # a background only
    s.set_camera(_camera((0.0, -16.0, 9.0), (0.0, 0.0, 0.5), width, height))
    return s


def museum(width: int = 640, height: int = 480, rows: int = 25, cols: int = 40) -> Scene:
    """A 40 x 30 m hall: rows x cols plinths (boxes), each with a sculpture on top.

    With the defaults: 1,000 plinths + 1,000 sculptures + room + mirror = 2,002 objects and
    about 300k triangles (sculptures alternate between an icosphere and a torus).
    """
    s = Scene()
    wall = s.add_material(Material("wall", diffuse=(0.7, 0.68, 0.62)))
    stone = s.add_material(Material("stone", diffuse=(0.5, 0.5, 0.52), specular=(0.1,) * 3,
                                    roughness=0.3))
    bronze = s.add_material(Material("bronze", diffuse=(0.35, 0.22, 0.1),
                                     specular=(0.35, 0.3, 0.2), roughness=0.2))
    marble = s.add_material(Material("marble", diffuse=(0.8, 0.8, 0.78), specular=(0.15,) * 3,
                                     roughness=0.1))
    mirror = s.add_material(Material("mirror", diffuse=(0.02,) * 3, mirror=(0.92,) * 3))
    W, D, H = 40.0, 30.0, 8.0
    room = s.add_mesh(shapes.box((W, D, H), name="room", inward=True))
    plinth = s.add_mesh(shapes.box((0.5, 0.5, 1.0), name="plinth"))
    ico = s.add_mesh(shapes.icosphere(2, 0.3, name="sculpture_ico"))
    tor = s.add_mesh(shapes.torus(0.25, 0.09, 16, 8, name="sculpture_torus"))
    glass = s.add_mesh(shapes.plane(1.0, name="mirror_panel"))
    s.add_instance(room, shapes.transform((0, 0, H / 2)), [wall], name="Room")
    s.add_instance(glass, shapes.transform((0, D / 2 - 0.05, 3.0), (20.0, 5.0, 1.0), 0, 90),
                   [mirror], name="MirrorWall")
    xs = np.linspace(-W / 2 + 2.0, W / 2 - 2.0, cols)
    ys = np.linspace(-D / 2 + 2.0, D / 2 - 3.0, rows)
    k = 0
    for y in ys:
        for x in xs:
            s.add_instance(plinth, shapes.transform((x, y, 0.5)), [stone], name=f"Plinth{k:04d}")
            if k % 2 == 0:
                s.add_instance(ico, shapes.transform((x, y, 1.3)), [marble],
                               name=f"Sculpture{k:04d}")
            else:
                s.add_instance(tor, shapes.transform((x, y, 1.35), 1.0, 30.0 * k, 60.0),
                               [bronze], name=f"Sculpture{k:04d}")
            k += 1
    for j, (x, y) in enumerate([(-12, -8), (12, -8), (-12, 6), (12, 6), (0, -1)]):
        s.add_light(Light(f"Ceiling{j}", "POINT", power=1200.0, position=(x, y, H - 0.5)))
    s.add_light(Light("Spot", "SPOT", power=4000.0, position=(0.0, -D / 2 + 1.0, H - 1.0),
                      direction=(0.0, 1.0, -0.6), spot_size=math.radians(50)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(_camera((-14.0, -13.5, 4.2), (2.0, 4.0, 1.0), width, height, lens=24.0))
    return s


def museum_1999(width: int = 640, height: int = 480) -> Scene:
    """A scene like seed 000's museum (Plate B), lit by two ceiling lights and a spot
    (:func:`_museum_1999_objects`)."""
    s = _museum_1999_objects(skylight=False)
    H = MUSEUM_1999_SIZE[2]
    s.add_light(Light("Ceiling0", "POINT", power=300.0, position=(-3.0, 0.0, H - 0.4)))
    s.add_light(Light("Ceiling1", "POINT", power=300.0, position=(3.0, 0.0, H - 0.4)))
    s.add_light(Light("Spot", "SPOT", power=600.0, position=(0.0, -3.5, H - 0.3),
                      direction=(0.0, 0.55, -0.6), spot_size=math.radians(40)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(_camera((1.5, -4.3, 1.7), (-0.3, 1.5, 1.2), width, height, lens=22.0))
    return s


#: ``museum_1999``'s room: width, depth, height (m)
MUSEUM_1999_SIZE = (13.7, 9.1, 4.5)
#: ``museum_soft``'s skylight: centre (x, y) and size (x, y) of the opening in the ceiling
SKYLIGHT = ((1.8, 0.6), (2.0, 1.2))


def _room_without_ceiling(size) -> Mesh:
    """An inward box (a room) whose two ceiling triangles are left out."""
    m = shapes.box(size, name="room_open", inward=True)
    top = np.all(m.vertices[m.triangles][:, :, 2] > 0.0, axis=1)
    return Mesh("room_open", m.vertices, m.triangles[~top], smooth=False)


def _museum_1999_objects(skylight: bool) -> Scene:
    """The objects of a scene like seed 000's museum (Plate B): a 45 x 30 ft room
    (13.7 x 9.1 m, 4.5 m high), a mirror on a wall, a green cube, and four sculptures on
    plinths made of about 1,100 primitives: a twisted tower of 60 boxes under a sphere
    (Edit-(a)/(b): its top and bottom), a spiral of 600 small spheres, a stepped pyramid of
    204 boxes and a ring of 200 small tori. Unlike ``museum`` (2,000 small objects, the hard
    case) most pixels are large smooth surfaces, as in the paper. No lights, no world, no
    camera. ``skylight``: the ceiling is a slab with an opening (:data:`SKYLIGHT`) instead
    of the room's top.
    """
    s = Scene()
    wall = s.add_material(Material("wall", diffuse=(0.72, 0.7, 0.64)))
    floor = s.add_material(Material("floor", diffuse=(0.45, 0.38, 0.3), specular=(0.08,) * 3,
                                    roughness=0.3))
    stone = s.add_material(Material("stone", diffuse=(0.55, 0.55, 0.57)))
    marble = s.add_material(Material("marble", diffuse=(0.8, 0.8, 0.78), specular=(0.12,) * 3,
                                     roughness=0.15))
    bronze = s.add_material(Material("bronze", diffuse=(0.4, 0.26, 0.12),
                                     specular=(0.3, 0.25, 0.18), roughness=0.25))
    green = s.add_material(Material("green", diffuse=(0.12, 0.5, 0.15)))
    mirror = s.add_material(Material("mirror", diffuse=(0.02,) * 3, mirror=(0.9,) * 3))
    W, D, H = MUSEUM_1999_SIZE
    if skylight:
        room = s.add_mesh(_room_without_ceiling((W, D, H)))
    else:
        room = s.add_mesh(shapes.box((W, D, H), name="room", inward=True))
    box = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="unit_box"))
    ball = s.add_mesh(shapes.icosphere(3, 1.0, name="ball"))
    pebble = s.add_mesh(shapes.icosphere(1, 1.0, name="pebble"))
    ring = s.add_mesh(shapes.torus(1.0, 0.3, 16, 8, name="ring"))
    panel = s.add_mesh(shapes.plane(1.0, name="mirror_panel"))
    s.add_instance(room, shapes.transform((0, 0, H / 2)), [wall, floor], name="Room")
    if skylight:  # four slabs 0.2 m thick around the opening
        (cx, cy), (sx, sy) = SKYLIGHT
        slab = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="ceiling_slab"))
        x0, x1, y0, y1 = cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2
        for j, (a, b, c, d) in enumerate([(-W / 2, x0, -D / 2, D / 2),
                                          (x1, W / 2, -D / 2, D / 2),
                                          (x0, x1, -D / 2, y0), (x0, x1, y1, D / 2)]):
            s.add_instance(slab, shapes.transform(((a + b) / 2, (c + d) / 2, H + 0.1),
                                                  (b - a, d - c, 0.2)),
                           [wall], name=f"CeilingSlab{j}")
    s.add_instance(panel, shapes.transform((-W / 2 + 0.02, 0.5, 1.9), (4.0, 2.6, 1.0), 90, 90),
                   [mirror], name="Mirror")
    s.add_instance(box, shapes.transform((4.3, -2.6, 0.4), 0.8, 20.0), [green], name="GreenCube")
    k = 0

    def add(mesh, m, mat):
        nonlocal k
        s.add_instance(mesh, m, [mat], name=f"Prim{k:04d}")
        k += 1

    # A: the twisted tower on a plinth (centre)
    add(box, shapes.transform((0.0, 1.0, 0.4), (1.2, 1.2, 0.8)), stone)
    for j in range(60):
        add(box, shapes.transform((0.0, 1.0, 0.8 + 0.04 * j + 0.02), (0.55, 0.55, 0.04),
                                  3.0 * j), bronze)
    add(ball, shapes.transform((0.0, 1.0, 3.25), 0.42), marble)
    # B: a spiral of small spheres (left)
    add(box, shapes.transform((-3.6, 2.0, 0.3), (1.4, 1.4, 0.6)), stone)
    for j in range(600):
        a = 0.105 * j
        r = 0.2 + 0.45 * j / 600
        add(pebble, shapes.transform((-3.6 + r * math.cos(a), 2.0 + r * math.sin(a),
                                      0.65 + 0.0036 * j), 0.05), marble)
    # C: a stepped pyramid of boxes (right)
    for lv in range(8):
        n = 8 - lv
        for i in range(n):
            for jj in range(n):
                add(box, shapes.transform((3.4 + 0.2 * (i - (n - 1) / 2),
                                           2.2 + 0.2 * (jj - (n - 1) / 2), 0.1 + 0.2 * lv),
                                          0.2), stone if lv % 2 == 0 else marble)
    # D: a ring of small tori (front left)
    add(box, shapes.transform((-2.2, -2.0, 0.35), (1.0, 1.0, 0.7)), stone)
    for j in range(200):
        a = 2 * math.pi * j / 200
        add(ring, shapes.transform((-2.2 + 0.4 * math.cos(a), -2.0 + 0.4 * math.sin(a),
                                    1.05 + 0.35 * math.sin(3 * a)), 0.05, math.degrees(a),
                                   60.0), bronze)
    return s


def museum_soft(width: int = 640, height: int = 480) -> Scene:
    """``museum_1999`` lit as a Blender user lights it: two 1.2 x 0.6 m area lights at the
    ceiling (where its point lights were), a sun of 3 degrees' angular diameter through a
    2 x 1.2 m skylight (onto the floor by the pyramid), its spot with a 5 cm radius, and a
    grey world that lights what sees the sky. Same camera."""
    s = _museum_1999_objects(skylight=True)
    H = MUSEUM_1999_SIZE[2]
    for j, x in enumerate((-3.0, 3.0)):
        s.add_light(Light(f"Ceiling{j}", "AREA", power=120.0, position=(x, 0.0, H - 0.01),
                          direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(1.2, 0.6)))
    s.add_light(Light("Spot", "SPOT", power=600.0, position=(0.0, -3.5, H - 0.3),
                      direction=(0.0, 0.55, -0.6), spot_size=math.radians(40), radius=0.05))
    s.add_light(Light("Sun", "SUN", power=3.0, direction=(0.3, 0.35, -1.0),
                      angle=math.radians(3.0)))
    s.set_world_color((0.05, 0.05, 0.05), lights=True)
    s.set_camera(_camera((1.5, -4.3, 1.7), (-0.3, 1.5, 1.2), width, height, lens=22.0))
    return s


def studio(width: int = 640, height: int = 480) -> Scene:
    """Objects on a floor under one large area light (a 2.5 x 2.5 m soft box above, tilted
    toward the camera's side), a sphere light of 0.4 m radius to the left and a grey world
    that lights: a sphere, a glossy torus, a box, a small mirror ball and a vase."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.6, 0.6, 0.58), specular=(0.05,) * 3,
                                    roughness=0.4))
    red = s.add_material(Material("red", diffuse=(0.7, 0.12, 0.1), specular=(0.2,) * 3,
                                  roughness=0.2))
    gold = s.add_material(Material("gold", diffuse=(0.45, 0.3, 0.08), specular=(0.4,) * 3,
                                   roughness=0.2))
    white = s.add_material(Material("white", diffuse=(0.75, 0.75, 0.75)))
    blue = s.add_material(Material("blue", diffuse=(0.1, 0.2, 0.6), specular=(0.1,) * 3,
                                   roughness=0.3))
    chrome = s.add_material(Material("chrome", diffuse=(0.03,) * 3, mirror=(0.85,) * 3))
    s.add_instance(s.add_mesh(shapes.plane(14.0, name="ground")), np.eye(4), [floor],
                   name="Floor")
    sphere = s.add_mesh(shapes.icosphere(4, name="sphere"))
    s.add_instance(sphere, shapes.transform((-1.3, 0.3, 0.7), 0.7), [red], name="Sphere")
    s.add_instance(s.add_mesh(shapes.torus(0.6, 0.22, 64, 32, name="torus")),
                   shapes.transform((0.9, 0.8, 0.5), 1.0, 30.0, 60.0), [gold], name="Torus")
    s.add_instance(s.add_mesh(shapes.box((0.9, 0.9, 0.9), name="cube")),
                   shapes.transform((0.6, -1.0, 0.45), 1.0, 25.0), [white], name="Cube")
    s.add_instance(sphere, shapes.transform((-0.2, -1.5, 0.25), 0.25), [chrome],
                   name="MirrorBall")
    vase = shapes.revolve([0.0, 0.25, 0.4, 0.3, 0.15, 0.2, 0.0],
                          [0.0, 0.02, 0.3, 0.7, 1.0, 1.2, 1.2], 48, name="vase")
    s.add_instance(s.add_mesh(vase), shapes.transform((-2.6, 1.6, 0.0)), [blue], name="Vase")
    s.add_light(Light("SoftBox", "AREA", power=300.0, position=(0.0, -1.0, 4.0),
                      direction=(0.0, 0.3, -1.0), shape="SQUARE", size=2.5))
    s.add_light(Light("Bulb", "POINT", power=150.0, position=(-3.5, -1.5, 2.0), radius=0.4))
    s.set_world_color((0.08, 0.08, 0.1), lights=True)
    s.set_camera(_camera((0.0, -7.0, 3.0), (0.0, 0.2, 0.6), width, height, lens=40.0))
    return s


def tori(width: int = 640, height: int = 480) -> Scene:
    """Smooth non-convex objects: three tori (one glossy, one mirror) on a plane."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.5, 0.5, 0.5)))
    gold = s.add_material(Material("gold", diffuse=(0.45, 0.3, 0.08), specular=(0.4,) * 3,
                                   roughness=0.2))
    green = s.add_material(Material("green", diffuse=(0.15, 0.55, 0.2), specular=(0.1,) * 3))
    chrome = s.add_material(Material("chrome", diffuse=(0.05,) * 3, mirror=(0.85,) * 3))
    tor = s.add_mesh(shapes.torus(1.0, 0.35, 96, 48, name="torus"))
    ground = s.add_mesh(shapes.plane(12.0, name="ground"))
    s.add_instance(ground, np.eye(4), [floor], name="Ground")
    s.add_instance(tor, shapes.transform((-1.8, 0.5, 0.35)), [gold], name="GoldTorus")
    s.add_instance(tor, shapes.transform((0.6, -0.6, 1.2), 1.0, 20.0, 70.0), [chrome],
                   name="ChromeTorus")
    s.add_instance(tor, shapes.transform((2.2, 1.8, 0.35), 0.8), [green], name="GreenTorus")
    s.add_light(Light("Key", "POINT", power=2500.0, position=(-3.0, -4.0, 6.0)))
    s.add_light(Light("Sun", "SUN", power=1.5, direction=(0.5, 0.3, -1.0)))
    s.set_world_color((0.05, 0.06, 0.08), lights=False)  # a background only
    s.set_camera(_camera((0.0, -8.5, 4.0), (0.0, 0.3, 0.6), width, height))
    return s


def _sky_texture(seed: int = 7, w: int = 128, h: int = 64) -> np.ndarray:
    """A pseudo-random procedural texture (sum of sinusoids), linear RGB (h, w, 3)."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, w), np.linspace(0, np.pi, h))
    val = np.zeros((h, w))
    for _ in range(12):
        a, b, c = rng.integers(1, 9), rng.integers(1, 7), rng.uniform(0, 2 * np.pi)
        val += np.sin(a * u + c) * np.sin(b * v + c * 0.7) / (a + b)
    val = (val - val.min()) / (val.max() - val.min())
    tex = np.stack([0.25 + 0.6 * val, 0.3 + 0.45 * val ** 2, 0.55 + 0.35 * (1 - val)], -1)
    return tex.astype(np.float32)


def _sky(s: Scene, radius: float) -> None:
    """The paper's large procedurally textured sphere around the scene (faces inward)."""
    sky = shapes.icosphere(3, radius, name="sky")
    sky.triangles = sky.triangles[:, ::-1].copy()
    sky.corner_normals = -sky.corner_normals[:, ::-1]
    sky.corner_uvs = sky.corner_uvs[:, ::-1].copy()
    mat = s.add_material(Material("sky", diffuse=(0.2,) * 3, emission=(0.6, 0.6, 0.6),
                                  texture=_sky_texture()))
    s.add_instance(s.add_mesh(sky), np.eye(4), [mat], name="Sky")


def bezier_surface(width: int = 600, height: int = 600) -> Scene:
    """Seed 004's Bezier surface: a smooth reflective C2 surface (a bicubic B-spline of
    10 x 10 patches, 73k triangles) inside a large procedurally textured sphere."""
    s = Scene()
    rng = np.random.default_rng(4)
    heights = rng.uniform(-0.45, 0.45, (13, 13))
    surf = s.add_mesh(shapes.bspline_surface(heights, (6.0, 6.0), 190, name="bezier"))
    chrome = s.add_material(Material("chrome", diffuse=(0.08, 0.08, 0.1), specular=(0.1,) * 3,
                                     roughness=0.15, mirror=(0.8,) * 3))
    s.add_instance(surf, shapes.transform((0, 0, 0), 1.0, 25.0), [chrome], name="Bezier")
    _sky(s, 30.0)
    s.add_light(Light("Key", "POINT", power=6000.0, position=(-4.0, -5.0, 7.0)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(_camera((0.0, -7.5, 4.5), (0.0, 0.0, -0.2), width, height))
    return s


def random_volumes(width: int = 600, height: int = 600, count: int = 6, seed: int = 11) -> Scene:
    """Seed 004's random volumes: non-intersecting random convex refractive blobs (surfaces
    of revolution of random convex profiles), one per cell of a random axis-aligned split of
    the region, over a checkered floor inside the textured sphere."""
    s = Scene()
    rng = np.random.default_rng(seed)
    glass = s.add_material(Material("glass", diffuse=(0.0,) * 3, specular=(0.0,) * 3,
                                    transmission=(0.92, 0.95, 0.97), ior=1.5))
    n = 16
    check = ((np.indices((n * 8, n * 8)).sum(axis=0) // 8) % 2).astype(np.float32)
    tex = np.stack([0.2 + 0.6 * check, 0.2 + 0.5 * check, 0.25 + 0.3 * check], -1)
    floor = s.add_material(Material("floor", diffuse=(0.9,) * 3, texture=tex))
    s.add_instance(s.add_mesh(shapes.plane(14.0, name="floor")), np.eye(4), [floor],
                   name="Floor")
    cells = [(-3.0, 3.0, -3.0, 3.0)]
    while len(cells) < count:
        cells.sort(key=lambda c: -(c[1] - c[0]) * (c[3] - c[2]))
        x0, x1, y0, y1 = cells.pop(0)
        if x1 - x0 >= y1 - y0:
            m = rng.uniform(0.4, 0.6) * (x1 - x0) + x0
            cells += [(x0, m, y0, y1), (m, x1, y0, y1)]
        else:
            m = rng.uniform(0.4, 0.6) * (y1 - y0) + y0
            cells += [(x0, x1, y0, m), (x0, x1, m, y1)]
    for k, (x0, x1, y0, y1) in enumerate(cells):
        rmax = 0.45 * min(x1 - x0, y1 - y0)
        hgt = rng.uniform(0.8, 2.2) * rmax
        p = rng.uniform(0.45, 0.9)
        sz = np.linspace(0.0, 1.0, 33)
        prof = rmax * np.sin(np.pi * sz) ** p
        mesh = shapes.revolve(prof, sz * hgt, 64, name=f"blob{k}")
        s.add_instance(s.add_mesh(mesh), shapes.transform(
            (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.05), 1.0, rng.uniform(0, 360)), [glass],
            name=f"Volume{k}")
    _sky(s, 30.0)
    s.add_light(Light("Key", "POINT", power=4000.0, position=(-3.0, -4.0, 8.0)))
    s.add_light(Light("Sun", "SUN", power=1.0, direction=(0.3, 0.5, -1.0)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(_camera((0.0, -8.0, 6.0), (0.0, 0.0, 0.4), width, height))
    return s


def tomatoes(width: int = 1200, height: int = 900) -> Scene:
    """Seed 004's tomatoes: spheres in a reflective bowl under a transparent, reflective,
    non-refractive wrap, a smooth tomato beside it, on a reflective table, inside the
    textured sphere."""
    s = Scene()
    red = s.add_material(Material("tomato", diffuse=(0.6, 0.06, 0.03), specular=(0.25,) * 3,
                                  roughness=0.12))
    bowl_m = s.add_material(Material("bowl", diffuse=(0.1, 0.1, 0.12), mirror=(0.75,) * 3))
    wrap_m = s.add_material(Material("wrap", diffuse=(0.0,) * 3, mirror=(0.12,) * 3,
                                     transmission=(0.85,) * 3, ior=1.0))
    table_m = s.add_material(Material("table", diffuse=(0.35, 0.25, 0.15), mirror=(0.35,) * 3))
    table = s.add_mesh(shapes.box((9.0, 7.0, 0.3), name="table"))
    s.add_instance(table, shapes.transform((0, 0, -0.15)), [table_m], name="Table")
    # the bowl: an open surface of revolution (a shell seen from both sides)
    a = np.linspace(0.0, 1.0, 40)
    bowl = shapes.revolve(1.6 * np.sin(a * 0.5 * np.pi * 0.95), 1.6 * (1 - np.cos(
        a * 0.5 * np.pi * 0.95)), 96, name="bowl")
    s.add_instance(s.add_mesh(bowl), shapes.transform((-0.6, 0.3, 0.0)), [bowl_m], name="Bowl")
    tom = s.add_mesh(shapes.icosphere(3, 0.42, name="tomato"))
    for k, (x, y, z) in enumerate([(-0.95, 0.15, 0.55), (-0.2, 0.35, 0.6), (-0.65, 0.85, 0.62),
                                   (-0.55, -0.3, 0.58), (-0.6, 0.3, 1.05)]):
        s.add_instance(tom, shapes.transform((x, y, z)), [red], name=f"Tomato{k}")
    sz = np.linspace(0.0, 1.0, 33)
    btom = shapes.revolve(0.55 * np.sin(np.pi * sz) ** 0.7, 0.8 * sz, 64, name="bezier_tomato")
    s.add_instance(s.add_mesh(btom), shapes.transform((1.9, -0.6, 0.0)), [red],
                   name="BezierTomato")
    rng = np.random.default_rng(9)
    hts = 1.75 + 0.12 * rng.uniform(-1, 1, (8, 8))
    hts[0, :] = hts[-1, :] = hts[:, 0] = hts[:, -1] = 0.9
    wrap = shapes.bspline_surface(hts, (4.2, 4.2), 120, name="wrap")
    s.add_instance(s.add_mesh(wrap), shapes.transform((-0.6, 0.3, 0.0)), [wrap_m], name="Wrap")
    _sky(s, 30.0)
    s.add_light(Light("Key", "POINT", power=5000.0, position=(-3.0, -5.0, 8.0)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(_camera((1.5, -7.0, 4.2), (-0.2, 0.2, 0.6), width, height))
    return s


def glass_horizon(width: int = 240, height: int = 180) -> Scene:
    """A glass sphere, a glass torus and a chrome ball on a floor before a horizon, two point
    lights (issue 22: the floor's horizon seen through the glass shows an exit ray's error
    as a shifted edge)."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.6, 0.6, 0.6)))
    glass = s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(0.95,) * 3,
                                    ior=1.5))
    chrome = s.add_material(Material("chrome", diffuse=(0.05,) * 3, mirror=(0.9,) * 3))
    s.add_instance(s.add_mesh(shapes.plane(20.0)), np.eye(4), [floor], name="Floor")
    ball = s.add_mesh(shapes.icosphere(4, name="ball"))
    s.add_instance(ball, shapes.transform((-1.3, 0.0, 1.0)), [glass], name="GlassSphere")
    s.add_instance(s.add_mesh(shapes.torus(0.7, 0.25, 96, 48, name="ring")),
                   shapes.transform((1.3, 0.8, 0.6), 1.0, 60.0, 20.0), [glass],
                   name="GlassTorus")
    s.add_instance(ball, shapes.transform((0.9, -1.2, 0.5), 0.5), [chrome], name="ChromeBall")
    s.add_light(Light("Key", "POINT", power=1500.0, position=(-3.0, -4.0, 6.0)))
    s.add_light(Light("Fill", "POINT", power=600.0, position=(4.0, -2.0, 3.0)))
    s.set_world_color((0.3, 0.35, 0.45), lights=False)
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -5.0, 1.5), (0.0, 0.0, 0.8)), lens=30.0,
                        width=width, height=height))
    return s


def glossy(width: int = 640, height: int = 480, roughness: float = 0.3) -> Scene:
    """Rough materials (issue 24): a rough metal sphere, a default plastic (Principled's
    defaults: roughness 0.5) and a rough glass sphere on a chequered floor, between
    coloured diffuse objects they reflect, under a point light, a sphere light and a grey
    world that lights. ``roughness``: the metal's and the glass's."""
    s = Scene()

    def principled(name, base, **kw):
        mat, _ = principled_material(name, base, **kw)
        return s.add_material(mat)

    light = principled("floor_light", (0.7, 0.7, 0.68), specular_level=0.0)
    dark = principled("floor_dark", (0.15, 0.15, 0.17), specular_level=0.0)
    metal = principled("metal", (0.9, 0.72, 0.45), metallic=1.0, roughness=roughness)
    plastic = principled("plastic", (0.2, 0.35, 0.8))
    glass = principled("glass", (1.0, 1.0, 1.0), roughness=roughness, transmission=1.0)
    red = principled("red", (0.8, 0.1, 0.08), specular_level=0.0)
    green = principled("green", (0.1, 0.6, 0.15), specular_level=0.0)
    tile = s.add_mesh(shapes.plane(1.0, name="tile"))
    for i in range(-5, 5):
        for j in range(-3, 5):
            s.add_instance(tile, shapes.transform((i + 0.5, j + 0.5, 0.0)),
                           [light if (i + j) % 2 else dark], name=f"Tile{i}_{j}")
    sphere = _rough_set(s, metal, plastic, glass, red)
    s.add_instance(sphere, shapes.transform((1.3, 2.0, 0.5), 0.5), [green], name="Green")
    s.add_light(Light("Key", "POINT", power=1200.0, position=(-3.0, -3.5, 5.0)))
    s.add_light(Light("Bulb", "POINT", power=200.0, position=(3.0, -1.0, 2.5), radius=0.3))
    s.set_world_color((0.15, 0.16, 0.2), lights=True)
    s.set_camera(_camera((0.0, -6.5, 2.6), (0.0, 0.4, 0.6), width, height, lens=40.0))
    return s


def _rough_set(s: Scene, metal: int, plastic: int, glass: int, red: int) -> int:
    """The metal, plastic and glass spheres and the red box of the rough scenes; returns
    the sphere mesh."""
    sphere = s.add_mesh(shapes.icosphere(4, name="sphere"))
    s.add_instance(sphere, shapes.transform((0.0, 0.3, 0.8), 0.8), [metal], name="Metal")
    s.add_instance(sphere, shapes.transform((-2.0, 0.2, 0.6), 0.6), [plastic],
                   name="Plastic")
    s.add_instance(sphere, shapes.transform((1.9, -0.4, 0.6), 0.6), [glass], name="Glass")
    s.add_instance(s.add_mesh(shapes.box((0.8, 0.8, 1.6), name="cube")),
                   shapes.transform((-0.8, 2.3, 0.8), 1.0, 20.0), [red], name="RedBox")
    return sphere


def rough_materials(width: int = 640, height: int = 480, roughness: float = 0.3) -> Scene:
    """Rough materials that Mitsuba 3 models the same way (``bench frame``, issue 24): a
    rough metal sphere (Principled, metallic, a light gold whose Schlick curve stays near
    its colour), a rough clear glass sphere (IOR 1.5) and a default plastic (Principled's
    defaults: roughness 0.5, specular 0.5) beside a red box, on a Lambertian floor
    (specular 0), under one point light; the world is a background only (it lights nothing).
    So every pixel is direct light plus glossy and refracted bounces, no diffuse
    interreflection. ``roughness``: the metal's and the glass's."""
    s = Scene()

    def principled(name, base, **kw):
        mat, _ = principled_material(name, base, **kw)
        return s.add_material(mat)

    floor = principled("floor", (0.6, 0.6, 0.58), specular_level=0.0)
    metal = principled("metal", (0.95, 0.85, 0.7), metallic=1.0, roughness=roughness)
    glass = principled("glass", (1.0, 1.0, 1.0), roughness=roughness, transmission=1.0)
    plastic = principled("plastic", (0.15, 0.3, 0.75))
    red = principled("red", (0.75, 0.1, 0.08), specular_level=0.0)
    s.add_instance(s.add_mesh(shapes.plane(12.0, name="ground")), np.eye(4), [floor],
                   name="Floor")
    _rough_set(s, metal, plastic, glass, red)
    s.add_light(Light("Key", "POINT", power=1000.0, position=(-3.0, -3.5, 5.0)))
    s.set_world_color((0.12, 0.13, 0.16), lights=False)  # a background only
    s.set_camera(_camera((0.0, -6.5, 2.6), (0.0, 0.4, 0.6), width, height, lens=40.0))
    return s


SCENES = {"three_spheres": three_spheres, "museum": museum, "museum_1999": museum_1999,
          "grid": grid, "tori": tori,
          "bezier_surface": bezier_surface, "random_volumes": random_volumes,
          "tomatoes": tomatoes, "museum_soft": museum_soft, "studio": studio,
          "glass_horizon": glass_horizon, "glossy": glossy,
          "rough_materials": rough_materials}


def build(name: str, width: int = 640, height: int = 480) -> Scene:
    """Build a benchmark scene by name (one of :data:`SCENES`)."""
    try:
        return SCENES[name](width, height)
    except KeyError:
        raise ValueError(f"unknown scene {name!r}; choose from {sorted(SCENES)}") from None
