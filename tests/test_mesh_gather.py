"""The add-on's gather of a host mesh's corners into per-triangle arrays
(:func:`rstrace_engine.geometry.mesh_math.gather_corners`): what numpy's indexing gives, bit
for bit, in one kernel pass that checks the corners' range."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rstrace_engine.geometry import mesh_math
from rstrace_engine.geometry.mesh_math import gather_corners


def _case(seed: int = 5, n: int = 400, m: int = 250):
    rng = np.random.default_rng(seed)
    corner_vert = rng.integers(0, 1000, n).astype(np.int32)
    corners = rng.integers(0, n, (m, 3)).astype(np.int32)
    uvs = rng.standard_normal((n, 2)).astype(np.float32)
    # (a NaN payload, signed zeros, infinities, subnormals: moved as bits, not as floats)
    special = np.array([0x7FC12345, 0x7F812345, 0x80000000, 0, 0x7F800000, 0xFF800000, 1,
                        0x80000001], np.uint32).view(np.float32)
    uvs.reshape(-1)[:len(special)] = special
    corners[0] = (0, 1, 2)
    corners[1] = (3, 2, 1)
    return corner_vert, corners, uvs


def test_gathers_vertices_and_uvs_as_numpy_indexing_bit_for_bit():
    """The triangles' vertices ``corner_vert[corners]`` and uvs ``uvs[corners]`` (bit for
    bit: NaN payloads, signed zeros, subnormals), fresh C-contiguous arrays of the Mesh's
    dtypes; no uvs given: None."""
    corner_vert, corners, uvs = _case()
    tris, got = gather_corners(corner_vert, corners, uvs)
    np.testing.assert_array_equal(tris, corner_vert[corners.astype(np.int64)])
    assert tris.dtype == np.int32 and tris.shape == (250, 3) and tris.flags.c_contiguous
    want = uvs[corners.astype(np.int64)]
    assert got.dtype == np.float32 and got.shape == (250, 3, 2) and got.flags.c_contiguous
    assert got.tobytes() == want.tobytes()
    assert not np.shares_memory(got, uvs) and not np.shares_memory(tris, corner_vert)
    tris2, none = gather_corners(corner_vert, corners)
    assert none is None
    np.testing.assert_array_equal(tris2, tris)


def test_reads_the_hosts_read_only_views_and_flat_uvs():
    """Read-only inputs (Blender's arrays read in place) give the same result as writable
    copies (one kernel signature for both), and the uvs may come flat (``nl * 2``)."""
    corner_vert, corners, uvs = _case(9)
    want_t, want_uv = gather_corners(corner_vert.copy(), corners.copy(), uvs.copy())
    for a in (corner_vert, corners, uvs):
        a.flags.writeable = False
    tris, got = gather_corners(corner_vert, corners, uvs.reshape(-1))
    np.testing.assert_array_equal(tris, want_t)
    assert got.tobytes() == want_uv.tobytes()
    assert corner_vert.flags.writeable is False  # (the caller's arrays left as they were)


@pytest.mark.parametrize("bad", [-1, 400, 1 << 30])
def test_a_corner_out_of_range_gives_none(bad):
    """A corner outside ``0 .. len(corner_vert) - 1`` (Blender's data inconsistent) gives
    None, with or without uvs, wherever it lies (the caller then names the mesh)."""
    corner_vert, corners, uvs = _case()
    for at in ((0, 0), (249, 2), (120, 1)):
        c = corners.copy()
        c[at] = bad
        assert gather_corners(corner_vert, c, uvs) is None
        assert gather_corners(corner_vert, c) is None


def test_uvs_must_match_the_corners_and_empty_meshes_gather_nothing():
    corner_vert, corners, uvs = _case()
    with pytest.raises(ValueError, match="399 corner uvs for 400 corners"):
        gather_corners(corner_vert, corners, uvs[:399])
    tris, got = gather_corners(corner_vert, corners[:0], uvs)
    assert tris.shape == (0, 3) and got.shape == (0, 3, 2)


def test_a_large_gather_is_shared_by_two_threads_and_gives_one_threads_bits(monkeypatch):
    """Ranges of ``GATHER_CHUNK`` triangles taken by the calling thread and the pool's
    (``beside.Shared``): the same bits as one thread; a corner out of range in any range
    (the last one's last corner too) gives None."""
    monkeypatch.setattr(mesh_math, "GATHER_CHUNK", 16)
    corner_vert, corners, uvs = _case(11, n=400, m=1000)
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        want_t, want_uv = gather_corners(corner_vert, corners, uvs, spare=3)
    finally:
        numba.set_num_threads(before)
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    started: list = []

    class Seen(mesh_math.Shared):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            started.append(self.started)

    monkeypatch.setattr(mesh_math, "Shared", Seen)
    try:
        tris, got = gather_corners(corner_vert, corners, uvs, spare=3)
        assert tris.tobytes() == want_t.tobytes() and got.tobytes() == want_uv.tobytes()
        # (and numpy's indexing: each range's rows where they belong, on either thread)
        assert tris.tobytes() == corner_vert[corners.astype(np.int64)].tobytes()
        assert got.tobytes() == uvs[corners.astype(np.int64)].tobytes()
        for at in ((0, 0), (500, 1), (999, 2)):
            c = corners.copy()
            c[at] = 400
            assert gather_corners(corner_vert, c, uvs) is None
            assert gather_corners(corner_vert, c) is None
    finally:
        numba.set_num_threads(before)
    assert started[0] is (numba.config.NUMBA_NUM_THREADS > 1)


@pytest.mark.parametrize("which", ["corner_vert", "corners"])
@pytest.mark.parametrize("dtype", [np.int64, np.uint32, np.float64])
def test_indices_of_a_dtype_wider_than_int32_are_refused(which, dtype):
    """The int32 contract is checked on the dtype (no pass over the values): an int64
    corner 2^32 + 5 would wrap to corner 5 in the cast and gather a wrong triangle (main:
    gathered silently); int16 and other narrower integers are accepted."""
    corner_vert, corners, uvs = _case()
    args = {"corner_vert": corner_vert, "corners": corners}
    wide = args[which].astype(dtype)
    if which == "corners" and dtype == np.int64:
        wide[0, 0] = (1 << 32) + 5
    args[which] = wide
    what = "corner vertices" if which == "corner_vert" else "corners"
    with pytest.raises(TypeError, match=f"{what} must be int32 .* not {np.dtype(dtype)}"):
        gather_corners(args["corner_vert"], args["corners"], uvs)
    narrow = _case()[:2]
    tris, _ = gather_corners(narrow[0].astype(np.int16), narrow[1].astype(np.int16))
    np.testing.assert_array_equal(tris, narrow[0][narrow[1].astype(np.int64)])
