"""The vector slab test of a 4-wide node (accel/box4.py) is the scalar test, bit for bit."""

import numpy as np
import pytest
from numba import njit

from rstrace_engine import tolerances as tol
from rstrace_engine.accel.box4 import lanes4
from rstrace_engine.accel.bvh import _inv_dir, _near


@njit(cache=False)
def _scalar(bounds, node, j, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1):
    """The traversal's former per-lane test (main before session 32), the reference."""
    tn = max(max((bounds[node, nx + j] - ox) * ix, (bounds[node, ny + j] - oy) * iy),
             max((bounds[node, nz + j] - oz) * iz, t0))
    tf = min(min((bounds[node, 12 - nx + j] - ox) * ix, (bounds[node, 20 - ny + j] - oy) * iy),
             min((bounds[node, 28 - nz + j] - oz) * iz, t1))
    if tn <= tf * tol.BOX_TFAR_SCALE:
        return tn
    return np.inf


@njit(cache=False)
def _both(bounds, o, d, t0, t1, out_vec, out_ref):
    for r in range(o.shape[0]):
        ix, iy, iz = _inv_dir(d[r, 0]), _inv_dir(d[r, 1]), _inv_dir(d[r, 2])
        nx, ny, nz = _near(ix, iy, iz)
        for node in range(bounds.shape[0]):
            a, b, c, e = lanes4(bounds, node, nx, ny, nz, o[r, 0], o[r, 1], o[r, 2],
                                ix, iy, iz, t0[r], t1[r])
            out_vec[r, node, 0], out_vec[r, node, 1] = a, b
            out_vec[r, node, 2], out_vec[r, node, 3] = c, e
            for j in range(4):
                out_ref[r, node, j] = _scalar(bounds, node, j, nx, ny, nz, o[r, 0], o[r, 1],
                                              o[r, 2], ix, iy, iz, t0[r], t1[r])


def _nodes(rng, n):
    """4-wide node rows (SoA) with ordinary, degenerate, touching, unused (inverted,
    infinite) and signed-zero boxes."""
    lo = rng.uniform(-2, 2, (n, 3, 4))
    hi = lo + rng.exponential(2.0, (n, 3, 4))
    flat = rng.random((n, 3, 4)) < 0.15
    hi[flat] = lo[flat]  # zero-thickness boxes (a plane's)
    lo[rng.random((n, 3, 4)) < 0.05] = -0.0
    hi[rng.random((n, 3, 4)) < 0.05] = 0.0
    unused = rng.random((n, 4)) < 0.15
    lo[np.repeat(unused[:, None, :], 3, axis=1)] = np.inf  # what collapse4 writes
    hi[np.repeat(unused[:, None, :], 3, axis=1)] = -np.inf
    big = rng.random((n, 3, 4)) < 0.03
    hi[big] = np.inf
    return np.concatenate([lo.reshape(n, 12), hi.reshape(n, 12)], axis=1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_vector_slab_test_is_the_scalar_one_bit_for_bit(dtype):
    """Random and adversarial rays (axis-parallel, zero and signed-zero components, origins
    on box faces, rays through box edges, empty intervals) against random nodes in float32
    (mesh) and float64 (top level): every lane's entry distance (or inf) has the scalar
    test's bits."""
    rng = np.random.default_rng(7)
    bounds = np.ascontiguousarray(_nodes(rng, 64), dtype)
    n = 400
    o = rng.uniform(-3, 3, (n, 3))
    d = rng.normal(size=(n, 3))
    d[:60] = np.eye(3)[rng.integers(0, 3, 60)] * rng.choice([-1.0, 1.0], (60, 1))
    d[60:90, rng.integers(0, 3)] = 0.0
    d[90:120, 0] = -0.0
    d[120:150] *= 1e-310  # tiny components: the huge finite reciprocals
    face = rng.integers(0, 64, 50)
    o[150:200, 0] = bounds[face, rng.integers(0, 4, 50)].astype(np.float64)  # on a lo x plane
    # rays through a box's edge (lo x, lo y of a lane, any z between): entry and exit
    # round within ulps of each other, where the conservative t_far scale decides
    k, j = rng.integers(0, 64, 150), rng.integers(0, 4, 150)
    b = bounds.astype(np.float64)
    with np.errstate(invalid="ignore"):  # an unused lane's inf + -inf: dropped below
        edge = np.stack([b[k, j], b[k, 4 + j], 0.5 * (b[k, 8 + j] + b[k, 20 + j])], axis=1)
    ok = np.all(np.isfinite(edge), axis=1)
    d[250:400][ok] = edge[ok] - o[250:400][ok]
    t0 = np.where(rng.random(n) < 0.2, rng.uniform(0, 2, n), 0.0)
    t1 = np.where(rng.random(n) < 0.5, rng.uniform(0, 4, n), np.inf)
    t0[250:400], t1[250:400] = 0.0, np.inf
    t1[200:220] = t0[200:220]  # empty intervals of one point
    vec = np.empty((n, 64, 4))
    ref = np.empty((n, 64, 4))
    _both(bounds, o, d, t0, t1, vec, ref)
    assert np.array_equal(vec.view(np.int64), ref.view(np.int64))
    hit = ref < np.inf
    assert hit.sum() > 2000 and (~hit).sum() > 2000, hit.sum()  # both outcomes exercised


def _inv_dir_branches(x):
    """The reciprocal as the traversal took it before session 42 (branches on the sign),
    the reference for :func:`.bvh._inv_dir`'s selects."""
    if x >= 0.0:
        return 1e300 if x < 1e-300 else 1.0 / x
    return -1e300 if x > -1e-300 else 1.0 / x


@njit(cache=False)
def _inv_all(x, out):
    for k in range(x.shape[0]):
        out[k] = _inv_dir(x[k])


def test_inv_dir_is_the_branching_reciprocal_bit_for_bit():
    """Every direction component (signed zeros, subnormals, the 1e-300 threshold and its
    neighbours, infinities, NaN, ordinary values) gets the very bits of the old test's
    reciprocal: the box entries, and so the traversal, are unchanged."""
    edge = [0.0, -0.0, 5e-324, -5e-324, 1e-310, -1e-310, 1e-300, -1e-300,
            np.nextafter(1e-300, 0.0), np.nextafter(-1e-300, 0.0),
            np.nextafter(1e-300, 1.0), np.nextafter(-1e-300, -1.0),
            np.inf, -np.inf, np.nan, 1.0, -1.0, 3.0, -7.5e-12, 1e300, -1e300]
    rng = np.random.default_rng(42)
    x = np.concatenate([edge, rng.normal(size=500), rng.normal(size=200) * 1e-299,
                        np.ldexp(rng.normal(size=200), rng.integers(-1074, 1000, 200))])
    got = np.empty_like(x)
    _inv_all(x, got)
    want = np.array([_inv_dir_branches(float(v)) for v in x])
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
