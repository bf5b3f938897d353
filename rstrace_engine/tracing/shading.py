"""Shading math for the Whitted tracer: numba device functions over scalars.

Everything here is a small ``@njit`` function that the tracer's kernels call per ray; vectors
are passed and returned as separate float64 components (no per-ray array allocation).
Conventions:

* ``d`` is a ray direction (unit, pointing *away* from the eye), ``n`` a unit normal.
* Direction arguments of the BRDF both point *away* from the surface: ``wi`` toward the
  light, ``wo`` toward the viewer.
* ``eta`` is the ratio ``n1 / n2`` of the indices of refraction on the incident and the
  transmitted side.

Ward isotropic BRDF (Ward 1992, the normalisation used by Radiance)::

    f = rho_d / pi + rho_s * exp(-tan^2(delta) / alpha^2) / (4 pi alpha^2 sqrt(cos_i cos_o))

with ``delta`` the angle between the normal and the half vector. Its peak, at the mirror
direction of ``wo`` (``delta = 0``), is ``rho_d / pi + rho_s / (4 pi alpha^2 cos_o)``.

Principled-like model (the default for Blender materials, close to Cycles' Principled BSDF
in direct light): a Lambertian base under a GGX layer whose Fresnel is exact for the
dielectric part and Schlick for the metallic part; the base is scaled by one minus the
layer's directional albedo (see :func:`principled_brdf`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.attributes import corner_normals, corner_uvs
from ..geometry.elements import (
    MODEL_PRINCIPLED,
    TEX_CLIP,
    TEX_CLOSEST,
    TEX_EXTEND,
    TEX_GENERATED,
    TEX_OBJECT,
    TEX_SRGB,
    TEX_TRANSMISSION_SQRT,
)
from .multiscatter import (  # noqa: F401  (re-exported: the GGX albedo's home)
    F82_S5,
    F82_SCALE,
    dielectric_fss,
    ggx_e,
    ggx_e_avg,
    ggx_glass_albedo,
    multiscatter_factors,
)

INV_PI = 1.0 / math.pi


@njit(cache=True, nogil=True)
def dot3(ax, ay, az, bx, by, bz):
    """Dot product of two 3-vectors given as components."""
    return ax * bx + ay * by + az * bz


@njit(cache=True, nogil=True)
def normalize3(x, y, z):
    """``(x, y, z) / |(x, y, z)|`` and the length (zero vector: returned unchanged, length 0)."""
    ln = math.sqrt(x * x + y * y + z * z)
    if ln > 0.0:
        return x / ln, y / ln, z / ln, ln
    return x, y, z, 0.0


# ----------------------------------------------------------------------------- BRDF


@njit(cache=True, nogil=True)
def ward_specular(nx, ny, nz, ix, iy, iz, ox, oy, oz, alpha):
    """Ward isotropic specular lobe (without ``rho_s``), sr^-1.

    ``n`` unit normal, ``wi`` (toward the light) and ``wo`` (toward the viewer) unit, all
    on the same side. Returns 0 when either direction is below the surface.
    """
    ci = nx * ix + ny * iy + nz * iz
    co = nx * ox + ny * oy + nz * oz
    if ci <= 0.0 or co <= 0.0:
        return 0.0
    hx = ix + ox
    hy = iy + oy
    hz = iz + oz
    hn = nx * hx + ny * hy + nz * hz
    if hn <= 0.0:
        return 0.0
    h2 = hx * hx + hy * hy + hz * hz
    tan2 = max(h2 - hn * hn, 0.0) / (hn * hn)  # tan^2(delta), h need not be unit
    a2 = alpha * alpha
    return math.exp(-tan2 / a2) / (4.0 * math.pi * a2 * math.sqrt(ci * co))


@njit(cache=True, nogil=True)
def ward_brdf(nx, ny, nz, ix, iy, iz, ox, oy, oz, dr, dg, db, sr, sg, sb, alpha):
    """Full Ward isotropic BRDF value ``(r, g, b)`` for diffuse ``d*`` and specular ``s*``."""
    spec = 0.0
    if sr > 0.0 or sg > 0.0 or sb > 0.0:
        spec = ward_specular(nx, ny, nz, ix, iy, iz, ox, oy, oz, alpha)
    return (dr * INV_PI + sr * spec, dg * INV_PI + sg * spec, db * INV_PI + sb * spec)


# ----------------------------------------------------------------------------- Principled-like


@njit(cache=True, nogil=True)
def ggx_lambda(cos_t, a2):
    """Smith's Lambda of GGX for a direction at ``cos_t`` from the normal (``a2 = alpha^2``)."""
    c2 = cos_t * cos_t
    if c2 <= 0.0:
        return 0.0
    tan2 = max(1.0 - c2, 0.0) / c2
    return 0.5 * (math.sqrt(1.0 + a2 * tan2) - 1.0)


