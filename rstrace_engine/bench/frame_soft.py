"""Soft light against Mitsuba 3 at equal time (``bench frame``'s ``studio_lights``,
``studio_world`` and ``museum_soft_lights`` rows, issue 20 item 5).

The scenes are :func:`rstrace_engine.scenes.studio` and ``museum_soft`` reduced to what
Mitsuba's ``direct`` integrator computes alike: the same triangles, camera and lights, every
material its Lambertian base (a mirror a grey one: ``direct`` follows no mirror).

* ``studio_lights``: the 2.5 m square soft box (Mitsuba: a ``rectangle`` with an ``area``
  emitter of radiance ``P / (pi A)``, emitting on its front side as Cycles' area light) and
  the 0.4 m sphere light (a ``sphere`` with an ``area`` emitter of radiance
  ``P / (4 pi^2 r^2)``, Cycles' sphere light without soft falloff); the world a black
  background. The lights are made visible to the camera (Mitsuba's emitters are shapes it
  sees; rstrace shows a light's surface as Cycles does), and Mitsuba's emitting shapes
  reflect nothing.
* ``studio_world``: the grey world alone (Mitsuba: a ``constant`` emitter), no light.
* ``museum_soft_lights``: :func:`rstrace_engine.scenes.museum_soft`'s two rectangular
  ceiling lights; its spot (a radius: Mitsuba's spot is a point), its sun (an angle:
  Mitsuba's is parallel) and its world are left out.

The world is compared apart because Mitsuba's emitters are shapes that also stop rays: with
the world and the soft box in one scene the box would shade the floor below it from the sky,
which Cycles' and rstrace's lights do not. Mitsuba's ``direct`` integrator (its defaults: one
emitter and one BSDF sample per pixel sample, combined by multiple importance sampling)
renders with ``llvm_ad_rgb`` (:func:`.frame_rough.mitsuba_llvm`: it needs LLVM >= 16).

Equal time as in :mod:`.frame_rough`: rstrace at its defaults (1 pixel sample, 16 light
samples) timed after a warm-up (the best of three renders), Mitsuba at the spp that takes
that wall time, both against a Mitsuba reference at ``ref_spp``; rstrace at ``ref_samples``
pixel samples against it is the models' bias. A second rstrace frame spends about the same
shadow rays as 4 pixel samples of 4 light samples: fewer samples per light, but the pixel's
area sampled. Pixels that see a light are left out of every measure
(:func:`seen_light_pixels`).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from functools import partial

import numba
import numpy as np

from .. import scenes
from ..accel.accelerators import create_accelerator
from ..frame import RenderSettings
from ..geometry.elements import Material
from ..geometry.scene import LIGHT_AREA, LIGHT_POINT, Scene
from ..tracing.whitted import render
from .frame_rough import _luminance, _mitsuba_render, error_stats, mitsuba_equal_time, mitsuba_llvm
from .mitsuba_scene import mitsuba_scene_dict

#: a pixel above this fraction of the dimmest light's radiance sees a light
SEEN_FRACTION = 0.5

#: the rows of ``bench frame --scenes``: (scene builder, what is compared)
SOFT_ROWS = {"studio_lights": (scenes.studio, "lights"),
             "studio_world": (scenes.studio, "world"),
             "museum_soft_lights": (scenes.museum_soft, "lights")}


def _mitsuba_light(li) -> bool:
    """Whether Mitsuba has light ``li``'s emitter: a rectangle or square area light
    without spread, or a sphere light (a point light with a radius; its soft falloff is
    turned off for the comparison)."""
    if li.kind == "AREA":
        return li.shape in ("SQUARE", "RECTANGLE") and li.spread >= math.pi
    return li.kind == "POINT" and li.radius > 0.0


def soft_scene(name: str, width: int, height: int) -> Scene:
    """The scene of a soft-light row (the module docstring): every material its Lambertian
    base (a mirror a grey one); ``lights``: the lights Mitsuba has (:func:`_mitsuba_light`;
    the others deleted, named in ``scene.warnings``), the world a black background;
    ``world``: the world alone."""
    if name not in SOFT_ROWS:
        raise ValueError(f"unknown soft-light row {name!r} (one of {', '.join(SOFT_ROWS)})")
    build, part = SOFT_ROWS[name]
    s = build(width, height)
    for mid, m in enumerate(s.materials):
        if m is not None:
            base = m.diffuse if max(m.diffuse) > max(m.mirror) else (0.5, 0.5, 0.5)
            s.set_material(mid, Material(m.name, diffuse=tuple(base)))
    for slot, li in s.live_lights():
        if part == "world" or not _mitsuba_light(li):
            s.delete_light(slot)
            if part != "world":
                s.warn(f"light '{li.name}' ({li.kind}) left out: no Mitsuba counterpart")
        else:  # Mitsuba's emitters are shapes the camera sees: so are these lights
            s.set_light(slot, replace(li, camera=True, soft_falloff=False))
    if part == "lights":
        s.set_world_color((0.0, 0.0, 0.0), lights=False)
    return s


def soft_scene_dict(scene: Scene, mi, width: int, height: int, spp: int = 1) -> dict:
    """The Mitsuba scene of a :func:`soft_scene`: its triangles (Lambertian), its area and
    sphere lights as emitting shapes, the world as a ``constant`` emitter where it lights;
    ``direct`` with Mitsuba's default samples."""
    sa = scene.arrays()
    d = mitsuba_scene_dict(scene, mi, width, height, spp=spp)
    d["integrator"] = {"type": "direct"}
    for key in [k for k in d if k.startswith("light")]:
        del d[key]
    black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
    for j, _ in scene.live_lights():  # (the arrays keep deleted lights' slots)
        rgb = {"type": "rgb", "value": [float(x) for x in sa.light_radiance[j]]}
        kind = int(sa.light_kind[j])
        if kind == LIGHT_AREA and not sa.light_ellipse[j] and sa.light_spread[j, 0] == np.inf:
            su, sv = sa.light_size[j]
            m = np.eye(4)
            # (u, v, direction) is left-handed (v = -direction x u): flip v, the
            # rectangle is symmetric; Mitsuba's rectangle spans [-1, 1]^2, normal +z
            m[:3, 0] = sa.light_u[j] * 0.5 * su
            m[:3, 1] = -sa.light_v[j] * 0.5 * sv
            m[:3, 2] = sa.light_dir[j]
            m[:3, 3] = sa.light_pos[j]
            d[f"light{j}"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f(m),
                              "emitter": {"type": "area", "radiance": rgb}, "bsdf": black}
        elif kind == LIGHT_POINT and sa.light_radius[j] > 0.0 and not sa.light_soft[j]:
            d[f"light{j}"] = {"type": "sphere", "center": [float(x) for x in sa.light_pos[j]],
                              "radius": float(sa.light_radius[j]),
                              "emitter": {"type": "area", "radiance": rgb}, "bsdf": black}
        else:
            raise ValueError(f"light {j}: only rectangles and sphere lights without soft "
                             f"falloff are compared here")
    if scene.world_lights:
        d["world"] = {"type": "constant", "radiance": {
            "type": "rgb", "value": [float(x) for x in sa.world_color]}}
    return d


