"""Rough materials against Mitsuba 3 at equal time (``bench frame``'s ``rough_materials`` row,
issue 24).

The scene (:func:`rstrace_engine.scenes.rough_materials`) holds only what both renderers
model alike: a Lambertian floor, a Principled rough metal (Mitsuba: ``roughconductor``,
GGX, alpha = roughness^2, its colour as a constant Fresnel), a rough glass (Mitsuba:
``roughdielectric``, GGX, the same IOR), a default Principled plastic (Mitsuba: rstrace's
Principled layer written as a Mitsuba BSDF, ``principled_layer``: neither ``roughplastic``
nor ``principled`` is that model), one point light (Mitsuba ``point`` with
intensity = P / (4 pi) W/sr, what rstrace's point light of P W radiates) and a world seen
as a background only. Mitsuba renders it with :class:`GlossyWhitted`, a Mitsuba integrator
(written here, in Python, compiled by Mitsuba's LLVM back end) that computes what rstrace's
tracer computes: at every hit the point light's direct light through the whole BSDF, then
one ray drawn from the BSDF's glossy and specular parts only (Mitsuba's own importance
sampling of them), up to the same ray depth, the background where a ray escapes. Mitsuba's
``path`` integrator would add diffuse interreflection (which rstrace does not compute) and
its ``direct`` integrator would drop rough reflections of other objects, so neither
computes the same image.

Known differences in the models (what the bias row measures, see :func:`run_rough`): rstrace's
metal uses Schlick's curve to white at grazing angles (Mitsuba's ``none`` conductor a
constant), rstrace's GGX carries Cycles' multiple-scattering factors (Mitsuba's is
single scattering: at alpha 0.09 about 1%), and rstrace does not light a rough interface's far
side (light refracted to the viewer through the glass: docs/glossy.md, "Not done").

Equal time: rstrace renders the frame at its default settings (1 pixel sample, 16 glossy
samples, depth 5; ``bench frame --samples/--glossy-samples`` time another allocation), timed
after a warm-up (the median of ``repeats`` frames); Mitsuba then renders the same frame with
the spp that takes that time, by the wall clock or by the process's CPU time (``--clock
cpu``: robust to other work on a shared machine), measured in the same run (a render at 4
spp, then the spp rescaled by the time until within 10%, at most 3 more renders). Both are
compared with a converged Mitsuba reference (``ref_spp`` samples per pixel), and rstrace's
converged frame (``ref_samples`` pixel samples) with the same reference gives the models'
bias, the floor under rstrace's error; every measure is also given without the pixels that
see the glass ball (``*_no_glass``: the far-side light above).

Mitsuba's ``llvm_ad_rgb`` variant needs an LLVM that compiles for this CPU: LLVM 14 and 15
abort the process ("Cannot select: fminimum") on this project's machine, LLVM 22 works.
Point ``DRJIT_LIBLLVM_PATH`` at a newer ``libLLVM.so``; with an older one the row reports
Mitsuba as unavailable (checked before anything compiles).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np

from .. import image, scenes
from ..accel.accelerators import create_accelerator
from ..frame import RenderSettings
from ..geometry.scene import LIGHT_POINT, Material, Scene
from ..tolerances import GLOSSY_ALPHA_MIN
from ..tracing.shading import dielectric_fss, ggx_albedo, ggx_e_avg
from ..tracing.whitted import render
from .mitsuba_scene import mitsuba_scene_dict

#: the scene's name in ``bench frame --scenes``
ROUGH = "rough_materials"

#: the oldest LLVM the bench lets Mitsuba's LLVM back end compile with (see the docstring)
LLVM_MIN = (16, 0, 0)
#: 8x8-block relative errors are taken over the blocks holding at least this fraction of
#: the reference's brightest block's light (as tests/blender/test_cycles_agreement.py does)
BLOCK = 8
BLOCK_FLOOR = 0.05
#: the relative error of a pixel is |a - r| / (r + REL_EPS) on luminance
REL_EPS = 0.01


def mitsuba_llvm():
    """``(mi, None)`` with the ``llvm_ad_rgb`` variant set, or ``(None, reason)``."""
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as e:
        return None, f"mitsuba is not installed ({e})"
    try:
        mi.set_variant("llvm_ad_rgb")
        version = tuple(dr.detail.llvm_version())
    except Exception as e:  # no libLLVM found, or a variant not compiled in
        return None, f"Mitsuba's LLVM back end is unavailable ({e})"
    if version < LLVM_MIN:
        return None, (f"Mitsuba's LLVM back end found LLVM {'.'.join(map(str, version))}; "
                      f"it needs >= {LLVM_MIN[0]} here (older ones abort compiling): set "
                      f"DRJIT_LIBLLVM_PATH to a newer libLLVM.so")
    _register(mi, dr)
    return mi, None


def _register(mi, dr) -> None:
    """Register :class:`GlossyWhitted` as Mitsuba's ``glossy_whitted`` integrator."""
    if getattr(_register, "done", False):
        return

    class GlossyWhitted(mi.SamplingIntegrator):
        """Direct light of the emitters at every hit, then one sample of the BSDF's glossy
        and specular (delta) parts, no diffuse bounce; ``max_depth`` bounces (0: primary
        hits only); escaping rays see ``background`` (which lights nothing)."""

        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", 5))
            bg = props.get("background", mi.ScalarColor3f(0.0))
            self.background = mi.Color3f(bg)

        @dr.syntax
        def sample(self, scene, sampler, ray, medium=None, active=True):
            import drjit as dr  # noqa: F811 (dr.syntax recompiles this body in the module's
            import mitsuba as mi  # noqa: F811 globals, without _register's closure)
            ctx = mi.BSDFContext()
            glossy = mi.BSDFContext()
            glossy.type_mask = mi.BSDFFlags.Glossy | mi.BSDFFlags.Delta
            ray = mi.Ray3f(ray)
            L = mi.Color3f(0.0)
            beta = mi.Color3f(1.0)
            depth = mi.UInt32(0)
            active = mi.Bool(active)
            while active:
                si = scene.ray_intersect(ray, active)
                miss = active & ~si.is_valid()
                L[miss] += beta * self.background
                active &= si.is_valid()
                bsdf = si.bsdf(ray)
                ds, em = scene.sample_emitter_direction(si, sampler.next_2d(), True, active)
                lit = active & (ds.pdf != 0.0)
                f = bsdf.eval(ctx, si, si.to_local(ds.d), lit)
                L[lit] += beta * f * em
                active &= depth < self.max_depth
                bs, w = bsdf.sample(glossy, si, sampler.next_1d(), sampler.next_2d(), active)
                beta *= w
                active &= dr.max(beta) > 0.0
                ray = si.spawn_ray(si.to_world(bs.wo))
                depth += 1
            return L, mi.Bool(True), []

    mi.register_integrator("glossy_whitted", lambda props: GlossyWhitted(props))
    mi.register_bsdf("principled_layer", lambda props: _principled_layer_class(mi, dr)(props))
    _register.done = True