@njit(cache=True, nogil=True)
def ggx_lobe(nx, ny, nz, ix, iy, iz, ox, oy, oz, alpha):
    """GGX microfacet lobe without its Fresnel factor, and the cosine it is evaluated at.

    Returns ``(D G2 / (4 cos_i cos_o), wi . h)`` with Trowbridge-Reitz ``D`` and the
    height-correlated Smith ``G2 = 1 / (1 + Lambda(wi) + Lambda(wo))`` (what Cycles uses);
    ``(0, 1)`` when either direction is below the surface.
    """
    ci = nx * ix + ny * iy + nz * iz
    co = nx * ox + ny * oy + nz * oz
    if ci <= 0.0 or co <= 0.0:
        return 0.0, 1.0
    hx, hy, hz, hl = normalize3(ix + ox, iy + oy, iz + oz)
    if hl <= 0.0:
        return 0.0, 1.0
    ch = nx * hx + ny * hy + nz * hz
    if ch <= 0.0:
        return 0.0, 1.0
    a2 = alpha * alpha
    t = ch * ch * (a2 - 1.0) + 1.0
    dist = a2 / (math.pi * t * t)
    g2 = 1.0 / (1.0 + ggx_lambda(ci, a2) + ggx_lambda(co, a2))
    return dist * g2 / (4.0 * ci * co), max(ix * hx + iy * hy + iz * hz, 0.0)


#: Stratified samples of the microfacet normal (cos theta_h, phi over a half circle: the
#: integrand is symmetric about the plane of the normal and the viewer) in
#: :func:`ggx_albedo`. 8 x 4 keeps the dielectric albedo within 0.005 of a 32 x 16 estimate
#: and the white albedo within 5% (tests/test_principled.py).
ALBEDO_SAMPLES_THETA = 8
ALBEDO_SAMPLES_PHI = 4


@njit(cache=True, nogil=True)
def ggx_albedo(cos_o, alpha, eta_s):
    """Directional albedos ``(E_white, E_dielectric)`` of the GGX lobe seen from ``cos_o``.

    ``E_white``: with Fresnel 1 (the energy single scattering keeps), read from the table
    (:func:`ggx_e`, as Cycles reads its own); ``E_dielectric``: with the exact dielectric
    Fresnel of index ``eta_s`` (0 when ``eta_s`` is 1), a deterministic quadrature over
    microfacet normals drawn from ``D cos_h`` (stratified, see ``ALBEDO_SAMPLES_*``): the
    estimator ``G2 (wo . h) / (cos_h cos_o)`` is smooth, so few samples do.
    """
    co = min(max(cos_o, tol.GGX_COS_MIN), 1.0)
    a2 = alpha * alpha
    so = math.sqrt(max(0.0, 1.0 - co * co))
    lo = ggx_lambda(co, a2)
    ed = 0.0
    if eta_s == 1.0:
        return ggx_e(co, alpha), 0.0
    nu = ALBEDO_SAMPLES_THETA
    nphi = ALBEDO_SAMPLES_PHI
    for i in range(nu):
        u = (i + 0.5) / nu
        ct = math.sqrt((1.0 - u) / (1.0 + (a2 - 1.0) * u))
        st = math.sqrt(max(0.0, 1.0 - ct * ct))
        for j in range(nphi):
            voh = co * ct + so * st * math.cos(math.pi * (j + 0.5) / nphi)
            if voh <= 0.0:
                continue
            nol = 2.0 * voh * ct - co
            if nol <= 0.0:
                continue
            w = voh / ((1.0 + ggx_lambda(nol, a2) + lo) * ct * co)
            ed += w * fresnel_dielectric(voh, 1.0 / eta_s)
    n = nu * nphi
    return ggx_e(co, alpha), min(ed / n, 1.0)