def seen_light_pixels(scene: Scene, ref: np.ndarray) -> np.ndarray | None:
    """(h, w) bool: the pixels that see a light's surface in the reference (luminance above
    ``SEEN_FRACTION`` of the dimmest light's radiance) and their neighbours, or None without
    lights. A light is tens of times brighter than what it lights: its edge pixels' aliasing
    would swamp every measure, and the 8x8 blocks' floor (5% of the brightest block) would
    leave only the lights' blocks."""
    sa = scene.arrays()
    slots = [j for j, _ in scene.live_lights()]
    if not slots:
        return None
    lum = _luminance(ref)
    dim = min(float(_luminance(sa.light_radiance[j])) for j in slots)
    seen = lum > SEEN_FRACTION * dim
    grown = seen.copy()
    grown[1:] |= seen[:-1]
    grown[:-1] |= seen[1:]
    grown[:, 1:] |= grown[:, :-1].copy()
    grown[:, :-1] |= grown[:, 1:].copy()
    return grown


def _best_of(scene: Scene, settings: RenderSettings, acc, repeats: int):
    """The frame of the fastest of ``repeats`` renders (its ``stats["time_s"]``)."""
    best = None
    for _ in range(max(1, repeats)):
        f = render(scene, settings, accel=acc)
        if best is None or f.stats["time_s"] < best.stats["time_s"]:
            best = f
    return best


