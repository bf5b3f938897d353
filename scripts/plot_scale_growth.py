"""How the first F12's time grows with the scene (issue 26: "growth with size is plotted"):
rstrace's and Cycles' first render of ``first_f12_split.py``'s heavy scene at each size.

    python scripts/plot_scale_growth.py [--data docs/scale_growth.jsonl]
                                        [--out docs/scale_growth.png]

``--data``: one JSON line a render (``size``, ``renderer`` rstrace or cycles, ``wall_s``,
``cpu_s``, ``triangles`` where known, ``load``, ``run``), taken from
``scripts/first_f12_split.py SIZE --only ours|cycles --json`` runs, each renderer in a
fresh process, rotated within each round (docs/bench-scale-bpy.md, "Session 40
(merged)"). Plots the per-size median wall and CPU seconds against the triangle count
(log-log), the rounds as dots, and prints the medians. Nothing is measured here.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT / "docs" / "scale_growth.jsonl")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "scale_growth.png")
    a = ap.parse_args()
    rows = [json.loads(line) for line in a.data.read_text().splitlines() if line.strip()]
    tris = {r["size"]: r["triangles"] for r in rows if r.get("triangles")}
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for name, colour in (("rstrace", "tab:blue"), ("cycles", "tab:orange")):
        sizes = sorted({r["size"] for r in rows if r["renderer"] == name}, key=tris.get)
        for key, style in (("wall_s", "-o"), ("cpu_s", ":s")):
            med = []
            for s in sizes:
                v = [r[key] for r in rows if r["renderer"] == name and r["size"] == s]
                med.append(statistics.median(v))
                if key == "wall_s":
                    ax.plot([tris[s]] * len(v), v, ".", color=colour, alpha=0.25, ms=4)
                sys.stdout.write(f"{name:8s} {s:>4s} {key[:-2]:4s} median {med[-1]:.3f} s "
                                 f"({len(v)} renders)\n")
            ax.plot([tris[s] for s in sizes], med, style, color=colour,
                    label=f"{name} {key[:-2]} (median)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("triangles in the scene")
    ax.set_ylabel("first F12, seconds")
    ax.set_title("First F12 of Suzanne beside a sphere and a floor, 320x240, 2 cores")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(a.out, dpi=100)
    sys.stdout.write(f"wrote {a.out}\n")


if __name__ == "__main__":
    main()
