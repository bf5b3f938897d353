"""Summarise ``scripts/trade_ab.sh``'s runs: per scene, samples per pixel and side (A, B),
each round's first / step / pan speedups (base / INTERPOLANT), interpolated share, pixels
over epsilon; then the medians.

``python scripts/trade_ab_summary.py OUT``
"""

from __future__ import annotations

import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path

KEYS = ("first_frame_speedup", "camera_step_speedup", "pan_speedup")


def main(out: str) -> None:
    rows = defaultdict(list)
    for f in sorted(Path(out).glob("*_[AB]_*.json")):
        name, who, rnd = f.stem.rsplit("_", 2)
        try:
            data = json.loads(f.read_text())
        except ValueError:  # a run that did not finish
            continue
        for r in data["rows"]:
            rows[name, r["spp"], who].append((rnd, r))
    for (name, spp, who), runs in sorted(rows.items()):
        for rnd, r in runs:
            sys.stdout.write(f"{name:12s} {spp:2d} spp {who} round {rnd}: "
                             + " ".join(f"{r[k]:.2f}" for k in KEYS)
                             + f"  interpolated {r['interpolated_fraction']:.1%}"
                             + f"  >eps {r['n_over_epsilon']}\n")
        med = [statistics.median(r[k] for _, r in runs) for k in KEYS]
        sys.stdout.write(f"{name:12s} {spp:2d} spp {who} median first / step / pan: "
                         + " / ".join(f"{m:.2f}" for m in med) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
