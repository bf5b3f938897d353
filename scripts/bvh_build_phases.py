"""A large mesh's BVH build split into its phases, checkouts alternated in one run.

    python scripts/bvh_build_phases.py [1M 4M] [--roots A B] [--rounds 2] [--threads 1]
                                       [--repeats 3] [--json out.jsonl] [--tbb] [--warm]

The mesh is ``bench_scale_bpy.py``'s Suzanne (subdivided to level 5 for ``1M``, 6 for
``4M``: 1.0M / 4.0M triangles, Blender's own triangle order), made once through ``bpy`` and
kept as ``.npy`` under ``--cache``. Each round runs every size in a fresh process per
checkout (``--roots``, default main's worktree and this script's; the order flips every
round: A B, B A, ...), which times ``bvh_mesh.build_mesh_bvh_indexed`` ``--repeats``
times with each phase wrapped (process CPU seconds, all threads; ``NUMBA_NUM_THREADS``
``--threads``): the triangle boxes, the items (quads), the top levels, the subtrees, the
item leaves, the items opened, the collapse to 4-wide (``flatten``: on every thread
from session 40), and the rest. The first build of a
process meets fresh memory, as an F12's does; the later ones reuse freed pages. It also
loads each kernel from numba's cache, which an F12 does before (``addon/kernels.py``):
``--warm`` first builds the mesh's first 70,000 triangles, untimed, so that the first
timed build is an F12's (kernels loaded, fresh memory; session 38). Each
line also gives the tree's SAH and 4-wide node count, so a change of tree shows. Nothing
is asserted; the numbers go to ``docs/bench-scale-bpy.md``.

Each phase also gets its wall (session 40), its system CPU and minor page faults
(``getrusage``: first touches of fresh memory; session 39).

Threads: each phase also gets the CPU of its busiest thread (``busiest``, from
``/proc/self/task/*/schedstat``): on an idle machine the phase's wall is about that, so the
wall the threads buy can be read off a loaded one. Outside Blender numba picks its OpenMP
layer here; an F12 runs on TBB (``bpy`` ships it): ``--tbb`` imports ``bpy`` in each child
first, so that numba picks TBB as in Blender (the layer is in each line; session 37,
docs/bench-scale.md "Session 37 (threads)").
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LEVELS = {"1M": 5, "4M": 6}
#: (module, function, label) of the phases, in build order
PHASES = (("bvh_mesh", "indexed_boxes", "boxes"), ("bvh_cluster", "pair_items", "items"),
          ("bvh_build", "split_top", "top"), ("bvh_build", "build_subtrees", "subtrees"),
          ("bvh_cluster", "item_leaves", "leaves"), ("bvh_cluster", "open_items", "open"),
          ("bvh_mesh", "flatten", "collapse"))


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _suzanne(size: str, cache: Path) -> tuple[Path, Path]:
    """The cached ``.npy`` vertices (float64) and triangles (int32) of Suzanne at ``size``
    (made through ``bpy`` in a child process the first time)."""
    v, t = cache / f"suzanne{size}_v.npy", cache / f"suzanne{size}_t.npy"
    if not (v.exists() and t.exists()):
        cache.mkdir(parents=True, exist_ok=True)
        code = f"""
