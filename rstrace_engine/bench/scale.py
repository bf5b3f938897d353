"""Scale: BVH build time, trace speed and memory per triangle as a scene grows.

``python -m rstrace_engine.bench scale [--quick] [--sizes 60k,1M,4M]
[--duplicates 2000x20k] [--threads N] [--repeats N] [--json]``

Scenes (:func:`big_scene`, :func:`duplicates_scene`): a dense lumpy sphere of each size
(:func:`~rstrace_engine.geometry.shapes.lumpy_sphere`) beside a small icosphere and a floor,
and ``count`` linked duplicates (one mesh, many objects) of a lumpy sphere. Per scene, in
one run and with the thread count stated:

* **scene** (``scene_s``, the scene model: validating the meshes) and **pack** (the
  packed arrays);
* **build** (wall seconds, and CPU seconds of all threads: on a shared machine the CPU time
  is the steadier measure of the work): the numba BVH
  (:class:`~rstrace_engine.accel.accelerators.BVHAccelerator`, all of it: mesh hashing, the
  mesh BVHs, the top level) and Embree's (``embreex``: its
  float32 copy of every instance in world space, and the commit that its first ray
  forces); Embree is left out past :data:`EMBREE_MAX_TRIANGLES` instanced triangles;
  ``numba_kept_s``: a second numba BVH over the same meshes given the first one's kept
  trees (:class:`~rstrace_engine.accel.accelerators.KeptBVHs`: a new session's build);
* **trace**: closest hits of the camera's primary rays (best of ``--repeats``, alternating
  the two accelerators), in million rays per second;
* **memory**: bytes per *unique* triangle (the meshes' own, not counting duplicates) of the
  scene model (the validated meshes), the packed scene arrays (geometry only) and the BVH
  (both levels as the traversal reads them, but for the packed vertices and triangles its
  leaves read, counted with the packed arrays); a buffer shared by several arrays counts
  once.

``--quick`` runs small sizes (what the tests run). Results: ``docs/bench-scale.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numba
import numpy as np

from ..accel.accelerators import AcceleratorUnavailable, KeptBVHs, create_accelerator
from ..accel.bvh_build import PARALLEL_MIN
from ..geometry import shapes
from ..geometry.cameras import camera_rays
from ..geometry.scene import Camera, Light, Material, Scene

SIZES = (60_000, 1_000_000, 4_000_000)
DUPLICATES = (2_000, 20_000)  # objects, triangles of their one mesh
QUICK_SIZES = (20_000,)
QUICK_DUPLICATES = (50, 2_000)
#: Past this many instanced triangles Embree (which copies every instance into world
#: space) is not built.
EMBREE_MAX_TRIANGLES = 12_000_000
WIDTH, HEIGHT = 320, 240


def _base(name: str) -> Scene:
    s = Scene()
    s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6), specular=(0.2,) * 3))
    s.add_material(Material("floor", diffuse=(0.4, 0.45, 0.4)))
    floor = s.add_mesh(shapes.plane(12.0, name="floor"))
    s.add_instance(floor, shapes.transform((0.0, 0.0, -1.1)), [1], name="Floor")
    s.add_light(Light("Sun", "SUN", power=3.0, direction=(-0.3, 0.4, -1.0)))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -4.5, 1.6), (0.0, 0.0, -0.2)),
                        lens=35.0, width=WIDTH, height=HEIGHT))
    return s


def big_scene(triangles: int, dense=None) -> Scene:
    """A lumpy sphere of ``triangles`` triangles (or the mesh ``dense``), a small icosphere
    (320) and a floor (2)."""
    s = _base("big")
    big = s.add_mesh(dense if dense is not None else shapes.lumpy_sphere(triangles,
                                                                          name="dense"))
    s.add_instance(big, np.eye(4), [0], name="Dense")
    small = s.add_mesh(shapes.icosphere(2, 0.25, name="small"))
    s.add_instance(small, shapes.transform((1.5, -0.8, -0.85)), [0], name="Small")
    return s


def duplicates_scene(count: int, triangles: int) -> Scene:
    """``count`` objects sharing one lumpy sphere of ``triangles`` triangles, on a square
    grid over the floor."""
    s = _base("duplicates")
    mesh = s.add_mesh(shapes.lumpy_sphere(triangles, name="pebble"))
    side = int(np.ceil(np.sqrt(count)))
    pitch = 10.0 / side
    for k in range(count):
        i, j = divmod(k, side)
        s.add_instance(mesh, shapes.transform((-5.0 + pitch * (j + 0.5), -5.0 + pitch * (i + 0.5),
                                               -1.1 + 0.4 * pitch), 0.4 * pitch),
                       [0], name=f"Pebble{k:04d}")
    return s


def _nbytes(arrays) -> int:
    """Bytes of the buffers behind ``arrays`` (a buffer shared by several counts once)."""
    seen = {}
    for a in arrays:
        if not isinstance(a, np.ndarray):
            continue
        root = a
        while isinstance(root.base, np.ndarray):
            root = root.base
        seen[id(root)] = root.nbytes
    return sum(seen.values())


def memory(scene: Scene, sa, acc) -> dict:
    """Bytes per unique triangle: ``model``, ``packed``, ``bvh`` and ``total``."""
    unique = int(sa.mesh_tri_start[-1])
    model = [m[k] for m in scene.meshes if m is not None
             for k in ("verts", "tris", "normals", "uvs", "slots")]
    packed = [sa.verts, sa.tris, sa.normals, sa.uvs, sa.tri_slot, sa.mesh_tri_start,
              sa.mesh_nrm, sa.mesh_uv]
    # the BVH's own arrays (its leaves read the packed verts and tris, counted there)
    bvh = [a for f, a in acc.sb._asdict().items() if f not in ("verts", "tris")]
    parts = {"model": _nbytes(model), "packed": _nbytes(packed), "bvh": _nbytes(bvh),
             "total": _nbytes(model + packed + bvh)}
    return {k: round(v / unique, 1) for k, v in parts.items()}


def _best(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure(name: str, scene: Scene, repeats: int = 3, scene_s: float | None = None) -> dict:
    """One row: counts, build seconds, primary-ray Mray/s and bytes per unique triangle
    (``scene_s``: the seconds the scene model took, validating its meshes)."""
    t0 = time.perf_counter()
    sa = scene.arrays()
    row = {"scene": name, "unique_triangles": int(sa.mesh_tri_start[-1]),
           "instanced_triangles": scene.triangle_count, "objects": scene.n_instances,
           "threads": numba.get_num_threads(), "pack_s": round(time.perf_counter() - t0, 3),
           "scene_s": None if scene_s is None else round(scene_s, 3)}
    kept = KeptBVHs()
    t0, c0 = time.perf_counter(), time.process_time()
    accs = {"numba": create_accelerator("BVH", sa, kept=kept)}
    row["numba_build_s"] = round(time.perf_counter() - t0, 3)
    row["numba_build_cpu_s"] = round(time.process_time() - c0, 3)
    row["numba_mesh_build_s"] = round(accs["numba"].stats["mesh_build_s"], 3)
    # a new session's accelerator over the same meshes: the kept trees (hashing, the copy)
    t0, c0 = time.perf_counter(), time.process_time()
    again = create_accelerator("BVH", sa, kept=kept)
    row["numba_kept_s"] = round(time.perf_counter() - t0, 5)
    row["numba_kept_cpu_s"] = round(time.process_time() - c0, 3)
    assert again.stats["meshes_built"] == 0
    del again
    row["embree_build_s"] = row["embree_build_cpu_s"] = None
    rays = camera_rays(scene.camera)
    if scene.triangle_count <= EMBREE_MAX_TRIANGLES:
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            emb = create_accelerator("EMBREE", sa)
            emb.closest_hit(rays[0][:1], rays[1][:1], 0.0, np.inf)  # commits its scene
            row["embree_build_s"] = round(time.perf_counter() - t0, 3)
            row["embree_build_cpu_s"] = round(time.process_time() - c0, 3)
            accs["embree"] = emb
        except AcceleratorUnavailable:
            pass
    for acc in accs.values():
        acc.closest_hit(*rays)  # warm-up
    best = dict.fromkeys(accs, np.inf)
    for _ in range(repeats):  # alternating, so load from elsewhere hits both
        for key, acc in accs.items():
            best[key] = min(best[key], _best(lambda a=acc: a.closest_hit(*rays), 1))
    n = len(rays[0])
    for key in ("numba", "embree"):
        row[f"{key}_mrays"] = round(n / best[key] / 1e6, 3) if key in best else None
    row["bytes_per_triangle"] = memory(scene, sa, accs["numba"])
    return row


def _warm() -> None:
    """Compile (or load) the kernels first: a mesh past
    :data:`~rstrace_engine.accel.bvh_build.PARALLEL_MIN` takes the parallel ones, a small
    one the others, so no row's times include a compilation."""
    for n in (2_000, PARALLEL_MIN + 1_000):
        s = big_scene(n)
        acc = create_accelerator("BVH", s.arrays())
        o, d = camera_rays(s.camera)[:2]
        acc.closest_hit(o[:64], d[:64], 0.0, np.inf)