def run_soft(name: str, width: int = 160, height: int = 120, depth: int = 5,
             accelerator: str = "BVH", ref_spp: int = 4096, ref_samples: int = 64,
             mitsuba: bool = True, repeats: int = 3) -> dict:
    """One soft-light row: rstrace at its defaults and at 4 pixel x 4 light samples, Mitsuba
    at equal time, each against Mitsuba's ``ref_spp`` reference; rstrace at ``ref_samples``
    pixel samples against it (the bias; 0: skip). ``mitsuba`` False: rstrace's times only."""
    st = RenderSettings(max_depth=depth, accelerator=accelerator)
    st4 = replace(st, samples=4, light_samples=max(1, st.light_samples // 4))
    warm = soft_scene(name, 16, 12)  # compiles / loads the kernels (not timed)
    for s in (st, st4):
        render(warm, s, accel=create_accelerator(accelerator, warm.arrays()))
    scene = soft_scene(name, width, height)
    acc = create_accelerator(accelerator, scene.arrays())
    # the best of ``repeats`` timings, alternated (the frames are the same bit for bit)
    frame, frame4 = _best_of(scene, st, acc, repeats), _best_of(scene, st4, acc, repeats)
    stats = frame.stats
    row = dict(scene=name, width=width, height=height, depth=st.max_depth,
               samples=st.samples, light_samples=st.light_samples,
               triangles=scene.triangle_count, lights=scene.n_lights,
               time_s=stats["time_s"], rays=stats["rays_traced"],
               shadow_rays=stats["shadow_rays"], time_4x4_s=frame4.stats["time_s"],
               rays_4x4=frame4.stats["rays_traced"],
               shadow_rays_4x4=frame4.stats["shadow_rays"], threads=numba.get_num_threads(),
               left_out=list(scene.warnings))
    mi, why = mitsuba_llvm() if mitsuba else (None, "not asked for (--no-mitsuba)")
    if mi is None:
        row["mitsuba_unavailable"] = why
        return row
    import drjit as dr

    ms = mi.load_dict(soft_scene_dict(scene, mi, width, height))
    row["mitsuba_threads"] = int(dr.thread_count())
    _mitsuba_render(mi, ms, 1, seed=3)  # compiles the kernels (not timed)
    t0 = time.perf_counter()
    img, spp, secs = mitsuba_equal_time(mi, ms, stats["time_s"])
    img4, spp4, secs4 = mitsuba_equal_time(mi, ms, frame4.stats["time_s"])
    ref, ref_s = _mitsuba_render(mi, ms, ref_spp, seed=1)
    skip = seen_light_pixels(scene, ref)
    row["light_pixels"] = 0 if skip is None else int(skip.sum())
    errors = partial(error_stats, skip=skip)  # every measure without the pixels of a light

    row.update(mitsuba_spp=spp, mitsuba_s=secs, mitsuba_spp_4x4=spp4, mitsuba_4x4_s=secs4,
               ref_spp=ref_spp, ref_s=ref_s, mitsuba_total_s=time.perf_counter() - t0,
               rstrace_error=errors(frame.radiance, ref),
               rstrace_4x4_error=errors(frame4.radiance, ref),
               mitsuba_error=errors(img, ref),
               mitsuba_4x4_error=errors(img4, ref))
    if ref_samples > 0:
        conv = render(scene, replace(st, samples=ref_samples), accel=acc)
        row.update(bias_samples=ref_samples, bias_s=conv.stats["time_s"],
                   bias_error=errors(conv.radiance, ref),
                   rstrace_noise=errors(frame.radiance, conv.radiance))
    return row


def soft_lines(r: dict) -> str:
    """A soft-light row as text."""
    head = (f"{r['scene']:>14} {r['width']}x{r['height']}: rstrace {r['samples']} spp x "
            f"{r['light_samples']} light samples {r['time_s']:.2f} s, 4 spp x 4 "
            f"{r['time_4x4_s']:.2f} s ({r['threads']} threads)")
    head += "".join(f"\n{'':>16}({w})" for w in r.get("left_out", ()))
    if "mitsuba_unavailable" in r:
        return head + f" | mitsuba: {r['mitsuba_unavailable']}"
    head += (f" | mitsuba llvm_ad_rgb direct: {r['mitsuba_spp']} spp in {r['mitsuba_s']:.2f} s,"
             f" {r['mitsuba_spp_4x4']} spp in {r['mitsuba_4x4_s']:.2f} s; reference "
             f"{r['ref_spp']} spp; {r['light_pixels']} pixels that see a light (and their "
             f"blocks) left out")
    lines = [head]
    for key, label in (("rstrace_error", "rstrace defaults"),
                       ("mitsuba_error", "mitsuba, same time"),
                       ("rstrace_4x4_error", "rstrace 4 x 4"),
                       ("mitsuba_4x4_error", "mitsuba, same time"),
                       ("bias_error", f"rstrace {r.get('bias_samples')} spp (bias)"),
                       ("rstrace_noise", "rstrace vs its own")):
        e = r.get(key)
        if e is not None:
            lines.append(f"{'':>16}{label:<24} rel {e['rel_mean']:.4f}  rmse {e['rmse']:.4f}"
                         f"  psnr {e['psnr']:.2f} dB  {e['blocks']} blocks: p50 "
                         f"{e['block_p50']:.5f} p98 {e['block_p98']:.4f} max "
                         f"{e['block_max']:.4f}")
    return "\n".join(lines)
