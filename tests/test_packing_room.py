"""The packing laid in the room around the largest mesh's rows (``packing._in_place``): the
add-on's gathers leave spare rows around a large mesh's triangles and uvs
(``mesh_math.with_room``), and the packing writes the other meshes' rows there instead of
copying the largest mesh's (36 MB of fresh memory at 1M triangles). The packed values are
those of a packing that copies, bit for bit; the room is claimed once (two scenes sharing the
mesh never write the same rows), and memory that was not left as room is never written."""

from __future__ import annotations

import numpy as np

from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.mesh_math import gather_corners, has_room
from rstrace_engine.geometry.packing import pack_meshes
from rstrace_engine.geometry.scene import Mesh, Scene


def _uvs(m: int, seed: int) -> np.ndarray:
    """Per-corner uvs with no coarser mode (each corner its own)."""
    return np.random.default_rng(seed).random((m, 3, 2)).astype(np.float32)


def _exported(base: Mesh, name: str, spare: int, seed: int) -> Mesh:
    """``base`` as the add-on exports it: triangles and uvs gathered from its corners
    (with ``spare`` rows of room), float32 vertices, owned."""
    t = np.asarray(base.triangles, np.int32)
    uv = _uvs(len(t), seed)
    tris, uvs = gather_corners(t.reshape(-1), np.arange(t.size, dtype=np.int32).reshape(-1, 3),
                               uv.reshape(-1, 2), spare=spare)
    return Mesh(name, np.asarray(base.vertices, np.float32), tris, corner_uvs=uvs,
                smooth=False, owned=True)


def _copy(mesh: Mesh) -> Mesh:
    """The same mesh with arrays of its own (no room)."""
    return Mesh(mesh.name, mesh.vertices.copy(), mesh.triangles.copy(),
                corner_uvs=mesh.corner_uvs.copy(), smooth=False, owned=True)


def _root(a: np.ndarray) -> np.ndarray:
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def _scene(meshes) -> tuple[Scene, dict]:
    s = Scene()
    for m in meshes:
        s.add_mesh(m)
    return s, s._pack_meshes()


def _same_packing(a: dict, b: dict) -> None:
    for f in ("verts", "tris", "normals", "uvs", "tri_slot", "mesh_nrm", "mesh_uv",
              "mesh_slot", "mesh_tri_start", "mesh_gen"):
        assert a[f].dtype == b[f].dtype and a[f].shape == b[f].shape, f
        assert a[f].tobytes() == b[f].tobytes(), f


def _meshes(spare: int):
    small = _exported(shapes.lumpy_sphere(20, name="s"), "small", spare, 1)
    big = _exported(shapes.lumpy_sphere(3000, name="b"), "big", spare, 2)
    other = _exported(shapes.lumpy_sphere(60, name="o"), "other", spare, 3)
    return small, big, other


def test_the_largest_meshs_rows_are_the_packings_bit_for_bit():
    """The largest mesh (in the middle: other meshes' rows before and after it) keeps its
    triangles and uvs where the export wrote them: the packing's arrays are laid around
    them (the same memory) and hold what a packing of copies holds, bit for bit; the
    smaller meshes' rows are copied as before. (Fails on main: no room, no claim.)"""
    small, big, other = _meshes(spare=500)
    t0, uv0 = big.triangles, big.corner_uvs
    _, packed = _scene((small, big, other))
    _, want = _scene([_copy(m) for m in _meshes(spare=0)])
    _same_packing(packed, want)
    assert np.shares_memory(packed["tris"], t0) and np.shares_memory(packed["uvs"], uv0)
    assert _root(packed["tris"]) is _root(t0) and _root(packed["uvs"]) is _root(uv0)
    assert not has_room(t0) and not has_room(uv0)  # (claimed: no one else writes there)
    # the Mesh holds its values once (handed back: views of the packing)
    assert np.shares_memory(big.triangles, packed["tris"])
    np.testing.assert_array_equal(big.triangles, want["tris"][len(small.triangles):][
        :len(t0)])


def test_a_second_scene_sharing_the_mesh_copies_and_the_first_is_unchanged():
    """The room is claimed once: a second scene over the same meshes (another session
    over the export cache) copies, and the first scene's packing keeps its values."""
    small, big, other = _meshes(spare=500)
    _, first = _scene((small, big, other))
    before = {f: first[f].copy() for f in ("tris", "uvs")}
    extra = _exported(shapes.lumpy_sphere(40, name="e"), "extra", 0, 4)
    _, second = _scene((extra, big, small))  # (other rows around it than the first's)
    for f in ("tris", "uvs"):
        assert first[f].tobytes() == before[f].tobytes(), f
        assert not np.shares_memory(second[f], first[f]), f
    _, want = _scene([_copy(m) for m in (extra, big, small)])
    _same_packing(second, want)


