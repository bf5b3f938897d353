"""Rough surfaces in RI_TREE frames against BASE (docs/glossy.md, issue 22): one scene, a
converged base reference (16 pixel samples, 64 glossy samples, another seed), then the base
frame and an RI_TREE frame (fallback off: the trees are measured) at the given settings.
Prints each one's display error against the reference (mean, 99th percentile, max; the
largest channel per pixel), the RI_TREE frame's against the base frame and its rays.

``PYTHONPATH=. python scripts/ritree_glossy.py SCENE WIDTH HEIGHT SPP GLOSSY_SAMPLES``,
e.g. ``glossy 160 120 1 16``."""

import sys
from dataclasses import replace

import numpy as np

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.ri_tree.render import RITreeRenderer
from rstrace_engine.tracing.whitted import render


def display_error(a, b) -> np.ndarray:
    return np.abs(image.to_display(a.radiance) - image.to_display(b.radiance)).max(axis=-1)


def main(name: str, w: int, h: int, spp: int, glossy: int) -> None:
    sc = scenes.build(name, w, h)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(max_depth=5, samples=spp, glossy_samples=glossy)
    ref = render(sc, replace(st, samples=16, glossy_samples=64, seed=7), accel=accel)
    base = render(sc, st, accel=accel)
    r = RITreeRenderer()
    r.auto_fallback = False
    f = r.render(sc, replace(st, mode="RI_TREE"), accel)
    out = [f"{name} {w}x{h}, {spp} spp, Glossy Samples {glossy}: "
           f"{f.stats['ri_objects']} objects with a tree"]
    for label, a, b in (("BASE vs reference", base, ref), ("RI_TREE vs reference", f, ref),
                        ("RI_TREE vs BASE", f, base)):
        px = display_error(a, b)
        out.append(f"  {label}: mean {px.mean():.4f} p99 {np.quantile(px, 0.99):.4f} "
                   f"max {px.max():.3f}")
    out.append(f"  RI_TREE rays traced {f.stats['rays_traced']}")
    sys.stdout.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
