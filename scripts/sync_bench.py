"""What one small edit costs the viewport's depsgraph sync, in a big scene (bpy, background).

    python scripts/sync_bench.py [--objects 2000] [--repeat 30] [--json out.json]

A scene of ``--objects`` linked duplicates of a small mesh (one mesh datablock, one material),
a light and a camera. Each change is made with the data API, the depsgraph is updated, and
``depsgraph_update_post`` hands the updates to :class:`addon.depsgraph_diff.SceneMirror`
as ``view_update``'s ``addon.sync.sync`` does (updates -> dirty -> read -> diff -> commit; no
session). Timed: that whole sync,
in ms per update, for

* ``move``: one object moved (one ``ObjectTransform``),
* ``colour``: the shared material's base colour (one ``MaterialSet``; every object using it
  is listed in the updates, so this one touches all of them),
* ``light``: the light's power (one ``LightSet``),
* ``select``: a selection change (no edit),

once with every update walking ``depsgraph.object_instances`` (``SceneMirror.partial =
False``, the behaviour before reading only the updated objects) and once reading only what
the updates name where they cannot have changed the set of instances. Both in one run:
the ratio is what to compare (the machine is shared and noisy).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def build(n: int):
    import bpy

    from tests.blender import builders as b

    bpy.ops.wm.read_factory_settings(use_empty=True)
    b.setup_render(64, 48)
    mat = b.principled("Grey", (0.6, 0.6, 0.6))
    me = b.uv_sphere("Ball", 0.2, 8, 4)
    me.materials.append(mat)
    side = int(n ** 0.5) + 1
    for k in range(n):
        b.add_object(f"Ball{k}", me, (0.5 * (k % side), 0.5 * (k // side), 0.2))
    b.add_object("Ground", b.grid("Ground", 40.0), (0.0, 0.0, 0.0))
    b.point_light("Key", (0.0, -4.0, 6.0), 800.0)
    b.camera((side * 0.25, -12.0, 8.0), (side * 0.25, side * 0.25, 0.0))
    bpy.context.view_layer.update()
    return mat


class Syncer:
    """depsgraph_update_post -> SceneMirror, as view_update does; times each sync."""

    def __init__(self, partial: bool) -> None:
        import bpy

        import addon

        self.sync = addon.depsgraph_diff.SceneMirror()
        self.sync.partial = partial
        self.times: list[float] = []
        self.edits: list = []
        self.walks = 0
        dg = bpy.context.evaluated_depsgraph_get()
        self._sync(dg, None)
        bpy.app.handlers.depsgraph_update_post.append(self.handler)

    def _sync(self, dg, dirty):
        import addon

        snap = self.sync.read(dg, dirty, "VIEWPORT", with_camera=False)
        result = self.sync.diff(snap, exists=addon.depsgraph_diff.existing_objects)
        self.sync.commit(result)
        self.walks += bool(snap.stats.get("walked", True))
        return result.edits

    def handler(self, _scene, dg):
        t0 = time.perf_counter()
        dirty = self.sync.dirty(dg)
        out = [] if dirty is None else self._sync(dg, dirty)
        self.times.append(1e3 * (time.perf_counter() - t0))
        self.edits.append(sorted(type(e).__name__ for e in out))

    def close(self):
        import bpy

        bpy.app.handlers.depsgraph_update_post.remove(self.handler)


def measure(n: int, repeat: int, partial: bool) -> dict:
    import bpy

    mat = build(n)
    obs = [o for o in bpy.data.objects if o.name.startswith("Ball")]
    lamp = bpy.data.objects["Key"]
    bsdf = mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"]
    s = Syncer(partial)
    changes = {
        "move": lambda k: setattr(obs[k % len(obs)].location, "z", 0.2 + 0.01 * (k + 1)),
        "colour": lambda k: setattr(bsdf, "default_value", (0.5 + 0.01 * k, 0.4, 0.3, 1.0)),
        "light": lambda k: setattr(lamp.data, "energy", 800.0 + k),
        "select": lambda k: obs[k % len(obs)].select_set(k % 2 == 0),
    }
    rows = {}
    for name, change in changes.items():
        s.times.clear()
        s.edits.clear()
        walks0 = s.walks
        for k in range(repeat):
            change(k)
            bpy.context.view_layer.update()
        rows[name] = dict(ms_median=statistics.median(s.times), ms_min=min(s.times),
                          updates=len(s.times), walks=s.walks - walks0,
                          edits=s.edits[len(s.edits) // 2])
    s.close()
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    import addon

    addon.register()
    before = measure(a.objects, a.repeat, partial=False)
    after = measure(a.objects, a.repeat, partial=True)
    out = {"objects": a.objects, "rows": []}
    for name in before:
        b, f = before[name], after[name]
        ratio = b["ms_median"] / max(f["ms_median"], 1e-9)
        out["rows"].append(dict(edit=name, before_ms=round(b["ms_median"], 3),
                                after_ms=round(f["ms_median"], 3), ratio=round(ratio, 1),
                                walks_before=b["walks"], walks_after=f["walks"],
                                edits=f["edits"]))
        sys.stdout.write(f"{name:7s} before {b['ms_median']:8.2f} ms ({b['walks']} walks)  "
                         f"after {f['ms_median']:8.2f} ms ({f['walks']} walks)  "
                         f"x{ratio:6.1f}  {f['edits']}\n")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    addon.unregister()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