#: cosines at which :func:`_albedo_table` tabulates the layer's albedos (linear in between)
ALBEDO_TABLE = 65


def _albedo_table(alpha: float, eta: float) -> tuple[list, list]:
    """rstrace's GGX albedos ``(E_white, E_dielectric)`` (``tracing.shading.ggx_albedo``) at
    ``ALBEDO_TABLE`` cosines from 0 to 1."""
    vals = [ggx_albedo(c, alpha, eta) for c in np.linspace(0.0, 1.0, ALBEDO_TABLE)]
    return [float(w) for w, _ in vals], [float(d) for _, d in vals]


def _principled_layer_class(mi, dr):
    """rstrace's Principled dielectric layer (``tracing.shading.principled_brdf``) as a
    Mitsuba BSDF: Lambertian ``base (1 - E_d(wi)) / pi`` under a GGX lobe ``D G2 / (4 cos
    cos)`` with the exact dielectric Fresnel of ``eta`` and the multiple-scattering factor
    ``1 + Fms (1 - E_w(wi)) / E_w(wi)`` (``multiscatter.multiscatter_factors``). Mitsuba's
    ``roughplastic`` scales its diffuse part by both transmittances and its internal
    reflections instead (about 0.78 of rstrace's Lambertian part on the default plastic),
    Mitsuba's ``principled`` is Disney's, so neither
    renders what a Blender Principled BSDF is. The glossy part is sampled from Mitsuba's GGX
    distribution of visible normals, the diffuse part by the cosine."""
    cls = getattr(_principled_layer_class, "cls", None)
    if cls is not None:
        return cls

    class PrincipledLayer(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.base = mi.Color3f(props["base_r"], props["base_g"], props["base_b"])
            self.spec = float(props["specular"])
            self.alpha = float(props["alpha"])
            self.eta = float(props["eta"])
            fss, ea = float(dielectric_fss(self.eta)), float(ggx_e_avg(self.alpha))
            self.fms = fss * ea / (1.0 - fss * (1.0 - ea))
            ew, ed = _albedo_table(self.alpha, self.eta)
            self.e_white = mi.Float(ew)
            self.e_diel = mi.Float(ed)
            self.distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, True)
            front = mi.BSDFFlags.FrontSide
            self.m_components = [mi.BSDFFlags.DiffuseReflection | front,
                                 mi.BSDFFlags.GlossyReflection | front]
            self.m_flags = self.m_components[0] | self.m_components[1]

        def _table(self, table, c):
            x = dr.clip(c, 0.0, 1.0) * (ALBEDO_TABLE - 1)
            i = mi.UInt32(dr.minimum(dr.floor(x), ALBEDO_TABLE - 2))
            t = x - mi.Float(i)
            return dr.lerp(dr.gather(mi.Float, table, i), dr.gather(mi.Float, table, i + 1), t)

        def _lambda(self, c):
            c2 = dr.maximum(c * c, 1e-12)
            return 0.5 * (dr.sqrt(1.0 + self.alpha ** 2 * dr.maximum(1.0 - c2, 0.0) / c2) - 1.0)

        def _parts(self, ctx, si, wo, active):
            """(value with the cosine, pdf) of the enabled parts."""
            diff_on = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            spec_on = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)
            ci = mi.Frame3f.cos_theta(si.wi)  # toward the viewer
            co = mi.Frame3f.cos_theta(wo)  # toward the light
            ok = active & (ci > 0.0) & (co > 0.0)
            value = mi.Color3f(0.0)
            pdf = mi.Float(0.0)
            p_spec = self._p_spec(diff_on, spec_on)
            if diff_on:
                kd = (1.0 - self._table(self.e_diel, ci)) * dr.inv_pi * co
                value += self.base * kd
                pdf += (1.0 - p_spec) * dr.inv_pi * co
            if spec_on:
                h = dr.normalize(si.wi + wo)
                ch = mi.Frame3f.cos_theta(h)
                a2 = self.alpha ** 2
                t = ch * ch * (a2 - 1.0) + 1.0
                d = a2 / (dr.pi * t * t)
                g2 = 1.0 / (1.0 + self._lambda(ci) + self._lambda(co))
                ih = dr.dot(wo, h)
                fr = mi.fresnel(dr.clip(ih, 0.0, 1.0), self.eta)[0] * self.spec
                e = dr.maximum(self._table(self.e_white, ci), 1e-3)
                ms = 1.0 + self.fms * (1.0 - e) / e
                value += mi.Color3f(d * g2 / (4.0 * ci) * fr * ms)
                pdf += p_spec * self.distr.pdf(si.wi, h) / (4.0 * dr.abs(dr.dot(si.wi, h)))
            return dr.select(ok, value, 0.0), dr.select(ok, pdf, 0.0)

        @staticmethod
        def _p_spec(diff_on, spec_on):
            if spec_on and not diff_on:
                return 1.0
            if diff_on and not spec_on:
                return 0.0
            return 0.5

        def sample(self, ctx, si, sample1, sample2, active):
            diff_on = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            spec_on = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)
            p_spec = self._p_spec(diff_on, spec_on)
            bs = dr.zeros(mi.BSDFSample3f)
            pick_spec = sample1 < p_spec
            m, _ = self.distr.sample(si.wi, sample2)
            wo_spec = mi.reflect(si.wi, m)
            wo_diff = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.wo = dr.select(pick_spec, wo_spec, wo_diff)
            bs.eta = 1.0
            bs.sampled_component = dr.select(pick_spec, mi.UInt32(1), mi.UInt32(0))
            bs.sampled_type = dr.select(pick_spec, mi.UInt32(int(mi.BSDFFlags.GlossyReflection)),
                                        mi.UInt32(int(mi.BSDFFlags.DiffuseReflection)))
            value, pdf = self._parts(ctx, si, bs.wo, active)
            bs.pdf = pdf
            ok = active & (pdf > 0.0)
            return bs, dr.select(ok, value / dr.maximum(pdf, 1e-30), 0.0)

        def eval(self, ctx, si, wo, active):
            return self._parts(ctx, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active):
            return self._parts(ctx, si, wo, active)[1]

        def eval_pdf(self, ctx, si, wo, active):
            return self._parts(ctx, si, wo, active)

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"PrincipledLayer[alpha={self.alpha}, eta={self.eta}]"

    _principled_layer_class.cls = PrincipledLayer
    return PrincipledLayer


