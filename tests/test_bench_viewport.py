"""``python -m rstrace_engine.bench viewport``'s measurement runs (a smoke test on a small
view: the rows and their keys; no times are asserted)."""

from __future__ import annotations

from rstrace_engine.bench import viewport


def test_measure_gives_one_row_per_edit():
    rows = viewport.measure("museum", "BASE", 64, 48, repeat=1)
    assert [r["edit"] for r in rows] == list(viewport.EDITS)
    for r in rows:
        assert set(r) == {"scene", "edit", "mode", "first_image_ms", "full_image_ms",
                          "full_image_median_ms", "interrupt_ms", "relit", "split_ms"}
        assert r["scene"] == "museum" and r["mode"] == "BASE"
        assert r["first_image_ms"] is not None and r["first_image_ms"] > 0
        assert r["full_image_ms"] is not None and r["full_image_ms"] >= r["first_image_ms"]
    # the light drag's full images are relit from the per-light records (BASE)
    drag = rows[list(viewport.EDITS).index("drag a light")]
    assert drag["relit"] == "2/2", drag
    assert {"shadow_rays", "shade", "recombine", "other"} <= set(drag["split_ms"]), drag
