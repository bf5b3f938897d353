"""rstrace_engine.linalg: np.linalg.inv's bits with OpenBLAS on one thread for the call."""

import numpy as np
import pytest

from rstrace_engine import linalg
from rstrace_engine.geometry import scene as scene_mod


def _matrices(n: int = 300):
    rng = np.random.default_rng(7)
    for k in range(n):
        m = np.eye(4)
        if k % 3 == 0:  # affine
            m[:3, :4] = rng.normal(size=(3, 4)) * rng.choice([1e-3, 1.0, 1e3])
        elif k % 3 == 1:  # general
            m = rng.normal(size=(4, 4))
        else:  # rotation, scale, translation
            q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
            m[:3, :3] = q * rng.uniform(0.1, 10.0, 3)
            m[:3, 3] = rng.normal(size=3) * 10.0
        yield m


def test_inv_is_numpys_inverse_bit_for_bit():
    for m in _matrices():
        assert np.array_equal(linalg.inv(m), np.linalg.inv(m))
    with pytest.raises(np.linalg.LinAlgError):
        linalg.inv(np.zeros((4, 4)))


def test_inv_runs_openblas_on_one_thread_and_sets_it_back(monkeypatch):
    c = linalg.controls()
    if c is None:
        pytest.skip("numpy's BLAS here is not an OpenBLAS with thread controls")
    get, set_ = c
    before = get()
    set_(2)
    try:
        seen = []
        real = np.linalg.inv

        def spy(m):
            seen.append(get())
            return real(m)

        monkeypatch.setattr(np.linalg, "inv", spy)
        linalg.inv(np.eye(4) * 2.0)
        assert seen == [1] and get() == 2
        with pytest.raises(np.linalg.LinAlgError):
            linalg.inv(np.zeros((4, 4)))
        assert get() == 2  # (set back after an error too)
    finally:
        set_(before)


def test_the_scene_places_objects_with_it(monkeypatch):
    calls = []
    real = linalg.inv
    monkeypatch.setattr(linalg, "inv", lambda m: calls.append(1) or real(m))
    from rstrace_engine.geometry import shapes

    s = scene_mod.Scene()
    s.add_material(scene_mod.Material("m"))
    mid = s.add_mesh(shapes.lumpy_sphere(200))
    m = np.eye(4)
    m[:3, 3] = (1.0, 2.0, 3.0)
    s.add_instance(mid, m)
    assert calls