@njit(cache=True, nogil=True)
def f82_metal(c, f0, tint):
    """One channel of Cycles' F82-tint conductor Fresnel at cosine ``c``: Schlick's
    ``F0 + (1 - F0)(1 - c)^5`` less ``B c (1 - c)^6``, ``B`` chosen so that at ``c = 1/7``
    it is Schlick's value times ``tint`` (``fresnel_f82tint_B``, ``fresnel_f82``), clamped
    to [0, 1]. A white tint is Schlick's curve exactly."""
    x = 1.0 - min(max(c, 0.0), 1.0)
    x5 = x * x * x * x * x
    f = f0 + (1.0 - f0) * x5
    if tint == 1.0:
        return f
    b = (f0 + (1.0 - f0) * F82_S5) * F82_SCALE * (1.0 - tint)
    return min(max(f - b * (1.0 - x) * x5 * x, 0.0), 1.0)


@njit(cache=True, nogil=True)
def principled_fresnel(c, sr, sg, sb, eta_s, metallic, mr, mg, mb, tr=1.0, tg=1.0, tb=1.0,
                       zr=1.0, zg=1.0, zb=1.0):
    """Reflectance ``(r, g, b)`` of the Principled-like specular layer at cosine ``c``.

    ``s*`` the dielectric layer's weight times its tint with the exact dielectric Fresnel of
    index ``eta_s`` (none when ``eta_s`` is 1); ``metallic`` the conductor's weight and
    ``m*`` its colour at normal incidence, ``t*`` its F82 tint (Cycles 4+: the Principled
    BSDF's Specular Tint, a Metallic BSDF's Edge Tint; :func:`f82_metal`: white is
    Schlick's curve to white at grazing angles), ``z*`` factors of the metal's channels (its
    multiple scattering, :func:`multiscatter_factors`).
    """
    fd = 0.0
    if eta_s != 1.0:
        fd = fresnel_dielectric(c, 1.0 / eta_s)
    if metallic == 0.0:  # no conductor: its terms are (+)0 (F82 and z* are not negative)
        return sr * fd + 0.0, sg * fd + 0.0, sb * fd + 0.0
    return (sr * fd + metallic * zr * f82_metal(c, mr, tr),
            sg * fd + metallic * zg * f82_metal(c, mg, tg),
            sb * fd + metallic * zb * f82_metal(c, mb, tb))


@njit(cache=True, nogil=True)
def principled_brdf(nx, ny, nz, ix, iy, iz, ox, oy, oz, dr, dg, db, sr, sg, sb, eta_s,
                    metallic, mr, mg, mb, alpha, e_white, e_diel, tr=1.0, tg=1.0, tb=1.0):
    """Principled-like BRDF value ``(r, g, b)``: Lambertian diffuse under a GGX layer.

    ``d*`` the diffuse albedo, scaled by ``1 - e_diel``, one minus the dielectric layer's
    albedo toward the viewer (the energy the layer reflects never reaches the base, as in
    Cycles' layering); the GGX lobe (:func:`ggx_lobe`) carries the Fresnel of
    :func:`principled_fresnel` at ``wi . h`` and each layer's multiple-scattering factor
    (:func:`multiscatter_factors`, Cycles' multiscatter GGX: rough metals keep their
    energy). ``e_white, e_diel`` come from :func:`ggx_albedo` for the viewer. No
    lobe below ``tolerances.GLOSSY_ALPHA_MIN``: a (near) mirror reflects through mirror rays.
    """
    zd = zr = zg = zb = 0.0  # (no lobe: not read)
    if alpha >= tol.GLOSSY_ALPHA_MIN and (sr > 0.0 or sg > 0.0 or sb > 0.0 or metallic > 0.0):
        zd, zr, zg, zb = multiscatter_factors(alpha, e_white, eta_s, mr, mg, mb, tr, tg, tb)
    return principled_brdf_z(nx, ny, nz, ix, iy, iz, ox, oy, oz, dr, dg, db, sr, sg, sb, eta_s,
                             metallic, mr, mg, mb, alpha, e_diel, tr, tg, tb, zd, zr, zg, zb)


