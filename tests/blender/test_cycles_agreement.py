"""The base tracer against Cycles set up as a Whitted tracer (issue 11): sun, glass slab and
sphere, Principled highlights at normal and grazing views, emission seen directly and in a
mirror. Spot, point lights, camera models and the mirror sphere are in test_render.

Each case's thresholds sit next to the measured values in the README table "Accuracy of the
base tracer". Scenes are small (64 x 48 px) and Cycles renders direct light only, plus the
glossy/transmission bounces the case needs; emissive meshes light nothing there (invisible to
diffuse rays: Cycles still samples them as lights with ``emission_sampling = 'NONE'``), as
RSTrace does not model them as light sources.
"""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from . import builders as b
from .test_render import _compare, _cycles, _lum, _ours, needs_cycles

pytestmark = needs_cycles

W, H = 64, 48


def _block_errors(ours: np.ndarray, ref: np.ndarray, block: int = 8,
                  floor: float = 0.05) -> np.ndarray:
    """Relative errors of block means (``block`` x ``block`` px, luminance) of image ``ours``
    against image ``ref``, over the blocks of ``ref`` holding at least ``floor`` of its
    brightest block's light (darker blocks: a relative error says nothing there)."""
    def blocks(a):
        lum = _lum(a)
        h, w = (lum.shape[0] // block) * block, (lum.shape[1] // block) * block
        return lum[:h, :w].reshape(h // block, block, w // block, block).mean(axis=(1, 3))

    o, c = blocks(ours), blocks(ref)
    keep = c > floor * c.max()
    return np.abs(o[keep] - c[keep]) / c[keep]


def _block_error(ours: list, cycles: list, block: int = 8, floor: float = 0.05) -> float:
    """Largest relative error of block means over the blocks holding at least ``floor`` of
    the brightest block's light (each renderer's two seeds averaged)."""
    errs = _block_errors((ours[0] + ours[1]) / 2, (cycles[0] + cycles[1]) / 2, block, floor)
    err = float(np.max(errs))
    print(f"block error {err:.4f} over {errs.size} blocks")
    return err


def _block_stats(ours: list, cycles: list) -> dict:
    """Mean and 98th percentile of the 8x8-block relative errors of ours against Cycles
    (two seeds each, averaged), and the same for Cycles' seed 1 against its seed 2: its
    own noise (that of one seed against another, so twice the averaged reference's)."""
    errs = _block_errors((ours[0] + ours[1]) / 2, (cycles[0] + cycles[1]) / 2)
    own = _block_errors(cycles[0], cycles[1])
    stats = dict(mean=float(errs.mean()), p98=float(np.percentile(errs, 98)),
                 max=float(errs.max()), cycles_mean=float(own.mean()),
                 cycles_p98=float(np.percentile(own, 98)), blocks=int(errs.size))
    print("block errors:", {k: round(v, 4) for k, v in stats.items()})
    return stats


def _setup(max_depth: int = 0, samples: int = 16):
    sc = b.setup_render(W, H, samples=samples, max_depth=max_depth)
    b.set_world((0.0, 0.0, 0.0))
    return sc


def _emissive(name: str, colour, strength: float):
    mat = b.principled(name, (0.0, 0.0, 0.0), roughness=0.5, specular_level=0.0)
    node = mat.node_tree.nodes["Principled BSDF"]
    node.inputs["Emission Color"].default_value = (*colour, 1.0)
    node.inputs["Emission Strength"].default_value = strength
    return mat


def _box(name: str):
    """A cube from -1 to 1 (bmesh; flat shaded)."""
    import bmesh

    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bm.to_mesh(me)
    bm.free()
    return me


def _glass(name: str = "Glass"):
    return b.principled(name, (1.0, 1.0, 1.0), roughness=0.0,
                        **{"IOR": 1.5, "Transmission Weight": 1.0})


# ----------------------------------------------------------------------------- lights


def test_sun_agrees_with_cycles():
    _setup()
    b.add_object("Ground", b.grid("Ground", 12.0), material=b.diffuse("Floor", (0.6, 0.6, 0.55)))
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 32, 16), (0.0, 0.3, 1.0),
                 b.diffuse("Red", (0.7, 0.15, 0.1)))
    sun = b.point_light("Sun", (0.0, 0.0, 5.0), 3.0, kind="SUN")
    sun.data.angle = 0.0
    sun.rotation_euler = (math.radians(35.0), 0.0, math.radians(-30.0))
    b.camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8))
    stats = _compare(_ours(), _cycles())
    assert stats["rel_l1"] < 0.01
    assert abs(stats["median_ratio"] - 1.0) < 0.005
    assert stats["frac_over"] < 0.03


