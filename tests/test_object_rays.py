"""Rays against one object, proven without its tree (tracing/object_rays.py): every proof
agrees with the accelerators' own object test (BVH and brute force) on closed, open,
non-convex, inside-out, welded and mirrored meshes, rays grazing the proven balls
included; and the proofs decide most rays through a closed convex object."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Material, Mesh, Scene
from rstrace_engine.tracing.object_rays import (
    meets_object,
    prove_rays,
    solid_ball,
)


def _open_sphere() -> Mesh:
    """An icosphere with one triangle taken out (a hole facing +x)."""
    m = shapes.icosphere(2, name="open")
    v, f = m.vertices, m.triangles
    return Mesh("open", v, np.delete(f, _hole(v, f), axis=0), smooth=False)


def _hole(v, f) -> int:
    return int(np.argmax(v[f].mean(axis=1)[:, 0]))


def _welded_box() -> Mesh:
    """A box whose faces each have their own four vertices (as exporters split them at
    sharp edges): closed only once equal coordinates are welded."""
    b = shapes.box((1.0, 0.7, 0.5))
    v, f = b.vertices, b.triangles
    return Mesh("split", v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3),
                smooth=False)


MESHES = {
    "ico": (shapes.icosphere(3), True),
    "box": (shapes.box((1.0, 0.6, 0.4)), True),
    "inward": (shapes.box((0.8, 0.8, 0.8), inward=True), True),
    "split": (_welded_box(), True),
    "lumpy": (shapes.lumpy_sphere(800), None),  # (star-shaped or not: either is sound)
    "torus": (shapes.torus(0.8, 0.25, 24, 12), False),  # (its centre is outside it)
    "open": (_open_sphere(), False),
}

PLACES = [
    shapes.transform((0.0, 0.0, 0.0)),
    shapes.transform((3.0, -1.0, 0.5), (0.6, 1.3, 0.8), 35, 20),
    shapes.transform((-2.0, 2.0, 1.0), (-0.7, 0.7, 0.7), 10, 70),  # mirrored
    shapes.transform((1e3, 2e3, -5e2), 0.01, 60, 15),  # small and far from the origin
]


@pytest.fixture(scope="module")
def placed():
    s = Scene()
    s.add_material(Material("m"))
    names = []
    for key, (mesh, _) in MESHES.items():
        mid = s.add_mesh(mesh, key=key)
        for p, m in enumerate(PLACES):
            s.add_instance(mid, m, [0], name=f"{key}{p}")
            names.append((key, s.instance_slot(f"{key}{p}")))
    return s, s.arrays(), names


def _rays(sa, i, rng, n=4000):
    """Rays from outside object ``i``'s vertex sphere towards points in and about it (ends
    at the target, beyond it or at infinity), and rays grazing its proven balls."""
    lo, hi = sa.inst_aabb[i]
    c = 0.5 * (lo + hi)
    r = 0.5 * float(np.linalg.norm(hi - lo))
    u = rng.normal(size=(n, 3))
    o = c + 3.0 * r * u / np.linalg.norm(u, axis=1)[:, None]
    target = c + r * rng.uniform(-1.1, 1.1, (n, 3))
    d = target - o
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    tmax = np.where(rng.random(n) < 0.3, np.inf, dist * rng.choice([0.5, 1.0, 2.0], n))
    return o, d, tmax


def _grazing(sa, i, ball, rng, n=600):
    """Rays passing at the proven radii (relative offsets of a few 1e-9 to 1e-4 about
    them), in world space."""
    c, r_in, r_out = ball
    m = np.linalg.inv(sa.inst_inv[i])
    out = []
    for radius in (r_in, r_out):
        if radius <= 0.0:
            continue
        a = rng.normal(size=(n, 3))
        a /= np.linalg.norm(a, axis=1)[:, None]
        b = np.cross(a, rng.normal(size=(n, 3)))
        b /= np.linalg.norm(b, axis=1)[:, None]
        eps = rng.choice([-1e-4, -1e-6, -3e-9, 0.0, 3e-9, 1e-6, 1e-4], n)
        near = c + b * (radius * (1.0 + eps))[:, None]  # (object space)
        start = near - a * 3.0 * r_out
        wo = start @ m[:3, :3].T + m[:3, 3]
        wn = near @ m[:3, :3].T + m[:3, 3]
        d = wn - wo
        d /= np.linalg.norm(d, axis=1)[:, None]
        out.append((wo, d, np.full(n, np.inf)))
    return [np.concatenate(x) for x in zip(*out, strict=True)]


@pytest.mark.parametrize("accel_name", ["BVH", "BRUTE_FORCE"])
def test_proofs_agree_with_the_object_test(placed, accel_name):
    scene, sa, names = placed
    accel = create_accelerator(accel_name, sa)
    rng = np.random.default_rng(7)
    proven = {}
    for key, i in names:
        mesh = sa.inst_mesh[i]
        s, e = sa.mesh_tri_start[mesh], sa.mesh_tri_start[mesh + 1]
        ball = solid_ball(sa.verts, sa.tris[s:e])
        closed = MESHES[key][1]
        if closed is not None:
            assert (ball[1] > 0.0) == closed, (key, ball)
        for o, d, tmax in (_rays(sa, i, rng), _grazing(sa, i, ball, rng)):
            rows = np.arange(len(o))
            proof = np.zeros(len(o), np.int8)
            prove_rays(sa.inst_inv, i, *ball, o, d, tmax, rows, proof)
            truth = accel.occludes_object(i, o, d, np.zeros(len(o)), tmax)
            assert truth[proof > 0].all(), (key, i, int((~truth[proof > 0]).sum()))
            assert not truth[proof < 0].any(), (key, i)
            counters: dict = {}
            got = meets_object(sa, accel, i, o, d, tmax, rows, counters)
            np.testing.assert_array_equal(got, truth)
            hit, miss = proven.get(key, (0, 0))
            proven[key] = (hit + int((proof > 0).sum()), miss + int((proof < 0).sum()))
    # the proofs decide rays through closed objects that c sees from inside, and no ray
    # is proven to meet an object that is open or does not hold c
    for key in ("ico", "box", "inward", "split"):
        assert proven[key][0] > 1000, (key, proven[key])
    for key in ("torus", "open"):
        assert proven[key][0] == 0, (key, proven[key])
    assert all(miss > 0 for _, miss in proven.values())


def test_a_ray_through_the_hole_is_not_proven():
    """Rays through the missing triangle of an open sphere, into its centre: the object
    test finds nothing before the centre (no proof may claim a hit there)."""
    mesh = _open_sphere()
    s = Scene()
    s.add_material(Material("m"))
    s.add_instance(s.add_mesh(mesh), np.eye(4), [0], name="open")
    sa = s.arrays()
    accel = create_accelerator("BVH", sa)
    full = shapes.icosphere(2)
    hole = full.vertices[full.triangles[_hole(full.vertices, full.triangles)]].mean(axis=0)
    rng = np.random.default_rng(3)
    target = hole + 0.01 * rng.normal(size=(200, 3))
    o = np.tile(hole * 3.0, (200, 1))
    d = target - o
    t = np.linalg.norm(d, axis=1)
    d /= t[:, None]
    tmax = t + np.linalg.norm(hole) * 0.9  # (ends inside, short of the far side)
    truth = accel.occludes_object(0, o, d, np.zeros(200), tmax)
    assert not truth.all()  # (some pass through the hole)
    proof = np.zeros(200, np.int8)
    ball = solid_ball(mesh.vertices, mesh.triangles)
    prove_rays(sa.inst_inv, 0, *ball, o, d, tmax, np.arange(200), proof)
    assert not (proof[~truth] > 0).any()


@pytest.mark.parametrize("accel_name", ["BVH", "BRUTE_FORCE"])
def test_scene_query_is_its_objects(placed, accel_name):
    """What the re-shade relies on (``Accelerator.any_hit_by_object``): a ray's any-hit
    answer over the whole scene is, bit for bit, whether one of the live objects' own
    tests meets it -- rays grazing the objects' boxes included."""
    scene, sa, names = placed
    accel = create_accelerator(accel_name, sa)
    assert accel.any_hit_by_object
    rng = np.random.default_rng(11)
    o, d, tmax = [], [], []
    for _, i in names[::3]:
        a, b, c = _rays(sa, i, rng, 1500)
        o.append(a)
        d.append(b)
        tmax.append(c)
        lo, hi = sa.inst_aabb[i]  # (rays along the box's faces and edges)
        corner = np.where(rng.random((300, 3)) < 0.5, lo, hi)
        start = corner + rng.normal(size=(300, 3)) * np.linalg.norm(hi - lo)
        o.append(start)
        dd = corner - start
        d.append(dd / np.linalg.norm(dd, axis=1)[:, None])
        tmax.append(np.full(300, np.inf))
    o, d, tmax = np.concatenate(o), np.concatenate(d), np.concatenate(tmax)
    zero = np.zeros(len(o))
    any_hit = accel.any_hit(o, d, zero, tmax)
    each = np.zeros(len(o), bool)
    for i in np.flatnonzero(sa.inst_alive):
        each |= accel.occludes_object(np.full(len(o), i, np.int32), o, d, zero, tmax)
    np.testing.assert_array_equal(any_hit, each)
    assert 0.2 < any_hit.mean() < 0.95


def test_a_large_mesh_proves_nothing(monkeypatch):
    """Over the size examined (object_rays.SOLID_MAX_TRIS) a mesh gets no proof either
    way: every ray goes to the accelerator."""
    from rstrace_engine.tracing import object_rays

    mesh = shapes.icosphere(2)
    monkeypatch.setattr(object_rays, "SOLID_MAX_TRIS", len(mesh.triangles) - 1)
    c, r_in, r_out = solid_ball(mesh.vertices, mesh.triangles)
    assert r_in == 0.0 and r_out == np.inf
    rng = np.random.default_rng(5)
    o = rng.normal(size=(500, 3)) * 4.0
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    proof = np.ones(500, np.int8)
    prove_rays(np.eye(4)[None], 0, c, r_in, r_out, o, d, np.full(500, np.inf),
               np.arange(500), proof)
    assert (proof == 0).all()