@njit(cache=True, nogil=True)
def principled_brdf_z(nx, ny, nz, ix, iy, iz, ox, oy, oz, dr, dg, db, sr, sg, sb, eta_s,
                      metallic, mr, mg, mb, alpha, e_diel, tr, tg, tb, zd, zr, zg, zb):
    """:func:`principled_brdf` (the same values) with the point's
    :func:`multiscatter_factors` ``z*`` given: a point's lights and samples share them."""
    kd = (1.0 - e_diel) * INV_PI
    r = dr * kd
    g = dg * kd
    bl = db * kd
    if alpha < tol.GLOSSY_ALPHA_MIN or not (sr > 0.0 or sg > 0.0 or sb > 0.0
                                            or metallic > 0.0):
        return r, g, bl
    lobe, ch = ggx_lobe(nx, ny, nz, ix, iy, iz, ox, oy, oz, alpha)
    if lobe <= 0.0:
        return r, g, bl
    fr, fg, fb = principled_fresnel(ch, sr * zd, sg * zd, sb * zd, eta_s, metallic, mr, mg, mb,
                                    tr, tg, tb, zr, zg, zb)
    return r + lobe * fr, g + lobe * fg, bl + lobe * fb


# ----------------------------------------------------------------------------- mirror / glass


@njit(cache=True, nogil=True)
def reflect(dx, dy, dz, nx, ny, nz):
    """Mirror direction of ``d`` about the unit normal ``n``: ``d - 2 (d.n) n``."""
    k = 2.0 * (dx * nx + dy * ny + dz * nz)
    return dx - k * nx, dy - k * ny, dz - k * nz


