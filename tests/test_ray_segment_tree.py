"""Ray segment trees and the membership index against brute force (seed 000, 4.2-5.1).

Random tunnels (boxes A -> B, point lights, infinite ones, some leaving the domain) and
random query regions: every tunnel with a sampled segment inside a region must be found
(no false negatives), and everything found must have its shaft meet the region.
"""

from __future__ import annotations

import numpy as np

from rstrace_engine.interpolants import membership as membership_mod
from rstrace_engine.interpolants import ray_segment_tree as rst_mod
from rstrace_engine.interpolants.membership import Membership
from rstrace_engine.interpolants.ray_segment_tree import RaySegmentTrees, section_box

DOM = np.array([[0.0, 0.0, 0.0], [10.0, 8.0, 6.0]])


def _box(rng, center, size):
    h = 0.5 * size * rng.random(3)
    return np.concatenate([center - h, center + h])


def random_tunnels(rng, n):
    """(ta, tb, tinf): most inside the domain, some to far points, some infinite."""
    ta = np.empty((n, 6))
    tb = np.empty((n, 6))
    tinf = np.zeros(n, bool)
    for t in range(n):
        ca = DOM[0] + (DOM[1] - DOM[0]) * rng.random(3)
        ta[t] = _box(rng, ca, rng.choice([0.05, 0.5, 2.0]))
        kind = rng.random()
        if kind < 0.4:  # a point light
            p = DOM[0] + (DOM[1] - DOM[0]) * rng.random(3)
            tb[t] = np.concatenate([p, p])
        elif kind < 0.8:  # a reflected object's points
            cb = DOM[0] + (DOM[1] - DOM[0]) * rng.random(3)
            tb[t] = _box(rng, cb, rng.choice([0.1, 1.0, 3.0]))
        elif kind < 0.9:  # leaving the domain
            cb = DOM[0] - 5.0 + (DOM[1] - DOM[0] + 10.0) * rng.random(3)
            tb[t] = _box(rng, cb, 1.0)
        else:  # infinite: far points of misses
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            cb = ca + 40.0 * d
            tb[t] = _box(rng, cb, 4.0)
            tinf[t] = True
    return ta, tb, tinf


def random_regions(rng, n):
    out = np.empty((n, 2, 3))
    for g in range(n):
        c = DOM[0] - 2.0 + (DOM[1] - DOM[0] + 4.0) * rng.random(3)
        h = 0.5 * rng.choice([0.2, 1.0, 3.0]) * (0.2 + rng.random(3))
        out[g] = [c - h, c + h]
    return out


def _segment_meets(p, q, lo, hi):
    """Does segment p->q meet the box (slab method)?"""
    t0, t1 = 0.0, 1.0
    d = q - p
    for m in range(3):
        if abs(d[m]) < 1e-300:
            if p[m] < lo[m] or p[m] > hi[m]:
                return False
            continue
        a = (lo[m] - p[m]) / d[m]
        b = (hi[m] - p[m]) / d[m]
        t0 = max(t0, min(a, b))
        t1 = min(t1, max(a, b))
    return t0 <= t1


def sampled_hits(rng, ta, tb, tinf, regions, k=48):
    """Tunnels with a sampled segment meeting a region (a lower bound of the truth)."""
    n = len(ta)
    hit = np.zeros(n, bool)
    for t in range(n):
        a = ta[t].reshape(2, 3)
        b = tb[t].reshape(2, 3)
        ps = a[0] + (a[1] - a[0]) * rng.random((k, 3))
        qs = b[0] + (b[1] - b[0]) * rng.random((k, 3))
        corners = np.array([[(v >> m) & 1 for m in range(3)] for v in range(8)])
        ps[:8] = np.where(corners, a[1], a[0])
        qs[:8] = np.where(corners[::-1], b[1], b[0])
        if tinf[t]:
            qs = ps + 50.0 * (qs - ps)
        for p, q in zip(ps, qs, strict=True):
            if any(_segment_meets(p, q, r[0], r[1]) for r in regions):
                hit[t] = True
                break
    return hit


def build(ta, tb, tinf, live=None):
    n = len(ta)
    trees = RaySegmentTrees(DOM, 1e-9)
    q = np.arange(n, dtype=np.int32)
    serial = np.arange(1, n + 1, dtype=np.int64)
    trees.add_tunnels(ta, tb, tinf, q, serial)
    pool_live = np.ones(n, bool) if live is None else live
    return trees, serial, pool_live


