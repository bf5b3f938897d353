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
from rstrace_engine.tracing.frame_reuse import FrameReuse
from rstrace_engine.tracing.light_bits import column
from rstrace_engine.tracing.light_subset import recombine_pixels
from rstrace_engine.tracing.pixel_records import FLAG_ALWAYS
from rstrace_engine.tracing.sample_rays import ALL, crossing_rays


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
    bit that may change) or one the query proved stays blocked (tracing/sample_proofs.py:
    blocked in the records' frame, its exact ray through an object the edits placed), and
    the frame equals a fresh one."""
    scene = scenes.studio(80, 60) if name == "studio" else SOAK_SCENES[name](48, 36)
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=8)
    sess = Session(scene, settings)
    sess.light_terms = True
    sess.render()
    real = shadow_reshade.crossing_rows
    seen = {"rows": 0, "with": 0, "found": 0, "proved": 0}
    margin = sess.reuse.records.margin(sess.scene.arrays())
    grow = float(np.linalg.norm(margin))

    def both(*a):
        sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, lo, hi, c, r, tag, old, cand, windows, \
            mask, count = a
        real(*a)
        own = np.empty_like(mask)
        real(sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, lo + margin, hi - margin, c, r - grow,
             tag, old, np.full(len(cand), ALL), windows, own, np.empty_like(count))
        proved = own & ~cand
        assert not (proved & old).any()  # (only blocked samples are proven)
        if proved.any():
            start = np.zeros(len(pt) + 1, np.int64)
            np.cumsum([bin(int(b)).count("1") for b in proved], out=start[1:])
            k = int(start[-1])
            o, d, tmax = np.empty((k, 3)), np.empty((k, 3)), np.empty(k)
            crossing_rays(sa, P, Q, NG, NS, MAT, seeds, pt, lj, n, proved, start, o, d, tmax,
                          np.empty(k, np.int64), np.empty(k, np.uint64))
            live = sess.scene.arrays().inst_alive
            met = np.zeros(k, bool)
            for i in sess.reuse.reshade_changed:
                if live[i]:
                    met |= sess.accel.occludes_object(i, o, d, np.zeros(k), tmax)
            assert met.all()
            seen["proved"] += k
        assert not (own & ~mask & ~proved).any()
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


def test_placed_objects_prove_samples_stay_blocked(monkeypatch):
    """studio, the mirror ball moved (the bench's move_small, smaller): the records' query
    drops the soft samples that were blocked and whose rays provably pass through the
    ball's new place, and the sphere light's rows whose whole cone does
    (tracing/sample_proofs.py), every world row asked sample by sample. Against the same
    query without the proofs: most rows go, and every sample dropped is blocked in a fresh
    frame of the edited scene too (its bit in the fresh records); the frame equals a fresh
    one."""
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=8)
    n = settings.light_samples
    full = np.uint64((1 << n) - 1)
    asked = {}
    for prove in (False, True):
        scene = scenes.studio(96, 72)
        sess = Session(scene, settings)
        sess.light_terms = True
        sess.render()
        if not prove:
            monkeypatch.setattr(FrameReuse, "_placed_balls", staticmethod(lambda *a: None))
        sess.apply([_moved(sess.scene, "MirrorBall", 0.1)])
        monkeypatch.undo()
        r = sess.reuse
        L = len(sess.scene.arrays().light_kind)
        per = []  # (L + 1, n_rays) uint64: the samples each row may change (0: none)
        for c in range(L + 1):
            on = r.reshade_world if c == L else column(r.reshade_lights, c)
            bits = np.zeros(len(on), np.uint64)
            nodes = np.flatnonzero(on)
            bits[nodes] = r.reshade_cand.of_rows(nodes, c) & full
            per.append(bits)
        asked[prove] = np.stack(per)
        # every world row has its samples (the cube's sides, whose normals' z is +0.0,
        # among them: that basis is the tracer's, sample_rays._world_crosses)
        w = np.flatnonzero(r.reshade_world)
        assert len(w) and (r.reshade_cand.of_rows(w, L) != ALL).all()
        before = np.asarray(r.records.p_vis, np.uint64).T.copy()
        frame = sess.render()
    fresh = Session(sess.scene.copy(), settings)
    ref = fresh.render()
    np.testing.assert_array_equal(frame.radiance, ref.radiance)
    after = np.asarray(fresh.records.p_vis, np.uint64).T
    dropped = asked[False] & ~asked[True]
    assert not (asked[True] & ~asked[False]).any()
    assert not (dropped & before).any()  # (blocked before ...)
    assert not (dropped & after).any()  # (... and after)
    rows = [int(np.count_nonzero(asked[p])) for p in (False, True)]
    assert rows[1] < 0.6 * rows[0], rows
    for c in range(L):  # the sphere light's rows dropped whole, the area light's samples
        assert np.count_nonzero(asked[True][c]) < np.count_nonzero(asked[False][c]), c


def test_some_pixels_recombine_as_the_whole_frame():
    """tracing/light_subset.py: after object edits under soft light (with mirror and glossy
    secondary nodes), recombining any set of pixels gives their values in the whole
    frame's recombination bit for bit, which is the frame (but where a light's own surface
    is seen), and the incremental frame, which recombines only the pixels it shaded again,
    equals a fresh one."""
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=8, samples=2)
    sess = Session(scenes.studio(64, 48), settings)
    sess.light_terms = True
    sess.render()
    sess.apply([_moved(sess.scene, "MirrorBall", 0.1)])
    assert sess.reshade_mask.any()
    frame = sess.render()
    assert frame.stats["reshaded_pixels"] > 0
    np.testing.assert_array_equal(
        frame.radiance, Session(sess.scene.copy(), settings).render().radiance)
    rec, sa = sess.reuse.records, sess.scene.arrays()
    lr = rec.light
    assert len(lr.s) > 0  # (the mirror ball's reflections: secondary nodes)
    whole = lr.recombine(sa, rec.secondary_rays(), rec.spp, rec.n_pixels)
    # (but where a light's own surface is seen: in no term, traced by every frame)
    always = (rec.t_flags[rec.p_combo] & FLAG_ALWAYS) != 0
    always[rec.secondary_rays()[(rec.t_flags[rec.s_combo] & FLAG_ALWAYS) != 0]] = True
    own = ~always.reshape(rec.spp, -1).any(axis=0)
    assert own.mean() > 0.9
    np.testing.assert_array_equal(whole[own], frame.radiance.reshape(-1, 3)[own])
    rng = np.random.default_rng(3)
    for pix in (np.arange(rec.n_pixels), np.sort(rng.choice(rec.n_pixels, 500, False)),
                np.flatnonzero(sess.reuse.frame.pixel_class.reshape(-1) >= 0)[::7],
                np.zeros(0, np.int64)):
        some = recombine_pixels(lr, sa, rec.secondary_rays(), rec.spp, rec.n_pixels, pix)
        np.testing.assert_array_equal(some, whole[pix])