@njit(cache=True, nogil=True)
def refract(dx, dy, dz, nx, ny, nz, eta):
    """Snell refraction of unit ``d`` through a surface with unit normal ``n`` facing ``-d``.

    Returns ``(ok, tx, ty, tz)``; ``ok`` is False on total internal reflection (then ``t``
    is zero). ``t`` is unit: ``t = eta d + (eta cos_i - cos_t) n``.
    """
    cos_i = -(dx * nx + dy * ny + dz * nz)
    sin2_t = eta * eta * max(0.0, 1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return False, 0.0, 0.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    k = eta * cos_i - cos_t
    tx = eta * dx + k * nx
    ty = eta * dy + k * ny
    tz = eta * dz + k * nz
    tx, ty, tz, _ = normalize3(tx, ty, tz)
    return True, tx, ty, tz


@njit(cache=True, nogil=True)
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric interface (1 on total reflection).

    ``cos_i`` cosine of the incidence angle (>= 0), ``eta = n1 / n2``. At normal incidence
    this is ``((n2 - n1) / (n2 + n1))**2``.
    """
    cos_i = min(max(cos_i, 0.0), 1.0)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (rs * rs + rp * rp)


# ----------------------------------------------------------------------------- lights


@njit(cache=True, nogil=True)
def smoothstep(x):
    """Hermite smoothstep of ``x`` clamped to [0, 1]: ``3x^2 - 2x^3``."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, nogil=True)
def spot_falloff(cos_angle, cos_outer, cos_inner):
    """Spot light falloff for a direction at ``cos_angle`` from the spot axis.

    0 outside the cone (``cos_angle <= cos_outer``), 1 inside the inner cone, and a
    smoothstep across the blend region between them, as Blender does. ``cos_inner`` comes
    from :class:`~.geometry.scene.SceneArrays` (equal to ``cos_outer`` when blend is 0).
    """
    if cos_angle <= cos_outer:
        return 0.0
    span = cos_inner - cos_outer
    if span <= 0.0 or cos_angle >= cos_inner:
        return 1.0
    return smoothstep((cos_angle - cos_outer) / span)


# ----------------------------------------------------------------------------- surfaces


@njit(cache=True, nogil=True)
def geometric_normal(verts, tris, nmat, tri):
    """Unit world-space geometric normal of global triangle ``tri`` (winding order).

    verts : (V, 3) float64 object space; tris : (T, 3) int32; nmat : (3, 3) float64 normal
    matrix of the instance (inverse transpose, so mirrored instances keep their outside).
    """
    a = tris[tri, 0]
    b = tris[tri, 1]
    c = tris[tri, 2]
    e1x = verts[b, 0] - verts[a, 0]
    e1y = verts[b, 1] - verts[a, 1]
    e1z = verts[b, 2] - verts[a, 2]
    e2x = verts[c, 0] - verts[a, 0]
    e2y = verts[c, 1] - verts[a, 1]
    e2z = verts[c, 2] - verts[a, 2]
    cx = e1y * e2z - e1z * e2y
    cy = e1z * e2x - e1x * e2z
    cz = e1x * e2y - e1y * e2x
    wx = nmat[0, 0] * cx + nmat[0, 1] * cy + nmat[0, 2] * cz
    wy = nmat[1, 0] * cx + nmat[1, 1] * cy + nmat[1, 2] * cz
    wz = nmat[2, 0] * cx + nmat[2, 1] * cy + nmat[2, 2] * cz
    wx, wy, wz, _ = normalize3(wx, wy, wz)
    return wx, wy, wz


@njit(cache=True, nogil=True)
def shading_normal(s, k, nmat, tri, b1, b2, gx, gy, gz):
    """Interpolated unit world-space shading normal at barycentrics ``(b1, b2)`` of global
    triangle ``tri`` of mesh ``k``.

    ``s``: a struct with the packing's ``normals``, ``mesh_nrm``, ``verts`` and ``tris``
    (the corners' float32 object-space normals, :func:`~..geometry.attributes.corner_normals`).
    Falls back to the geometric normal ``g`` when the interpolated normal is (near) zero.
    """
    n = corner_normals(s, k, tri)
    b0 = 1.0 - b1 - b2
    ox = b0 * n[0] + b1 * n[3] + b2 * n[6]
    oy = b0 * n[1] + b1 * n[4] + b2 * n[7]
    oz = b0 * n[2] + b1 * n[5] + b2 * n[8]
    wx = nmat[0, 0] * ox + nmat[0, 1] * oy + nmat[0, 2] * oz
    wy = nmat[1, 0] * ox + nmat[1, 1] * oy + nmat[1, 2] * oz
    wz = nmat[2, 0] * ox + nmat[2, 1] * oy + nmat[2, 2] * oz
    wx, wy, wz, ln = normalize3(wx, wy, wz)
    if not ln > tol.NORMAL_MIN_LENGTH:  # also catches NaN
        return gx, gy, gz
    return wx, wy, wz


@njit(cache=True, nogil=True)
def surface_uv(s, k, tri, b1, b2):
    """Texture coordinates ``(u, v)`` of global triangle ``tri`` of mesh ``k`` interpolated
    from its corners' float32 uvs (``s``: a struct with ``uvs``, ``mesh_uv`` and ``tris``,
    :func:`~..geometry.attributes.corner_uvs`)."""
    c = corner_uvs(s, k, tri)
    b0 = 1.0 - b1 - b2
    u = b0 * c[0] + b1 * c[2] + b2 * c[4]
    v = b0 * c[1] + b1 * c[3] + b2 * c[5]
    return u, v


@njit(cache=True, nogil=True)
def texture_uv(sa, tex, tri, b1, b2):
    """The image coordinates ``(u, v)`` of texture ``tex`` at barycentrics ``(b1, b2)`` of
    global triangle ``tri``: the coordinates its ``TEX_*`` flags name (the mesh uvs as
    ``(u, v, 0)``; the object-space position, interpolated from the triangle's vertices,
    exact on a flat triangle; or that position in the mesh's automatic texture space,
    ``sa.mesh_gen``), through the affine ``sa.tex_map[tex]`` (Mapping nodes)."""
    flags = sa.tex_size[tex, 2]
    if flags & (TEX_OBJECT | TEX_GENERATED):
        b0 = 1.0 - b1 - b2
        a = sa.tris[tri, 0]
        b = sa.tris[tri, 1]
        c = sa.tris[tri, 2]
        x = b0 * sa.verts[a, 0] + b1 * sa.verts[b, 0] + b2 * sa.verts[c, 0]
        y = b0 * sa.verts[a, 1] + b1 * sa.verts[b, 1] + b2 * sa.verts[c, 1]
        z = b0 * sa.verts[a, 2] + b1 * sa.verts[b, 2] + b2 * sa.verts[c, 2]
        if flags & TEX_GENERATED:
            k = np.searchsorted(sa.mesh_tri_start, tri, side="right") - 1
            x = (x - sa.mesh_gen[k, 0, 0]) / sa.mesh_gen[k, 1, 0]
            y = (y - sa.mesh_gen[k, 0, 1]) / sa.mesh_gen[k, 1, 1]
            z = (z - sa.mesh_gen[k, 0, 2]) / sa.mesh_gen[k, 1, 2]
    else:
        k = np.searchsorted(sa.mesh_tri_start, tri, side="right") - 1
        x, y = surface_uv(sa, k, tri, b1, b2)
        z = 0.0
    m = sa.tex_map[tex]
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3],
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3])


