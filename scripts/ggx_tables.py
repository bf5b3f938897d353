"""Write ``rstrace_engine/tracing/ggx_tables.py``: the GGX lobe's single-scattering albedo
``E(roughness, cos_o)`` (32 x 32) and its cosine-weighted average ``E_avg(roughness)`` (32),
on the grid Cycles' multiscatter GGX reads its own tables on (``roughness = sqrt(alpha)`` and
``cos_o`` each at ``i / 31``, read with linear interpolation), computed here by quadrature.

    python scripts/ggx_tables.py            # writes the module (about a minute)
    python scripts/ggx_tables.py --check    # compares the module with a fresh computation

``E(cos_o) = integral of D G2 / (4 cos_o) over reflected directions`` (Fresnel 1), written as
an integral over microfacet normals drawn from ``D cos_h`` (inverse CDF in ``u``, azimuth
``phi``): ``E = mean of G2 (o . h) / (cos_h cos_o)`` over reflections above the surface. The
midpoint rule on a 1024 x 512 grid in ``(u, phi)``, float64; ``cos_o = 0`` is taken at
``tolerances.GGX_COS_MIN`` (the shader's own clamp); roughness 0 is a mirror (``E = 1``).
``E_avg = 2 * integral of E(mu) mu dmu`` by the midpoint rule over 128 values of ``mu``.
``tests/test_glossy.py`` checks the module against an independent estimate (directions
drawn over the hemisphere, not normals).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rstrace_engine import tolerances as tol  # noqa: E402

N = 32
OUT = ROOT / "rstrace_engine" / "tracing" / "ggx_tables.py"


def _lambda(c, a2):
    c = np.maximum(c, 1e-300)
    return 0.5 * (np.sqrt(1.0 + a2 * np.maximum(1.0 / (c * c) - 1.0, 0.0)) - 1.0)


def albedo(mu: float, alpha: float, nu: int = 1024, nphi: int = 512) -> float:
    """E(mu) of the GGX lobe of roughness ``alpha`` (Fresnel 1)."""
    if alpha <= 0.0:
        return 1.0
    mu = max(mu, tol.GGX_COS_MIN)
    a2 = alpha * alpha
    u = (np.arange(nu) + 0.5) / nu
    ct = np.sqrt((1.0 - u) / (1.0 + (a2 - 1.0) * u))[:, None]
    st = np.sqrt(np.maximum(0.0, 1.0 - ct * ct))
    cphi = np.cos(np.pi * (np.arange(nphi) + 0.5) / nphi)[None, :]  # phi in (0, pi): symmetric
    so = np.sqrt(1.0 - mu * mu)
    voh = mu * ct + so * st * cphi
    nol = 2.0 * voh * ct - mu
    ok = (voh > 0.0) & (nol > 0.0)
    g2 = 1.0 / (1.0 + _lambda(np.where(ok, nol, 1.0), a2) + _lambda(mu, a2))
    return float(np.where(ok, voh * g2 / (ct * mu), 0.0).mean())


def tables() -> tuple[np.ndarray, np.ndarray]:
    e = np.empty((N, N))
    e_avg = np.empty(N)
    mus = (np.arange(128) + 0.5) / 128
    for i in range(N):
        alpha = (i / (N - 1)) ** 2
        for j in range(N):
            e[i, j] = albedo(j / (N - 1), alpha)
        e_avg[i] = 2.0 * np.mean([albedo(m, alpha, 512, 256) * m for m in mus])
    return e, e_avg


def _rows(a: np.ndarray) -> str:
    """Rows of ``a`` as tuple lines, eight numbers a line."""
    lines = []
    for row in a:
        nums = [f"{x:.6f}" for x in row]
        chunks = [", ".join(nums[k:k + 8]) for k in range(0, len(nums), 8)]
        lines.append("    (" + ",\n     ".join(chunks) + "),")
    return "\n".join(lines)


def _flat(a: np.ndarray) -> str:
    nums = [f"{x:.6f}" for x in a]
    return ",\n".join("    " + ", ".join(nums[k:k + 8]) for k in range(0, len(nums), 8))


def write(e: np.ndarray, e_avg: np.ndarray) -> None:
    OUT.write_text(f'''"""GGX single-scattering albedo tables, written by ``scripts/ggx_tables.py``.

``GGX_E[i, j]``: the albedo of the GGX lobe (Fresnel 1) of roughness ``i / {N - 1}`` (``alpha =
roughness ** 2``) seen at ``cos_o = j / {N - 1}``; ``GGX_E_AVG[i]``: its cosine-weighted average
over ``cos_o``. Cycles' multiscatter GGX reads tables of the same function on the same grid
(``microfacet_ggx_preserve_energy``); :func:`~.multiscatter.ggx_e` and
:func:`~.multiscatter.ggx_e_avg` read these with linear interpolation.
"""

import numpy as np

GGX_E = np.array((
{_rows(e)}
))

GGX_E_AVG = np.array((
{_flat(e_avg)},
))
''')


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args(argv)
    e, e_avg = tables()
    if args.check:
        from rstrace_engine.tracing.ggx_tables import GGX_E, GGX_E_AVG

        de, da = np.abs(GGX_E - e).max(), np.abs(GGX_E_AVG - e_avg).max()
        sys.stdout.write(f"largest difference: E {de:.2e}, E_avg {da:.2e}\n")
        return 0 if max(de, da) < 1e-5 else 1
    write(e, e_avg)
    sys.stdout.write(f"wrote {OUT}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