# ----------------------------------------------------------------------------- soft light

#: Soft-light cases (issue 20): 128 x 96 px (192 blocks of 8 x 8), so that the 98th
#: percentile of block errors is not just the largest block.
SOFT_W, SOFT_H = 128, 96
SOFT_CASES = ["area_square", "area_rectangle", "area_disk", "area_ellipse", "sphere",
              "sphere_soft_falloff", "spot_radius", "sun_angle", "world"]


def _area(name: str, shape: str, size: float, size_y: float, location, rotation_deg,
          power: float):
    data = bpy.data.lights.new(name, "AREA")
    data.shape, data.size, data.size_y, data.energy = shape, size, size_y, power
    ob = b.add_object(name, data, location)
    ob.rotation_euler = tuple(math.radians(a) for a in rotation_deg)
    return ob


def _soft_scene(case: str):
    """A red ball and a grey box on a floor under one soft light (or only the world), the
    light above the frame (Cycles shows lights to camera rays). Direct light only."""
    sc = b.setup_render(SOFT_W, SOFT_H, samples=16, max_depth=0)
    sc.rstrace.light_samples = 16
    b.set_world((0.0, 0.0, 0.0))
    b.add_object("Ground", b.grid("Ground", 14.0), material=b.diffuse("Floor", (0.6, 0.6, 0.55)))
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 48, 24), (-0.6, 0.4, 1.0),
                 b.diffuse("Red", (0.7, 0.15, 0.1)))
    b.add_object("Box", _box("Box"), (1.9, -0.4, 0.6), b.diffuse("Grey", (0.5, 0.5, 0.5)),
                 scale=(0.6, 0.6, 0.6)).rotation_euler = (0.0, 0.0, math.radians(25.0))
    b.camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8))
    if case == "area_square":
        _area("Area", "SQUARE", 2.0, 2.0, (0.8, -1.0, 4.6), (15.0, 0.0, 30.0), 800.0)
    elif case == "area_rectangle":
        _area("Area", "RECTANGLE", 3.0, 0.6, (-0.5, -0.5, 4.6), (-15.0, 0.0, 30.0), 800.0)
    elif case == "area_disk":
        _area("Area", "DISK", 2.5, 2.5, (0.5, 0.5, 4.6), (0.0, 10.0, 0.0), 800.0)
    elif case == "area_ellipse":
        _area("Area", "ELLIPSE", 3.0, 1.2, (0.0, -0.8, 4.6), (10.0, 0.0, -40.0), 800.0)
    elif case in ("sphere", "sphere_soft_falloff"):
        lamp = b.point_light("Lamp", (2.2, -1.2, 4.0), 1500.0)
        lamp.data.shadow_soft_size = 0.7
        lamp.data.use_soft_falloff = case == "sphere_soft_falloff"
    elif case == "spot_radius":
        spot = b.point_light("Spot", (1.5, -2.0, 5.0), 3000.0, kind="SPOT")
        spot.data.spot_size, spot.data.spot_blend = math.radians(70.0), 0.3
        spot.data.shadow_soft_size = 0.5
        spot.data.use_soft_falloff = True  # Blender's default
        b.look_at(spot, (0.0, 0.3, 0.5))
    elif case == "sun_angle":  # 30 degrees above the horizon; closer, on the ball's shadow
        sun = b.point_light("Sun", (0.0, 0.0, 5.0), 3.0, kind="SUN")
        sun.data.angle = math.radians(10.0)
        sun.rotation_euler = (math.radians(60.0), 0.0, math.radians(100.0))
        sc.camera.data.lens = 50.0
        b.look_at(sc.camera, (-2.0, 0.15, 0.3))
    elif case == "world":
        b.set_world((0.5, 0.55, 0.6))
    else:
        raise ValueError(case)
    return sc


