"""The interpolants' query structures (``InterpolantCache.qs``, :func:`~rstrace_engine.
interpolants.shafts.query_scene`: the mesh and instance BVHs, topology, materials, lights)
are not built again by a light or world edit (issue 21): the packing differs in its lights
and world alone (``shafts.lights_only``), so its light fields are replaced and the
geometry's kept -- field for field what a build over the edited packing gives. An object
edit builds them again."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from test_relight_interpolants import cells_always, session  # noqa: F401 (the fixture)

from rstrace_engine.bench.soak import soft_room_unlit_world
from rstrace_engine.geometry.edits import (
    LightDelete,
    LightSet,
    MaterialSet,
    ObjectTransform,
    WorldColor,
)
from rstrace_engine.geometry.mesh_topology import mesh_topology
from rstrace_engine.geometry.scene import Light
from rstrace_engine.interpolants import interpolant_cache
from rstrace_engine.interpolants.sampled_term import sampled_possible
from rstrace_engine.interpolants.shafts import query_scene

BUILD = interpolant_cache.query_scene


def _built(sa):
    """What the cache's ``qs`` holds when built over ``sa`` from nothing."""
    qs = query_scene(sa, mesh_topology(sa))
    if sampled_possible(sa):
        qs = qs._replace(light_closed=np.ascontiguousarray(qs.light_ext, np.bool_),
                         mat_glossy=np.zeros_like(qs.mat_glossy))
    return qs


def _same(a, b) -> None:
    for f in a._fields:
        x, y = getattr(a, f), getattr(b, f)
        if isinstance(x, np.ndarray):
            assert x.dtype == np.asarray(y).dtype and np.array_equal(x, y), f
        else:
            assert x == y, f


def _light(sess, key, **kw):
    li = sess.scene.lights[sess.scene.light_slot(key)]
    return [LightSet(key, replace(li, **kw))]


def _counted_session(monkeypatch):
    """A soft room's INTERPOLANT session after its first frame, and the list that grows by
    one at every build of the query structures."""
    calls = []

    def build(sa, topo):
        calls.append(1)
        return BUILD(sa, topo)

    monkeypatch.setattr(interpolant_cache, "query_scene", build)
    sess = session(soft_room_unlit_world(96, 72), True)
    sess.render()
    return calls, sess


def test_light_edits_keep_the_query_structures(monkeypatch):
    calls, sess = _counted_session(monkeypatch)
    cache = sess.interpolants.cache
    assert len(calls) == 1
    lamp = sess.scene.lights[sess.scene.light_slot("Lamp")]
    for batch in (
            lambda: _light(sess, "Lamp", position=tuple(np.asarray(lamp.position) + 0.3)),
            lambda: _light(sess, "Area", size=(2.0, 1.0)),
            lambda: _light(sess, "Lamp", radius=0.5, power=500.0),
            lambda: _light(sess, "Sun", angle=0.2, direction=(0.2, 0.5, -1.0)),
            lambda: [WorldColor((0.1, 0.1, 0.1))],
            lambda: [LightSet("Extra", Light("Extra", "POINT", power=100.0,
                                             position=(0.0, 0.0, 3.0)))],
            lambda: [LightDelete("Extra")]):
        sess.apply(batch())
        assert sess.interpolants.cache is cache
        sess.render()
        _same(cache.qs, _built(cache.sa))
    assert len(calls) == 1  # (built once, by the first frame)
    # an object edit: built again
    m = sess.scene.instances[sess.scene.instance_slot("Small")]["matrix"].copy()
    m[0, 3] += 0.1
    sess.apply([ObjectTransform("Small", m)])
    sess.render()
    assert len(calls) == 2
    _same(cache.qs, _built(cache.sa))


def test_a_light_edit_with_an_object_or_material_edit_builds_them_again(monkeypatch):
    """A batch that edits a light and an object (or a material) packs the geometry again:
    the query structures are built again, not taken from the last packing's, and they are
    a fresh build's (a light drag with an object move in one batch kept no stale BVH)."""
    calls, sess = _counted_session(monkeypatch)
    lamp = sess.scene.lights[sess.scene.light_slot("Lamp")]
    m = sess.scene.instances[sess.scene.instance_slot("Small")]["matrix"].copy()
    m[0, 3] += 0.1
    key = next(iter(sess.scene.material_keys.slot))
    mat = sess.scene.materials[sess.scene.material_id(key)]
    for n, batch in enumerate((
            [_light(sess, "Lamp", position=tuple(np.asarray(lamp.position) + 0.3))[0],
             ObjectTransform("Small", m)],
            [_light(sess, "Lamp", power=2.0 * lamp.power)[0],
             MaterialSet(key, replace(mat, roughness=0.5 * mat.roughness + 0.1))],
            [WorldColor((0.1, 0.1, 0.1)), ObjectTransform("Small", np.eye(4))])):
        sess.apply(batch)
        sess.render()
        assert len(calls) == n + 2
        _same(sess.interpolants.cache.qs, _built(sess.interpolants.cache.sa))