def test_too_little_room_or_none_is_copied_and_memory_beyond_a_mesh_never_written():
    """Where the other meshes' rows do not fit in the room, or the largest mesh's rows lie
    in a larger array that was not left as room (a caller's own memory), the packing
    copies them: nothing outside the mesh's own rows is written."""
    small, big, other = _meshes(spare=5)  # (less room than the others' rows)
    t0, uv0 = big.triangles, big.corner_uvs
    _, packed = _scene((small, big, other))
    assert not np.shares_memory(packed["tris"], t0) and has_room(t0)  # (left unclaimed)
    assert not np.shares_memory(packed["uvs"], uv0) and has_room(uv0)
    _, want = _scene([_copy(m) for m in _meshes(spare=0)])
    _same_packing(packed, want)
    s, b, o = (_copy(m) for m in _meshes(spare=0))
    host = np.full((len(b.triangles) + 2000, 3), 7, np.int32)  # (a caller's larger array)
    host[1000:1000 + len(b.triangles)] = b.triangles
    b.triangles = host[1000:1000 + len(b.triangles)]
    _, packed = _scene((s, b, o))
    _same_packing(packed, want)
    assert (host[:1000] == 7).all() and (host[1000 + len(b.triangles):] == 7).all()


def test_an_unclaimed_room_does_not_count_as_an_old_packing():
    """A mesh with room that is not the largest keeps its triangles as they are (its room
    is its own, unwritten: not an older packing's rows to let go of by copying)."""
    small, big, other = _meshes(spare=500)
    bigger = _exported(shapes.lumpy_sphere(6000, name="B"), "bigger", 500, 5)
    t0 = big.triangles
    _scene((small, bigger, big, other))
    assert big.triangles is t0 and has_room(t0)


_FREED_UNDER_THE_LOCK = """
import gc, threading
from rstrace_engine.geometry import mesh_math as mm
gc.disable()
cycle = [mm.with_room(10, (3,), "int32", 4)]
cycle.append(cycle)  # (garbage only a collection frees)
del cycle

def collect_under_the_lock():
    with mm._ROOMY_LOCK:  # (as with_room holds it while it allocates the weakref)
        gc.collect()

t = threading.Thread(target=collect_under_the_lock, daemon=True)
t.start()
t.join(10)
print("DEADLOCK" if t.is_alive() else "ok", len(mm._ROOMY))
"""


def test_a_room_freed_by_a_collection_under_the_registrys_lock_does_not_deadlock():
    """A collection may start inside the registry's locked region (``with_room`` allocates
    its weakref there: a collection starts at that allocation once the count is due), and
    may free an array with room that sat in cyclic garbage (a traceback's frames, say): its
    weakref callback then takes the lock again on the same thread. It must not hang that
    thread (the render's) forever. Own process: a hung thread would keep the lock."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.run([sys.executable, "-c", _FREED_UNDER_THE_LOCK], cwd=root, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["ok", "0"], proc.stdout + proc.stderr[-2000:]


def _copies(meshes: list) -> list:
    """Scene model mesh dicts with copies of their arrays and no source (a packing of them
    copies every row and hands nothing back)."""
    return [None if m is None else {k: v.copy() if isinstance(v, np.ndarray) else v
                                    for k, v in m.items() if k != "source"} for m in meshes]


def test_random_edits_over_a_claimed_room_stay_exact():
    """Seeded random edits of every kind (meshes added, replaced and deleted included) on a
    scene whose largest mesh is exported with room that its first packing claims: every
    incremental frame equals a fresh session's bit for bit (each re-packing copies: the
    room is claimed once), and the claimed rows are never written again."""
    from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.session import Session
    from tests.test_incremental import H, W, check_base_step

    scene = SOAK_SCENES["room"](W, H)
    big = _exported(shapes.lumpy_sphere(4000, name="big"), "big", 800, 7)
    t0, uv0 = big.triangles, big.corner_uvs
    rows = (t0.copy(), uv0.copy())
    scene.add_instance(scene.add_mesh(big), np.diag([0.4, 0.4, 0.4, 1.0]), name="big")
    settings = RenderSettings(mode="BASE", max_depth=3)
    want = pack_meshes(_copies(scene.meshes))  # (before any packing: the meshes' own rows)
    gen = EditGenerator(scene, seed=11, extra=("mesh_delete",))  # (packs: the claim)
    assert not has_room(t0) and not has_room(uv0)
    packed = scene._mesh_arrays
    _same_packing(packed, want)
    claimed = (packed["tris"].copy(), packed["uvs"].copy())
    assert np.shares_memory(packed["tris"], t0) and np.shares_memory(packed["uvs"], uv0)
    sess = Session(gen.scene.copy(), settings)
    prev = sess.render()
    seen = {}  # (every packing the session made, as it was made: none is written again)
    for _ in range(16):
        sess.apply(gen.step())
        prev, _ = check_base_step(sess, prev, settings)
        geo = sess.scene._mesh_arrays
        seen.setdefault(id(geo), (geo, geo["tris"].tobytes(), geo["uvs"].tobytes()))
        # (what a packing of copies holds: no room, nothing handed back)
        _same_packing(geo, pack_meshes(_copies(sess.scene.meshes)))
    assert {"mesh_set", "mesh_delete", "geometry", "add", "delete"} <= set(gen.kinds_done)
    assert t0.tobytes() == rows[0].tobytes() and uv0.tobytes() == rows[1].tobytes()
    assert packed["tris"].tobytes() == claimed[0].tobytes()
    assert packed["uvs"].tobytes() == claimed[1].tobytes()
    assert len(seen) >= 2, len(seen)
    for geo, tris, uvs in seen.values():
        assert geo["tris"].tobytes() == tris and geo["uvs"].tobytes() == uvs