@pytest.mark.parametrize("case", SOFT_CASES)
def test_soft_light_agrees_with_cycles(case):
    """Each kind of soft light Blender has, against Cycles' direct light (max bounces 0) at
    1024 samples: the mean of the 8x8-block relative errors within 1% and their 98th
    percentile within 5% (penumbrae are a small share of an image). Cycles' own noise (one
    seed against another) is checked to be far below both. Measured values beside the
    thresholds in docs/accuracy.md."""
    _soft_scene(case)
    cycles = _cycles(samples=1024)
    stats = _block_stats(_ours(), cycles)
    assert stats["cycles_mean"] < 0.002 and stats["cycles_p98"] < 0.01  # the reference
    assert stats["mean"] <= 0.01
    assert stats["p98"] <= 0.05


# ----------------------------------------------------------------------------- glass


def _backdrop():
    """An emissive checker-free backdrop (radiance (1, 0.8, 0.6) x 2) facing the camera."""
    wall = b.add_object("Backdrop", b.grid("Backdrop", 20.0), (0.0, 4.0, 0.0),
                        _emissive("Glow", (1.0, 0.8, 0.6), 2.0))
    wall.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    return wall


@pytest.mark.parametrize("shape", ["slab", "sphere"])
def test_glass_agrees_with_cycles(shape):
    """Clear glass (Principled transmission 1, IOR 1.5, roughness 0) in front of an emissive
    wall. The old conversion applied the Fresnel factor twice: the slab passed 0.926 and the
    sphere 0.954 of Cycles' light, which the median-ratio threshold rejects."""
    _setup(max_depth=8)
    _backdrop()
    if shape == "slab":  # 3 wide, 2 tall, 0.3 thick along the view
        b.add_object("Slab", _box("Slab"), material=_glass(), scale=(1.5, 0.15, 1.0))
    else:
        b.add_object("Ball", b.uv_sphere("Ball", 1.0, 64, 32), material=_glass())
    b.camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), lens=50.0)
    ours = _ours()
    cycles = _cycles(max_bounces=8, transmission_bounces=8)
    stats = _compare(ours, cycles)
    # the glass covers the middle of the frame: compare there
    mid = (slice(H // 4, 3 * H // 4), slice(W // 3, 2 * W // 3))
    o = _lum((ours[0] + ours[1]) / 2)[mid]
    c = _lum((cycles[0] + cycles[1]) / 2)[mid]
    ratio = float(np.median(o / np.maximum(c, 1e-6)))
    print(f"glass {shape}: median ratio in the glass {ratio:.4f}")
    assert abs(ratio - 1.0) < 0.01 if shape == "slab" else abs(ratio - 1.0) < 0.02
    assert abs(stats["median_ratio"] - 1.0) < 0.01
    assert stats["rel_l1"] < 0.01


# ----------------------------------------------------------------------------- highlights


def _glossy_scene(view: str, model: str):
    # 64 samples: the highlights are small, and at 16 samples which pixels of a block catch
    # them depends on the jitter pattern (the tile layout): up to 19% block error from noise
    sc = _setup(samples=64)
    sc.rstrace.shading_model = model
    b.add_object("Ground", b.grid("Ground", 16.0),
                 material=b.principled("Glossy", (0.5, 0.3, 0.2), roughness=0.3))
    b.add_object("Ball", b.uv_sphere("Ball", 0.8, 48, 24), (-1.6, 1.2, 0.8),
                 b.principled("Blue", (0.1, 0.25, 0.6), roughness=0.2))
    if view == "normal":
        b.point_light("Key", (1.5, 0.0, 3.0), 800.0)
        b.camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0))
    else:  # about 76 degrees from the floor's normal
        b.point_light("Key", (0.0, 4.0, 1.5), 800.0)
        b.camera((0.0, -8.0, 2.0), (0.0, 0.0, 0.0))
    return sc


