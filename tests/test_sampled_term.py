"""The sampled terms of lights with an extent, traced per pixel (interpolants/sampled_term.py):
what the base tracer adds for a glossy lobe under an extended light, or for a light without a
closed form, beyond the closed-form diffuse part the interpolants hold."""

from __future__ import annotations

import numpy as np
from tracer_scenes import ortho_down

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_params, camera_rays
from rstrace_engine.geometry.scene import Camera, Light, Material, Mesh, Scene
from rstrace_engine.interpolants.sampled_term import sampled_possible, sampled_term
from rstrace_engine.tracing.soft_lights import sample_seeds
from rstrace_engine.tracing.whitted import trace

SAMPLES = 8


def _floor(material: Material, lights, ball: bool = False, camera: Camera | None = None):
    s = Scene()
    m = s.add_material(material)
    s.add_instance(s.add_mesh(shapes.plane(30.0, name="floor")), np.eye(4), [m], "Floor")
    if ball:
        s.add_instance(s.add_mesh(shapes.icosphere(2, name="ball")),
                       shapes.transform((0.2, 0.0, 0.5), 0.5), [m], "Ball")
    for light in lights:
        s.add_light(light)
    s.set_camera(camera or ortho_down(scale=4.0, width=32, rows=24))
    return s


def _lines(s: Scene):
    sa = s.arrays()
    accel = create_accelerator("BVH", sa)
    cp = camera_params(s.camera)
    pix = np.arange(cp.width * cp.height, dtype=np.int64)
    o, d, tmin, tmax = camera_rays(cp, pix, np.full((len(pix), 2), 0.5))
    hits = accel.closest_hit(o, d, tmin, tmax)
    return sa, accel, o, d, tmin, tmax, hits, sample_seeds(pix, 7)


RECT = dict(power=40.0, position=(0.3, -0.2, 2.0), direction=(0.0, 0.0, -1.0),
            size=(1.5, 0.7))
SPHERE = Light("K", "POINT", power=30.0, position=(-1.0, 0.6, 2.5), radius=0.2)
GLOSSY = Material("gloss", diffuse=(0.5, 0.45, 0.4), specular=(0.2,) * 3, roughness=0.3)
MATTE = Material("grey", diffuse=(0.6, 0.6, 0.6))


def test_glossy_lobe_is_the_tracers_less_its_closed_form():
    """On a glossy floor under a rectangle and a sphere light, fully visible: the tracer's
    radiance less the sampled term is the radiance of the same floor without its glossy
    lobe (the closed-form diffuse part, the same samples) to float rounding; taking every
    sample as visible (what a cell's proof gives a pixel) changes nothing there."""
    s = _floor(GLOSSY, [Light("L", "AREA", **RECT), SPHERE])
    sa, accel, o, d, tmin, tmax, hits, seeds = _lines(s)
    assert sampled_possible(sa)
    rad, _ = trace(sa, accel, o, d, tmin, tmax, 0, primary=hits, seeds=seeds,
                   light_samples=SAMPLES)
    coef = np.zeros((len(o), len(sa.light_kind), 3))
    proven = sampled_term(sa, accel, o, d, tmax, hits, seeds, SAMPLES, 0, proven=True,
                          coefficient=coef)
    traced = sampled_term(sa, accel, o, d, tmax, hits, seeds, SAMPLES, 0, proven=False)
    assert np.array_equal(proven, traced)
    assert np.all(proven >= 0.0) and proven.max() > 1e-3  # the highlight is there
    assert np.allclose(np.einsum("ilc,lc->ic", coef, np.asarray(sa.light_radiance)), proven,
                       rtol=1e-14, atol=0.0)
    lobe_off = sa._replace(mat_specular=np.zeros_like(sa.mat_specular))
    diffuse, _ = trace(lobe_off, accel, o, d, tmin, tmax, 0, primary=hits, seeds=seeds,
                       light_samples=SAMPLES)
    assert np.abs(rad - proven - diffuse).max() <= 1e-12 * max(1.0, rad.max())


