"""A full base-tracer frame against Mitsuba 3, in one run.

``python -m rstrace_engine.bench frame [--json] [--width W] [--height H] [--depth D]
[--scenes three_spheres,museum] [--accelerator BVH] [--no-mitsuba] [--out DIR]``

For each scene (default *three_spheres* and *museum* at 640x480, depth 5) it renders one
frame with :func:`rstrace_engine.tracing.whitted.render` (after a tiny warm-up frame so that numba's
compile/cache load is not timed) and reports the time, the rays traced and rays per second.
Where the ``mitsuba`` package imports, it then renders the *same triangles and lights* with
Mitsuba 3's ``scalar_rgb`` variant and its ``direct`` integrator (as many emitter samples
as lights, no BSDF samples, 1 spp): point lights become ``point`` emitters with intensity
= our W/sr, spots ``spot`` emitters, suns ``directional`` emitters; materials become
``diffuse`` BSDFs (mirrors a perfect ``conductor``). Mitsuba's direct integrator does not
follow mirrors, so it does less work than our Whitted frame; the ratio (ours / Mitsuba,
render times without the acceleration-structure builds, which are reported apart) is
therefore conservative for us.
``--json`` prints ``{"frames": [{...}, ...]}``.

``--scenes rough_materials`` (issue 24) adds the rough-materials row: rstrace at its default
settings against Mitsuba 3 at equal time, each one's error against a converged Mitsuba
reference (``--ref-spp``), and rstrace's converged frame (``--ref-samples``) against it, the
models' bias (:mod:`.frame_rough`; docs/bench-frame.md). ``--scenes studio_lights,studio_world``
(issue 20) add the soft-light rows the same way: the studio's area and sphere lights, and its
world, against Mitsuba's ``direct`` integrator at equal time (:mod:`.frame_soft`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from .. import image, scenes
from ..accel.accelerators import create_accelerator
from ..frame import GLOSSY_SAMPLES_DEFAULT, RenderSettings
from ..geometry.scene import Scene
from ..tracing.whitted import render
from .frame_rough import CLOCKS, ROUGH, run_rough
from .frame_soft import SOFT_ROWS, run_soft, soft_lines
from .mitsuba_scene import mitsuba_scene_dict, world_triangles  # noqa: F401 (re-exported)


def run_mitsuba(scene: Scene, width: int, height: int):
    """Render ``scene`` with Mitsuba; returns (image (h, w, 3) bottom-up, build_s, render_s)
    or None when Mitsuba is not installed."""
    try:
        import mitsuba as mi
    except ImportError:
        return None
    mi.set_variant("scalar_rgb")
    t0 = time.perf_counter()
    ms = mi.load_dict(mitsuba_scene_dict(scene, mi, width, height))
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    img = np.array(mi.render(ms, spp=1))
    elapsed = time.perf_counter() - t0
    return img[::-1, :, :3].astype(np.float32), build, elapsed


def run(scene_names, width=640, height=480, depth=5, accelerator="BVH", mitsuba=True,
        out: Path | None = None, ref_spp: int = 4096, ref_samples: int = 64,
        samples: int = 1, glossy_samples: int = GLOSSY_SAMPLES_DEFAULT, clock: str = "wall",
        repeats: int = 3) -> dict:
    """Measure each scene; returns ``{"frames": [...]}``. ``rough_materials`` is measured by
    :func:`.frame_rough.run_rough` (``ref_spp``, ``ref_samples``: its references; rstrace
    at ``samples`` pixel samples and ``glossy_samples``, timed by ``clock``, the median of
    ``repeats`` frames)."""
    frames = []
    if ROUGH in scene_names:
        st = RenderSettings(max_depth=depth, accelerator=accelerator, samples=samples,
                            glossy_samples=glossy_samples)
        frames.append(run_rough(width, height, depth, accelerator, settings=st,
                                ref_spp=ref_spp, ref_samples=ref_samples if mitsuba else 0,
                                out=out, mitsuba=mitsuba, clock=clock, repeats=repeats))
    for name in [n for n in scene_names if n in SOFT_ROWS]:
        frames.append(run_soft(name, width, height, depth, accelerator, ref_spp=ref_spp,
                               ref_samples=ref_samples if mitsuba else 0, mitsuba=mitsuba))
    scene_names = [n for n in scene_names if n != ROUGH and n not in SOFT_ROWS]
    if not scene_names:
        return {"frames": frames}
    settings = RenderSettings(max_depth=depth, accelerator=accelerator)
    # warm-up on a different, tiny scene: compiles (or loads) every kernel without putting
    # the benchmark scenes' meshes into the accelerator's per-mesh cache
    warm = scenes.three_spheres(16, 12, subdivisions=1)
    render(warm, settings, accel=create_accelerator(accelerator, warm.arrays()))
    for name in scene_names:
        scene = scenes.build(name, width, height)
        sa = scene.arrays()
        t0 = time.perf_counter()
        acc = create_accelerator(accelerator, sa)
        build = time.perf_counter() - t0
        frame = render(scene, settings, accel=acc)
        st = frame.stats
        row = dict(scene=name, width=width, height=height, depth=depth,
                   triangles=scene.triangle_count, instances=len(scene.instances),
                   lights=len(scene.lights), accelerator=acc.name, build_s=build,
                   time_s=st["time_s"], rays=st["rays_traced"],
                   primary_rays=st["primary_rays"], secondary_rays=st["secondary_rays"],
                   shadow_rays=st["shadow_rays"], mrays_per_s=st["rays_per_s"] / 1e6)
        if out is not None:
            image.write_render_png(Path(out) / f"{name}_rstrace.png", frame.radiance)
        if mitsuba:
            res = run_mitsuba(scene, width, height)
            if res is not None:
                img, mbuild, mtime = res
                row.update(mitsuba_build_s=mbuild, mitsuba_s=mtime,
                           ratio=st["time_s"] / mtime if mtime > 0 else math.inf)
                if out is not None:
                    image.write_render_png(Path(out) / f"{name}_mitsuba.png", img)
        frames.append(row)
    return {"frames": frames}


def rough_lines(r: dict) -> str:
    """The ``rough_materials`` row as text."""
    lines = [f"{r['scene']:>14} {r['width']}x{r['height']} depth {r['depth']}, "
             f"{r['samples']} spp, {r['glossy_samples']} glossy, {r['light_samples']} light "
             f"samples: frame {r['time_s']:.3f} s {r['clock']} (wall {r['wall_s']:.3f} s, "
             f"median of {r['repeats']}), {r['rays']:,} rays ({r['threads']} threads)"]
    if "mitsuba_unavailable" in r:
        return lines[0] + f" | mitsuba: {r['mitsuba_unavailable']}"
    lines[0] += (f" | mitsuba llvm_ad_rgb glossy_whitted: {r['mitsuba_spp']} spp in "
                 f"{r['mitsuba_s']:.3f} s {r['clock']} ({r['mitsuba_threads']} threads); reference "
                 f"{r['ref_spp']} spp ({r['ref_s']:.1f} s)")
    for key, label in (("rstrace_error", "rstrace, equal time"),
                       ("mitsuba_error", "mitsuba, equal time"),
                       ("bias_error", f"rstrace {r.get('bias_samples')} spp (bias)"),
                       ("rstrace_noise", "rstrace vs its own")):
        for suffix, where in (("", "all"), ("_no_glass", "no glass")):
            e = r.get(key + suffix)
            if e is None:
                continue
            lines.append(f"{'':>16}{label:<24} {where:<8} rel {e['rel_mean']:.4f}  rmse "
                         f"{e['rmse']:.4f}  psnr {e['psnr']:.2f} dB  {e['blocks']} blocks: "
                         f"p50 {e['block_p50']:.5f} p98 {e['block_p98']:.4f} max "
                         f"{e['block_max']:.4f}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine.bench frame",
                                description=__doc__.split("\n")[0])
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--depth", type=int, default=5)
    p.add_argument("--scenes", default="three_spheres,museum")
    p.add_argument("--accelerator", default="BVH")
    p.add_argument("--no-mitsuba", action="store_true")
    p.add_argument("--out", type=Path, default=None, help="write both images as PNG here")
    p.add_argument("--ref-spp", type=int, default=4096,
                   help=f"{ROUGH}: samples per pixel of Mitsuba's converged reference")
    p.add_argument("--ref-samples", type=int, default=64,
                   help=f"{ROUGH}: pixel samples of rstrace's converged frame (the models' "
                        f"bias; 0: none)")
    p.add_argument("--samples", type=int, default=1,
                   help=f"{ROUGH}: rstrace's pixel samples (the equal-time allocation)")
    p.add_argument("--glossy-samples", type=int, default=GLOSSY_SAMPLES_DEFAULT,
                   help=f"{ROUGH}: rstrace's glossy samples at a path's first rough bounce")
    p.add_argument("--clock", choices=sorted(CLOCKS), default="wall",
                   help=f"{ROUGH}: equal time by wall time or by the process's CPU time "
                        f"(all its threads; robust to a loaded machine)")
    p.add_argument("--repeats", type=int, default=3,
                   help=f"{ROUGH}: rstrace's time is the median of this many frames")
    a = p.parse_args(argv)
    res = run([s for s in a.scenes.split(",") if s], a.width, a.height, a.depth,
              a.accelerator, not a.no_mitsuba, a.out, a.ref_spp, a.ref_samples, a.samples,
              a.glossy_samples, a.clock, a.repeats)
    if a.json:
        print(json.dumps(res))
        return 0
    for r in res["frames"]:
        if r["scene"] == ROUGH:
            print(rough_lines(r))
            continue
        if r["scene"] in SOFT_ROWS:
            print(soft_lines(r))
            continue
        line = (f"{r['scene']:>14} {r['width']}x{r['height']} depth {r['depth']}: "
                f"{r['triangles']:,} tris, build {r['build_s']:.2f} s, frame "
                f"{r['time_s']:.2f} s, {r['rays']:,} rays, {r['mrays_per_s']:.2f} Mrays/s")
        if "mitsuba_s" in r:
            line += (f" | mitsuba scalar_rgb direct: build {r['mitsuba_build_s']:.2f} s, "
                     f"render {r['mitsuba_s']:.2f} s, ratio ours/mitsuba {r['ratio']:.2f}")
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
