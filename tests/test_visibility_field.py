"""The visibility field (seed 003): direction look-up, tile lists, dynamic objects.

Agreement with the brute-force oracle on the shared accelerator suite is in
``test_accelerators.py`` (parametrised); here: what is particular to the field.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_accelerators import (
    VF_OPTIONS,
    adversarial_rays,
    assert_same_hits,
    mixed_scene,
    random_rays,
)

from rstrace_engine.accel import directions as dirs_mod
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.accel.visibility_field import DYNAMIC, STATIC, VisibilityField
from rstrace_engine.frame import VF_MAX_DIRECTIONS
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import SceneError

# ----------------------------------------------------------------------------- directions


def test_direction_counts():
    for level in range(dirs_mod.MAX_LEVEL + 1):
        d = dirs_mod.tetra_directions(level)
        assert len(d) == dirs_mod.direction_count(level)
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
        # distinct, and nearly uniform: nearest-neighbour angles within a factor 2.6
        cos = d @ d.T
        np.fill_diagonal(cos, -1.0)
        nn = np.arccos(np.clip(cos.max(axis=1), -1, 1))
        assert nn.min() > 0.0 and nn.max() < 2.6 * nn.min()
    assert [dirs_mod.direction_count(k) for k in range(6)] == [4, 10, 34, 130, 514, 2050]
    assert dirs_mod.level_for(130) == 3 and dirs_mod.level_for(131) == 4
    assert dirs_mod.level_for(1) == 0



def test_direction_limit_is_the_settings_limit():
    assert dirs_mod.direction_count(dirs_mod.MAX_LEVEL) == VF_MAX_DIRECTIONS


@pytest.mark.parametrize("level", range(dirs_mod.MAX_LEVEL + 1))
def test_direction_lookup_matches_brute_force(level):
    table = dirs_mod.direction_table(level)
    rng = np.random.default_rng(level)
    d = rng.normal(size=(20000, 3)) * rng.uniform(1e-3, 1e3, (20000, 1))
    # hard cases too: the stored directions, the tetrahedron's corners, edges and axes
    special = np.concatenate([table.dirs, -table.dirs, table.corners, -table.corners,
                              np.eye(3), -np.eye(3), table.dirs + 1e-12])
    d = np.concatenate([d, special])
    k = dirs_mod.lookup(table, d)
    du = d / np.linalg.norm(d, axis=1, keepdims=True)
    cos = du @ table.dirs.T
    assert np.all(cos[np.arange(len(d)), k] >= cos.max(axis=1) - 1e-15)
    # constant time: a bounded number of candidates per look-up cell, whatever l is
    assert np.diff(table.cell_start).max() <= 16


# ----------------------------------------------------------------------------- tile lists


@pytest.fixture(scope="module")
def field():
    return create_accelerator("VISIBILITY_FIELD", mixed_scene().arrays(), **VF_OPTIONS)


def tile_of(vf: VisibilityField, k: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Tile index of world points ``p`` (m, 3) in subfields ``k`` (m,), as the query maps."""
    sf = vf.sf
    f = sf.frame[k]
    u, v = np.einsum("ij,ij->i", p, f[:, 0:3]), np.einsum("ij,ij->i", p, f[:, 3:6])
    g = sf.grid[k]
    col = np.clip(np.floor((u - g[:, 0]) * g[:, 2]), 0, sf.n - 1).astype(np.int64)
    row = np.clip(np.floor((v - g[:, 1]) * g[:, 3]), 0, sf.n - 1).astype(np.int64)
    return (k * sf.n + row) * sf.n + col


