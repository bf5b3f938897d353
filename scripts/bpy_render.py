"""``blender -b`` for the ``bpy`` module: render a .blend's frames the way a farm worker does.

The render farms (Flamenco, Deadline, a shell loop) start one Blender process per chunk of
frames::

    blender -b scene.blend -E RSTRACE -o //render/frame_#### -s 1 -e 250 -a
    blender -b scene.blend --scene Scene --render-output out/###### \\
        --render-format OPEN_EXR --render-frame 1..10          # Flamenco's stock job type

Where Blender is the ``bpy`` module (``pip install bpy``), this script stands in for the
``blender`` binary with the same options, so the tests and benchmarks drive workers exactly
like a farm (one process per chunk)::

    python scripts/bpy_render.py scene.blend -E RSTRACE -o out/frame_#### -s 1 -e 4 -a

Options are Blender's: ``-E/--engine``, ``-o/--render-output``, ``-F/--render-format``,
``-S/--scene``, ``-s/--frame-start``, ``-e/--frame-end``, ``-j/--frame-jump``,
``-a/--render-anim``, ``-f/--render-frame`` (``7``, ``1..10``, ``1,3,5..7``) and
``-t/--threads``. As in Blender, ``-f`` renders each range as an animation job of that range,
so consecutive frames of one process share one RSTrace session, exactly like ``-a``.

The add-on is imported from this checkout (``--addon-root``, default: the repository this
script is in) and registered, as an installed extension would be at start-up. The last line
printed is ``RESULT {json}``: start-up timings, per-frame times, and the numba kernels the
process compiled or loaded from the cache (``rstrace_engine.kernel_cache.counts``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

T_START = time.perf_counter()
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def frame_ranges(spec: str) -> list[tuple[int, int]]:
    """Blender's ``--render-frame`` syntax: ``7``, ``1..10``, ``1,3,5..7``."""
    out = []
    for part in spec.split(","):
        part = part.strip()
        if ".." in part:
            a, b = part.split("..", 1)
            out.append((int(a), int(b)))
        elif part:
            out.append((int(part), int(part)))
    if not out:
        raise ValueError(f"no frames in {spec!r}")
    return out


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("blendfile")
    p.add_argument("-b", "--background", action="store_true", help="ignored (always)")
    p.add_argument("-E", "--engine")
    p.add_argument("-o", "--render-output")
    p.add_argument("-F", "--render-format")
    p.add_argument("-S", "--scene")
    p.add_argument("-s", "--frame-start", type=int)
    p.add_argument("-e", "--frame-end", type=int)
    p.add_argument("-j", "--frame-jump", type=int)
    p.add_argument("-a", "--render-anim", action="store_true")
    p.add_argument("-f", "--render-frame", type=frame_ranges)
    p.add_argument("-t", "--threads", type=int, help="0: all cores (Blender's default)")
    p.add_argument("--addon-root", default=ROOT, help="checkout to import the add-on from")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if not (args.render_anim or args.render_frame):
        sys.stderr.write("nothing to render: give -a or -f\n")
        return 2
    result: dict = {"pid": os.getpid()}
    import bpy

    result["import_bpy_s"] = time.perf_counter() - T_START
    if args.addon_root and args.addon_root not in sys.path:
        sys.path.insert(0, args.addon_root)
    import addon

    addon.register()
    result["addon_s"] = time.perf_counter() - T_START
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.blendfile))
    result["open_s"] = time.perf_counter() - T_START
    scene = bpy.data.scenes[args.scene] if args.scene else bpy.context.scene
    if args.engine:
        scene.render.engine = args.engine
    if args.render_output:
        scene.render.filepath = args.render_output
    if args.render_format:
        scene.render.image_settings.file_format = args.render_format
    if args.threads is not None:
        scene.render.threads_mode = "FIXED" if args.threads > 0 else "AUTO"
        if args.threads > 0:
            scene.render.threads = args.threads
    if args.frame_jump:
        scene.frame_step = args.frame_jump

    frames: list[dict] = []
    started: dict = {}

    def pre(sc, *_):
        started["t"] = time.perf_counter()

    def post(sc, *_):
        state = addon.session.peek_state(sc)
        frames.append({"frame": sc.frame_current,
                       "seconds": time.perf_counter() - started.get("t", T_START),
                       "at_s": time.perf_counter() - T_START,
                       "error": state.error if state else "not rendered by RSTrace",
                       "stats": {k: v for k, v in (state.stats if state else {}).items()
                                 if isinstance(v, (int, float, str, dict))}})

    bpy.app.handlers.render_pre.append(pre)
    bpy.app.handlers.render_post.append(post)
    if args.render_frame:
        ranges = args.render_frame
    else:
        ranges = [(args.frame_start if args.frame_start is not None else scene.frame_start,
                   args.frame_end if args.frame_end is not None else scene.frame_end)]
    for first, last in ranges:
        scene.frame_start, scene.frame_end = first, last
        bpy.ops.render.render(animation=True, scene=scene.name)

    from rstrace_engine import kernel_cache

    errors = [f"frame {f['frame']}: {f['error']}" for f in frames if f["error"]]
    result.update(frames=frames, total_s=time.perf_counter() - T_START,
                  cpu_s=time.process_time(),  # all threads: independent of other load
                  kernels=kernel_cache.counts(), engine=scene.render.engine, errors=errors,
                  mode=scene.rstrace.mode if hasattr(scene, "rstrace") else None)
    sys.stdout.write("RESULT " + json.dumps(result, default=str) + "\n")
    sys.stdout.flush()
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