def _count(text: str) -> int:
    t = text.strip().lower()
    scale = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    return int(float(t[:-1] if scale > 1 else t) * scale)


def run(sizes=SIZES, duplicates=DUPLICATES, repeats: int = 3, threads: int | None = None,
        progress=None, warm: bool = True) -> dict:
    """Measure every scene (after :func:`_warm` with ``warm``); returns
    ``{"rows": [...], "threads": n}``."""
    saved = numba.get_num_threads()
    if threads:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    rows = []
    try:
        if warm:
            _warm()
        for n in sizes:
            dense = shapes.lumpy_sphere(n, name="dense")
            t0 = time.perf_counter()
            scene = big_scene(n, dense)
            rows.append(measure(f"dense {n:,}", scene, repeats, time.perf_counter() - t0))
            if progress:
                progress(rows[-1])
        if duplicates:
            count, tris = duplicates
            rows.append(measure(f"{count:,} x {tris:,}", duplicates_scene(count, tris),
                                repeats))
            if progress:
                progress(rows[-1])
    finally:
        numba.set_num_threads(saved)
    return {"rows": rows, "threads": threads or saved}


def _print_row(r: dict) -> None:
    emb_b = "n/a" if r["embree_build_s"] is None else f"{r['embree_build_s']:.2f}"
    emb_t = "n/a" if r["embree_mrays"] is None else f"{r['embree_mrays']:.2f}"
    m = r["bytes_per_triangle"]
    emb_c = "n/a" if r["embree_build_cpu_s"] is None else f"{r['embree_build_cpu_s']:.2f}"
    scene_s = "n/a" if r["scene_s"] is None else f"{r['scene_s']:.2f}"
    print(f"{r['scene']:<20}{r['unique_triangles']:>11,}{r['instanced_triangles']:>12,}"
          f"{scene_s:>9}{r['pack_s']:>9.2f}{r['numba_build_s']:>9.2f}{emb_b:>9}"
          f"{r['numba_build_cpu_s']:>9.2f}{emb_c:>9}{r['numba_kept_cpu_s']:>9.2f}"
          f"{r['numba_mrays']:>9.2f}{emb_t:>9}"
          f"{m['model']:>8.0f}{m['packed']:>8.0f}{m['bvh']:>8.0f}{m['total']:>8.0f}",
          flush=True)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m rstrace_engine.bench scale")
    ap.add_argument("--quick", action="store_true",
                    help=f"small sizes ({QUICK_SIZES}, duplicates {QUICK_DUPLICATES})")
    ap.add_argument("--sizes", help="comma-separated triangle counts, e.g. 60k,1M,4M")
    ap.add_argument("--duplicates", help="COUNTxTRIANGLES, e.g. 2000x20k; 0: none")
    ap.add_argument("--threads", type=int, help="numba threads (default: all)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    sizes = QUICK_SIZES if args.quick else SIZES
    dup = QUICK_DUPLICATES if args.quick else DUPLICATES
    if args.sizes:
        sizes = tuple(_count(x) for x in args.sizes.split(",") if x.strip())
    if args.duplicates:
        dup = None if args.duplicates == "0" else tuple(
            _count(x) for x in args.duplicates.lower().split("x"))
    if not args.json:
        print(f"{'scene':<20}{'unique':>11}{'instanced':>12}{'scene s':>9}{'pack s':>9}"
              f"{'build s':>9}{'embree':>9}"
              f"{'cpu s':>9}{'embree':>9}{'kept':>9}{'Mray/s':>9}{'embree':>9}{'B/tri: model':>14}"
              f"{'packed':>8}{'bvh':>8}{'total':>8}")
    res = run(sizes, dup, args.repeats, args.threads,
              progress=None if args.json else _print_row)
    if args.json:
        print(json.dumps(res))
    else:
        print(f"threads: {res['threads']} numba (Embree: its own pool)", file=sys.stderr)
    return 0
