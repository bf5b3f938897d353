"""Which re-shaded soft samples are traced again, and against what (tracing/shadow_reshade.py,
issue 20 item 5): the records' queries' per-sample candidates hold every sample the exact
crossing test finds; kept visible samples are tested against the placed objects alone (most
of them proven without a tree, tracing/object_rays.py); frames equal fresh ones bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.edits import ObjectAdd, ObjectDelete, ObjectTransform
from rstrace_engine.session import Session
from rstrace_engine.tracing import shadow_reshade
from rstrace_engine.tracing.sample_rays import ALL


def _moved(scene, key, dx):
    m = scene.instances[scene.instance_slot(key)]["matrix"].copy()
    m[0, 3] += dx
    return ObjectTransform(key, m)


def _edits(name, scene):
    if name == "studio":
        return [[_moved(scene, "MirrorBall", 0.1)], [_moved(scene, "Cube", -0.2)],
                [ObjectAdd("NewBall", "sphere", shapes.transform((0.3, -1.9, 0.15), 0.15),
                           ("blue",))],
                [ObjectDelete("NewBall"), _moved(scene, "MirrorBall", -0.15)]]
    return [[_moved(scene, "Small", 0.25)], [_moved(scene, "Box", -0.3)],
            [ObjectAdd("Extra", "ball", shapes.transform((0.4, 0.3, 0.25), 0.2), ("red",))],
            [ObjectDelete("Extra")]]


@pytest.mark.parametrize("name", ["studio", "soft_room"])
def test_candidates_hold_every_crossing_sample(monkeypatch, name):
    """Each re-shaded row's crossing test is run again on every sample, against the
    edited objects' own boxes and spheres (the records' queries grow them by the margin
    that covers their quantised points; the re-shade tests exact rays against the grown
    ones): every sample found is a candidate (a candidate set missing one would keep a
    bit that may change), and the frame equals a fresh one."""
    scene = scenes.studio(80, 60) if name == "studio" else SOAK_SCENES[name](48, 36)
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=8)
    sess = Session(scene, settings)
    sess.light_terms = True
    sess.render()
    real = shadow_reshade.crossing_rows
    seen = {"rows": 0, "with": 0, "found": 0}
    margin = sess.reuse.records.margin(sess.scene.arrays())
    grow = float(np.linalg.norm(margin))

    def both(*a):
        sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, lo, hi, c, r, tag, old, cand, windows, \
            mask, count = a
        real(*a)
        own = np.empty_like(mask)
        real(sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, lo + margin, hi - margin, c, r - grow,
             tag, old, np.full(len(cand), ALL), windows, own, np.empty_like(count))
        assert not (own & ~cand).any()
        assert not (own & ~mask).any()
        seen["rows"] += len(cand)
        seen["with"] += int((cand != ALL).sum())
        seen["found"] += int(np.count_nonzero(own[cand != ALL]))

    monkeypatch.setattr(shadow_reshade, "crossing_rows", both)
    for edits in _edits(name, sess.scene):
        rep = sess.apply(edits)
        assert not rep.full_frame
        frame = sess.render()
        ref = Session(sess.scene.copy(), settings).render()
        np.testing.assert_array_equal(frame.radiance, ref.radiance)
    # candidates were given, and the exact test found crossing samples among them
    assert seen["with"] > 0.3 * seen["rows"], seen
    assert seen["found"] > 0, seen


def test_placed_objects_decide_kept_samples_exactly():
    """studio, the mirror ball moved (the bench's move_small, smaller): the samples that
    may cross it are tested against it alone, most proven without its tree; the frame
    equals a fresh one, and equals the frame of a session that asks the whole scene."""
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=8)
    frames = []
    for placed in (True, False):
        scene = scenes.studio(96, 72)
        sess = Session(scene, settings)
        sess.light_terms = True
        sess.render()
        sess.apply([_moved(sess.scene, "MirrorBall", 0.1)])
        if not placed:
            sess.accel.any_hit_by_object = False  # (the whole scene asked: the reference)
        frame = sess.render()
        frames.append(frame)
        stats = frame.stats
        assert stats["reshaded_pixels"] > 0
        if placed:
            assert stats["relight_shadow_proven"] > 0.5 * stats["relight_shadow_rays"], stats
        else:
            assert stats["relight_shadow_proven"] == 0
    np.testing.assert_array_equal(frames[0].radiance, frames[1].radiance)
    ref = Session(sess.scene.copy(), settings).render()
    np.testing.assert_array_equal(frames[0].radiance, ref.radiance)