@njit(cache=True, nogil=True)
def _texel_index(x, n, flags):
    """Texel index along an axis of ``n`` texels for the float index ``x`` (floored), by
    the texture's extension: Repeat wraps, Extend clamps, Clip gives -1 outside."""
    if flags & TEX_CLIP:
        if x < 0.0 or x >= n:
            return -1
        return int(x)
    if flags & TEX_EXTEND:
        return int(min(max(x, 0.0), n - 1.0))
    i = int(x - n * math.floor(x / n))  # wrapped in float: no overflow for huge x
    return min(max(i, 0), n - 1)


@njit(cache=True, nogil=True)
def _srgb_decode(c):
    """One sRGB-encoded value in [0, 1] -> linear (IEC 61966-2-1)."""
    c = min(max(c, 0.0), 1.0)
    if c <= 0.04045:
        return c / 12.92
    return ((c + 0.055) / 1.055) ** 2.4


@njit(cache=True, nogil=True)
def texture_lookup(tex_data, tex_start, tex_size, tex, u, v):
    """Lookup of texture ``tex`` at ``(u, v)`` as Cycles' Image Texture does; ``(r, g, b)``.

    tex_data : (X, 3) float32 texels, textures concatenated row-major, row 0 at ``v = 0``
    (bottom, as Blender stores images); tex_start : (NT + 1,) int64; tex_size : (NT, 3)
    int32 (width, height, ``TEX_*`` flags of :mod:`~rstrace_engine.geometry.elements`).
    Texel centres sit at ``((i + 0.5) / w, (j + 0.5) / h)``. Bilinear, or the texel holding
    ``(u, v)`` (``TEX_CLOSEST``); repeating, clamped (``TEX_EXTEND``) or black outside the
    unit square (``TEX_CLIP``, bilinear blends the border toward black); sRGB-encoded texels
    (``TEX_SRGB``) are decoded after interpolation, as Cycles does for byte images.
    """
    w = tex_size[tex, 0]
    h = tex_size[tex, 1]
    flags = tex_size[tex, 2]
    base = tex_start[tex]
    if not (math.isfinite(u) and math.isfinite(v)):
        u = 0.0
        v = 0.0
    if flags & TEX_CLOSEST:
        x0 = _texel_index(math.floor(u * w), w, flags)
        y0 = _texel_index(math.floor(v * h), h, flags)
        x1 = y1 = -1
        fx = fy = 0.0
    else:
        x = u * w - 0.5
        y = v * h - 0.5
        fx0 = math.floor(x)
        fy0 = math.floor(y)
        fx = x - fx0
        fy = y - fy0
        x0 = _texel_index(fx0, w, flags)
        y0 = _texel_index(fy0, h, flags)
        x1 = _texel_index(fx0 + 1.0, w, flags)
        y1 = _texel_index(fy0 + 1.0, h, flags)
    r = 0.0
    g = 0.0
    b = 0.0
    for k in range(4):
        xi = x0 if k % 2 == 0 else x1
        yi = y0 if k < 2 else y1
        wk = (1.0 - fx if k % 2 == 0 else fx) * (1.0 - fy if k < 2 else fy)
        if xi < 0 or yi < 0 or wk == 0.0:
            continue
        i = base + yi * w + xi
        r += wk * tex_data[i, 0]
        g += wk * tex_data[i, 1]
        b += wk * tex_data[i, 2]
    if flags & TEX_SRGB:
        return _srgb_decode(r), _srgb_decode(g), _srgb_decode(b)
    return r, g, b