def mitsuba_bsdf(sa, mid: int, name: str = "") -> dict:
    """Mitsuba's BSDF for rstrace material ``mid`` of a Principled-like scene (the module
    docstring's mapping). Raises ValueError naming the material where there is none."""
    alpha = float(sa.mat_roughness[mid])
    rough = alpha >= GLOSSY_ALPHA_MIN
    ggx = {"distribution": "ggx", "alpha": alpha} if rough else {}
    metallic = float(sa.mat_metallic[mid])
    trans = sa.mat_transmission[mid]
    spec = sa.mat_specular[mid]
    diffuse = sa.mat_diffuse[mid]

    def rgb(v):
        return {"type": "rgb", "value": [float(x) for x in v]}

    if metallic == 1.0:
        return {"type": "roughconductor" if rough else "conductor", "material": "none",
                "specular_reflectance": rgb(sa.mat_metal[mid]), **ggx}
    if trans.max() > 0.0 and diffuse.max() == 0.0 and spec.max() == 0.0 and metallic == 0:
        return {"type": "roughdielectric" if rough else "dielectric",
                "int_ior": float(sa.mat_ior[mid]), "ext_ior": 1.0,
                "specular_transmittance": rgb(trans), **ggx}
    if trans.max() == 0.0 and metallic == 0.0 and spec.max() > 0.0:
        if not np.allclose(spec, spec[0]):
            raise ValueError(f"material '{name}': a tinted specular layer has no Mitsuba "
                             f"counterpart here")
        if not rough:
            raise ValueError(f"material '{name}': a smooth dielectric layer is not mapped")
        return {"type": "principled_layer", "base_r": float(diffuse[0]),
                "base_g": float(diffuse[1]), "base_b": float(diffuse[2]),
                "specular": float(spec[0]), "alpha": alpha,
                "eta": float(sa.mat_specular_ior[mid])}
    if trans.max() == 0.0 and metallic == 0.0:
        return {"type": "diffuse", "reflectance": rgb(diffuse)}
    raise ValueError(f"material '{name}': a mix of metal, transmission and a dielectric layer "
                     f"has no single Mitsuba BSDF here")


