"""Write ``rstrace_engine/tracing/ggx_glass_tables.py``: the albedo ``E`` of
a rough dielectric interface (GGX, reflection plus refraction), tabulated over the view
cosine, the roughness and the index ratio, for both sides of the interface, as Cycles
tabulates its own (``ggx_glass_E``, ``ggx_glass_inv_E``) for its multiscatter GGX glass.

    python scripts/ggx_glass_tables.py            # writes the module (about a minute)
    python scripts/ggx_glass_tables.py --check    # compares the module with a fresh computation

Each value is :func:`rstrace_engine.tracing.glass_albedo.ggx_glass_albedo_quadrature` on a
``QUADRATURE`` x ``QUADRATURE`` lattice of visible normals (float64), at ``cos_o = k / (NC -
1)`` (0 taken at ``tolerances.GGX_COS_MIN``, the shader's clamp), ``roughness = j / (NR - 1)``
(``alpha = roughness ** 2``, 0 taken at ``tolerances.GLOSSY_ALPHA_MIN``, where the lobe is
a mirror's) and ``z = Z_MAX i / (NZ - 1)`` with ``z = (k - 1) / (k + 1)``, ``k`` the ratio of
the indices (the larger over the smaller): side 0 looks from the lower index into the
higher (``eta = 1 / k``, entering glass), side 1 from the higher (``eta = k``: total internal
reflection). The values are stored as 16-bit fractions (steps of 1.5e-5), base64-encoded.
"""

from __future__ import annotations

import argparse
import base64
import sys
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rstrace_engine import tolerances as tol  # noqa: E402
from rstrace_engine.tracing.glass_albedo import ggx_glass_albedo_quadrature  # noqa: E402

NZ, NR, NC = 16, 16, 32
Z_MAX = 0.8  # k = 9
QUADRATURE = 128
OUT = ROOT / "rstrace_engine" / "tracing" / "ggx_glass_tables.py"


def compute() -> np.ndarray:
    """(2, NZ, NR, NC) float64: E on the grid (the module docstring)."""
    out = np.empty((2, NZ, NR, NC))
    for i in range(NZ):
        z = Z_MAX * i / (NZ - 1)
        k = (1.0 + z) / (1.0 - z)
        for side, eta in enumerate((1.0 / k, k)):
            for j in range(NR):
                alpha = max((j / (NR - 1)) ** 2, tol.GLOSSY_ALPHA_MIN)
                for c in range(NC):
                    co = max(c / (NC - 1), tol.GGX_COS_MIN)
                    out[side, i, j, c] = ggx_glass_albedo_quadrature(co, alpha, eta,
                                                                     QUADRATURE)
    return out


def encode(e: np.ndarray) -> str:
    q = np.round(np.clip(e, 0.0, 1.0) * 65535.0).astype("<u2")
    return base64.b64encode(q.tobytes()).decode("ascii")


def module_text(e: np.ndarray) -> str:
    data = "\n".join(f'    "{line}"' for line in textwrap.wrap(encode(e), 88))
    return f'''"""Rough dielectric albedo tables, written by ``scripts/ggx_glass_tables.py`` (its
docstring says how): ``GLASS_E[side, i, j, k]``, the single-scattering albedo of a GGX
interface (reflection plus refraction) seen at ``cos_o = k / {NC - 1}`` with ``roughness = j /
{NR - 1}`` and index ratio ``(1 + z) / (1 - z)``, ``z = {Z_MAX} i / {NZ - 1}``; side 0 from the
lower index, side 1 from the higher. Read trilinearly by
:func:`~.multiscatter.ggx_glass_albedo`.
"""

import base64

import numpy as np

NZ, NR, NC = {NZ}, {NR}, {NC}
Z_MAX = {Z_MAX}

_DATA = (
{data}
)

GLASS_E = (np.frombuffer(base64.b64decode(_DATA), "<u2").astype(np.float64)
           / 65535.0).reshape(2, NZ, NR, NC)
'''


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true",
                    help="compare the module with a fresh computation instead of writing")
    a = ap.parse_args()
    e = compute()
    if a.check:
        from rstrace_engine.tracing.ggx_glass_tables import GLASS_E

        diff = float(np.abs(GLASS_E - e).max())
        sys.stdout.write(f"largest difference {diff:.2e}\n")
        return 0 if diff <= 1.0 / 65535.0 else 1
    OUT.write_text(module_text(e))
    sys.stdout.write(f"wrote {OUT.relative_to(ROOT)}: E in [{e.min():.4f}, {e.max():.4f}]\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