@njit(cache=True, nogil=True, inline="always")
def texel_weight(flags, bits, r, g, b, xr, xg, xb):
    """A material's weight ``(r, g, b)`` at a hit whose texel is ``(xr, xg, xb)``: times the
    texel where the texture's ``flags`` have one of ``bits`` (``TEX_TRANSMISSION_SQRT``:
    times its square root, the Principled BSDF's transmission tint per crossing); as it is
    where they have none (no texture: ``flags`` 0)."""
    if not flags & bits:
        return r, g, b
    if flags & bits & TEX_TRANSMISSION_SQRT:
        return (r * math.sqrt(max(xr, 0.0)), g * math.sqrt(max(xg, 0.0)),
                b * math.sqrt(max(xb, 0.0)))
    return r * xr, g * xg, b * xb


@njit(cache=True, nogil=True)
def spawn_offset(px, py, pz, scene_extent):
    """Self-intersection offset at point ``p``: scales with the coordinate magnitude.

    ``SPAWN_OFFSET_REL * max(|p|_inf, scene_extent * SPAWN_OFFSET_EXTENT_FRAC)`` (see
    :mod:`.tolerances`).
    """
    m = max(abs(px), abs(py), abs(pz), scene_extent * tol.SPAWN_OFFSET_EXTENT_FRAC)
    return tol.SPAWN_OFFSET_REL * m


# ----------------------------------------------------------------------------- glossy rays


@njit(cache=True, nogil=True)
def onb(ax, ay, az):
    """Two unit vectors completing unit ``a`` to an orthonormal basis (Duff et al. 2017)."""
    sign = 1.0 if az >= 0.0 else -1.0
    a = -1.0 / (sign + az)
    b = ax * ay * a
    return (1.0 + sign * ax * ax * a, sign * b, -sign * ax,
            b, sign + ay * ay * a, -ay)


@njit(cache=True, nogil=True)
def rough_interface(sa, m):
    """Whether material ``m`` is a rough dielectric interface (a Principled-like material at
    GGX alpha ``>= tolerances.GLOSSY_ALPHA_MIN`` with transmission and an IOR other than 1):
    light on the far side of its surface reaches the viewer through its transmission lobe
    (:func:`ggx_btdf`), so its shadow rays may leave through the far side."""
    if m < 0:  # branch-free past this, as glossy_rays.is_glossy (~350 ns a call else)
        return False
    return ((sa.mat_model[m] == MODEL_PRINCIPLED)
            & (not sa.mat_roughness[m] < tol.GLOSSY_ALPHA_MIN) & (sa.mat_ior[m] != 1.0)
            & ((sa.mat_transmission[m, 0] > 0.0) | (sa.mat_transmission[m, 1] > 0.0)
               | (sa.mat_transmission[m, 2] > 0.0)))


@njit(cache=True, nogil=True, inline="always")
def far_origin(sa, px, py, pz, gx, gy, gz):
    """The shadow-ray origin on the far side of a surface point ``p`` (``g`` its geometric
    normal turned toward the viewer): ``p`` moved off the surface by the spawn offset, as
    the refracted rays leave it."""
    off = spawn_offset(px, py, pz, sa.scene_extent)
    return px - gx * off, py - gy * off, pz - gz * off


