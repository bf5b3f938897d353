"""The main job (`make demo`) runs end to end in a fresh process and writes what it says."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_demo_renders_edits_and_reports(tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "demo.py"), "--out", str(out),
                           "--width", "96", "--height", "72", "--samples", "1"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    for name in ("before", "after", "interpolated"):
        for ext in ("png", "exr"):
            assert (out / f"{name}.{ext}").stat().st_size > 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["edit"]["object"] == "RedSphere"
    assert 0.0 < stats["changed_pixels_fraction"] < 0.5
    assert stats["renders"]["interpolated"]["mode"] == "INTERPOLANT"
    acc = stats["interpolated_vs_base"]
    # the bound holds for every pixel (epsilon 0.01, float32 slack 1e-6)
    assert acc["n_over"] == 0 and acc["max_error"] <= 0.01 + 1e-6, acc
    # the edit loop: each edit rendered incrementally, with its dirty pixels beside it
    loop = stats["edit_loop"]
    assert [r["edit"].split()[0] for r in loop][:4] == ["move", "rotate", "BlueSphere's",
                                                        "Key"]
    assert all(sum(r["depsgraph_edits"].values()) >= 1 for r in loop)
    colour = loop[2]
    assert colour["depsgraph_edits"] == {"MaterialSet": 1}
    assert colour["incremental"] and colour["dirty_fraction"] < 0.2
    # the Key light's colour and move after its first light edit: relit (issue 21)
    assert [r["relit"] for r in loop[3:6]] == [False, True, True], loop[3:6]
    assert (out / "edits" / "edits.txt").read_text().count("\n") == len(loop)
    for k in range(1, len(loop) + 1):
        assert len(list((out / "edits").glob(f"{k:02d}_*.png"))) == 2
