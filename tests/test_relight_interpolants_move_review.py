"""Review of the moved light in INTERPOLANT mode (``interpolants/moved_light.py``): cases the
branch's own tests leave open.

* At a tight epsilon a lamp moved next to the glass ball, then nearer, and the key light
  moved far then near: cells whose corners still pass the predicate fail the radiance test
  on the new corners; without the re-run of the test the frames leave the bound (0.018 and
  0.032 against 0.01 by the glass ball; 0.012 far/near).
* A light moved far (its new shafts nowhere near its old ones): a point on a kept lit
  cell's new shaft, away from the old shaft, finds the cell (only the renewed tunnel
  sections can).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_relight_interpolants import cells_always  # noqa: F401 (the autouse fixture)

from rstrace_engine import image
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_REBUILT, RenderSettings
from rstrace_engine.geometry.edits import LightSet
from rstrace_engine.interpolants.invalidation import affected
from rstrace_engine.session import Session

FLOAT_TOL = 1e-6


def _session(scene, eps):
    s = Session(scene.copy(), RenderSettings(mode="INTERPOLANT", epsilon=eps, max_depth=3))
    s.light_terms = True
    return s


def _place(sess, key, pos):
    li = sess.scene.lights[sess.scene.light_slot(key)]
    return [LightSet(key, replace(li, position=tuple(pos)))]


def _error(frame, scene, eps) -> float:
    base = Session(scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
    traced = (frame.pixel_class != CLASS_INTERPOLATED) & (frame.pixel_class != CLASS_REBUILT)
    np.testing.assert_allclose(frame.radiance[traced], base.radiance[traced], atol=1e-6)
    return image.compare(frame.radiance, base.radiance, eps)["max_error"]


@pytest.mark.parametrize(("name", "key", "places"), [
    ("room", "Lamp", [(1.5, 1.5, 2.0), (1.5, 1.5, 1.3)]),
    ("spheres", "Key", [(-9.0, -12.0, 16.0), (0.0, 0.0, 2.5)])])
def test_moved_light_keeps_a_tight_bound(name, key, places):
    eps = 0.01
    sess = _session(SOAK_SCENES[name](96, 72), eps)
    sess.render()
    cache = sess.interpolants.cache
    for pos in places:
        sess.apply(_place(sess, key, pos))
        frame = sess.render()
        assert frame.stats["term_pixels"] > 0  # (the move path ran)
        err = _error(frame, sess.scene, eps)
        assert err <= eps + FLOAT_TOL
    assert sess.interpolants.cache is cache and cache.totals["terms_moved"] > 0


@pytest.mark.parametrize(("name", "key", "place"), [
    ("room", "Lamp", (2.0, -2.0, 3.5)), ("spheres", "Key", (3.0, -4.0, 6.0))])
def test_far_moved_light_new_shaft_finds_its_cells(name, key, place):
    scene = SOAK_SCENES[name](96, 72)
    sess = _session(scene, 0.05)
    sess.render()
    j = sess.scene.light_slot(key)
    old = np.asarray(scene.lights[j].position, float)
    sess.apply(_place(sess, key, place))
    cache = sess.interpolants.cache
    p, sm = cache.pool, cache.samples
    new = np.asarray(place, float)
    checked = 0
    for q in np.flatnonzero(p.live):
        s0 = p.samples[q, 0]
        if sm._nocc[sm._nstart[s0], j] != -1:  # (lit at its root)
            continue
        root = sm._npoint[sm._nstart[s0]]
        for frac in (0.5, 0.8):
            pt = root + frac * (new - root)
            d = old - root
            t = np.clip(np.dot(pt - root, d) / np.dot(d, d), 0.0, 1.0)
            if np.linalg.norm(root + t * d - pt) < 1.0:  # (near the old shaft: skip)
                continue
            box = np.stack([pt - 1e-3, pt + 1e-3])[None]
            assert q in set(affected(cache, box).ids.tolist())
            checked += 1
    assert checked > 5



def test_kept_cells_record_the_moved_lights_new_states():
    """The key light moved into the red sphere: the floor cells it no longer lights are kept
    (nothing lights them from there), and their samples' recorded states for it say
    occluded, as their zero shares do (the predicate and the membership entries read the
    states: left at the old light's, a cell occluded at its build and lit after a move
    would get no tunnel toward the light), then lit again once it is moved back out."""
    scene = SOAK_SCENES["spheres"](96, 72)
    sess = _session(scene, 0.05)
    sess.render()
    cache = sess.interpolants.cache
    p, sm = cache.pool, cache.samples
    j = sess.scene.light_slot("Key")
    for place, lit in (((-1.6, 0.4, 1.0), False), ((-3.0, -4.0, 6.0), True)):
        sess.apply(_place(sess, "Key", place))
        share, shared = sm.shares()
        checked = 0
        for q in np.flatnonzero(p.live):
            s0 = p.samples[q, 0]
            if abs(sm._npoint[sm._nstart[s0]][2]) > 1e-6 or not shared[s0]:
                continue  # (floor roots only: one node, its share says lit or not)
            assert (share[s0, j].max() > 0.0) == lit
            assert (sm._nocc[sm._nstart[s0], j] == -1) == lit
            checked += 1
        assert checked > 5
        err = _error(sess.render(), sess.scene, 0.05)
        assert err <= 0.05 + FLOAT_TOL
