"""The packing takes over the export's rows of the largest owned mesh (packing._adopted):
its uv, normal or slot rows array is grown in place (realloc, no copy into fresh memory),
its rows first, the other meshes' rows after them; where anything else refers to that
array it is left alone and the rows are copied as before. Rows are read through each
mesh's bias, so every triangle reads the values it read before, bit for bit."""

from __future__ import annotations

import gc

import numpy as np

from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.attributes import ATTR_CORNER
from rstrace_engine.geometry.scene import Mesh, Scene


def _mesh(name: str, n: int, seed: int, uv_rows=None) -> tuple[Mesh, np.ndarray]:
    base = shapes.lumpy_sphere(n, name=name)
    t = np.asarray(base.triangles, np.int32).copy()
    uv = (np.random.default_rng(seed).random((len(t), 3, 2)).astype(np.float32)
          if uv_rows is None else uv_rows)
    mesh = Mesh(name, np.asarray(base.vertices, np.float32), t, corner_uvs=uv.copy(),
                smooth=True, owned=True)
    return mesh, uv


def _uv_of(packed: dict, k: int) -> np.ndarray:
    """Mesh ``k``'s corner uvs read through the packing (CORNER rows and their bias)."""
    mode, b = packed["mesh_uv"][k]
    assert mode == ATTR_CORNER
    t0, t1 = packed["mesh_tri_start"][k], packed["mesh_tri_start"][k + 1]
    rows = b + 3 * np.arange(t0, t1)[:, None] + np.arange(3)[None, :]
    return packed["uvs"][rows]


def test_the_largest_meshs_uv_rows_are_taken_over_and_come_first():
    small, uv_s = _mesh("small", 40, 1)
    big, uv_b = _mesh("big", 2000, 2)
    other, uv_o = _mesh("other", 60, 3)
    scene = Scene()
    ids = [scene.add_mesh(m) for m in (small, big, other)]
    gc.collect()
    packed = scene._pack_meshes()
    _, b = packed["mesh_uv"][ids[1]]
    assert b + 3 * packed["mesh_tri_start"][ids[1]] == 0  # (its rows first: main 120)
    for k, uv in zip(ids, (uv_s, uv_b, uv_o), strict=True):
        assert _uv_of(packed, k).tobytes() == uv.tobytes()
    assert big.corner_uvs.tobytes() == uv_b.tobytes() and big.corner_uvs.shape == uv_b.shape
    assert np.shares_memory(big.corner_uvs, packed["uvs"])
    again = Scene()  # (the Mesh now holds a view of the packing: copied, the same bits)
    for m in (small, big, other):
        again.add_mesh(m)
    repacked = again._pack_meshes()
    for k, uv in zip(ids, (uv_s, uv_b, uv_o), strict=True):
        assert _uv_of(repacked, k).tobytes() == uv.tobytes()


def test_rows_held_elsewhere_are_copied_and_left_as_they_are():
    small, uv_s = _mesh("small", 40, 1)
    big, uv_b = _mesh("big", 2000, 2)
    held = big.corner_uvs  # (someone else holds the Mesh's array: never resized)
    address, shape = held.ctypes.data, held.shape
    scene = Scene()
    ids = [scene.add_mesh(m) for m in (small, big)]
    packed = scene._pack_meshes()
    assert held.ctypes.data == address and held.shape == shape
    assert held.tobytes() == uv_b.tobytes()
    for k, uv in zip(ids, (uv_s, uv_b), strict=True):
        assert _uv_of(packed, k).tobytes() == uv.tobytes()


def test_a_mesh_alone_packs_its_own_rows_unchanged():
    big, uv_b = _mesh("big", 800, 2)
    twin = Mesh("twin", big.vertices, big.triangles, corner_uvs=big.corner_uvs,
                smooth=True, owned=True)  # (the same arrays in another Mesh)
    scene = Scene()
    k = scene.add_mesh(big)
    packed = scene._pack_meshes()
    assert _uv_of(packed, k).tobytes() == uv_b.tobytes()
    assert twin.corner_uvs.shape == uv_b.shape and twin.corner_uvs.tobytes() == uv_b.tobytes()
