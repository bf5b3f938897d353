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
models' bias (:mod:`.frame_rough`; docs/bench-frame.md).
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
from ..frame import RenderSettings
from ..geometry.scene import LIGHT_SPOT, LIGHT_SUN, Scene
from ..tracing.whitted import render
from .frame_rough import ROUGH, run_rough


def world_triangles(scene: Scene):
    """World-space triangle soup grouped by material.

    Returns ``{material_id: (positions (3k, 3) float64, normals (3k, 3) float64)}``: every
    instance's triangles transformed by its matrix (normals by the normal matrix), three
    unshared vertices per triangle so per-corner normals survive.
    """
    sa = scene.arrays()
    groups: dict[int, list] = {}
    for i in range(len(sa.inst_mesh)):
        m = sa.inst_mesh[i]
        t0, t1 = sa.mesh_tri_start[m], sa.mesh_tri_start[m + 1]
        tris = sa.tris[t0:t1]
        xf = sa.inst_xform[i]
        p = sa.verts[tris.reshape(-1)] @ xf[:3, :3].T + xf[:3, 3]
        n = sa.tri_normals[t0:t1].reshape(-1, 3).astype(np.float64) @ sa.inst_nmat[i].T
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        mats = sa.inst_mat[sa.inst_mat_start[i]:sa.inst_mat_start[i + 1]]
        slot = np.minimum(sa.tri_slot[t0:t1], len(mats) - 1)
        for mid in np.unique(mats[slot]):
            sel = np.repeat(mats[slot] == mid, 3)
            groups.setdefault(int(mid), []).append((p[sel], n[sel]))
    return {k: (np.concatenate([a for a, _ in v]), np.concatenate([b for _, b in v]))
            for k, v in groups.items()}


def _plain_bsdf(sa, mid: int) -> dict:
    """The direct integrator's material: a perfect conductor where the mirror dominates,
    else Lambertian."""
    mirror = sa.mat_mirror[mid]
    if mirror.max() > sa.mat_diffuse[mid].max():
        return {"type": "conductor", "material": "none",
                "specular_reflectance": {"type": "rgb", "value": mirror.tolist()}}
    return {"type": "diffuse",
            "reflectance": {"type": "rgb", "value": sa.mat_diffuse[mid].tolist()}}