@pytest.mark.parametrize("view", ["normal", pytest.param("grazing", marks=pytest.mark.xfail(
    reason="measured 0.151 largest 8x8-block error (goal 0.05; median ratio 1.002): noise on "
    "both sides, not a difference. The block holds one pixel on the ball's silhouette whose "
    "highlight is a near-singular spike: over 48 seeds its 64-sample value spreads sd 2.1 "
    "(mean 7.6; the jittered grid before: 2.7), Cycles' sd 1.9 at 64 and 0.7 at 256 samples "
    "(12 seeds); a 5% block needs both under about 0.2 (ours: 0.19 at 1,024 samples; "
    "docs/accuracy.md, 'Pixel samples')",
    strict=False))])
def test_principled_highlights_agree_with_cycles(view):
    """Specular level 0.5, roughness 0.3 (floor) and 0.2 (ball): the default Principled-like
    model agrees with Cycles' direct lighting within 5% in every block of 8 x 8 px. Ward
    (seed 000's model, kept as an option) is measured and must stay far off."""
    _glossy_scene(view, "PRINCIPLED")
    cycles = _cycles(samples=256)
    ours = _ours()
    stats = _compare(ours, cycles)
    assert _block_error(ours, cycles) < 0.05
    assert abs(stats["median_ratio"] - 1.0) < 0.02
    bpy.context.scene.rstrace.shading_model = "WARD"
    ward = _ours()
    ward_stats = _compare(ward, cycles)
    assert _block_error(ward, cycles) > 0.05  # the reason for the default
    assert ward_stats["rel_l1"] > stats["rel_l1"]


# ----------------------------------------------------------------------------- emission


@pytest.mark.parametrize("where", ["direct", "mirror"])
def test_emission_agrees_with_cycles(where):
    """An emissive sphere seen directly, and in a metallic roughness-0 mirror floor."""
    depth = 0 if where == "direct" else 1
    _setup(max_depth=depth)
    ball = _emissive("Glow", (1.0, 0.5, 0.2), 3.0)
    ob = b.add_object("Ball", b.uv_sphere("Ball", 1.0, 48, 24), (0.0, 0.0, 1.2), ball)
    ob.visible_diffuse = False  # Cycles: not a light source for the floor (nor in RSTrace)
    if where == "direct":
        b.add_object("Ground", b.grid("Ground", 16.0),
                     material=b.diffuse("Floor", (0.6, 0.6, 0.6)))
        b.point_light("Key", (3.0, -3.0, 5.0), 1000.0)
    else:
        b.add_object("Ground", b.grid("Ground", 16.0),
                     material=b.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0,
                                           roughness=0.0))
    b.camera((0.0, -7.0, 2.5), (0.0, 0.0, 0.5))
    stats = _compare(_ours(), _cycles(max_bounces=depth))
    assert stats["rel_l1"] < 0.01
    assert abs(stats["median_ratio"] - 1.0) < 0.005
    assert stats["frac_over"] < 0.02