@njit(cache=True, nogil=True)
def ggx_btdf(sx, sy, sz, lx, ly, lz, ox, oy, oz, alpha, eta):
    """GGX microfacet refraction (Walter et al. 2007) from light direction ``l`` on the far
    side of the surface to the view direction ``o`` (both unit, pointing away from the
    surface; ``s`` the normal on the viewer's side), ``eta = n_view / n_far``::

        f = |o.h| |l.h| (1 - F(|o.h|)) D(h) G2 / (|s.o| |s.l| |o + l / eta|^2) / eta^2

    with ``h`` the normalised ``o + l / eta``, ``F`` the dielectric Fresnel seen from the
    viewer and the height-correlated Smith ``G2``: Cycles' ``bsdf_microfacet_eval`` of a
    refraction (its ``bsdf->ior`` is ``1 / eta``), whose ``f cos / pdf`` is the glossy
    rays' refraction weight ``(1 - F) G2 / G1``. No radiance scaling by ``eta^2`` (Cycles
    has none). 0 where ``l`` is not below the surface.

    As Cycles' evaluation, this does not check that the pair is a refraction through some
    microfacet (``o`` and ``l`` on opposite sides of ``h``: ``o . l < -min(eta, 1 /
    eta)``, within the critical cone); Cycles' source leaves that check as a TODO, so its
    rough glass passes light (through next-event estimation) for pairs no microfacet
    refracts, and so does this (docs/glossy.md, "The rim of rough glass": measured, a rough
    glass ball lit from outside and seen through it is a third as bright as Cycles' with
    the check)."""
    co = dot3(sx, sy, sz, ox, oy, oz)
    cl = dot3(sx, sy, sz, lx, ly, lz)
    if co <= 0.0 or cl >= 0.0 or eta == 1.0:
        return 0.0
    k = 1.0 / eta  # n_far / n_view
    hx, hy, hz, hl = normalize3(ox + k * lx, oy + k * ly, oz + k * lz)
    if not hl > 0.0:
        return 0.0
    ch = abs(dot3(sx, sy, sz, hx, hy, hz))
    oh = abs(dot3(ox, oy, oz, hx, hy, hz))
    lh = abs(dot3(lx, ly, lz, hx, hy, hz))
    a2 = alpha * alpha
    t = ch * ch * (a2 - 1.0) + 1.0
    dist = a2 / (math.pi * t * t)
    g2 = 1.0 / (1.0 + ggx_lambda(co, a2) + ggx_lambda(-cl, a2))
    f = 1.0 - fresnel_dielectric(oh, eta)
    return oh * lh * k * k * f * dist * g2 / (co * (-cl) * hl * hl)


@njit(cache=True, nogil=True)
def transmit(dx, dy, dz, sx, sy, sz, gx, gy, gz, eta):
    """Refraction of unit ``d`` at shading and geometric normals ``s``, ``g`` turned toward
    it, as the tracer refracts a smooth surface: about ``s`` (about ``g`` where ``s`` faces
    away from ``d``, or where refracting about ``s`` would send the ray back out). Returns
    ``(ok, tx, ty, tz, fresnel)``: ``ok`` False on total internal reflection (fresnel 1)."""
    nx, ny, nz = sx, sy, sz
    if dot3(dx, dy, dz, nx, ny, nz) >= 0.0:
        nx, ny, nz = gx, gy, gz
    ok, tx, ty, tz = refract(dx, dy, dz, nx, ny, nz, eta)
    if ok and dot3(tx, ty, tz, gx, gy, gz) >= 0.0:
        # the shading normal would send the ray back out: refract about g instead
        nx, ny, nz = gx, gy, gz
        ok, tx, ty, tz = refract(dx, dy, dz, nx, ny, nz, eta)
    f = fresnel_dielectric(-dot3(dx, dy, dz, nx, ny, nz), eta) if ok else 1.0
    return ok, tx, ty, tz, f


@njit(cache=True, nogil=True)
def mirror_dir(dx, dy, dz, sx, sy, sz, gx, gy, gz):
    """Mirror reflection of ``d`` about the shading normal ``s``, about the geometric
    normal ``g`` where that would go below the surface."""
    qx, qy, qz = reflect(dx, dy, dz, sx, sy, sz)
    if dot3(qx, qy, qz, gx, gy, gz) <= 0.0:
        qx, qy, qz = reflect(dx, dy, dz, gx, gy, gz)
    return qx, qy, qz