def test_trees_find_every_tunnel_a_region_meets():
    rng = np.random.default_rng(7)
    ta, tb, tinf = random_tunnels(rng, 600)
    trees, serial, live = build(ta, tb, tinf)
    assert trees.n_nodes > 6, "the trees never split"
    for _ in range(12):
        regions = random_regions(rng, int(rng.integers(1, 3)))
        found = np.zeros(len(ta), bool)
        trees.query(regions, serial, live, found)
        brute = np.zeros(len(ta), bool)
        trees.query_brute(regions, serial, live, brute)
        truth = sampled_hits(rng, ta, tb, tinf, regions)
        assert not np.any(truth & ~found), np.flatnonzero(truth & ~found)
        assert not np.any(found & ~brute)
        # selective: a small region does not report everything
        assert found.sum() < len(ta)


def test_sections_hold_their_segments():
    """Every segment p -> q of a tunnel lies in the section of its dominant face pair."""
    rng = np.random.default_rng(3)
    ta, tb, tinf = random_tunnels(rng, 200)
    out = np.empty(10)
    checked = 0
    for t in range(len(ta)):
        if tinf[t]:
            continue
        a = ta[t].reshape(2, 3)
        b = tb[t].reshape(2, 3)
        for _ in range(20):
            p = a[0] + (a[1] - a[0]) * rng.random(3)
            q = b[0] + (b[1] - b[0]) * rng.random(3)
            d = q - p
            k = int(np.argmax(np.abs(d)))
            neg = d[k] < 0
            f = 2 * k + int(neg)
            i, j = (k + 1) % 3, (k + 2) % 3
            L = DOM[1, k] - DOM[0, k]
            front = DOM[1, k] if neg else DOM[0, k]
            li, wi = DOM[0, i] - L, DOM[1, i] - DOM[0, i] + 2 * L
            lj, wj = DOM[0, j] - L, DOM[1, j] - DOM[0, j] + 2 * L
            tp = ((front - p[k]) if neg else (p[k] - front)) / L
            tq = ((front - q[k]) if neg else (q[k] - front)) / L
            lo_t, hi_t = max(min(tp, tq), 0.0), min(max(tp, tq), 1.0)
            if lo_t > hi_t:
                continue  # outside the domain
            F = p + (0.0 - tp) / (tq - tp) * (q - p)
            B = p + (1.0 - tp) / (tq - tp) * (q - p)
            abcd = [(F[i] - li) / wi, (F[j] - lj) / wj, (B[i] - li) / wi, (B[j] - lj) / wj]
            assert section_box(DOM, f, a[0], a[1], b[0], b[1], out), (t, f)
            for m in range(4):
                assert out[2 * m] - 1e-9 <= abcd[m] <= out[2 * m + 1] + 1e-9, (t, m)
            assert out[8] - 1e-9 <= lo_t and hi_t <= out[9] + 1e-9
            checked += 1
    assert checked > 1000


def test_dead_tunnels_are_skipped_and_compaction_keeps_answers(monkeypatch):
    rng = np.random.default_rng(11)
    ta, tb, tinf = random_tunnels(rng, 400)
    live = rng.random(len(ta)) < 0.3
    trees, serial, _ = build(ta, tb, tinf)
    regions = random_regions(rng, 3)
    before = np.zeros(len(ta), bool)
    trees.query(regions, serial, live, before)
    assert not np.any(before & ~live)
    mem = trees.memory_bytes
    monkeypatch.setattr(rst_mod, "COMPACT_SLACK", 0)
    assert trees.compact(serial, live)
    assert trees.n_tun == live.sum() and trees.memory_bytes < mem
    after = np.zeros(len(ta), bool)
    trees.query(regions, serial, live, after)
    np.testing.assert_array_equal(before, after)
    # a reused id with a new serial is not the old interpolant
    serial2 = serial.copy()
    serial2[live] += 1000
    none = np.zeros(len(ta), bool)
    trees.query(regions, serial2, live, none)
    assert not none.any()


def test_membership_lists_against_brute_force(monkeypatch):
    rng = np.random.default_rng(5)
    n, keys_per = 300, 6
    keys = rng.integers(0, 50, size=(n, keys_per))
    m = Membership()
    q = np.repeat(np.arange(n, dtype=np.int32), keys_per)
    serial = np.arange(1, n + 1, dtype=np.int64)
    m.add(keys.reshape(-1), q, serial[q])
    live = rng.random(n) < 0.3
    for key in range(50):
        flag = np.zeros(n, bool)
        m.query([key], serial, live, flag)
        np.testing.assert_array_equal(flag, live & np.any(keys == key, axis=1))
    monkeypatch.setattr(membership_mod, "COMPACT_SLACK", 0)
    mem = m.memory_bytes
    assert m.compact(serial, live)
    assert m.memory_bytes < mem
    for key in range(50):
        flag = np.zeros(n, bool)
        m.query([key], serial, live, flag)
        np.testing.assert_array_equal(flag, live & np.any(keys == key, axis=1))
