"""The edge pixels of ``scripts/rough_edge_samples.py`` (issue 24, session 44): a pixel whose
centre key differs from a 4-neighbour's, the frame's border, and the keys themselves."""

from __future__ import annotations

import numpy as np
from repo_files import load_module

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator


def _script():
    return load_module("scripts/rough_edge_samples.py", "rough_edge_samples")


def test_edges_are_the_key_changes_and_the_border():
    mod = _script()
    key = np.zeros((6, 8), np.int64)
    key[2:4, 3:5] = 7  # a 2 x 2 block
    e = mod.edges_of(key)
    want = np.zeros((6, 8), bool)
    want[0, :] = want[-1, :] = want[:, 0] = want[:, -1] = True
    want[2:4, 3:5] = True  # the block's own pixels each touch the outside
    want[1, 3:5] = want[4, 3:5] = True  # above and below it
    want[2:4, 2] = want[2:4, 5] = True  # left and right (not the diagonals)
    assert (e == want).all()
    assert not mod.edges_of(np.zeros((6, 8), np.int64))[1:-1, 1:-1].any()
    big = np.zeros((10, 12), np.int64)
    big[4:6, 5:7] = 7
    wide = mod.edges_of(big, ring=2)
    assert wide[:2].all() and wide[:, -2:].all()  # the border, two wide
    assert wide[4, 3] and not wide[4, 2]  # two to the block's left, three
    assert wide[2, 5] and not wide[2, 3]  # two above it; beside that


def test_centre_keys_see_the_floor_lit_and_the_background():
    mod = _script()
    scene = scenes.rough_materials(32, 24)
    acc = create_accelerator("BVH", scene.arrays())
    key = mod.centre_keys(scene, acc)
    assert key.shape == (24, 32)
    assert (key == -1).any()  # a miss: instance -1, the background's colour
    inst = key // 2
    assert ((inst >= 0) & (key % 2 == 1)).any() and ((inst >= 0) & (key % 2 == 0)).any()
    again = mod.centre_keys(scene, acc)
    assert (again == key).all()
    e = mod.edge_pixels(scene, acc)
    assert (e == mod.edges_of(key)).all() and 0 < e.sum() < e.size
