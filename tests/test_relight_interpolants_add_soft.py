"""A light with an extent added in INTERPOLANT mode keeps the cells it is proven on (issue 21
item 3, ``interpolants/added_light.py``): a sphere light, an area light or a sun with an
angle is shaded at the kept samples alone (its sampled term taken off, as a build takes it
off), proven on each live cell by the soft-light proof with the other lights off, and the
cells that pass keep their interpolants with the new term -- where the old code invalidated
every cell. Every frame is held to the bound (its maximum display error against a fresh
BASE frame, and against a fresh INTERPOLANT frame, at most epsilon).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from bound_scenes import soft_sun
from test_relight_interpolants import (  # noqa: F401 (cells_always: the autouse fixture)
    EPS,
    FLOAT_TOL,
    SCENES,
    cells_always,
    check_bound,
    session,
    settings,
)
from test_relight_interpolants_add import _live, check_kept_cells

from rstrace_engine import image
from rstrace_engine.frame import CLASS_INTERPOLATED
from rstrace_engine.geometry.edits import LightSet
from rstrace_engine.geometry.scene import Light
from rstrace_engine.session import Session

MAKE = {"spheres": SCENES["spheres"][0], "soft_penumbra": SCENES["soft_penumbra"][0],
        "soft_sun": lambda: soft_sun("PERSP")}


def _soft_light(sess: Session, kind: str) -> Light:
    """An added light with an extent above the scene's middle: a sphere light, an area
    light (a square, or a disk: no closed form) or a sun with an angle. Mirror and
    refraction rays see its surface where they already see another light's
    (``render._newly_seen``: the samples are flagged), not where they saw none (a new
    cache)."""
    sa = sess.scene.arrays()
    box = sa.scene_aabb
    c = 0.5 * (box[0] + box[1])
    top = (c[0] + 0.2 * (box[1][0] - box[0][0]), c[1], box[0][2] + 0.8 * (box[1][2] - box[0][2]))
    seen = bool(np.any(np.asarray(sa.light_ext, bool) & (np.asarray(sa.light_vis)[:, 1] > 0)))
    vis = dict(glossy=seen, transmission=seen)
    if kind in ("AREA", "DISK"):  # (a disk has no closed form: all its term per pixel)
        return Light("Added", "AREA", power=40.0, position=top, direction=(0.0, 0.0, -1.0),
                     size=(0.5, 0.4), shape="SQUARE" if kind == "AREA" else "DISK", **vis)
    if kind == "SUN":
        return Light("Added", "SUN", power=2.0, direction=(0.2, 0.1, -1.0), angle=0.2, **vis)
    return Light("Added", "POINT", power=40.0, position=top, radius=0.3, **vis)


CASES = [("spheres", "AREA"), ("spheres", "SPHERE"), ("soft_penumbra", "AREA"),
         ("soft_penumbra", "SPHERE"), ("soft_penumbra", "SUN"), ("soft_penumbra", "DISK"),
         ("soft_sun", "SPHERE")]


@pytest.mark.parametrize(("name", "kind"), CASES)
def test_an_added_soft_light_keeps_the_cells_it_is_proven_on(name, kind):
    """The cache and the cells the light is proven on are kept (the old code invalidated
    every cell: ``kept == 0``); the kept cells pass their radiance test, their corners are
    a fresh build's samples, a later edit of the light finds the cells that took its term;
    the frame is within epsilon of a fresh BASE frame and of a fresh INTERPOLANT frame."""
    sess = session(MAKE[name](), True)
    f0 = sess.render()
    assert (f0.pixel_class == CLASS_INTERPOLATED).mean() > 0.1
    cache = sess.interpolants.cache
    before = _live(cache)
    rep = sess.apply([LightSet("Added", _soft_light(sess, kind))])
    assert sess.interpolants.cache is cache, "the cache started over"
    after = _live(cache)
    kept = [q for q, (s, _) in after.items() if q in before and before[q][0] == s]
    changed = [q for q in kept if not np.array_equal(after[q][1], before[q][1])]
    assert len(kept) > 0, "no cell kept"
    assert len(kept) + rep.invalidated_interpolants == len(before)
    if kind != "DISK":  # (the light reaches kept cells: the term was taken)
        assert len(changed) > 0
    frame = sess.render()
    assert frame.stats["relit"] and frame.stats["incremental"]
    assert frame.stats["dirty_fraction"] < 1.0
    err = check_bound(frame, sess.scene)
    assert err <= EPS + FLOAT_TOL
    # ... and within epsilon of a fresh INTERPOLANT frame (whose kept cells are a fresh
    # build's: their corners equal the kept cells')
    fresh = Session(sess.scene.copy(), settings())
    fresh.light_terms = True
    ff = fresh.render()
    m = image.compare(frame.radiance, ff.radiance, EPS)
    assert m["max_error"] <= EPS + FLOAT_TOL, m
    check_kept_cells(sess, fresh.interpolants.cache, changed, kind)


@pytest.mark.parametrize("step", ["add", "move"])
def test_proven_shadow_rays_are_not_traced(monkeypatch, step):
    """Shading the kept samples again for an added or moved light with an extent skips the
    shadow rays a shaft proves unoccluded over each cell's roots (``tracing.shaft_skip``,
    one group per cell): fewer shadow rays than with the skips off, and the samples'
    states, shares and radiance, the kept cells and the frame bit for bit the same."""
    from rstrace_engine.tracing import shaft_skip

    out = []
    for skip in (True, False):
        monkeypatch.setattr(shaft_skip, "SHAFT_SKIP", skip)
        sess = session(MAKE["soft_penumbra"](), True)
        sess.render()
        cache = sess.interpolants.cache
        if step == "add":
            edits = [LightSet("Added", _soft_light(sess, "AREA"))]
        else:
            li = sess.scene.lights[sess.scene.light_slot("Area")]
            pos = tuple(np.asarray(li.position) + (0.3, 0.0, 0.0))
            edits = [LightSet("Area", replace(li, position=pos))]
        sess.apply(edits)
        sm = cache.samples
        f = sess.render()
        out.append((cache.totals.get("terms_shadow", 0),
                    cache.totals.get("terms_shadow_skipped", 0),
                    sm._nocc[:sm.n_nodes].copy(), sm.shares()[0].copy(),
                    sm.radiance().copy(), np.flatnonzero(cache.pool.live), f.radiance))
    (traced, skipped, *a), (traced0, skipped0, *b) = out
    assert skipped > 0 and skipped0 == 0
    assert traced < traced0
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)


def test_a_light_mirror_rays_see_first_starts_a_new_cache():
    """The first light mirror and refraction rays can see (none could before) starts a new
    cache (``render._newly_seen``): the cells' samples were not flagged below their roots
    (``samples.seen_flags`` flags them only while some light is seen), so no kept cell may
    be trusted to hold no node the new light shows in. The loosened condition (any light
    seen now, none before) is what keeps the cache for a light added beside a seen one."""
    sess = session(MAKE["spheres"](), True)
    sess.render()
    sa = sess.scene.arrays()
    assert not np.any(np.asarray(sa.light_ext, bool) & (np.asarray(sa.light_vis)[:, 1] > 0))
    cache = sess.interpolants.cache
    light = replace(_soft_light(sess, "SPHERE"), glossy=True, transmission=True)
    sess.apply([LightSet("Added", light)])
    assert sess.interpolants.cache is not cache, "the cache was kept"
    frame = sess.render()
    assert check_bound(frame, sess.scene) <= EPS + FLOAT_TOL