def test_light_without_closed_form_is_traced_whole():
    """A spot with a radius has no closed form: its whole term is sampled, and the tracer's
    radiance less it is the radiance without the spot (the sphere light keeps its samples:
    its row's seed does not depend on the spot, which comes last)."""
    spot = Light("S", "SPOT", power=60.0, position=(0.0, 0.0, 3.0),
                 direction=(0.0, 0.0, -1.0), spot_size=2.5, radius=0.3)
    s = _floor(MATTE, [SPHERE, spot])
    sa, accel, o, d, tmin, tmax, hits, seeds = _lines(s)
    rad, _ = trace(sa, accel, o, d, tmin, tmax, 0, primary=hits, seeds=seeds,
                   light_samples=SAMPLES)
    term = sampled_term(sa, accel, o, d, tmax, hits, seeds, SAMPLES, 0, proven=False)
    assert term.max() > 1e-3
    no_spot = _floor(MATTE, [SPHERE])
    rest, _ = trace(no_spot.arrays(), accel, o, d, tmin, tmax, 0, primary=hits, seeds=seeds,
                    light_samples=SAMPLES)
    assert np.abs(rad - term - rest).max() <= 1e-12 * max(1.0, rad.max())


def test_occluded_samples_are_traced_unless_proven():
    """Traced (``proven=False``), the term follows the tracer's shadows; taken as proven it
    does not -- which is why only the pixels of cells whose shaft proof passed take it so
    (``render.py``), and a sample line with a shadowed sample is in no valid cell."""
    s = _floor(GLOSSY, [Light("L", "AREA", **RECT)], ball=True,
               camera=Camera(matrix=shapes.look_at((3.0, -4.0, 3.0), (0.0, 0.0, 0.3)),
                             lens=30.0, width=32, height=24))
    sa, accel, o, d, tmin, tmax, hits, seeds = _lines(s)
    proven = sampled_term(sa, accel, o, d, tmax, hits, seeds, SAMPLES, 0, proven=True)
    counters: dict = {}
    traced = sampled_term(sa, accel, o, d, tmax, hits, seeds, SAMPLES, 0, proven=False,
                          counters=counters)
    assert counters["shadow"] > 0
    assert np.all(traced <= proven + 1e-15)
    assert np.any(traced < proven)  # the ball's shadow on the floor's highlight


def test_no_sampled_rows_without_glossy_or_open_forms():
    """A Lambertian scene under lights with closed forms has nothing to sample."""
    s = _floor(MATTE, [Light("L", "AREA", **RECT), SPHERE])
    sa, accel, o, d, tmin, tmax, hits, seeds = _lines(s)
    assert not sampled_possible(sa)
    assert not np.any(sampled_term(sa, accel, o, d, tmax, hits, seeds, SAMPLES, 0))


def test_reprojected_samples_add_their_sampled_terms(monkeypatch):
    """A camera step reprojects samples (no visibility ray) where no world lights; those on
    an object with sampled rows trace their visibility ray for their sampled term
    (``sampled_term.add_sampled_terms``), so the moved frame keeps the bound against BASE."""
    from rstrace_engine import image
    from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
    from rstrace_engine.interpolants import interpolant_cache
    from rstrace_engine.interpolants.render import InterpolantRenderer
    from rstrace_engine.tracing import whitted

    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    eps = 0.02
    s = _floor(GLOSSY, [Light("L", "AREA", **RECT), SPHERE],
               camera=Camera(matrix=shapes.look_at((0.5, -4.0, 3.0), (0.0, 0.0, 0.0)),
                             lens=35.0, width=64, height=48))
    accel = create_accelerator("BVH", s.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=eps, depth_cap=7, light_samples=4,
                        max_depth=2)
    r = InterpolantRenderer()
    r.auto_fallback = False
    r.render(s, st, accel)
    s.set_camera(Camera(matrix=shapes.look_at((0.55, -4.0, 3.0), (0.05, 0.0, 0.0)),
                        lens=35.0, width=64, height=48))
    frame = r.render(s, st, accel)
    base = whitted.render(s, st, accel=accel)
    err = np.abs(image.to_display(frame.radiance)
                 - image.to_display(base.radiance)).max(axis=-1)
    interp = frame.pixel_class == CLASS_INTERPOLATED
    assert frame.stats["reprojected_fraction"] > 0.2, frame.stats["reprojected_fraction"]
    assert interp.mean() > 0.3, interp.mean()
    assert err.max() <= eps + 1e-6, err.max()


def _slab(convex: bool):
    """The roof slab; not ``convex``: the same slab and a small box beside it in one mesh
    (not convex: the umbra proof refuses it)."""
    b = shapes.box((6.0, 3.0, 0.2), name="slab")
    if convex:
        return b
    c = shapes.box((0.1, 0.1, 0.1), name="bit")
    return Mesh("slab2", np.concatenate([b.vertices, c.vertices + (0.0, 0.0, 1.0)]),
                np.concatenate([b.triangles, c.triangles + len(b.vertices)]), smooth=False)


