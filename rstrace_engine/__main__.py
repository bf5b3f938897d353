"""Command line: ``python -m rstrace_engine render <scene> --out x.png [options]``.

Renders a built-in scene (:mod:`rstrace_engine.scenes`) with the base tracer (or
``--mode INTERPOLANT``) and writes the image as PNG plus a JSON file of the frame's
statistics next to it (``x.json``).

``python -m rstrace_engine warm-cache [--json] [--jobs N]`` compiles every render kernel into
numba's cache (``NUMBA_CACHE_DIR`` if set) without rendering anything (:mod:`.warm_kernels`),
in ``N`` processes (default: one per core), printing ``kernels done/total`` as they land.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from . import image, scenes
from .frame import AVAILABLE_ACCELERATORS, AVAILABLE_MODES, RenderSettings
from .geometry.scene import SceneError
from .session import Session


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m rstrace_engine",
                                description="rstrace core: render a built-in scene")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a built-in scene to PNG + JSON stats")
    r.add_argument("scene", choices=sorted(scenes.SCENES))
    r.add_argument("--out", required=True, help="output PNG path (stats go to .json beside it)")
    r.add_argument("--width", type=int, default=640)
    r.add_argument("--height", type=int, default=480)
    r.add_argument("--depth", type=int, default=5, help="max reflection/refraction depth")
    r.add_argument("--samples", type=int, default=1, help="jittered samples per pixel")
    r.add_argument("--accelerator", default="BVH", choices=AVAILABLE_ACCELERATORS)
    r.add_argument("--mode", default="BASE", choices=AVAILABLE_MODES)
    r.add_argument("--epsilon", type=float, default=0.01,
                   help="error bound of interpolated radiance (INTERPOLANT mode)")
    r.add_argument("--npy", action="store_true", help="also save linear radiance as .npy")
    r.add_argument("-v", "--verbose", action="store_true")
    w = sub.add_parser("warm-cache", help="compile every kernel into numba's cache, no render")
    w.add_argument("--json", action="store_true", help="print the counts as JSON")
    w.add_argument("--jobs", type=int, default=0,
                   help="processes compiling at once (default: one per core)")
    w.add_argument("--modes", nargs="+", choices=AVAILABLE_MODES, default=None)
    w.add_argument("--accelerators", nargs="+", choices=AVAILABLE_ACCELERATORS, default=None)
    w.add_argument("--no-soft-light", dest="soft", action="store_false",
                   help="leave out the orthographic steps with soft light, an area light and "
                        "a lighting world (for scenes of hard lights only, as make demo's)")
    w.add_argument("--no-textures", dest="textures", action="store_false",
                   help="leave out textured surfaces (the kernels that texture interpolated "
                        "rays; for scenes without textures, as make demo's)")
    w.add_argument("--part", default=None, help=argparse.SUPPRESS)  # k/n: one of n workers
    w.add_argument("-v", "--verbose", action="store_true")
    return p


def render_command(args) -> int:
    scene = scenes.build(args.scene, args.width, args.height)
    settings = RenderSettings(mode=args.mode, epsilon=args.epsilon, max_depth=args.depth,
                              samples=args.samples, accelerator=args.accelerator)
    session = Session(scene, settings)
    frame = session.render()
    out = Path(args.out)
    image.write_render_png(out, frame.radiance)
    if args.npy:
        image.save_npy(out.with_suffix(".npy"), frame.radiance)
    stats = dict(scene=args.scene, **session.stats)
    stats_path = out.with_suffix(".json")
    stats_path.write_text(json.dumps(stats, indent=2, default=str) + "\n")
    fs = frame.stats
    speed = (f"{fs['rays_per_s'] / 1e6:.2f} Mrays/s" if "rays_per_s" in fs else
             f"{100 * fs.get('interpolated_fraction', 0.0):.1f}% interpolated")
    print(f"{out}: {fs['width']}x{fs['height']} {args.scene} {args.mode} in "
          f"{fs['time_s']:.2f} s, {speed} (stats: {stats_path})")
    return 0


def _stop_on_sigterm():
    """A ``cancel()`` that turns true on SIGTERM (``make demo`` stops its background warm-up
    so): the parallel warm-up then stops its parts and waits for them, so none is left
    compiling and their CPU time is their parent's (None off the main thread)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
    return stop.is_set


def _exit_with_parent(poll_s: float = 0.5):
    """A part of the parallel warm-up ends when its parent does: a parent killed outright
    (SIGKILL: a test's timeout, Blender crashing) runs no clean-up, and its parts would
    otherwise go on compiling, minutes of CPU holding compile claims that a later warm-up
    waits on. A daemon thread watches the parent's pid (it changes when the part is
    orphaned) and ends the process at once (its claims' file locks go with it). The parent
    names itself in ``RSTRACE_WARM_PARENT``: a part orphaned while still importing finds
    another parent already at its first look."""
    import os
    import threading
    import time

    parent = int(os.environ.get("RSTRACE_WARM_PARENT") or os.getppid())

    def watch():
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(3)

    threading.Thread(target=watch, name="rstrace-part-watch", daemon=True).start()


def warm_cache_command(args) -> int:
    import numba

    from . import warm_kernels

    progress = None if args.json else print
    everything = args.modes is None and args.accelerators is None  # else: unreached is moot
    if args.part:
        from . import warm_first

        _exit_with_parent()
        k, n = (int(x) for x in args.part.split("/"))
        # first the viewport's first image in part 0, the error predicate's chain (the
        # longest compile) in part 1 (warm_kernels.PART_HEADS)
        warm_first.part_head(k, n, args.modes)
        result = warm_kernels.warm(args.modes, args.accelerators, part=(k, n),
                                   report_unreached=False, soft=args.soft,
                                   textures=args.textures)
    elif args.jobs == 1:
        result = warm_kernels.warm(args.modes, args.accelerators, progress=progress,
                                   report_unreached=everything and args.soft and args.textures,
                                   soft=args.soft,
                                   textures=args.textures)
    else:
        result = warm_kernels.warm_parallel(args.jobs or None, args.modes, args.accelerators,
                                            progress=progress, soft=args.soft,
                                            textures=args.textures,
                                            report_unreached=everything and args.soft
                                            and args.textures,
                                            cancel=_stop_on_sigterm())
    result["cache_dir"] = numba.config.CACHE_DIR or "numba default (beside the sources)"
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"kernel cache ({result['cache_dir']}) warm in {result['seconds']:.1f} s "
          f"({result.get('jobs', 1)} processes): "
          f"{result['compiled']} compiled, {result['loaded']} loaded from the cache")
    if result["unreached"]:
        print("kernels no render step uses (not cached): " + ", ".join(result["unreached"]))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        if args.command == "warm-cache":
            return warm_cache_command(args)
        return render_command(args)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
