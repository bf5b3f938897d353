"""Shading math against closed forms: Ward, mirror, Snell, Fresnel, spot falloff, textures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rstrace_engine import tolerances
from rstrace_engine.geometry.attributes import ATTR_CORNER
from rstrace_engine.geometry.elements import (
    TEX_CLIP,
    TEX_CLOSEST,
    TEX_EXTEND,
    TEX_SRGB,
    srgb_decode,
)
from rstrace_engine.geometry.scene import Material, Mesh, Scene
from rstrace_engine.tracing import shading

RNG = np.random.default_rng(7)


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def random_hemisphere(n, rng=RNG):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- Ward


@pytest.mark.parametrize("theta_deg", [0.0, 10.0, 45.0, 70.0, 85.0])
@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.6])
def test_ward_peak_at_mirror_direction(theta_deg, alpha):
    th = math.radians(theta_deg)
    wo = (math.sin(th), 0.0, math.cos(th))
    wi = (-math.sin(th), 0.0, math.cos(th))  # mirror direction of wo about +Z
    got = shading.ward_specular(0.0, 0.0, 1.0, *wi, *wo, alpha)
    want = 1.0 / (4.0 * math.pi * alpha * alpha * math.cos(th))
    assert got == pytest.approx(want, rel=1e-12)
    rd, rs = (0.3, 0.2, 0.1), (0.25, 0.5, 0.75)
    f = shading.ward_brdf(0.0, 0.0, 1.0, *wi, *wo, *rd, *rs, alpha)
    for k in range(3):
        assert f[k] == pytest.approx(rd[k] / math.pi + rs[k] * want, rel=1e-12)


def test_ward_matches_formula_with_explicit_angles():
    n = unit((0.2, -0.3, 1.0))
    # build a frame around n and random directions in its upper hemisphere
    t = unit(np.cross(n, (1.0, 0.0, 0.0)))
    b = np.cross(n, t)
    frame = np.stack([t, b, n], 1)
    wi = random_hemisphere(200) @ frame.T
    wo = random_hemisphere(200) @ frame.T
    alpha = 0.3
    for a, o in zip(wi, wo, strict=True):
        h = unit(a + o)
        delta = math.acos(min(1.0, float(h @ n)))
        want = (math.exp(-math.tan(delta) ** 2 / alpha ** 2)
                / (4 * math.pi * alpha ** 2 * math.sqrt((a @ n) * (o @ n))))
        got = shading.ward_specular(*n, *a, *o, alpha)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-300)
        # reciprocity
        assert shading.ward_specular(*n, *o, *a, alpha) == pytest.approx(got, rel=1e-12)


def test_ward_zero_below_horizon():
    assert shading.ward_specular(0, 0, 1, 0.0, 0.6, -0.8, 0.0, -0.6, 0.8, 0.2) == 0.0
    assert shading.ward_specular(0, 0, 1, 0.0, 0.6, 0.8, 0.0, -0.6, -0.8, 0.2) == 0.0
    f = shading.ward_brdf(0, 0, 1, 0.0, 0.6, -0.8, 0.0, -0.6, 0.8, 0.5, 0.5, 0.5, 0.3, 0.3, 0.3,
                          0.2)
    assert f == pytest.approx((0.5 / math.pi,) * 3)


def _lobe_albedo(alpha, wo, n_theta=400, n_phi=200):
    """Cosine-weighted hemispherical integral of the specular lobe (midpoint rule)."""
    th = (np.arange(n_theta) + 0.5) * (math.pi / 2 / n_theta)
    ph = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
    total = 0.0
    for t in th:
        st, ct = math.sin(t), math.cos(t)
        for p in ph:
            total += shading.ward_specular(0, 0, 1, st * math.cos(p), st * math.sin(p), ct,
                                           *wo, alpha) * ct * st
    return total * (math.pi / 2 / n_theta) * (2 * math.pi / n_phi)


def test_ward_lobe_albedo_is_at_most_one():
    """Ward's normalisation: the lobe's albedo is close to 1 for narrow lobes, below 1 wider."""
    a1 = _lobe_albedo(0.1, (0.0, 0.0, 1.0))
    a3 = _lobe_albedo(0.3, (0.0, 0.0, 1.0))
    assert 0.95 < a1 < 1.0
    assert 0.7 < a3 < a1


# ----------------------------------------------------------------------------- mirror / glass


def test_reflect_mirror_direction():
    for _ in range(50):
        n = unit(RNG.normal(size=3))
        d = unit(RNG.normal(size=3))
        if d @ n > 0:
            d = -d
        r = np.array(shading.reflect(*d, *n))
        assert np.linalg.norm(r) == pytest.approx(1.0, abs=1e-14)
        assert r @ n == pytest.approx(-(d @ n), abs=1e-14)  # equal angles
        assert np.linalg.det(np.stack([d, n, r])) == pytest.approx(0.0, abs=1e-12)  # coplanar
    # along an axis and a diagonal: exact
    assert shading.reflect(0.0, 0.0, -1.0, 0.0, 0.0, 1.0) == (0.0, 0.0, 1.0)
    s = 1 / math.sqrt(2)
    r = shading.reflect(s, 0.0, -s, 0.0, 0.0, 1.0)
    assert r == pytest.approx((s, 0.0, s), abs=1e-16)


@pytest.mark.parametrize("eta", [1 / 1.5, 1.5, 1 / 1.33, 1.0])
def test_refract_snell(eta):
    n = np.array([0.0, 0.0, 1.0])
    for deg in (0.0, 5.0, 25.0, 40.0, 41.0, 60.0, 89.0):
        th = math.radians(deg)
        d = np.array([math.sin(th), 0.0, -math.cos(th)])
        ok, *t = shading.refract(*d, *n, eta)
        sin_t = eta * math.sin(th)
        if sin_t >= 1.0:
            assert not ok, (deg, eta)
            continue
        assert ok
        t = np.array(t)
        assert np.linalg.norm(t) == pytest.approx(1.0, abs=1e-14)
        assert t[0] == pytest.approx(sin_t, abs=1e-14)  # sin of the refraction angle
        assert t[2] == pytest.approx(-math.sqrt(1 - sin_t ** 2), abs=1e-14)
        assert t[1] == 0.0


def test_total_internal_reflection_at_critical_angle():
    ior = 1.5
    crit = math.asin(1 / ior)
    n = (0.0, 0.0, 1.0)
    below = crit - 1e-6
    above = crit + 1e-6
    ok, *_ = shading.refract(math.sin(below), 0.0, -math.cos(below), *n, ior)
    assert ok
    ok, *_ = shading.refract(math.sin(above), 0.0, -math.cos(above), *n, ior)
    assert not ok
    assert shading.fresnel_dielectric(math.cos(above), ior) == 1.0
    assert shading.fresnel_dielectric(math.cos(below), ior) < 1.0


@pytest.mark.parametrize("ior", [1.0, 1.33, 1.5, 2.4])
def test_fresnel_normal_incidence(ior):
    want = ((ior - 1) / (ior + 1)) ** 2
    assert shading.fresnel_dielectric(1.0, 1 / ior) == pytest.approx(want, rel=1e-14, abs=1e-16)
    assert shading.fresnel_dielectric(1.0, ior) == pytest.approx(want, rel=1e-14, abs=1e-16)


def test_fresnel_brewster_and_grazing():
    ior = 1.5
    tb = math.atan(ior)  # Brewster: p-polarised reflectance vanishes
    ci = math.cos(tb)
    ct = math.cos(math.asin(math.sin(tb) / ior))
    rs = (ci - ior * ct) / (ci + ior * ct)
    assert shading.fresnel_dielectric(ci, 1 / ior) == pytest.approx(0.5 * rs * rs, rel=1e-12)
    assert shading.fresnel_dielectric(0.0, 1 / ior) == pytest.approx(1.0)
    # monotone in the angle for entering light
    vals = [shading.fresnel_dielectric(math.cos(math.radians(a)), 1 / ior)
            for a in range(60, 90)]
    assert np.all(np.diff(vals) >= 0.0)


# ----------------------------------------------------------------------------- lights


def test_spot_falloff_smoothstep():
    outer, inner = math.cos(0.5), math.cos(0.4)
    assert shading.spot_falloff(math.cos(0.6), outer, inner) == 0.0
    assert shading.spot_falloff(outer, outer, inner) == 0.0
    assert shading.spot_falloff(math.cos(0.3), outer, inner) == 1.0
    assert shading.spot_falloff(inner, outer, inner) == 1.0
    mid = 0.5 * (outer + inner)
    assert shading.spot_falloff(mid, outer, inner) == pytest.approx(0.5, abs=1e-12)
    x = 0.25
    c = outer + x * (inner - outer)
    assert shading.spot_falloff(c, outer, inner) == pytest.approx(3 * x * x - 2 * x ** 3)
    # blend 0: a hard edge
    assert shading.spot_falloff(math.cos(0.49), outer, outer) == 1.0
    assert shading.spot_falloff(math.cos(0.51), outer, outer) == 0.0


# ----------------------------------------------------------------------------- textures, normals


def _texture(w=4, h=3, flags=0):
    img = RNG.random((h, w, 3)).astype(np.float32)
    data = img.reshape(-1, 3)
    return img, data, np.array([0, w * h], np.int64), np.array([[w, h, flags]], np.int32)


def test_texture_bilinear_and_repeat():
    img, data, start, size = _texture()
    h, w = img.shape[:2]
    # texel centres give the texel exactly
    for j in range(h):
        for i in range(w):
            got = shading.texture_lookup(data, start, size, 0, (i + 0.5) / w, (j + 0.5) / h)
            assert got == pytest.approx(tuple(img[j, i]), abs=1e-7)
    # half-way between two texels: their mean
    got = shading.texture_lookup(data, start, size, 0, 2.0 / w, 0.5 / h)
    assert got == pytest.approx(tuple(0.5 * (img[0, 1] + img[0, 2])), abs=1e-7)
    # repeat: shifting by whole periods changes nothing, also negative
    for du, dv in ((1.0, 0.0), (-3.0, 2.0), (7.0, -5.0)):
        u, v = 0.37, 0.61
        a = shading.texture_lookup(data, start, size, 0, u, v)
        b = shading.texture_lookup(data, start, size, 0, u + du, v + dv)
        assert a == pytest.approx(b, abs=1e-6)
    # the seam wraps: u = 0 is half-way between the last and first column
    got = shading.texture_lookup(data, start, size, 0, 0.0, 0.5 / h)
    assert got == pytest.approx(tuple(0.5 * (img[0, 0] + img[0, w - 1])), abs=1e-7)


def test_texture_closest_takes_the_texel_holding_the_point():
    img, data, start, size = _texture(flags=TEX_CLOSEST)
    h, w = img.shape[:2]
    for u, v in ((0.01, 0.01), (0.49, 0.7), (0.99, 0.34), (0.251, 0.999)):
        got = shading.texture_lookup(data, start, size, 0, u, v)
        assert got == pytest.approx(tuple(img[int(v * h), int(u * w)]), abs=1e-7)
    # repeats: u = -0.01 is in the last column
    got = shading.texture_lookup(data, start, size, 0, -0.01, 0.5)
    assert got == pytest.approx(tuple(img[1, w - 1]), abs=1e-7)


def test_texture_extend_and_clip():
    img, data, start, size = _texture(flags=TEX_EXTEND)
    h, w = img.shape[:2]
    # extend: beyond the border the edge texel, and the seam does not wrap
    assert shading.texture_lookup(data, start, size, 0, 3.0, 0.5 / h) == pytest.approx(
        tuple(img[0, w - 1]), abs=1e-7)
    assert shading.texture_lookup(data, start, size, 0, 0.0, 0.5 / h) == pytest.approx(
        tuple(img[0, 0]), abs=1e-7)
    size[0, 2] = TEX_CLIP
    assert shading.texture_lookup(data, start, size, 0, 1.5, 0.5) == (0.0, 0.0, 0.0)
    assert shading.texture_lookup(data, start, size, 0, 0.5, -0.2) == (0.0, 0.0, 0.0)
    # clip: the border texel blends toward black half a texel out
    got = shading.texture_lookup(data, start, size, 0, 0.0, 0.5 / h)
    assert got == pytest.approx(tuple(0.5 * img[0, 0]), abs=1e-7)
    size[0, 2] = TEX_CLIP | TEX_CLOSEST
    assert shading.texture_lookup(data, start, size, 0, 1.01, 0.5) == (0.0, 0.0, 0.0)


def test_texture_srgb_interpolates_before_decoding():
    """Cycles interpolates a byte sRGB image's encoded values, then decodes: half-way
    between a black and a white texel is decode(0.5) = 0.214, not 0.5."""
    data = np.array([[0.0] * 3, [1.0] * 3], np.float32)
    start = np.array([0, 2], np.int64)
    size = np.array([[2, 1, TEX_SRGB]], np.int32)
    got = shading.texture_lookup(data, start, size, 0, 0.5, 0.5)
    assert got[0] == pytest.approx(float(srgb_decode(0.5)), abs=1e-9)
    assert shading.texture_lookup(data, start, size, 0, 0.75, 0.5)[0] == pytest.approx(1.0)


def _corners(normals=None, uvs=None, m=2):
    """The packing of ``m`` triangles given per-corner ``normals`` / ``uvs`` (held as one
    CORNER-mode mesh: mesh 0, triangles 0..m-1)."""
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)
    s = Scene()
    s.add_material(Material("m"))
    s.add_mesh(Mesh("corners", verts, np.tile([[0, 1, 2]], (m, 1)), corner_normals=normals,
                    corner_uvs=uvs))
    s.add_instance(0, np.eye(4))
    sa = s.arrays()
    if normals is not None:
        assert sa.mesh_nrm[0, 0] == ATTR_CORNER
    return sa


def test_surface_uv_interpolates_corners():
    uvs = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]]], np.float32)
    assert shading.surface_uv(_corners(uvs=uvs, m=1), 0, 0, 0.25, 0.5) == pytest.approx(
        (0.25, 1.0))


def test_shading_normal_interpolation_and_fallback():
    nm = np.eye(3)
    normals = _corners(np.array([[[0, 0, 1], [1, 0, 0], [0, 1, 0]],
                                 [[0, 0, 1], [0, 0, -1], [0, 0, 0]]], np.float32))
    got = shading.shading_normal(normals, 0, nm, 0, 1 / 3, 1 / 3, 9.0, 9.0, 9.0)
    assert got == pytest.approx(tuple(unit((1, 1, 1))), abs=1e-7)
    # opposite corner normals cancel at the midpoint: fall back to the geometric normal
    g = tuple(unit((0.1, 0.2, 0.9)))
    assert shading.shading_normal(normals, 0, nm, 1, 0.5, 0.0, *g) == g
    # normals go through the normal matrix (inverse transpose of a non-uniform scale)
    m = np.diag([2.0, 1.0, 1.0])
    nmat = np.linalg.inv(m).T
    got = shading.shading_normal(normals, 0, nmat, 0, 1 / 3, 1 / 3, 0.0, 0.0, 1.0)
    assert got == pytest.approx(tuple(unit((0.5, 1, 1))), abs=1e-7)


def test_geometric_normal_keeps_outside_under_mirroring():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)
    tris = np.array([[0, 1, 2]], np.int32)
    assert shading.geometric_normal(verts, tris, np.eye(3), 0) == pytest.approx((0, 0, 1))
    mirror = np.diag([1.0, 1.0, -1.0])  # z -> -z: the outside (+z) maps to -z
    nmat = np.linalg.inv(mirror).T
    assert shading.geometric_normal(verts, tris, nmat, 0) == pytest.approx((0, 0, -1))


def test_spawn_offset_scales_with_magnitude():
    rel = tolerances.SPAWN_OFFSET_REL
    assert shading.spawn_offset(1e6, 0.0, 0.0, 10.0) == pytest.approx(rel * 1e6)
    assert shading.spawn_offset(0.0, -3e-4, 0.0, 1e-3) == pytest.approx(rel * 3e-4)
    # near the origin of a big scene the extent sets the floor
    floor = rel * 1e5 * tolerances.SPAWN_OFFSET_EXTENT_FRAC
    assert shading.spawn_offset(0.0, 0.0, 0.0, 1e5) == pytest.approx(floor)
