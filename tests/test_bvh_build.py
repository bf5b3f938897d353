"""The parallel BVH build (:mod:`rstrace_engine.accel.bvh_build`): the same tree on any
thread count and as one sequential build, mesh BVHs reused through edits and held once,
cancelled builds, meshes too large for the memory, and ``bench scale`` at a small size."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rstrace_engine import warm_first
from rstrace_engine.accel import accelerators, bvh, bvh_bins, bvh_build, bvh_mesh
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench import scale
from rstrace_engine.cancel import CancelFlag, Cancelled
from rstrace_engine.geometry import footprint, shapes
from rstrace_engine.geometry.attributes import ATTR_VERTEX
from rstrace_engine.geometry.edits import MeshSet, ObjectTransform
from rstrace_engine.geometry.packing import mesh_triangles
from rstrace_engine.geometry.scene import Material, Scene, SceneError
from rstrace_engine.session import Session


def _tv(mesh) -> np.ndarray:
    return np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.triangles)]


def _same_tree(a: bvh_mesh.MeshBVH, b: bvh_mesh.MeshBVH) -> None:
    assert np.array_equal(a.bvh.bounds, b.bvh.bounds)
    assert np.array_equal(a.bvh.child, b.bvh.child)
    assert np.array_equal(a.tri, b.tri)


def _skewed(n: int) -> np.ndarray:
    """Triangles of geometrically shrinking sizes (deep, lopsided SAH trees)."""
    s = 2.0 ** (-np.arange(n, dtype=np.float64) / 40)
    return np.stack([np.stack([s, s, s], 1), np.stack([2 * s, s, s], 1),
                     np.stack([s, 2 * s, s], 1)], 1)


@pytest.mark.parametrize("tv", [
    _tv(shapes.lumpy_sphere(30_000)),
    np.tile(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float64), (3000, 1, 1)),
    _skewed(4000),
], ids=["lumpy", "coincident", "skewed"])
def test_parallel_build_is_the_sequential_tree(tv):
    """Top levels split in parallel (a small grain: many levels, many subtrees) give
    exactly the tree of one sequential build, on one thread or all of them."""
    seq = bvh_mesh.build_mesh_bvh(tv, grain=len(tv))
    saved = numba.get_num_threads()
    try:
        for threads in sorted({1, saved}):
            numba.set_num_threads(threads)
            for grain in (64, None):
                _same_tree(bvh_mesh.build_mesh_bvh(tv, grain=grain), seq)
    finally:
        numba.set_num_threads(saved)
    assert sorted(seq.tri.tolist()) == list(range(len(tv)))


@pytest.mark.parametrize("cheap_max", [bvh_bins.CHEAP_MAX, bvh_bins.CHEAP_ALL])
def test_one_primitive_leaf_trees_are_the_same_on_any_grain(cheap_max):
    """A tree of one-primitive leaves (a large mesh's item tree, the top level) built as one
    subtree and with many (a small grain: many top levels) is the same tree (session 35: a
    partition whose order differed between the phases broke this), with the cheap rule
    up to ``CHEAP_MAX`` primitives and on every node (the item build's, session 37)."""
    tv = _tv(shapes.lumpy_sphere(20_000))
    pb = bvh_mesh.outward32(tv.min(axis=1), tv.max(axis=1))
    seq, par = (bvh_mesh.flatten(*bvh_build.build_flat_boxes(pb.copy(), 1, grain=g,
                                                              cheap_max=cheap_max)[:3],
                                 np.float32) for g in (len(pb), 64))
    assert np.array_equal(seq.bounds.view(np.int32), par.bounds.view(np.int32))
    assert np.array_equal(seq.child, par.child)
    assert np.array_equal(seq.perm, par.perm)


def test_small_nodes_are_binned_on_their_long_axes_only():
    """A node of at most ``CHEAP_MAX`` primitives is binned only on the axes whose
    centroid extent is at least ``CHEAP_AXIS_FRAC`` of the longest's (session 36: ~13%
    less subtree CPU for ~0.4% more SAH cost). Two rows of small boxes along x, 4 apart
    in z (less than half their extent in x): the SAH would split between the rows, but
    a small node splits across x; a node past the cheap size still splits between them."""
    assert 200 <= bvh_bins.CHEAP_MAX < 5000
    for n, between_rows in ((200, False), (5000, True)):
        x = np.linspace(0.0, 10.0, n // 2)
        c = np.concatenate([np.stack([x, 0 * x, 0 * x], 1), np.stack([x, 0 * x, 4 + 0 * x], 1)])
        b, ch, perm, sah = bvh_build.build_flat(c - 0.05, c + 0.05)
        z_extent = b[0, 5] - b[0, 2], b[0, 11] - b[0, 8]  # the root's two children
        assert (max(z_extent) < 1.0) == between_rows, (n, z_extent)
        assert (min(z_extent) > 3.0) == (not between_rows), (n, z_extent)


def test_an_sah_splits_children_are_binned_over_their_boxes():
    """Below an SAH split a node's bins are laid over its box, not its centroid bounds
    (session 37: the partition gathers nothing, the bins give the boxes). Two rows of
    boxes along x, 4 apart in z, each box 2 tall in z, beside a far cluster the root
    splits off: the rows' node spreads its centroids 0.4 as far in z as in x (z not
    binned, ``CHEAP_AXIS_FRAC``: split across x) but its box 0.59 as far (z binned: split
    between the rows, the lower SAH cost). Fails on main (centroid bounds)."""
    x = np.linspace(0.0, 10.0, 50)
    c = np.concatenate([np.stack([x, 0 * x, 0 * x], 1), np.stack([x, 0 * x, 4 + 0 * x], 1),
                        [[1000.0, 0, 0], [1001, 0, 0], [1000, 1, 0], [1001, 1, 0]]])
    half = np.array([0.05, 0.05, 1.0])
    for grain in (None, 16):
        b, ch, perm, sah = bvh_build.build_flat(c - half, c + half, grain=grain)
        rows = [s for s in range(2) if b[0, 6 * s + 3] < 100.0]
        assert len(rows) == 1 and ch[0, rows[0]] >= 0
        node = ch[0, rows[0]]
        z_extent = b[node, 5] - b[node, 2], b[node, 11] - b[node, 8]
        assert max(z_extent) < 3.0, (grain, z_extent)


def _long_cylinder(n: int) -> np.ndarray:
    """A cylinder 10 long along x, radius 1, of ``n`` full-length triangles (its quads
    split), in a shuffled order."""
    a = np.linspace(0.0, 2 * np.pi, n // 2 + 1)
    ring = np.stack([0 * a, np.cos(a), np.sin(a)], 1)
    q0, q1, length = ring[:-1], ring[1:], np.array([10.0, 0.0, 0.0])
    tv = np.concatenate([np.stack([q0, q0 + length, q1 + length], 1),
                         np.stack([q0, q1 + length, q1], 1)])
    return tv[np.random.default_rng(3).permutation(len(tv))]


def test_a_node_whose_centroids_share_one_bin_of_its_box_is_binned_over_its_centroids():
    """Bins laid over a node's box (below an SAH split, session 37) can hold all its
    centroids in one bin: a long cylinder's full-length triangles all have their
    centroid in the middle of the box along x, the only axis the cheap rule bins. Such a
    node is binned again over its centroid bounds (as on main), not split at an object
    median along x, where every centroid is equal (the shuffled mesh order: SAH cost 142
    instead of main's 21.9; 40.3 at a mesh's :data:`.bvh_mesh.SMALL_TRAV_COST` 2, session
    42). The same tree on any grain."""
    tv = _long_cylinder(3000)
    seq = bvh_mesh.build_mesh_bvh(tv, grain=len(tv))
    assert seq.sah_cost < 60.0, seq.sah_cost
    _same_tree(bvh_mesh.build_mesh_bvh(tv, grain=16), seq)
    pb = tv.min(axis=1), tv.max(axis=1)
    for grain in (len(tv), 16):  # the item build's rule (the cheap rule on every node)
        b, c, perm, sah = bvh_build.build_flat_boxes(np.concatenate(pb, 1), 1, grain=grain,
                                                     cheap_max=bvh_bins.CHEAP_ALL)
        assert sah < 30.0, (grain, sah)


def test_binary_nodes_are_packed():
    """The binary build's nodes are all reachable from the root (none left unused by the
    subtrees' stretches) and every primitive is in one leaf."""
    tv = _tv(shapes.lumpy_sphere(20_000))
    lo, hi = tv.min(axis=1), tv.max(axis=1)
    b, c, perm, sah = bvh_build.build_flat(lo, hi, grain=256)
    seen_nodes, seen_prims = set(), np.zeros(len(tv), int)
    stack = [0]
    while stack:
        node = stack.pop()
        seen_nodes.add(node)
        for s in range(2):
            ch = int(c[node, s])
            if ch >= 0:
                stack.append(ch)
            else:
                start, count = (~ch) >> 3, (~ch) & 7
                seen_prims[start:start + count] += 1
    assert seen_nodes == set(range(len(c)))
    assert np.all(seen_prims == 1) and sah > 0
    assert sorted(perm.tolist()) == list(range(len(tv)))


def test_mesh_tree_collapsed_from_the_unpacked_nodes_is_the_packed_one():
    """A mesh's 4-wide tree collapsed straight from the builder's unpacked node arrays,
    each box widened as it is read (``build_flat_boxes(packed=False)``, ``flatten``) is
    the tree of the packed nodes widened first (``pad_outward``), bit for bit, and the
    unpacked arrays are left as built: one subtree, and many (grain 256, rows between the
    subtrees' stretches unused)."""
    tv = _tv(shapes.lumpy_sphere(20_000))
    pb = np.concatenate([tv.min(axis=1), tv.max(axis=1)], axis=1)
    for grain in (None, 256):
        b, c, perm, sah = bvh_build.build_flat_boxes(pb.copy(), grain=grain)
        b4, c4, m = bvh_mesh.collapse4(bvh_mesh.pad_outward(b), c,
                                       np.empty((len(c), 24), np.float32), False)
        ub, uc, uperm, usah = bvh_build.build_flat_boxes(pb.copy(), grain=grain,
                                                         packed=False)
        assert len(uc) > len(c) and usah == sah and np.array_equal(uperm, perm)
        built = ub.copy()
        flat = bvh_mesh.flatten(ub, uc, uperm, np.float32)
        assert np.array_equal(flat.bounds.view(np.int32), b4[:m].view(np.int32))
        assert np.array_equal(flat.child, c4[:m])
        assert np.array_equal(ub.view(np.int64), built.view(np.int64))


def test_a_two_primitive_split_is_the_binned_one():
    """``_two_split`` (a node of two primitives, no bins) gives the cost, axis and bin the
    bins give (``_bin_range`` then ``_best_split``), on random pairs, pairs whose centroids
    agree on one or two axes, equal boxes, and flat (zero-area) boxes."""
    rng = np.random.default_rng(5)
    nb = 2
    bin_n = np.zeros((3, nb), np.int64)
    bin_b = np.empty((3, nb, 6))
    right_a, right_n = np.empty(nb), np.empty(nb, np.int64)
    cases = 0
    for trial in range(400):
        lo = rng.integers(-4, 4, (2, 3)).astype(np.float32)
        pb = np.concatenate([lo, lo + rng.integers(0, 3, (2, 3))], 1).astype(np.float32)
        if trial % 4 == 1:  # the same centroid on some axes
            same = rng.random(3) < 0.6
            pb[1, :3][same], pb[1, 3:][same] = pb[0, :3][same], pb[0, 3:][same]
        elif trial % 4 == 2:
            pb[1] = pb[0]
        c = 0.5 * (pb[:, :3].astype(np.float64) + pb[:, 3:])
        cmin, cmax = c.min(axis=0), c.max(axis=0)
        bvh_build._clear_bins(bin_n, bin_b, nb)
        bvh_build._bin_range(pb, 0, 2, cmin, cmax, nb, bin_n, bin_b)
        want = bvh_build._best_split(cmin, cmax, nb, bin_n, bin_b, right_a, right_n)
        got = bvh_build._two_split(pb, 0, cmin, cmax)
        assert got == want, (pb, got, want)
        cases += want[1] >= 0
    assert 0 < cases < 400  # (both a split and no split are checked)


def test_build_kernels_are_in_the_first_image_list():
    assert set(bvh_build.BUILD_KERNELS) <= set(warm_first.FIRST_IMAGE_KERNELS)


def test_the_large_build_warm_up_runs_the_parallel_kernels_renders_call(monkeypatch):
    """``warm_kernels._warm_large_bvh`` runs each parallel builder kernel a render calls
    from Python for a mesh past ``PARALLEL_MIN`` triangles: the mesh BVH's
    (``indexed_boxes``, ``build_subtrees``) and ``pack_nodes``, which the mesh BVH no longer
    runs (it collapses the unpacked nodes) but the interpolants' query scene does
    (``shafts.binary_bvh``: ``build_flat``, packed). A kernel no warm-up step runs is
    missing from the shipped cache: the user's first such frame compiles it (pack_nodes:
    about 4 s of CPU)."""
    from rstrace_engine import warm_kernels

    calls = dict.fromkeys(("pack_nodes", "build_subtrees", "indexed_boxes"), 0)
    for module, name in ((bvh_build, "pack_nodes"), (bvh_build, "build_subtrees"),
                         (bvh_mesh, "indexed_boxes")):
        assert f"accel.{module.__name__.rsplit('.', 1)[1]}.{name}" in \
            bvh_build.LARGE_BUILD_KERNELS

        real = getattr(module, name)

        def counted(*args, _real=real, _name=name):
            calls[_name] += 1
            return _real(*args)

        monkeypatch.setattr(module, name, counted)
    warm_kernels._warm_large_bvh()
    assert all(calls.values()), calls


# ----------------------------------------------------------------------------- reuse


def _big_and_small(big: int = 20_000) -> Scene:
    s = Scene()
    s.add_material(Material("m"))
    s.add_instance(s.add_mesh(shapes.lumpy_sphere(big, name="big"), key="big"), np.eye(4),
                   key="Big")
    s.add_instance(s.add_mesh(shapes.icosphere(1, 0.2, name="small"), key="small"),
                   shapes.transform((1.5, 0.0, 0.0)), key="Small")
    return s


def _rays(n: int = 4000, seed: int = 3):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d


def _same_hits(acc, sa) -> None:
    o, d = _rays()
    h, ref = acc.closest_hit(o, d, 0.0, np.inf), create_accelerator("BVH", sa).closest_hit(
        o, d, 0.0, np.inf)
    for a, b in zip(h, ref, strict=True):
        assert np.array_equal(a, b)


def test_mesh_bvh_reused_through_edits_and_held_once():
    """Moving the small object rebuilds no mesh BVH; re-meshing it rebuilds its BVH
    alone, the big mesh's is reused (moved to its new place in the concatenation, which
    holds every mesh's tree once), and the hits equal a fresh build's."""
    session = Session(_big_and_small())
    acc = session.accel
    assert acc.stats["meshes_built"] == 2
    session.apply([ObjectTransform("Small", shapes.transform((1.2, 0.3, 0.0)))])
    assert acc.stats["meshes_built"] == 2 and acc.stats["meshes_reused"] == 0
    _same_hits(acc, session.scene.arrays())
    session.apply([MeshSet("small", shapes.icosphere(2, 0.25, name="small"))])
    assert acc.stats["meshes_built"] == 3 and acc.stats["meshes_reused"] == 1
    _same_hits(acc, session.scene.arrays())
    # the scene's BVH arrays are the only copy: every cached mesh is a view of them
    for placed in acc._cache.values():
        for part, whole in ((placed.bounds, acc.sb.bounds), (placed.child, acc.sb.child),
                            (placed.tri, acc.sb.tri)):
            assert part.base is whole
    # the big mesh grows: the small one's tree moves, and is still reused
    session.apply([MeshSet("big", shapes.lumpy_sphere(30_000, name="big"))])
    assert acc.stats["meshes_built"] == 4 and acc.stats["meshes_reused"] == 2
    _same_hits(acc, session.scene.arrays())
    assert acc.stats["memory_mb"] > 0 and session.stats["accel_memory_mb"] > 0


# ----------------------------------------------------------------------------- cancel


def test_cancelled_build_raises_and_keeps_nothing():
    tv = _tv(shapes.lumpy_sphere(20_000))
    flag = CancelFlag()
    flag.set()
    with pytest.raises(Cancelled):
        bvh_mesh.build_mesh_bvh(tv, stop=flag.array)
    with pytest.raises(Cancelled):
        bvh_mesh.build_mesh_bvh(tv, grain=tv.shape[0], stop=flag.array)
    with pytest.raises(Cancelled):
        create_accelerator("BVH", _big_and_small().arrays(), cancel=flag)


def test_cancelled_update_leaves_the_session_as_it_was():
    session = Session(_big_and_small())
    acc, sb, scene = session.accel, session.accel.sb, session.scene
    before = scene.arrays()
    session.submit([MeshSet("small", shapes.icosphere(2, 0.3, name="small"))])
    flag = CancelFlag()
    flag.set()
    with pytest.raises(Cancelled):
        session.apply([ObjectTransform("Big", shapes.transform((0.0, 0.0, 0.5)))], cancel=flag)
    assert session.failed is None
    assert session.scene is scene and session.scene.arrays() is before
    assert session.accel is acc and acc.sb is sb
    assert acc.stats["meshes_built"] == 2
    _same_hits(acc, before)
    # the queued edit is still queued: the next apply (not cancelled) makes it
    flag.clear()
    report = session.apply(cancel=flag)
    assert report.edits == 1 and acc.stats["meshes_built"] == 3
    _same_hits(acc, session.scene.arrays())


def test_cancelled_first_build_builds_on_the_next_apply():
    session = Session(_big_and_small(), build=False)
    flag = CancelFlag()
    flag.set()
    with pytest.raises(Cancelled):
        session.apply(cancel=flag)
    assert session.accel is None and session.failed is None
    session.apply()
    assert session.accel.stats["meshes_built"] == 2


# ----------------------------------------------------------------------------- memory


def test_mesh_too_large_for_the_memory_is_refused_before_it_is_copied():
    s = Scene()
    s.add_material(Material("m"))
    small = shapes.icosphere(2, name="pebble")
    s.memory_limit = 2_000_000  # bytes: a few thousand triangles
    mid = s.add_mesh(small)
    big = shapes.lumpy_sphere(10_000, name="Boulder")
    with pytest.raises(SceneError, match=r"mesh 'Boulder': 10,\d{3} triangles need about "
                                         r".* more than the 1.9 MiB"):
        s.add_mesh(big)
    assert len(s.meshes) == 1
    with pytest.raises(SceneError, match="mesh 'Boulder'"):
        s.set_mesh(mid, big)
    assert s.meshes[mid]["name"] == "pebble"
    s.set_mesh(mid, shapes.icosphere(3, name="pebble"))  # 1,280 triangles fit
    s.copy().add_mesh(shapes.icosphere(1, name="grain"))  # the limit is copied
    c = s.copy()
    with pytest.raises(SceneError, match="mesh 'Boulder'"):
        c.add_mesh(big)
    # without a limit, the memory available decides: an ordinary mesh fits
    s.memory_limit = None
    s.add_mesh(big)


def test_meshes_past_the_bvhs_triangle_limit_are_refused_before_anything_is_built(
        monkeypatch):
    """The scene's meshes hold at most :data:`.footprint.MAX_TRIANGLES` in all (the BVH's
    leaf codes hold 28-bit triangle ids): a mesh past it is refused by name when added or
    set, before it is copied or any BVH built, whatever the memory (main: refused only by
    ``concat_meshes``' OverflowError, after every mesh's BVH was built). A small limit
    stands in for 2^28 - 1."""
    assert footprint.MAX_TRIANGLES == (1 << 28) - 1 == bvh.MAX_TRIANGLES
    monkeypatch.setattr(footprint, "MAX_TRIANGLES", 1_000)
    s = Scene()
    s.add_material(Material("m"))
    mid = s.add_mesh(shapes.icosphere(2, name="pebble"))  # 320 triangles
    s.add_instance(mid, np.eye(4))
    with pytest.raises(SceneError, match=r"mesh 'Boulder': 1,280 triangles \(with the "
                                         r"scene's other meshes 1,600\) are more than the "
                                         r"1,000 a scene can hold"):
        s.add_mesh(shapes.icosphere(3, name="Boulder"))
    assert len(s.meshes) == 1 and s._mesh_tris == 320
    with pytest.raises(SceneError, match=r"mesh 'Boulder': 1,280 triangles are more than"):
        s.set_mesh(mid, shapes.icosphere(3, name="Boulder"))  # (its own 320 are replaced)
    assert s.meshes[mid]["name"] == "pebble"
    grain = s.add_mesh(shapes.icosphere(2, name="grain"))  # 640 in all: fits
    s.delete_mesh(grain)  # its triangles are given back
    s.copy().add_mesh(shapes.icosphere(2, name="grain"))  # (copied with the count)
    s.set_mesh(mid, shapes.icosphere(2, name="pebble2"))
    assert s._mesh_tris == 320


# ----------------------------------------------------------------------------- bench


def test_bench_scale_runs_small():
    res = scale.run(sizes=(3_000,), duplicates=(6, 800), repeats=1, warm=False)
    dense, dup = res["rows"]
    assert dense["unique_triangles"] >= 3_000 and dup["objects"] == 6 + 1
    assert dup["instanced_triangles"] > 5 * dup["unique_triangles"]
    for row in res["rows"]:
        assert row["numba_build_s"] > 0 and row["numba_mrays"] > 0
        mem = row["bytes_per_triangle"]
        assert 0 < mem["bvh"] < mem["total"] <= mem["model"] + mem["packed"] + mem["bvh"] + 0.2
    # the BVH holds each mesh's tree once: well under twice its leaf-ordered triangles
    assert dense["bytes_per_triangle"]["bvh"] < 160
    # the scene holds each mesh once: the model's arrays are views of the packed ones but
    # its triangles (12 bytes, the mesh's own vertex indices)
    mem = dense["bytes_per_triangle"]
    assert mem["total"] <= mem["packed"] + mem["bvh"] + 12.5
    assert dense["scene_s"] > 0 and dense["numba_kept_s"] > 0


# ----------------------------------------------------------------------------- kept BVHs


def test_a_new_session_takes_the_kept_mesh_bvhs_and_hits_the_same():
    """A session given the process's kept BVHs (as the add-on's are) builds no mesh BVH
    over meshes the last session built; a changed mesh is built, and the hits equal a
    session's built from nothing."""
    kept = accelerators.KeptBVHs()
    first = Session(_big_and_small(), build=False)
    first.kept_bvhs = kept
    first.apply()
    assert first.accel.stats["meshes_built"] == 2 and len(kept) == 2
    second = Session(_big_and_small(), build=False)  # new arrays, the same meshes
    second.kept_bvhs = kept
    second.apply()
    assert second.accel.stats["meshes_built"] == 0
    assert second.accel.stats["meshes_kept"] == 2
    _same_hits(second.accel, second.scene.arrays())
    # the kept trees are now views of the second session's arrays (the first's can go)
    for placed in kept._meshes.values():
        assert placed.bounds.base is second.accel.sb.bounds
    changed = _big_and_small()
    changed.set_mesh(changed.mesh_id("small"), shapes.icosphere(2, 0.3, name="small"))
    third = Session(changed, build=False)
    third.kept_bvhs = kept
    third.apply()
    assert third.accel.stats["meshes_built"] == 1 and third.accel.stats["meshes_kept"] == 1
    _same_hits(third.accel, third.scene.arrays())
    # without kept BVHs (the default) every session builds its own
    assert Session(_big_and_small()).accel.stats["meshes_built"] == 2


def test_kept_bvhs_are_bounded(monkeypatch):
    kept = accelerators.KeptBVHs()
    monkeypatch.setattr(accelerators, "KEPT_BVH_MAX_BYTES", 1000)
    create_accelerator("BVH", _big_and_small().arrays(), kept=kept)
    assert len(kept) == 0 and kept.nbytes == 0
    monkeypatch.setattr(accelerators, "KEPT_BVH_MAX_BYTES", 1 << 40)
    acc = create_accelerator("BVH", _big_and_small().arrays(), kept=kept)
    assert len(kept) == 2 and kept.nbytes == sum(a.nbytes for a in acc._concat[:3])
    kept.clear()
    assert len(kept) == 0


def test_mesh_key_in_chunks_is_the_content_hash_of_its_chunks(monkeypatch):
    from rstrace_engine.accel.content_hash import ContentHash

    mesh = shapes.lumpy_sphere(5_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), mesh.triangles
    whole = bvh_mesh.mesh_key(verts, tris)
    h = ContentHash()
    for part in (np.array([len(tris), len(verts)], np.int64), verts, tris):
        h.update(np.ascontiguousarray(part))
    assert whole == h.digest()
    chunk = 4096 + 8
    monkeypatch.setattr(bvh_mesh, "KEY_CHUNK", chunk)
    chunked = bvh_mesh.mesh_key(verts, tris)
    h = ContentHash()
    h.update(np.array([len(tris), len(verts)], np.int64))
    for part in (verts.reshape(-1), tris.reshape(-1)):
        step = chunk // part.itemsize
        for start in range(0, len(part), step):
            h.update(part[start:start + step])
    assert chunked == h.digest()
    # after 7 vertices of another mesh: its triangles hashed less 7, chunk by chunk
    shifted = np.concatenate([np.ones((7, 3)), verts])
    assert bvh_mesh.mesh_key(shifted, tris + 7) == chunked
    flag = CancelFlag()
    flag.set()
    with pytest.raises(Cancelled):
        bvh_mesh.mesh_key(verts, tris, flag.array)


def test_mesh_key_follows_the_triangles_not_their_place_in_the_scene():
    mesh = shapes.lumpy_sphere(2_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), mesh.triangles
    key = bvh_mesh.mesh_key(verts, tris)
    # the same mesh after 7 vertices of another one: the same key
    shifted = np.concatenate([np.ones((7, 3)), verts])
    assert bvh_mesh.mesh_key(shifted, tris + 7) == key
    moved = verts.copy()
    moved[int(tris[5, 1])] += 1e-12
    assert bvh_mesh.mesh_key(moved, tris) != key
    assert bvh_mesh.mesh_key(verts, tris[:, ::-1].copy()) != key


def test_indexed_build_is_the_build_over_the_gathered_triangles():
    mesh = shapes.lumpy_sphere(bvh_build.PARALLEL_MIN + 3_000)
    verts, tris = np.asarray(mesh.vertices, np.float64), mesh.triangles
    _same_tree(bvh_mesh.build_mesh_bvh_indexed(verts, tris), bvh_mesh.build_mesh_bvh(verts[tris]))


def test_scene_bvh_holds_each_built_mesh_tree_as_built_alone():
    """A large mesh's tree placed in the scene's concatenation (after a small mesh, so at
    an offset): its nodes and triangle ids there are those of the mesh's own build, and
    the leaves read the scene's own vertices and vertex indices (no copy of them)."""
    s = Scene()
    s.add_material(Material("m"))
    small = shapes.icosphere(1, 0.2, name="small")
    big = shapes.lumpy_sphere(bvh_build.PARALLEL_MIN + 5_000, name="big")
    s.add_instance(s.add_mesh(small, key="small"), np.eye(4), key="Small")
    s.add_instance(s.add_mesh(big, key="big"), shapes.transform((1.5, 0.0, 0.0)), key="Big")
    sa = s.arrays()
    acc = create_accelerator("BVH", sa)
    lo, hi = bvh_mesh.mesh_range(sa, 1)
    alone = bvh_mesh.build_mesh_bvh(sa.verts[sa.tris[lo:hi]])
    placed = acc._cache[acc._mesh_keys[1]]
    own = bvh.PlacedMesh.built(alone)  # (its leaves as the traversal reads them)
    assert placed.tri_base == lo and placed.leaf_base == len(acc._cache[acc._mesh_keys[0]].tri)
    assert np.array_equal(placed.tri, own.tri + lo)
    assert np.array_equal(bvh_mesh.leaf_order(placed.child, acc.sb.tri),
                          bvh_mesh.leaf_order(own.child, own.tri) + lo)
    # (the rows the tree uses: a parallel collapse leaves unused ones, not placed)
    assert np.array_equal(placed.bounds, np.concatenate(
        [alone.bvh.bounds[a:b] for a, b in bvh_mesh.used_runs(alone.bvh.child)]))
    assert acc.sb.verts is sa.verts and acc.sb.tris is sa.tris


def test_a_parallel_collapses_unused_rows_are_dropped_when_placed():
    """The rooms of :func:`.bvh_collapse.collapse4_parallel` leave rows no child reaches
    (empty nodes); placing the tree (:meth:`.bvh.PlacedMesh.built`, then the scene's
    concatenation) keeps only the rows reached from the root, renumbered: the same tree
    walked from the root as the serial collapse's, and as many rows as it has nodes."""
    big = shapes.lumpy_sphere(bvh_build.PARALLEL_MIN + 5_000, name="big")
    tv = np.asarray(big.vertices, np.float64)[big.triangles]
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        mb = bvh_mesh.build_mesh_bvh(tv)
    finally:
        numba.set_num_threads(before)
    reached = _reached(mb.bvh.child)
    if numba.config.NUMBA_NUM_THREADS > 1:  # (one thread: the serial collapse, no rooms)
        assert len(reached) < len(mb.bvh.child)
    pm = bvh.PlacedMesh.built(mb)
    assert len(pm.child) == len(reached)
    assert sum(b - a for a, b in pm.rows or ((0, len(pm.bounds)),)) == len(reached)
    bounds, child, tri, root, (placed,) = bvh.concat_meshes([pm], np.array([0, len(tv)]))
    assert len(child) == len(bounds) == len(reached)
    numba.set_num_threads(1)  # (the same binary tree, collapsed on one thread)
    try:
        serial = bvh.PlacedMesh.built(bvh_mesh.build_mesh_bvh(tv))
    finally:
        numba.set_num_threads(before)
    assert serial.rows == () and len(serial.child) == len(reached)
    assert _walked(bounds, child) == _walked(serial.bounds, serial.child)
    assert np.array_equal(bvh_mesh.leaf_order(child, tri),
                          bvh_mesh.leaf_order(serial.child, serial.tri))


def _reached(child, node=0):
    """The rows reached from ``node`` (depth first)."""
    out, todo = [], [node]
    while todo:
        n = todo.pop()
        out.append(n)
        todo.extend(int(c) for c in child[n] if c >= 0)
    return out


def _walked(bounds, child, node=0):
    """A tree's boxes and lane codes walked from ``node`` (leaf codes as they are, inner
    nodes replaced by their walk): equal for the same tree in any row order."""
    return [(bounds[node].tobytes(), tuple(
        _walked(bounds, child, int(c)) if c >= 0 else int(c) for c in child[node]))]


def test_pad_outward_is_nextafter_outward():
    rng = np.random.default_rng(3)
    special = [0.0, -0.0, 5e-324, -5e-324, 1e-310, -1e-310, 1.0, -1.0, np.finfo(float).max,
               -np.finfo(float).max, np.inf, -np.inf]
    x = np.concatenate([special, rng.normal(size=600) * 10.0 ** rng.integers(-300, 300, 600)])
    b = np.resize(x, (len(x) // 12 + 1) * 12).reshape(-1, 12)
    want = b.copy()
    with np.errstate(over="ignore"):
        for side in range(2):
            for q in range(3):
                lo, hi = want[:, 6 * side + q], want[:, 6 * side + 3 + q]
                want[:, 6 * side + q] = np.where(np.isfinite(lo), np.nextafter(lo, -np.inf), lo)
                want[:, 6 * side + 3 + q] = np.where(np.isfinite(hi), np.nextafter(hi, np.inf),
                                                     hi)
    got = bvh_mesh.pad_outward(b.copy())
    assert np.array_equal(got.view(np.int64), want.view(np.int64))


# ----------------------------------------------------------------------------- scene arrays


def test_scene_construction_stops_at_the_flag_and_leaves_the_scene_as_it_was(monkeypatch):
    from rstrace_engine.geometry import mesh_math

    monkeypatch.setattr(mesh_math, "PROPER_CHUNK", 1000)
    s = _big_and_small()
    before = (list(s.meshes), s._mesh_bytes, s.arrays())
    calls = []

    def cancel():  # turns True after two chunks
        calls.append(1)
        return len(calls) > 2

    with pytest.raises(Cancelled):
        s.add_mesh(shapes.lumpy_sphere(20_000, name="late"), cancel=cancel)
    assert len(calls) == 3
    assert s.meshes == before[0] and s._mesh_bytes == before[1] and s.arrays() is before[2]
    flag = CancelFlag()
    flag.set()
    with pytest.raises(Cancelled):
        s.set_mesh(s.mesh_id("small"), shapes.icosphere(3, name="small"), cancel=flag)
    assert s.meshes == before[0] and s.arrays() is before[2]
    flag.clear()  # not set: the same mesh as without a flag
    mid = s.add_mesh(shapes.lumpy_sphere(20_000, name="late"), cancel=flag)
    plain = Scene()
    ref = plain.meshes[plain.add_mesh(shapes.lumpy_sphere(20_000, name="late"))]
    for k in ("verts", "normals", "uvs", "slots"):
        assert np.array_equal(s.meshes[mid][k], ref[k])
    assert np.array_equal(mesh_triangles(s.meshes[mid]), mesh_triangles(ref))


def test_packed_scene_holds_each_mesh_once():
    """After packing, a mesh's vertices, triangles, normal rows, uvs and slots are views of
    the packed arrays (its triangles the global ones, its own indices less its first
    vertex); repacking after another mesh changes moves them to the new arrays, with the
    same values."""
    s = _big_and_small()
    sa = s.arrays()
    big = s.meshes[s.mesh_id("big")]
    copy = {k: big[k].copy() for k in ("verts", "normals", "uvs", "slots")}
    copy["tris"] = mesh_triangles(big).copy()
    for k, whole in (("verts", sa.verts), ("tris", sa.tris), ("normals", sa.normals)):
        assert big[k].base is whole
    s.set_mesh(s.mesh_id("small"), shapes.icosphere(3, 0.3, name="small"))
    sa2 = s.arrays()
    assert big["verts"].base is sa2.verts and big["normals"].base is sa2.normals
    for k, v in copy.items():
        assert np.array_equal(mesh_triangles(big) if k == "tris" else big[k], v)
    k = s.mesh_id("big")
    assert sa2.mesh_nrm[k, 0] == ATTR_VERTEX  # one normal row per vertex
    t0, t1 = sa2.mesh_tri_start[k], sa2.mesh_tri_start[k + 1]
    assert np.array_equal(sa2.normals[sa2.mesh_nrm[k, 1] + sa2.tris[t0:t1]],
                          copy["normals"][copy["tris"]])