def test_tinted_glass_agrees_with_cycles():
    """Green Principled glass (Base Color (0.2, 0.8, 0.2), transmission 1, IOR 1.5) in front
    of a red half and a white half of an emissive wall (issue 23). Cycles tints each crossing
    by sqrt(Base Color), so a ray in and out of the sphere is tinted by the colour once; the
    old conversion tinted every crossing by the full colour (twice through the sphere).
    Compared per channel, as the error was one of saturation as much as of brightness.

    Measured (largest 8x8-block relative error, red / green / blue): 0.078 / 0.020 / 0.108,
    the old conversion 0.80 / 0.21 / 0.80; the mean over the glass, ours / Cycles: 0.977 /
    0.998 / 0.983, the old 0.23 / 0.80 / 0.22. The blocks inside the sphere agree within
    0.001; what is left is at the rim, where light reflected inside the glass dominates:
    the tracer weights a transmissive material's reflection by its transmission colour,
    Cycles' Principled reflection is untinted (a follow-up, not this fix)."""
    _setup(max_depth=8)
    for name, colour, x in (("Red", (1.0, 0.1, 0.1), -5.0), ("White", (1.0, 1.0, 1.0), 5.0)):
        wall = b.add_object(name, b.grid(name, 10.0), (x, 4.0, 0.0),
                            _emissive(name + "Glow", colour, 2.0))
        wall.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    glass = b.principled("GreenGlass", (0.2, 0.8, 0.2), roughness=0.0,
                         **{"IOR": 1.5, "Transmission Weight": 1.0})
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 64, 32), material=glass)
    b.camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), lens=50.0)
    ours = _ours()
    cycles = _cycles(max_bounces=8, transmission_bounces=8)
    mid = (slice(H // 4, 3 * H // 4), slice(W // 3, 2 * W // 3))
    o, c = (ours[0] + ours[1]) / 2, (cycles[0] + cycles[1]) / 2
    for ch in range(3):
        def one(a, ch=ch):
            return np.repeat(a[..., ch:ch + 1], 3, axis=-1)
        err = _block_error([one(a) for a in ours], [one(a) for a in cycles])
        ratio = float(o[mid][..., ch].mean() / c[mid][..., ch].mean())
        print(f"tinted glass channel {ch}: block error {err:.4f}, glass mean ratio {ratio:.4f}")
        assert err < 0.12
        assert abs(ratio - 1.0) < 0.03


# ----------------------------------------------------------------------------- glossy rays

#: Rough materials (issue 24): 96 x 72 px (108 blocks of 8 x 8), Cycles as a Whitted-like
#: tracer (diffuse bounces 0, glossy and transmission bounces 8, caustics off).
GLOSSY_W, GLOSSY_H = 96, 72
GLOSSY_ROUGHNESS = [0.05, 0.2, 0.5, 1.0]
GLOSSY_KINDS = ["metal", "plastic", "glass"]


def _rough_scene(kind: str, roughness: float):
    """One ball of the material on a two-tone floor, a red box and a green ball beside and
    behind it to be reflected or seen through it, a point light and a grey world that
    lights."""
    sc = b.setup_render(GLOSSY_W, GLOSSY_H, samples=16, max_depth=8)
    sc.rstrace.light_samples = 16
    sc.rstrace.glossy_samples = 16
    b.set_world((0.25, 0.27, 0.3))
    b.add_object("Ground", b.grid("Ground", 14.0), material=b.diffuse("Floor", (0.5, 0.5, 0.45)))
    b.add_object("Stripe", b.grid("Stripe", 2.0), (0.0, -1.2, 0.001),
                 b.diffuse("Dark", (0.05, 0.05, 0.08)), scale=(3.0, 0.5, 1.0))
    if kind == "metal":
        mat = b.principled("Metal", (0.95, 0.75, 0.45), metallic=1.0, roughness=roughness)
    elif kind == "plastic":  # Principled's defaults but for the colour and roughness
        mat = b.principled("Plastic", (0.2, 0.35, 0.8), roughness=roughness)
    else:
        mat = b.principled("Glass", (1.0, 1.0, 1.0), roughness=roughness,
                           **{"IOR": 1.5, "Transmission Weight": 1.0})
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 64, 32), (0.0, 0.0, 1.0), mat)
    b.add_object("Box", _box("Box"), (-1.2, 2.2, 0.8), b.diffuse("Red", (0.8, 0.1, 0.08)),
                 scale=(0.5, 0.5, 0.8)).rotation_euler = (0.0, 0.0, math.radians(20.0))
    b.add_object("Green", b.uv_sphere("Green", 0.6, 32, 16), (1.5, 1.5, 0.6),
                 b.diffuse("GreenMat", (0.1, 0.6, 0.15)))
    b.point_light("Key", (-3.0, -3.5, 5.0), 1500.0)
    b.camera((0.0, -6.0, 2.2), (0.0, 0.3, 0.9))
    return sc


#: Measured (docs/glossy.md): the cases whose measured error misses the issue's goal keep
#: the goal as their threshold and are marked xfail with the measured value, not loosened.
GLOSSY_MISSES: dict = {}


