"""Deterministic sampling through bpy (issue 20): the same script, settings and seed give
the same F12 image bit for bit, in another process too.

The engine was deterministic already (a saved .blend renders the same bits in any process,
with any thread count); the scenes were not: ``bmesh.ops.create_uvsphere`` orders its edges
and faces differently from one process to the next, so Blender's vertex normals (summed in
face order) and the triangles' order differed, and the "same" scene rendered a few pixels
an ulp apart. :func:`builders.uv_sphere` now puts them in an order set by the vertices.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import bpy
import numpy as np

from . import builders as b

ROOT = Path(__file__).resolve().parents[2]

#: a sphere on a floor, F12 (BASE, 96x72) to an EXR; its Combined pass saved as .npy
SCRIPT = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    import numpy as np
    import addon
    from tests.blender import test_determinism as t
    addon.register()
    np.save(sys.argv[2], t.sphere_on_floor_f12())
    addon.unregister()
""")


def sphere_on_floor_f12() -> np.ndarray:
    """The Combined pass of one F12 of a fresh sphere-on-a-floor scene, (72, 96, 4)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = b.setup_render(96, 72, samples=1, max_depth=0)
    sc.rstrace.mode = "BASE"
    b.set_world((0.05, 0.05, 0.06), lights=False)
    grey = b.principled("Grey", (0.6, 0.6, 0.6), roughness=0.6)
    red = b.principled("Red", (0.7, 0.1, 0.1), roughness=0.4)
    b.add_object("Floor", b.grid("Floor", 40.0), material=grey)
    b.add_object("Ball", b.uv_sphere("BallMesh", 0.6, 48, 24), (0.6, -1.0, 0.6), red)
    b.point_light("Key", (-3.0, -4.0, 6.0), 2500.0)
    b.camera((0.0, -6.0, 2.5), (0.0, 0.0, 0.5))
    bpy.context.view_layer.update()
    return b.render_exr()["Combined"]


def _mesh_arrays(me) -> dict[str, np.ndarray]:
    out = {}
    for key, items, prop, n, dtype in (("corner_vert", me.loops, "vertex_index", 1, np.int32),
                                       ("edges", me.edges, "vertices", 2, np.int32),
                                       ("positions", me.vertices, "co", 3, np.float32),
                                       ("normals", me.vertex_normals, "vector", 3, np.float32),
                                       ("uvs", me.uv_layers[0].data, "uv", 2, np.float32)):
        values = np.empty(n * len(items), dtype)
        items.foreach_get(prop, values)
        out[key] = values
    return out


def test_uv_sphere_is_the_same_mesh_every_time():
    # (a large sphere: bmesh's order differs between two calls in one process as well)
    first, second = (_mesh_arrays(b.uv_sphere(f"S{k}", 0.2, 128, 80)) for k in range(2))
    for key, values in first.items():
        assert values.tobytes() == second[key].tobytes(), key


def test_f12_is_the_same_bits_in_another_process(tmp_path):
    here = sphere_on_floor_f12()
    assert here.shape == (72, 96, 4) and (here[..., 0] > here[..., 2] + 0.05).sum() > 50
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for k in range(2):
        out = tmp_path / f"f12_{k}.npy"
        proc = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT), str(out)], cwd=ROOT,
                              env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0 and out.exists(), proc.stdout[-2000:] + proc.stderr[-3000:]
        there = np.load(out)
        differ = int((here != there).any(axis=-1).sum())
        assert differ == 0, f"process {k}: {differ} pixels differ"
