"""The stable partition of the subtree builder (:mod:`rstrace_engine.accel.bvh_partition`):
the sides of ``bvh_build._partition``, each in its rows' order."""

from __future__ import annotations

import numpy as np

from rstrace_engine.accel import bvh_build
from rstrace_engine.accel.bvh_partition import partition_stable


def _boxes(rng, n):
    lo = rng.integers(-50, 50, (n, 3)).astype(np.float32)
    return np.concatenate([lo, lo + rng.integers(0, 9, (n, 3))], 1).astype(np.float32)


def test_the_stable_partition_keeps_each_sides_order():
    """Same split point, the same rows on each side and the same centroid bounds as
    ``_partition``; each side in the order its rows came (``_partition`` swaps them)."""
    rng = np.random.default_rng(3)
    reordered = 0
    for trial in range(60):
        n = int(rng.integers(2, 300))
        pb = _boxes(rng, n)
        start, end = int(rng.integers(0, n // 2 + 1)), n
        c = 0.5 * (pb[:, :3].astype(np.float64) + pb[:, 3:])
        k = trial % 3
        cmin, ext = c[start:end, k].min(), np.ptp(c[start:end, k])
        if ext <= 0:
            continue
        nb = int(min(24, end - start))
        split = int(rng.integers(0, nb - 1)) if nb > 1 else 0
        perm = np.arange(n, dtype=np.int32)
        a_pb, a_perm, a_l, a_r = pb.copy(), perm.copy(), np.empty(6), np.empty(6)
        want_mid = bvh_build._partition(a_pb, a_perm, start, end, k, cmin, ext, nb, split,
                                        a_l, a_r)
        b_pb, b_perm, b_l, b_r = pb.copy(), perm.copy(), np.empty(6), np.empty(6)
        sc, sp = np.empty((end - start, 6), np.float32), np.empty(end - start, np.int32)
        mid = partition_stable(b_pb, b_perm, start, end, k, cmin, ext, nb, split, b_l, b_r,
                               sc, sp)
        assert mid == want_mid
        assert np.array_equal(a_l, b_l) and np.array_equal(a_r, b_r)
        left = np.array([bvh_build._bin_at(x, cmin, nb / ext, nb) <= split
                         for x in c[start:end, k]], bool)
        rows = np.arange(start, end)
        want = np.concatenate([rows[left], rows[~left]]).astype(np.int32)
        assert np.array_equal(b_perm[start:end], want)  # stable: in the rows' order
        assert np.array_equal(b_pb[start:end], pb[want])
        assert np.array_equal(b_perm[:start], perm[:start])
        for lo_, hi_ in ((start, mid), (mid, end)):  # the same rows on each side
            assert sorted(a_perm[lo_:hi_]) == sorted(b_perm[lo_:hi_])
        reordered += not np.array_equal(a_perm, b_perm)
    assert reordered > 10  # (the swaps' order differs: the check above is not vacuous)