import bpy, numpy as np
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_monkey_add()
ob = bpy.context.object
mod = ob.modifiers.new("Subdivision", "SUBSURF")
mod.levels = mod.render_levels = {LEVELS[size]}
me = bpy.data.meshes.new_from_object(ob.evaluated_get(bpy.context.evaluated_depsgraph_get()))
me.calc_loop_triangles()
v = np.empty(3 * len(me.vertices), np.float32)
me.vertices.foreach_get("co", v)
t = np.empty(3 * len(me.loop_triangles), np.int32)
me.loop_triangles.foreach_get("vertices", t)
np.save({str(v)!r}, v.reshape(-1, 3).astype(np.float64))
np.save({str(t)!r}, t.reshape(-1, 3))
"""
        subprocess.run([sys.executable, "-c", code], check=True)
    return v, t


def _thread_cpu() -> dict:
    """CPU seconds of each thread of this process so far (``/proc/self/task``)."""
    out = {}
    for t in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{t}/schedstat") as fh:
                out[t] = int(fh.read().split()[0]) * 1e-9
        except OSError:  # (a thread that ended)
            pass
    return out


def child(root: Path, size: str, cache: Path, repeats: int, tbb: bool = False,
          warm: bool = False) -> dict:
    """One checkout's builds of one mesh, each phase timed (run in its own process)."""
    sys.path.insert(0, str(root))
    if tbb:
        import bpy  # noqa: F401  (numba then picks the TBB layer, as inside Blender)
    import numba
    import numpy as np

    from rstrace_engine.accel import bvh_build, bvh_cluster, bvh_mesh

    mods = dict(bvh_build=bvh_build, bvh_cluster=bvh_cluster, bvh_mesh=bvh_mesh)
    acc: dict = {}
    busy: dict = {}
    sysf: dict = {}
    walls: dict = {}
    for mod, name, label in PHASES:
        f = getattr(mods[mod], name)

        def timed(*a, _f=f, _label=label, **k):
            c, t0, w0 = time.process_time(), _thread_cpu(), time.perf_counter()
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            try:
                return _f(*a, **k)
            finally:
                acc[_label] = acc.get(_label, 0.0) + time.process_time() - c
                walls[_label] = walls.get(_label, 0.0) + time.perf_counter() - w0
                r1 = resource.getrusage(resource.RUSAGE_SELF)  # (system CPU, minor faults)
                sysf[_label] = (sysf.get(_label, (0.0, 0))[0] + r1.ru_stime - r0.ru_stime,
                                sysf.get(_label, (0.0, 0))[1] + r1.ru_minflt - r0.ru_minflt)
                t1 = _thread_cpu()
                busy[_label] = busy.get(_label, 0.0) + max(
                    (t1[t] - t0.get(t, 0.0) for t in t1), default=0.0)

        setattr(mods[mod], name, timed)
    vp, tp = _suzanne(size, cache)
    verts, tris = np.load(vp), np.load(tp)
    if warm:  # (past PARALLEL_MIN: every kernel of the large build loaded, untimed)
        bvh_mesh.build_mesh_bvh_indexed(verts, np.ascontiguousarray(tris[:70_000]))
    runs = []
    for _ in range(repeats):
        acc.clear()
        busy.clear()
        sysf.clear()
        walls.clear()
        c, w = time.process_time(), time.perf_counter()
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        mb = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
        total, wall = time.process_time() - c, time.perf_counter() - w
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        sysf["all"] = (r1.ru_stime - r0.ru_stime, r1.ru_minflt - r0.ru_minflt)
        row = {label: acc.get(label, 0.0) for _, _, label in PHASES}
        row["rest"] = total - sum(row.values())
        runs.append(dict(total=total, wall=wall, phases=row,
                         busiest={label: busy.get(label, 0.0) for _, _, label in PHASES},
                         sys_faults=dict(sysf),
                         walls={label: walls.get(label, 0.0) for _, _, label in PHASES}))
        del mb
    mb = bvh_mesh.build_mesh_bvh_indexed(verts, tris)
    return dict(root=str(root), size=size, triangles=len(tris), sah=mb.sah_cost,
                nodes4=len(mb.bvh.child), runs=runs, module=bvh_build.__file__, warm=warm,
                layer=numba.threading_layer(), threads=numba.get_num_threads(),
                load=os.getloadavg()[0])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("sizes", nargs="*", default=["1M", "4M"])
    p.add_argument("--roots", nargs="+", type=Path,
                   default=[Path("/work/main"), ROOT])
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--cache", type=Path, default=Path("/tmp/rstrace-suzanne"))
    p.add_argument("--json", type=Path, help="append one JSON line per process")
    p.add_argument("--tbb", action="store_true",
                   help="import bpy in each child first: numba's TBB layer, as in Blender")
    p.add_argument("--warm", action="store_true",
                   help="an untimed small build first: the first timed build an F12's")
    p.add_argument("--child", nargs=2, metavar=("ROOT", "SIZE"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        _say(json.dumps(child(Path(args.child[0]), args.child[1], args.cache,
                              args.repeats, args.tbb, args.warm)))
        return 0
    for size in args.sizes:
        _suzanne(size, args.cache)
    env = dict(os.environ, NUMBA_NUM_THREADS=str(args.threads))
    for r in range(args.rounds):
        roots = args.roots if r % 2 == 0 else args.roots[::-1]
        for size in args.sizes:
            for root in roots:
                out = subprocess.run(
                    [sys.executable, __file__, "--child", str(root.resolve()), size,
                     "--cache", str(args.cache), "--repeats", str(args.repeats)]
                    + (["--tbb"] if args.tbb else []) + (["--warm"] if args.warm else []),
                    env=env, check=True, capture_output=True, text=True).stdout
                row = json.loads(out.strip().splitlines()[-1])
                if args.json:
                    with open(args.json, "a") as fh:
                        fh.write(json.dumps(row) + "\n")
                totals = ", ".join(f"{x['total']:.3f}" for x in row["runs"])
                _say(f"round {r} {size} {root}: builds {totals} s CPU | SAH "
                     f"{row['sah']:.4f}, {row['nodes4']} nodes | {row['layer']}, "
                     f"{row['threads']} threads, load {row['load']:.2f}")
                for i, x in enumerate(row["runs"]):
                    _say(f"    build {i}: " + ", ".join(
                        f"{k} {v:.3f}" for k, v in x["phases"].items())
                        + f" | wall {x['wall']:.3f}, busiest thread " + ", ".join(
                        f"{k} {v:.3f}" for k, v in x["busiest"].items()))
                    _say("        wall s: " + ", ".join(
                        f"{k} {v:.3f}" for k, v in x.get("walls", {}).items()))
                    _say("        system s / minor faults: " + ", ".join(
                        f"{k} {v[0]:.3f}/{v[1]}" for k, v in x.get("sys_faults", {}).items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