def test_tile_lists_conservative(field):
    """Every point of every triangle, seen along any stored direction, lies in a tile whose
    list holds that triangle (vertices, edge points and interior points; brute force)."""
    vf = field
    sa, refs = vf.sa, vf.refs
    rng = np.random.default_rng(0)
    m = 20000
    q = rng.integers(0, len(refs.inst), m)
    bary = rng.dirichlet((1.0, 1.0, 1.0), m)
    bary[: m // 4] = np.eye(3)[rng.integers(0, 3, m // 4)]  # vertices
    bary[m // 4: m // 2, rng.integers(0, 3)] = 0.0  # edges
    bary /= bary.sum(axis=1, keepdims=True)
    x = sa.inst_xform[refs.inst[q]]
    local = np.einsum("ij,ijk->ik", bary, refs.tv[refs.prim[q]].reshape(-1, 3, 3))
    p = np.einsum("nij,nj->ni", x[:, :3, :3], local) + x[:, :3, 3]
    k = rng.integers(0, len(vf.table.dirs), m)
    t = tile_of(vf, k, p)
    st = vf.static
    for a, b in zip(t, q, strict=True):
        assert b in st.ref[st.start[a]:st.start[a + 1]]
    # ordered along the beam, depth bounds enclose the triangle
    for a in np.unique(t)[:200]:
        z = st.zmin[st.start[a]:st.start[a + 1]]
        assert np.all(np.diff(z) >= 0)
        assert np.all(np.diff(st.pmax[st.start[a]:st.start[a + 1]]) >= 0)


def test_same_hits_and_distances_as_bvh(field):
    """Not just close: the same triangle gives the same t, u, v bit for bit."""
    sa = field.sa
    bvh = create_accelerator("BVH", sa)
    # rays aimed at vertices and edges tie between adjacent triangles (either may win)
    for rays, min_same in ((random_rays(sa, 3000, seed=10), 0.999),
                           (adversarial_rays(sa, seed=11), 0.95)):
        got, want = field.closest_hit(*rays), bvh.closest_hit(*rays)
        assert_same_hits(sa, got, want)
        same = (got.prim == want.prim) & (got.inst == want.inst)
        assert np.mean(same) > min_same
        assert np.array_equal(got.t[same], want.t[same])
        assert np.array_equal(got.u[same], want.u[same])


def test_settings_and_memory_cap():
    sa = mixed_scene().arrays()
    vf = create_accelerator("VISIBILITY_FIELD", sa, directions=100, tiles=4)
    assert vf.stats["directions"] == 130 and vf.stats["tiles"] == 4
    assert vf.stats["memory_mb"] > 0 and vf.stats["static_entries"] > 0
    with pytest.raises(SceneError, match="over the cap"):  # 2050 x 1024^2 tiles: ~57 GB
        create_accelerator("VISIBILITY_FIELD", sa, directions=2050, tiles=1024)
    with pytest.raises(SceneError, match="over the cap"):
        create_accelerator("VISIBILITY_FIELD", sa, directions=34, tiles=8, memory_cap_mb=0.05)
    with pytest.raises(SceneError, match="vf_tiles"):
        create_accelerator("VISIBILITY_FIELD", sa, tiles=0)
    with pytest.raises(SceneError, match="vf_directions"):
        create_accelerator("VISIBILITY_FIELD", sa, directions=10**6)


# ----------------------------------------------------------------------------- dynamic


def test_move_through_a_ray_invalidates(field):
    """Moving an object into and out of a ray: the field sees it where it is now and never
    where it was (GV invalidates the previous dynamic lists)."""
    s = mixed_scene()
    vf = create_accelerator("VISIBILITY_FIELD", s.arrays(), **VF_OPTIONS)
    o = np.array([[5.0, 5.0, 1.0]])
    d = np.array([[-1.0, 0.0, 0.0]])  # along y = 5, z = 1: nothing there at first
    assert vf.closest_hit(o, d, 0.0, np.inf).inst[0] == -1
    gv = vf.gv
    path = [(2.0, 5.0, 1.0), (0.0, 5.0, 1.0), (0.0, 3.0, 1.0), (-3.0, 5.0, 1.0)]
    for step, pos in enumerate(path):
        s.set_instance_matrix(1, shapes.transform(pos))  # Ico1
        sa = s.arrays()
        vf.update(sa)
        assert vf.gv == gv + step + 1 and vf.stats["rebuilds"] == 0
        assert vf._state[1] == DYNAMIC and vf._state[0] == STATIC
        h = vf.closest_hit(o, d, 0.0, np.inf)
        want = create_accelerator("BVH", sa).closest_hit(o, d, 0.0, np.inf)
        assert h.inst[0] == want.inst[0] and h.t[0] == want.t[0]
        assert (h.inst[0] == 1) == (pos[1] == 5.0)
        if h.inst[0] == 1:
            assert h.t[0] == pytest.approx(5.0 - pos[0] - 1.0, abs=0.05)  # unit icosphere
    # the previous versions' entries are gone (memory reclaimed), the stamps are current
    dyn = vf.dynamic
    assert len(dyn.ref) == vf.stats["dynamic_entries"]
    assert np.all(vf.refs.inst[dyn.ref] == 1)
    assert np.count_nonzero(dyn.stamp == vf.gv) <= vf.stats["dynamic_entries"]


def test_dynamic_updates_match_bvh():
    """Several objects move over several frames: every frame equals a fresh BVH."""
    s = mixed_scene()
    vf = create_accelerator("VISIBILITY_FIELD", s.arrays(), **VF_OPTIONS)
    rng = np.random.default_rng(3)
    for frame in range(3):
        for inst in (1, 2, 4):
            s.set_instance_matrix(inst, shapes.transform(
                (rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(0.5, 1.0)),
                1.0, rng.uniform(0, 90), rng.uniform(0, 90)))
        sa = s.arrays()
        vf.update(sa)
        assert vf.stats["rebuilds"] == 0
        bvh = create_accelerator("BVH", sa)
        rays = random_rays(sa, 2000, seed=frame)
        assert_same_hits(sa, vf.closest_hit(*rays), bvh.closest_hit(*rays))
        assert np.array_equal(vf.any_hit(*rays), bvh.any_hit(*rays))
        for inst in (1, 4):
            assert_same_hits(sa, vf.intersect_object(inst, *rays),
                             bvh.intersect_object(inst, *rays))
    assert vf.stats["dynamic_instances"] == 3
    # leaving the field box: a rebuild, still exact
    s.set_instance_matrix(2, shapes.transform((40.0, 0.0, 1.0)))
    sa = s.arrays()
    vf.update(sa)
    assert vf.stats["rebuilds"] == 1 and vf.stats["dynamic_instances"] == 0
    rays = random_rays(sa, 2000, seed=9)
    assert_same_hits(sa, vf.closest_hit(*rays), create_accelerator("BVH", sa).closest_hit(*rays))
    # new geometry (an object added): a rebuild
    s.add_instance(0, shapes.transform((0.0, 0.0, 3.0)), [0], "Extra")
    sa = s.arrays()
    vf.update(sa)
    assert vf.stats["rebuilds"] == 2
    assert_same_hits(sa, vf.closest_hit(*rays), create_accelerator("BVH", sa).closest_hit(*rays))


# ----------------------------------------------------------------------------- bench


def test_bench_accel_json_quick():
    import io
    import json
    from contextlib import redirect_stdout

    from rstrace_engine.bench import accel

    buf = io.StringIO()
    with redirect_stdout(buf):
        assert accel.main(["--json", "--quick", "--directions", "34", "--tiles", "8"]) == 0
    rows = json.loads(buf.getvalue())["rows"]
    keys = {"scene", "accelerator", "dynamic_objects", "workload", "mrays", "update_ms",
            "build_s", "memory_mb"}
    assert all(keys <= set(r) for r in rows)
    names = {r["accelerator"] for r in rows}
    assert {"BVH", "VISIBILITY_FIELD"} <= names <= {"BVH", "EMBREE", "VISIBILITY_FIELD"}
    fig2 = [r for r in rows if r["workload"] == "figure2-primary"]
    assert {r["dynamic_objects"] for r in fig2} == {0, 2}
    assert all(r["mrays"] > 0 and r["update_ms"] >= 0 for r in fig2)
    vf = [r for r in fig2 if r["accelerator"] == "VISIBILITY_FIELD"]
    assert all(r["memory_mb"] > 0 and r["rebuilds"] == 0 for r in vf)
    # the moving dolphins' entries make the field bigger than the static scene alone
    assert vf[1]["memory_mb"] > vf[0]["memory_mb"]


def test_far_from_origin_and_degenerate_rays():
    """Offsets scale with the coordinates: the scene moved 1e5 away still equals the BVH;
    zero-length directions and empty intervals miss, as they do for the BVH."""
    s = mixed_scene()
    shift = shapes.transform((1e5, -2e5, 3e4))
    for i in range(len(s.instances)):
        s.set_instance_matrix(i, shift @ s.instances[i]["matrix"])
    sa = s.arrays()
    vf = create_accelerator("VISIBILITY_FIELD", sa, **VF_OPTIONS)
    bvh = create_accelerator("BVH", sa)
    rays = random_rays(sa, 2000, seed=21)
    assert_same_hits(sa, vf.closest_hit(*rays), bvh.closest_hit(*rays))
    o, d = rays[0][:50].copy(), rays[1][:50].copy()
    d[:25] = 0.0
    h = vf.closest_hit(o, d, 0.0, np.inf)
    assert np.array_equal(h.inst, bvh.closest_hit(o, d, 0.0, np.inf).inst)
    assert np.all(h.inst[:25] == -1)
    assert not vf.any_hit(o, d, np.full(50, 2.0), np.full(50, 1.0)).any()


def test_session_moves_make_objects_dynamic_and_frames_equal_bvh():
    """Through the session (what the add-on holds): a moved object becomes dynamic, and the
    frame equals the BVH session's pixel for pixel."""
    from rstrace_engine import scenes
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.session import Session

    frames = {}
    for acc in ("BVH", "VISIBILITY_FIELD"):
        sc = scenes.three_spheres(32, 24, subdivisions=2)
        sess = Session(sc, RenderSettings(max_depth=2, accelerator=acc, vf_directions=34,
                                          vf_tiles=8))
        sess.render()
        sc.set_instance_matrix(1, shapes.transform((0.3, 0.2, 1.0)))
        sess.update_scene(sc)
        frames[acc] = sess.render().radiance
        if acc == "VISIBILITY_FIELD":
            assert sess.accel.stats["dynamic_instances"] == 1 and sess.accel.gv == 1
            assert sess.stats["accel_memory_mb"] > 0
    np.testing.assert_array_equal(frames["VISIBILITY_FIELD"], frames["BVH"])
