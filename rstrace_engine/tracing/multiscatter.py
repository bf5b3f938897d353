"""Multiple scattering of the GGX lobes, as Cycles' multiscatter GGX gives it back.

Single-scattering GGX loses the light that bounces between microfacets (a white rough metal
turns grey at roughness 1). Cycles' multiscatter GGX, Principled's default
(``microfacet_ggx_preserve_energy``), scales each layer by ``1 + Fms (1 - E) / E``: ``E`` the
lobe's albedo toward the viewer and ``Fms`` Kulla and Conty's multiple-bounce Fresnel from the
layer's average Fresnel. ``E`` and its average come from tables of the same grid Cycles reads
(:mod:`.ggx_tables`); :func:`multiscatter_factors` is what the shader and the glossy rays use.
"""

from __future__ import annotations

import math

from numba import njit

from .. import tolerances as tol
from .ggx_glass_tables import GLASS_E, Z_MAX
from .ggx_tables import GGX_E, GGX_E_AVG

#: Cycles' F82-tint model: the tint is taken at cos = 1/7 (about 82 degrees); these are
#: (1 - 1/7)^5 and 7 / (1 - 1/7)^6 (``fresnel_f82tint_B``).
F82_S5 = (6.0 / 7.0) ** 5
F82_SCALE = 7.0 / (6.0 / 7.0) ** 6


@njit(cache=True, nogil=True, inline="always")
def _table_at(x, n):
    """Index and weight of ``x`` in [0, 1] on a table of ``n`` points at ``i / (n - 1)``
    (Cycles' ``lookup_table_read``: clamped, linear)."""
    x = min(max(x, 0.0), 1.0) * (n - 1)
    i = min(int(x), n - 2)
    return i, x - i


@njit(cache=True, nogil=True)
def ggx_glass_albedo(cos_o, alpha, eta):
    """Single-scattering albedo ``E`` of a rough dielectric interface (GGX, reflection plus
    refraction) of roughness ``alpha`` seen at ``cos_o`` from the side whose index over the
    other's is ``eta`` (``eta < 1``: from air into glass): :data:`~.ggx_glass_tables.GLASS_E`
    read trilinearly at ``((k - 1) / (k + 1), sqrt(alpha), cos_o)``, ``k = max(eta, 1 /
    eta)`` (clamped to the table's 9), as Cycles reads its ``ggx_glass_E`` tables. The
    multiscatter glass lobe is the single-scattering one over ``E``
    (:func:`~.glass_albedo.ggx_glass_albedo_quadrature` computes the tables)."""
    side = 0 if eta <= 1.0 else 1
    k = eta if eta >= 1.0 else 1.0 / eta
    nz, nr, nc = GLASS_E.shape[1], GLASS_E.shape[2], GLASS_E.shape[3]
    i, s = _table_at((k - 1.0) / (k + 1.0) / Z_MAX, nz)
    j, u = _table_at(math.sqrt(max(alpha, 0.0)), nr)
    c, v = _table_at(cos_o, nc)
    e = 0.0
    for di in range(2):
        for dj in range(2):
            w = (s if di else 1.0 - s) * (u if dj else 1.0 - u)
            row = GLASS_E[side, i + di, j + dj]
            e += w * ((1.0 - v) * row[c] + v * row[c + 1])
    return e


@njit(cache=True, nogil=True)
def ggx_e(cos_o, alpha):
    """Single-scattering albedo of the GGX lobe (Fresnel 1) of roughness ``alpha`` seen at
    ``cos_o``: :data:`~.ggx_tables.GGX_E` read bilinearly at ``(sqrt(alpha), cos_o)``."""
    i, u = _table_at(math.sqrt(max(alpha, 0.0)), GGX_E.shape[0])
    j, v = _table_at(cos_o, GGX_E.shape[1])
    return ((1.0 - u) * ((1.0 - v) * GGX_E[i, j] + v * GGX_E[i, j + 1])
            + u * ((1.0 - v) * GGX_E[i + 1, j] + v * GGX_E[i + 1, j + 1]))


@njit(cache=True, nogil=True)
def ggx_e_avg(alpha):
    """The cosine-weighted average of :func:`ggx_e` over view directions."""
    i, u = _table_at(math.sqrt(max(alpha, 0.0)), GGX_E_AVG.shape[0])
    return (1.0 - u) * GGX_E_AVG[i] + u * GGX_E_AVG[i + 1]


@njit(cache=True, nogil=True, inline="always")
def _multiscatter(fss, k, e_avg):
    """``1 + Fms (1 - E) / E`` for a layer whose average single-scattering Fresnel is
    ``fss`` (``k = (1 - E) / E``): Kulla and Conty's multiple-bounce Fresnel
    ``Fms = Fss E_avg / (1 - Fss (1 - E_avg))``, as Cycles' multiscatter GGX applies it."""
    return 1.0 + fss * e_avg / (1.0 - fss * (1.0 - e_avg)) * k


@njit(cache=True, nogil=True)
def dielectric_fss(eta):
    """Average single-scattering Fresnel of a dielectric of relative index ``eta`` (the
    cosine-weighted mean of its reflectance): Kulla and Conty's fit, as Cycles uses it."""
    if eta < 1.0:
        return 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607))
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


@njit(cache=True, nogil=True)
def multiscatter_factors(alpha, e_white, eta_s, mr, mg, mb, tr, tg, tb):
    """The energy the GGX layers' single scattering loses, given back as Cycles'
    multiscatter GGX does (``microfacet_ggx_preserve_energy``): factors ``(zd, zr, zg, zb)``
    of the dielectric layer and of the metal's three channels, each ``1 + Fms (1 - E) / E``
    with ``E = e_white`` the albedo toward the viewer, ``Fms`` from the layer's average
    Fresnel (:func:`dielectric_fss` of index ``eta_s``; the metal's F82 average ``F0 + (1 -
    F0) / 21 - B / 126``, ``m*`` its colour, ``t*`` its tint). A white metal keeps all its
    energy (factor ``1 / E``); a coloured one less (the bounces between facets tint it)."""
    e = max(e_white, tol.GGX_ALBEDO_MIN)
    k = (1.0 - e) / e
    ea = ggx_e_avg(alpha)
    zd = _multiscatter(dielectric_fss(eta_s), k, ea) if eta_s != 1.0 else 1.0
    return (zd, _multiscatter(_f82_fss(mr, tr), k, ea), _multiscatter(_f82_fss(mg, tg), k, ea),
            _multiscatter(_f82_fss(mb, tb), k, ea))


@njit(cache=True, nogil=True, inline="always")
def _f82_fss(f0, tint):
    """Average single-scattering Fresnel of :func:`f82_metal` (Cycles' ``fresnel_f82_Fss``):
    Schlick's ``F0 + (1 - F0) / 21`` less ``B / 126``."""
    b = 0.0 if tint == 1.0 else (f0 + (1.0 - f0) * F82_S5) * F82_SCALE * (1.0 - tint)
    return f0 + (1.0 - f0) / 21.0 - b / 126.0