def mitsuba_scene_dict(scene: Scene, mi, width: int, height: int, bsdf=None,
                       spp: int = 1) -> dict:
    """The Mitsuba 3 scene dict for ``scene`` (see the module docstring for the mapping).
    ``bsdf(material_id) -> dict`` maps materials (default: :func:`_plain_bsdf`)."""
    sa = scene.arrays()
    cam = scene.camera
    m = np.asarray(cam.matrix, np.float64)
    eye = m[:3, 3]
    fwd = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    up = m[:3, 1] / np.linalg.norm(m[:3, 1])
    horizontal = cam.sensor_fit == "HORIZONTAL" or (cam.sensor_fit == "AUTO" and
                                                    width >= height)
    sensor = cam.sensor_width if cam.sensor_fit in ("AUTO", "HORIZONTAL") else cam.sensor_height
    fov = math.degrees(2.0 * math.atan(0.5 * sensor / cam.lens))
    T = mi.ScalarTransform4f
    d: dict = {
        "type": "scene",
        "integrator": {"type": "direct", "bsdf_samples": 0,
                       "emitter_samples": max(1, len(sa.light_kind))},
        "sensor": {
            "type": "perspective", "fov": fov, "fov_axis": "x" if horizontal else "y",
            "near_clip": float(cam.clip_start), "far_clip": float(cam.clip_end),
            "to_world": T().look_at(origin=eye.tolist(), target=(eye + fwd).tolist(),
                                    up=up.tolist()),
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {"type": "hdrfilm", "width": width, "height": height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        },
    }
    for mid, (pos, nrm) in world_triangles(scene).items():
        nv = len(pos)
        mesh = mi.Mesh(f"mat{mid}", vertex_count=nv, face_count=nv // 3,
                       has_vertex_normals=True)
        params = mi.traverse(mesh)
        params["vertex_positions"] = pos.astype(np.float32).ravel()
        params["vertex_normals"] = nrm.astype(np.float32).ravel()
        params["faces"] = np.arange(nv, dtype=np.uint32)
        params.update()
        mesh.set_bsdf(mi.load_dict(_plain_bsdf(sa, mid) if bsdf is None else bsdf(mid)))
        d[f"mesh{mid}"] = mesh
    for j in range(len(sa.light_kind)):
        rgb = {"type": "rgb", "value": sa.light_intensity[j].tolist()}
        pos = sa.light_pos[j]
        ldir = sa.light_dir[j]
        if sa.light_kind[j] == LIGHT_SUN:
            d[f"light{j}"] = {"type": "directional", "direction": ldir.tolist(),
                              "irradiance": rgb}
        elif sa.light_kind[j] == LIGHT_SPOT:
            up_l = (0.0, 0.0, 1.0) if abs(ldir[2]) < 0.9 else (0.0, 1.0, 0.0)
            d[f"light{j}"] = {
                "type": "spot", "intensity": rgb,
                "cutoff_angle": math.degrees(math.acos(sa.light_cos_outer[j])),
                "beam_width": math.degrees(math.acos(min(1.0, sa.light_cos_inner[j]))),
                "to_world": T().look_at(origin=pos.tolist(), target=(pos + ldir).tolist(),
                                        up=up_l),
            }
        else:
            d[f"light{j}"] = {"type": "point", "position": pos.tolist(), "intensity": rgb}
    return d


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
        out: Path | None = None, ref_spp: int = 4096, ref_samples: int = 64) -> dict:
    """Measure each scene; returns ``{"frames": [...]}``. ``rough_materials`` is measured by
    :func:`.frame_rough.run_rough` (``ref_spp``, ``ref_samples``: its references)."""
    frames = []
    if ROUGH in scene_names:
        frames.append(run_rough(width, height, depth, accelerator, ref_spp=ref_spp,
                                ref_samples=ref_samples if mitsuba else 0, out=out,
                                mitsuba=mitsuba))
        scene_names = [n for n in scene_names if n != ROUGH]
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
             f"samples: frame {r['time_s']:.2f} s, {r['rays']:,} rays ({r['threads']} "
             f"threads)"]
    if "mitsuba_unavailable" in r:
        return lines[0] + f" | mitsuba: {r['mitsuba_unavailable']}"
    lines[0] += (f" | mitsuba llvm_ad_rgb glossy_whitted: {r['mitsuba_spp']} spp in "
                 f"{r['mitsuba_s']:.2f} s ({r['mitsuba_threads']} threads); reference "
                 f"{r['ref_spp']} spp ({r['ref_s']:.1f} s)")
    for key, label in (("rstrace_error", "rstrace, equal time"),
                       ("mitsuba_error", "mitsuba, equal time"),
                       ("bias_error", f"rstrace {r.get('bias_samples')} spp (bias)"),
                       ("rstrace_noise", "rstrace vs its own")):
        if key in r:
            e = r[key]
            lines.append(f"{'':>16}{label:<24} rel {e['rel_mean']:.4f}  rmse {e['rmse']:.4f}"
                         f"  psnr {e['psnr']:.2f} dB  blocks p50 {e['block_p50']:.4f} p98 "
                         f"{e['block_p98']:.4f} max {e['block_max']:.4f}")
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
    a = p.parse_args(argv)
    res = run([s for s in a.scenes.split(",") if s], a.width, a.height, a.depth,
              a.accelerator, not a.no_mitsuba, a.out, a.ref_spp, a.ref_samples)
    if a.json:
        print(json.dumps(res))
        return 0
    for r in res["frames"]:
        if r["scene"] == ROUGH:
            print(rough_lines(r))
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