def _skylight_room(glossy: bool, convex: bool = True) -> Scene:
    """A floor under a roof of two closed boxes with a gap between them (a skylight), a sun
    of 3 degrees through the gap and a sphere light under the roof: the roof hides the sun
    from most of the floor (an umbra), the gap lets a soft-edged patch through."""
    s = Scene()
    m = s.add_material(GLOSSY if glossy else MATTE)
    roof = s.add_material(MATTE)
    s.add_instance(s.add_mesh(shapes.plane(30.0, name="floor")), np.eye(4), [m], "Floor")
    slab = s.add_mesh(_slab(convex))
    s.add_instance(slab, shapes.transform((0.0, -2.0, 3.0)), [roof], "RoofA")
    s.add_instance(slab, shapes.transform((0.0, 2.0, 3.0)), [roof], "RoofB")
    s.add_light(Light("Sun", "SUN", power=3.0, direction=(0.2, 0.1, -1.0), angle=0.05))
    s.add_light(Light("K", "POINT", power=60.0, position=(-1.0, 0.0, 2.2), radius=0.2))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -3.5, 2.0), (0.0, 0.5, 0.0)), lens=24.0,
                        width=64, height=48))
    return s


def test_sun_umbra_is_proven_and_keeps_the_bound(monkeypatch):
    """Cells the roof hides the sun from pass (a closed convex roof slab blocks every
    direction of the sun's cone from the cell: ``occluders.cone_umbra``), on a matte and on
    a glossy floor (the sun's sampled rows are traced per pixel: its value there is 0),
    within epsilon of BASE; under a roof that is not convex (refused) they fail on
    ``light_shaft``."""
    from rstrace_engine import image
    from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
    from rstrace_engine.interpolants import interpolant_cache
    from rstrace_engine.interpolants.render import InterpolantRenderer
    from rstrace_engine.tracing import whitted

    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    eps = 0.02
    shares = {}
    for glossy in (False, True):
        s = _skylight_room(glossy)
        accel = create_accelerator("BVH", s.arrays())
        st = RenderSettings(mode="INTERPOLANT", epsilon=eps, depth_cap=7, light_samples=4,
                            max_depth=2)
        r = InterpolantRenderer()
        r.auto_fallback = False
        frame = r.render(s, st, accel)
        base = whitted.render(s, st, accel=accel)
        err = np.abs(image.to_display(frame.radiance)
                     - image.to_display(base.radiance)).max(axis=-1)
        interp = frame.pixel_class == CLASS_INTERPOLATED
        assert err.max() <= eps + 1e-6, (glossy, err.max())
        assert np.all(err[~interp] == 0.0)
        shares[glossy] = interp.mean()
    assert min(shares.values()) > 0.2, shares
    # the proof is what passes them: a roof that is not convex is not taken
    s = _skylight_room(False, convex=False)
    accel = create_accelerator("BVH", s.arrays())
    r = InterpolantRenderer()
    r.auto_fallback = False
    frame = r.render(s, st, accel)
    assert (frame.pixel_class == CLASS_INTERPOLATED).mean() < 0.5 * shares[False]


def test_moving_the_roof_invalidates_the_umbra(monkeypatch):
    """An INTERPOLANT session over the skylight room: moving a roof slab (the gap opens,
    sun falls where the umbra was proven) invalidates those cells through the sun's shafts;
    the frame after the edit stays within epsilon of a fresh BASE frame."""
    from rstrace_engine import image
    from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
    from rstrace_engine.geometry.edits import ObjectTransform
    from rstrace_engine.interpolants import interpolant_cache
    from rstrace_engine.interpolants.render import InterpolantRenderer
    from rstrace_engine.session import Session
    from rstrace_engine.tracing import whitted

    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    # cells wherever the rays need them (the measured fallback only traces: exact)
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    eps = 0.02
    scene = _skylight_room(True)
    st = RenderSettings(mode="INTERPOLANT", epsilon=eps, depth_cap=7, light_samples=4,
                        max_depth=2)
    sess = Session(scene, st)
    first = sess.render()
    assert (first.pixel_class == CLASS_INTERPOLATED).mean() > 0.2
    slot = scene.instance_slot("RoofB")
    m = scene.instances[slot]["matrix"].copy()
    m[1, 3] += 1.0
    sess.apply([ObjectTransform("RoofB", m)])
    frame = sess.render()
    moved = sess.scene
    base = whitted.render(moved, st, accel=create_accelerator("BVH", moved.arrays()))
    err = np.abs(image.to_display(frame.radiance)
                 - image.to_display(base.radiance)).max(axis=-1)
    assert err.max() <= eps + 1e-6, err.max()
    assert (frame.pixel_class == CLASS_INTERPOLATED).mean() > 0.1
