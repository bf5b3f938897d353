"""Interpolants under soft light (docs/INTERPOLANTS.md, "Soft light"):
``python scripts/soft_interpolant_numbers.py [W H] [--no-fallback]`` (default 320 240;
``--no-fallback``: cells are built wherever they may be, the measured fallback is off).

Per scene -- a *studio* (a box, a post and a ball on a Lambertian floor under a 2 m square
light and a sphere light, no world light), the soak's ``soft_room`` with its world a
background, and both with the world lighting -- the interpolated share of the pixels, the
BASE / INTERPOLANT frame time (best of 2, alternated in one run) of a first frame and of a
camera step, and the maximum and mean display error of the INTERPOLANT frame against BASE
(epsilon 0.01, 16 light samples, max depth 3).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from rstrace_engine import image
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.soak import soft_room
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing import whitted


def studio(width: int, height: int, world: bool) -> Scene:
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.7, 0.7, 0.68)))
    clay = s.add_material(Material("clay", diffuse=(0.65, 0.45, 0.3)))
    blue = s.add_material(Material("blue", diffuse=(0.2, 0.3, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="floor")), np.eye(4), [floor], "Floor")
    s.add_instance(s.add_mesh(shapes.box((0.8, 0.8, 0.8), name="cube")),
                   shapes.transform((-1.0, 0.4, 0.4), rotate_z_deg=25.0), [clay], "Cube")
    s.add_instance(s.add_mesh(shapes.icosphere(3, name="ball")),
                   shapes.transform((0.9, 0.2, 0.5), 0.5), [blue], "Ball")
    s.add_instance(s.add_mesh(shapes.box((0.4, 0.4, 1.2), name="post")),
                   shapes.transform((0.2, 1.5, 0.6)), [clay], "Post")
    s.add_light(Light("Softbox", "AREA", power=120.0, position=(0.0, -0.5, 3.0),
                      direction=(0.0, 0.0, -1.0), shape="SQUARE", size=(2.0, 2.0)))
    s.add_light(Light("Bulb", "POINT", power=50.0, position=(2.5, -2.0, 2.0), radius=0.5))
    s.set_world_color((0.2, 0.2, 0.25) if world else (0.05, 0.05, 0.06), lights=world)
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -6.0, 3.5), (0.0, 0.3, 0.3)), lens=35.0,
                        width=width, height=height))
    return s


def room(width: int, height: int, world: bool) -> Scene:
    s = soft_room(width, height)
    s.set_world_color((0.05, 0.05, 0.08), lights=world)
    return s


def stepped(cam: Camera, dx: float) -> Camera:
    m = cam.matrix.copy()
    m[0, 3] += dx
    return Camera(m, cam.kind, cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit,
                  cam.shift_x, cam.shift_y, cam.clip_start, cam.clip_end, cam.ortho_scale,
                  cam.width, cam.height)


def main(width: int, height: int, fallback: bool = True) -> None:
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.01, max_depth=3)
    bst = RenderSettings(mode="BASE", max_depth=3)
    for name, build in (("studio", studio), ("soft_room", room)):
        for world in (False, True):
            s = build(width, height, world)
            accel = create_accelerator("BVH", s.arrays())
            cam0 = s.camera
            r = InterpolantRenderer()
            r.auto_fallback = fallback
            for step in ("first frame", "camera step"):
                if step == "camera step":
                    s.set_camera(stepped(cam0, 0.05))
                tb, ti = [], []
                for rep in range(2):
                    t0 = time.perf_counter()
                    b = whitted.render(s, bst, accel=accel)
                    tb.append(time.perf_counter() - t0)
                    if step == "first frame" and rep == 1:
                        r = InterpolantRenderer()  # a first frame again
                        r.auto_fallback = fallback
                    t0 = time.perf_counter()
                    f = r.render(s, st, accel)
                    ti.append(time.perf_counter() - t0)
                m = image.compare(f.radiance, b.radiance, 0.01)
                share = float(np.mean(f.pixel_class == CLASS_INTERPOLATED))
                sys.stdout.write(
                    f"{name}{' + world' if world else ''}, {step}: interpolated {share:.3f}, "
                    f"BASE {min(tb):.3f} s, INTERPOLANT {min(ti):.3f} s, BASE / INTERPOLANT "
                    f"{min(tb) / min(ti):.2f}x, max error {m['max_error']:.2e}, mean "
                    f"{m['mean_error']:.2e}\n")
                sys.stdout.flush()


if __name__ == "__main__":
    size = (int(a) for a in sys.argv[1:3]) if len(sys.argv) >= 3 else (320, 240)
    main(*size, fallback="--no-fallback" not in sys.argv)
