"""The records' finish after an incremental frame: the splice of new nodes into the
per-light records (:func:`rstrace_engine.tracing.light_nodes.splice`: where every replaced
node's hit flag is unchanged, the geometry rows are written in place, no copy of the kept
rows, and the result is the gather of the old and new nodes either way), and the pixel
records' count of the table rows their nodes use (``_mark_used``)."""

import numpy as np

from rstrace_engine.tracing.light_nodes import GEO_KEYS
from rstrace_engine.tracing.light_records import _GEO, _Part
from rstrace_engine.tracing.record_codes import _mark_used


def _part(rng, hit: np.ndarray) -> _Part:
    """Random nodes with these hit flags: 0-3 entries per hit node, geometry per hit."""
    n = len(hit)
    count = np.where(hit, rng.integers(0, 4, n), 0)
    start = np.zeros(n + 1, np.int64)
    np.cumsum(count, out=start[1:])
    k = int(start[-1])
    h = int(hit.sum())
    geo = {}
    for key, (sh, dt) in _GEO.items():
        x = rng.integers(0, 1 << 20, (h,) + sh) if np.dtype(dt).kind in "iu" \
            else rng.standard_normal((h,) + sh)
        geo[key] = np.ascontiguousarray(x, dt)
    return _Part(hit.copy(), start, rng.integers(0, 8, k).astype(np.uint8),
                 rng.standard_normal((k, 3)), None, geo)


def _reference(old: _Part, rows: np.ndarray, new: _Part) -> _Part:
    """The old nodes with ``rows`` replaced, gathered from a concatenation."""
    row = np.arange(len(old))
    row[rows] = len(old) + np.arange(len(rows))
    return _Part.concat([old.take(np.arange(len(old))), new]).take(row)


def _check(got: _Part, ref: _Part) -> None:
    np.testing.assert_array_equal(got.hit, ref.hit)
    np.testing.assert_array_equal(got.start, ref.start)
    np.testing.assert_array_equal(got.slot, ref.slot)
    np.testing.assert_array_equal(got.val, ref.val)
    for key in GEO_KEYS:
        np.testing.assert_array_equal(got.geo[key], ref.geo[key])


def test_splice_same_hits_writes_geometry_in_place():
    rng = np.random.default_rng(5)
    hit = rng.random(400) < 0.7
    old = _part(rng, hit)
    rows = np.sort(rng.choice(400, 60, replace=False)).astype(np.int64)
    new = _part(rng, hit[rows])  # (the replaced nodes hit as before; their terms differ)
    ref = _reference(old, rows, new)
    kept = {key: old.geo[key] for key in GEO_KEYS}
    got = old.splice(rows, new)
    _check(got, ref)
    for key in GEO_KEYS:  # (no copy of the kept rows: the old arrays, rows written over)
        assert got.geo[key] is kept[key]


def test_splice_changed_hits_gathers():
    rng = np.random.default_rng(6)
    hit = rng.random(300) < 0.6
    old = _part(rng, hit)
    rows = np.sort(rng.choice(300, 50, replace=False)).astype(np.int64)
    flags = hit[rows].copy()
    flags[::3] = ~flags[::3]  # (some replaced nodes hit now, some miss now)
    new = _part(rng, flags)
    ref = _reference(old, rows, new)
    before = {key: old.geo[key].copy() for key in GEO_KEYS}
    got = old.splice(rows, new)
    _check(got, ref)
    for key in GEO_KEYS:  # (a gather: the old arrays untouched)
        assert got.geo[key] is not old.geo[key]
        np.testing.assert_array_equal(old.geo[key], before[key])


def test_mark_used_counts_the_rows_nodes_use():
    rng = np.random.default_rng(7)
    for dt in (np.uint16, np.uint32):
        p = rng.integers(0, 900, 5000).astype(dt)
        s = rng.integers(500, 1200, 3000).astype(dt)
        used = np.zeros(1500, np.bool_)
        n = _mark_used(p, used) + _mark_used(s, used)
        ref = np.zeros(1500, np.bool_)
        ref[p] = True
        ref[s] = True
        np.testing.assert_array_equal(used, ref)
        assert n == len(np.union1d(p, s)) == int(ref.sum())
    assert _mark_used(np.zeros(0, np.uint16), np.zeros(3, np.bool_)) == 0


def test_the_warm_up_loads_both_splices():
    """The in-place splice takes an empty splice's path: the warm-up still reaches the
    copying one (``_splice_geo``), which a frame whose replaced nodes change hit flags
    runs (review: it compiled cold in that frame). In a process of its own: other tests
    run the copying splice."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = ("from rstrace_engine.tracing import light_nodes as n; "
            "from rstrace_engine.tracing.light_records import load_kernels; load_kernels(); "
            "print(bool(n._splice_geo.signatures), bool(n._splice_entries.signatures))")
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, cwd=root)
    assert out.stdout.split() == ["True", "True"], out.stdout