@pytest.mark.parametrize("roughness", GLOSSY_ROUGHNESS)
@pytest.mark.parametrize("kind", GLOSSY_KINDS)
def test_glossy_agrees_with_cycles(kind, roughness):
    """Rough metal, default plastic and rough glass against Cycles at 256 samples (two
    seeds each): the mean of the 8x8-block relative errors within 2% and their 98th
    percentile within 8% (issue 24). Measured values beside the thresholds in
    docs/glossy.md."""
    if (kind, roughness) in GLOSSY_MISSES:
        pytest.xfail(GLOSSY_MISSES[(kind, roughness)])
    sc = _rough_scene(kind, roughness)
    # Cycles' unbiased integral: its two noise-reduction biases off (docs/glossy.md, "Light
    # with an extent through rough glass, and what is left"). Clamp Indirect (default 10)
    # cut the light through a rough glass ball's far side by up to 27% at roughness 0.5,
    # Filter Glossy (default 1) widened the lobes inside it; rstrace models neither.
    sc.cycles.sample_clamp_indirect = 0.0
    sc.cycles.blur_glossy = 0.0
    cycles = _cycles(samples=256, max_bounces=8, transmission_bounces=8)
    stats = _block_stats(_ours(), cycles)
    print(f"glossy {kind} {roughness}: {stats}")
    assert stats["mean"] <= 0.02
    assert stats["p98"] <= 0.08


def _rough_pane(roughness: float, behind: str):
    """tests/test_rough_glass_light.py's pane in Blender: a 4 x 4 rough glass sheet (IOR
    1.5) whose normal faces away from the camera (the viewer on the glass side), 1 behind it
    a 1 x 1 area light of 100 W facing it (``"area"``) or a mesh emitting that light's
    radiance (100 / pi) in its place, which Cycles does not sample as a light
    (``emission_sampling`` 'NONE': only the pane's sampled refractions reach it)."""
    sc = b.setup_render(32, 32, samples=4, max_depth=2)
    sc.rstrace.light_samples = 64
    sc.rstrace.glossy_samples = 64
    b.set_world((0.0, 0.0, 0.0), lights=False)
    glass = b.principled("Glass", (1.0, 1.0, 1.0), roughness=roughness,
                         **{"IOR": 1.5, "Transmission Weight": 1.0})
    b.add_object("Pane", b.grid("Pane", 4.0), material=glass).rotation_euler = (
        math.radians(-90.0), 0.0, 0.0)
    if behind == "area":
        data = bpy.data.lights.new("Area", "AREA")
        data.energy, data.size = 100.0, 1.0
        b.add_object("Area", data, (0.0, 1.0, 0.0)).rotation_euler = (
            math.radians(-90.0), 0.0, 0.0)
    else:
        mat = bpy.data.materials.new("Emitter")
        nodes = mat.node_tree.nodes
        nodes.remove(nodes["Principled BSDF"])
        em = nodes.new("ShaderNodeEmission")
        em.inputs["Strength"].default_value = 100.0 / math.pi
        mat.node_tree.links.new(em.outputs["Emission"], nodes["Material Output"].inputs[0])
        mat.cycles.emission_sampling = "NONE"
        b.add_object("Emitter", b.grid("Emitter", 1.0), (0.0, 1.0, 0.0),
                     mat).rotation_euler = (math.radians(90.0), 0.0, 0.0)
    b.camera((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), lens=50.0)


@pytest.mark.parametrize("roughness", [0.5, 1.0])
@pytest.mark.parametrize("behind", ["area", "mesh"])
def test_light_through_a_rough_pane_agrees_with_cycles(behind, roughness):
    """An area light behind a rough glass pane, and an emitter in its place that only the
    pane's sampled refractions reach: each image's mean within 1% of Cycles' (1024
    samples). Cycles' next-event estimation passes the area light's light for pairs no
    microfacet refracts (its BTDF evaluation has no validity check; its MIS weight, near 1
    here, takes almost none of it away): at roughness 1 its area light is 6.5% brighter than
    the emitter, as rstrace's (docs/glossy.md, 'Light with an extent through rough glass').
    Measured: area 3.7743 / 3.7785 (Cycles), emitter 3.5471 / 3.5482 at roughness 1; area
    2.9188 / 2.9226, emitter 2.9023 / 2.9079 at 0.5. A BTDF that checks the refraction
    (before session 29) gives the area light about the emitter's 3.55 at roughness 1: 6%
    below Cycles."""
    _rough_pane(roughness, behind)
    cycles = float(np.mean(_cycles(samples=1024, max_bounces=2, transmission_bounces=2)))
    ours = float(np.mean(_ours()))
    print(f"pane {behind} {roughness}: ours {ours:.5f} cycles {cycles:.5f}")
    assert cycles > 1.0
    assert abs(ours - cycles) <= 0.01 * cycles, (ours, cycles)
