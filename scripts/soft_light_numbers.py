"""Soft light's cost and noise (docs/SOFT_LIGHT.md): ``python scripts/soft_light_numbers.py``.

1. cost: museum_1999 with its lights hard (radius 0) and as Blender's defaults make them
   (point and spot radius 0.1 m), BASE frame time and shadow rays per light-sample count;
2. noise: a penumbra scene (an area light, a sphere light, a sun with an angle and a grey
   world over boxes on a floor), at half the resolution, against a converged reference
   (512 light samples): RMSE relative to the mean and the 98th percentile of 8x8-block
   relative errors, with the frame time, per light-sample count, ratio estimator on / off.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.tracing import soft_lights
from rstrace_engine.tracing.whitted import render

REF_SAMPLES = 512


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def soft_museum(w, h):
    s = scenes.museum_1999(w, h)
    for k, li in s.live_lights():
        if li.kind in ("POINT", "SPOT"):
            s.set_light(k, replace(li, radius=0.1))
    return s


def studio(w, h):
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.6, 0.6, 0.6)))
    red = s.add_material(Material("red", diffuse=(0.7, 0.2, 0.1), specular=(0.1,) * 3,
                                  roughness=0.3))
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="floor")), np.eye(4), [floor], "Floor")
    cube = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="cube"))
    ball = s.add_mesh(shapes.icosphere(3, 0.6, name="ball"))
    s.add_instance(cube, shapes.transform((-1.0, 0.5, 0.5), 1.0, 30), [red], "Box")
    s.add_instance(ball, shapes.transform((1.0, -0.3, 0.6)), [floor], "Ball")
    s.add_light(Light("Area", "AREA", power=800.0, position=(0.0, 0.0, 3.5),
                      direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(2.0, 1.0)))
    s.add_light(Light("Lamp", "POINT", power=300.0, position=(2.5, -2.0, 2.0), radius=0.25))
    s.add_light(Light("Sun", "SUN", power=1.5, direction=(-0.4, 0.3, -1.0), angle=0.1))
    s.set_world_color((0.08, 0.09, 0.11))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -6.0, 3.5), (0.0, 0.0, 0.5)), lens=35.0,
                        width=w, height=h))
    return s


def block_p98(img, ref):
    h, w = ref.shape[0] // 8 * 8, ref.shape[1] // 8 * 8
    a = img[:h, :w].mean(-1).reshape(h // 8, 8, w // 8, 8).mean((1, 3))
    b = ref[:h, :w].mean(-1).reshape(h // 8, 8, w // 8, 8).mean((1, 3))
    ok = b > 1e-3 * b.max()
    return float(np.percentile(np.abs(a[ok] - b[ok]) / b[ok], 98))


def timed(scene, st, reps=3):
    best, f = np.inf, None
    for _ in range(reps):
        t = time.perf_counter()
        f = render(scene, st)
        best = min(best, time.perf_counter() - t)
    return best, f


def main(w=320, h=240):
    out(f"## cost: museum_1999 {w}x{h}, BASE, 1 spp, max depth 5")
    hard = scenes.museum_1999(w, h)
    soft = soft_museum(w, h)
    render(hard, RenderSettings())  # warm
    for n in (1, 4, 8, 16, 32):
        # hard and soft frames alternate, best of each (the machine is shared)
        th = ts = np.inf
        for _ in range(3):
            t, fh = timed(hard, RenderSettings(), reps=1)
            th = min(th, t)
            t, fs = timed(soft, RenderSettings(light_samples=n), reps=1)
            ts = min(ts, t)
        out(f"radius 0.1, light_samples {n:3d}: {ts:.3f} s against hard {th:.3f} s "
            f"({ts / th:.2f}x), {fs.stats['shadow_rays'] / (w * h):.1f} against "
            f"{fh.stats['shadow_rays'] / (w * h):.2f} shadow rays/px")
    w, h = w // 2, h // 2
    out(f"\n## noise: studio {w}x{h}, 1 spp, max depth 1, against {REF_SAMPLES} light "
        f"samples (ratio estimator on / off)")
    sc = studio(w, h)
    ref = render(sc, RenderSettings(max_depth=1, light_samples=REF_SAMPLES,
                                    seed=99)).radiance
    for ratio in (True, False):
        soft_lights.RATIO_ESTIMATOR = ratio
        for n in (1, 4, 8, 16, 32, 64):
            t, f = timed(sc, RenderSettings(max_depth=1, light_samples=n), reps=2)
            rmse = float(np.sqrt(np.mean((f.radiance - ref) ** 2)) / ref.mean())
            out(f"ratio {'on ' if ratio else 'off'} light_samples {n:3d}: {t:.3f} s, "
                f"relative RMSE {rmse:.4f}, 98th pct 8x8-block error "
                f"{block_p98(f.radiance, ref):.4f}")
    soft_lights.RATIO_ESTIMATOR = True


if __name__ == "__main__":
    main(*(int(x) for x in sys.argv[1:3]))