def rough_scene_dict(scene: Scene, mi, width: int, height: int, depth: int, spp: int) -> dict:
    """The Mitsuba scene of ``scene`` for :class:`GlossyWhitted`: its triangles, BSDFs by
    :func:`mitsuba_bsdf`, point lights only."""
    sa = scene.arrays()
    if np.any(sa.light_kind != LIGHT_POINT):
        raise ValueError("the rough-materials comparison takes point lights only")
    if scene.world_lights:
        raise ValueError("the rough-materials comparison takes a world that lights nothing")
    names = {i: m.name for i, m in enumerate(scene.materials)}

    def bsdf(mid):
        return mitsuba_bsdf(sa, mid, names.get(mid, str(mid)))

    d = mitsuba_scene_dict(scene, mi, width, height, bsdf=bsdf, spp=spp)
    d["integrator"] = {"type": "glossy_whitted", "max_depth": int(depth),
                       "background": mi.ScalarColor3f(*map(float, sa.world_color))}
    return d


def _luminance(img: np.ndarray) -> np.ndarray:
    return img[..., 0] * 0.2126 + img[..., 1] * 0.7152 + img[..., 2] * 0.0722


def _blocks(a: np.ndarray) -> np.ndarray:
    h, w = (a.shape[0] // BLOCK) * BLOCK, (a.shape[1] // BLOCK) * BLOCK
    return a[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).mean(axis=(1, 3))


def block_errors(img: np.ndarray, ref: np.ndarray, skip: np.ndarray | None = None
                 ) -> np.ndarray:
    """Relative errors of the 8x8-block mean luminances of ``img`` against ``ref`` over the
    blocks holding none of the pixels ``skip``, (h, w) bool, marks and at least
    ``BLOCK_FLOOR`` of the brightest such block's light in the reference."""
    o, c = _blocks(_luminance(img)), _blocks(_luminance(ref))
    keep = np.ones(c.shape, bool)
    if skip is not None:
        keep = _blocks(skip.astype(np.float64)) == 0.0
    keep &= c > BLOCK_FLOOR * c[keep].max(initial=0.0)
    return np.abs(o[keep] - c[keep]) / c[keep]


def error_stats(img: np.ndarray, ref: np.ndarray, skip: np.ndarray | None = None) -> dict:
    """Error of a linear image against a converged linear reference: ``rel_mean`` (mean over
    pixels of ``|L - L_ref| / (L_ref + REL_EPS)`` on luminance), ``rmse`` (linear RGB),
    ``psnr`` and ``display_mean`` (display space, :func:`rstrace_engine.image.compare`) and
    the 8x8-block relative errors' median, 98th percentile and largest. ``skip`` (h, w)
    bool: leave out these pixels and the blocks holding any."""
    img = np.asarray(img, np.float64)
    ref = np.asarray(ref, np.float64)
    keep = np.ones(img.shape[:2], bool) if skip is None else ~skip
    la, lr = _luminance(img)[keep], _luminance(ref)[keep]
    disp = image.compare(img[keep][None], ref[keep][None])
    be = block_errors(img, ref, skip)
    return dict(rel_mean=float(np.mean(np.abs(la - lr) / (lr + REL_EPS))),
                rmse=float(np.sqrt(np.mean((img[keep] - ref[keep]) ** 2))),
                psnr=disp["psnr"], display_mean=disp["mean_error"],
                block_p50=float(np.percentile(be, 50)), block_p98=float(np.percentile(be, 98)),
                block_max=float(be.max()), blocks=int(be.size))


def material_pixels(scene: Scene, material: str, settings: RenderSettings, accel
                    ) -> np.ndarray:
    """(h, w) bool: the pixels whose camera ray (the frame's jitter) sees ``material``."""
    return material_cover(scene, material, settings, accel) > 0.5


def material_cover(scene: Scene, material: str, settings: RenderSettings, accel
                   ) -> np.ndarray:
    """(h, w) float32: the share of each pixel's samples that see ``material`` (a copy of
    the scene with that material white-emissive, every other black, no world, depth 0)."""
    sc = scene.copy()
    for mid, m in enumerate(sc.materials):
        if m is not None:
            sc.set_material(mid, Material(m.name, diffuse=(0.0,) * 3, emission=(
                (1.0,) * 3 if m.name == material else (0.0,) * 3)))
    sc.set_world_color((0.0, 0.0, 0.0), lights=False)
    frame = render(sc, replace(settings, max_depth=0), accel=accel)
    return frame.radiance.max(axis=-1)


#: the clocks the row can time both renderers by (``bench frame --clock``): wall time, or
#: the process's CPU time summed over its threads (robust to other work on a shared machine:
#: rstrace's numba threads and Mitsuba's Dr.Jit threads are both the process's)
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def _mitsuba_render(mi, ms, spp: int, seed: int, clock=time.perf_counter):
    """(image (h, w, 3) bottom-up float64, seconds by ``clock``)."""
    t0 = clock()
    img = np.array(mi.render(ms, spp=int(spp), seed=int(seed)))
    return img[::-1, :, :3].astype(np.float64), clock() - t0


def mitsuba_rough(scene: Scene, width: int, height: int, depth: int = 5):
    """``(mi, ms)``: Mitsuba and ``scene`` loaded as :func:`rough_scene_dict` makes it, its
    kernels compiled by a 4-spp render; raises ``SystemExit`` where Mitsuba is unavailable
    (the scripts' way to say why)."""
    mi, why = mitsuba_llvm()
    if mi is None:
        raise SystemExit(why)
    ms = mi.load_dict(rough_scene_dict(scene, mi, width, height, depth, 1))
    _mitsuba_render(mi, ms, 4, seed=3)  # compiles
    return mi, ms


def mitsuba_cpu_per_spp(mi, ms, spp: int = 64, repeats: int = 3) -> float:
    """Mitsuba's CPU seconds per sample per pixel on ``ms``: the median of ``repeats``
    ``spp``-sample renders (seed 99)."""
    per = []
    for _ in range(repeats):
        t0 = time.process_time()
        _mitsuba_render(mi, ms, spp, seed=99)
        per.append((time.process_time() - t0) / spp)
    return float(np.median(per))


def mitsuba_equal_time(mi, ms, seconds: float, probe_spp: int = 4, tries: int = 3,
                       clock=time.perf_counter):
    """Mitsuba's frame taking about ``seconds`` by ``clock``: a render at ``probe_spp`` gives
    the rate, then up to ``tries`` renders rescale the spp to the time (until within 10%).
    Returns ``(image, spp, seconds)`` of the last render."""
    spp = probe_spp
    img, t = _mitsuba_render(mi, ms, spp, seed=0, clock=clock)
    for _ in range(tries):
        if abs(t - seconds) <= 0.1 * seconds:
            break
        want = max(1, int(round(spp * seconds / max(t, 1e-6))))
        if want == spp:
            break
        spp = want
        img, t = _mitsuba_render(mi, ms, spp, seed=0, clock=clock)
    return img, spp, t


def timed_frames(scene: Scene, settings: RenderSettings, accel, clock, repeats: int):
    """``(frame, median seconds by clock, median wall seconds)`` of ``repeats`` renders of
    ``scene`` (deterministic: every render gives the same image)."""
    times, walls = [], []
    for _ in range(max(1, int(repeats))):
        c0, w0 = clock(), time.perf_counter()
        frame = render(scene, settings, accel=accel)
        times.append(clock() - c0)
        walls.append(time.perf_counter() - w0)
    return frame, float(np.median(times)), float(np.median(walls))


def run_rough(width: int = 160, height: int = 120, depth: int = 5, accelerator: str = "BVH",
              settings=None, ref_spp: int = 4096, ref_samples: int = 64,
              out=None, mitsuba: bool = True, clock: str = "wall", repeats: int = 3) -> dict:
    """The ``rough_materials`` row: rstrace at ``settings`` (default: the defaults at
    ``depth``) timed (the median of ``repeats`` frames by ``clock``, one of
    :data:`CLOCKS`), Mitsuba at equal time by the same clock, both against Mitsuba's
    ``ref_spp`` reference; rstrace at ``ref_samples`` pixel samples against it is the
    models' bias (0: skip). ``mitsuba`` False: rstrace's time only."""
    if clock not in CLOCKS:
        raise ValueError(f"rough_materials: clock {clock!r} is not one of {sorted(CLOCKS)}")
    tick = CLOCKS[clock]
    st = (settings if settings is not None else RenderSettings(
        max_depth=depth, accelerator=accelerator)).validated()
    warm = scenes.rough_materials(16, 12)  # compiles / loads the kernels (not timed)
    render(warm, st, accel=create_accelerator(accelerator, warm.arrays()))
    scene = scenes.rough_materials(width, height)
    t0 = time.perf_counter()
    acc = create_accelerator(accelerator, scene.arrays())
    build = time.perf_counter() - t0
    frame, secs, wall = timed_frames(scene, st, acc, tick, repeats)
    stats = frame.stats
    row = dict(scene=ROUGH, width=width, height=height, depth=st.max_depth,
               samples=st.samples, glossy_samples=st.glossy_samples,
               light_samples=st.light_samples, triangles=scene.triangle_count,
               instances=len(scene.instances), lights=len(scene.lights),
               accelerator=acc.name, build_s=build, clock=clock, repeats=repeats,
               time_s=secs, wall_s=wall, rays=stats["rays_traced"],
               primary_rays=stats["primary_rays"], secondary_rays=stats["secondary_rays"],
               shadow_rays=stats["shadow_rays"], mrays_per_s=stats["rays_traced"] / secs / 1e6,
               threads=numba.get_num_threads())
    if out is not None:
        image.write_render_png(Path(out) / "rough_materials_rstrace.png", frame.radiance)
    mi, why = mitsuba_llvm() if mitsuba else (None, "not asked for (--no-mitsuba)")
    if mi is None:
        row["mitsuba_unavailable"] = why
        return row
    import drjit as dr

    t0 = time.perf_counter()
    ms = mi.load_dict(rough_scene_dict(scene, mi, width, height, st.max_depth, 1))
    row["mitsuba_build_s"] = time.perf_counter() - t0
    row["mitsuba_threads"] = int(dr.thread_count())
    _mitsuba_render(mi, ms, 1, seed=3)  # compiles the kernels (not timed)
    img, spp, msecs = mitsuba_equal_time(mi, ms, secs, clock=tick)
    ref, ref_s = _mitsuba_render(mi, ms, ref_spp, seed=1)
    glass = material_pixels(scene, "glass", st, acc)
    row.update(mitsuba_spp=spp, mitsuba_s=msecs, ratio=secs / msecs,
               ref_spp=ref_spp, ref_s=ref_s, glass_pixels=int(glass.sum()),
               rstrace_error=error_stats(frame.radiance, ref),
               mitsuba_error=error_stats(img, ref),
               rstrace_error_no_glass=error_stats(frame.radiance, ref, glass),
               mitsuba_error_no_glass=error_stats(img, ref, glass))
    if ref_samples > 0:
        conv = render(scene, replace(st, samples=ref_samples), accel=acc)
        row.update(bias_samples=ref_samples, bias_s=conv.stats["time_s"],
                   bias_error=error_stats(conv.radiance, ref),
                   bias_error_no_glass=error_stats(conv.radiance, ref, glass),
                   rstrace_noise=error_stats(frame.radiance, conv.radiance))
    if out is not None:
        image.write_render_png(Path(out) / "rough_materials_mitsuba.png", img)
        image.write_render_png(Path(out) / "rough_materials_reference.png", ref)
    return row
