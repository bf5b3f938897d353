"""Render frames of the bench scenes and save them, to compare two checkouts bit for bit.

``python scripts/frames_dump.py OUT.npz [--size 320x240] [--scenes a,b] [--modes BASE,...]``
then ``python scripts/frames_dump.py --compare A.npz B.npz`` (max |difference| per frame;
0 everywhere: the same bits). Run the first with ``PYTHONPATH`` set to each checkout.
Each frame: ``Session(scene, RenderSettings(mode=...)).render()``'s radiance and pixel classes.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

DEFAULT_SCENES = ("three_spheres", "museum", "studio", "tori", "grid", "museum_soft",
                  "glossy", "tomatoes", "glass_horizon", "bezier_surface")


def dump(out: str, size: str, scenes, modes) -> None:
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.scenes import build
    from rstrace_engine.session import Session
    w, h = (int(x) for x in size.split("x"))
    frames = {}
    for name in scenes:
        scene = build(name, w, h)
        for mode in modes:
            try:
                frame = Session(scene, RenderSettings(mode=mode)).render()
            except Exception as exc:  # a mode a scene does not support: say so, go on
                sys.stderr.write(f"{name} {mode}: {type(exc).__name__}: {exc}\n")
                continue
            frames[f"{name}/{mode}"] = np.asarray(frame.radiance)
            frames[f"{name}/{mode}/class"] = np.asarray(frame.pixel_class)
            sys.stderr.write(f"{name} {mode}: done\n")
    np.savez(out, **frames)


def compare(a: str, b: str) -> int:
    fa, fb = np.load(a), np.load(b)
    bad = 0
    for k in sorted(set(fa.files) | set(fb.files)):
        if k not in fa.files or k not in fb.files:
            sys.stdout.write(f"{k}: only in one file\n")
            bad += 1
            continue
        x, y = fa[k], fb[k]
        same = (x.shape == y.shape and x.dtype == y.dtype
                and np.array_equal(x.view(np.uint8), y.view(np.uint8)))
        diff = (float(np.nanmax(np.abs(x.astype(np.float64) - y))) if x.shape == y.shape
                else np.inf)
        verdict = "bit for bit" if same else "DIFFERENT"
        sys.stdout.write(f"{k}: {verdict} (max |diff| {diff:g})\n")
        bad += not same
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="?")
    ap.add_argument("--compare", nargs=2)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--scenes", default=",".join(DEFAULT_SCENES))
    ap.add_argument("--modes", default="BASE")
    args = ap.parse_args(argv)
    if args.compare:
        return compare(*args.compare)
    dump(args.out, args.size, args.scenes.split(","), args.modes.split(","))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
