"""The batch's dielectric albedos (``tracing.dielectric_albedo``) are ``ggx_albedo``'s, bit
for bit, at every Principled point with a diffuse albedo (0 where it has none), and nothing
else is written."""

from __future__ import annotations

import numpy as np

from rstrace_engine import scenes, stripes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry.elements import TEX_SPECULAR
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import MODEL_PRINCIPLED
from rstrace_engine.session import Session
from rstrace_engine.tracing import whitted
from rstrace_engine.tracing.dielectric_albedo import dielectric_albedos
from rstrace_engine.tracing.shading import dot3, ggx_albedo


def test_the_batch_gives_ggx_albedos_dielectric_part_bit_for_bit():
    rng = np.random.default_rng(7)
    n = 6000
    vd = rng.normal(size=(n, 3))
    vd /= np.linalg.norm(vd, axis=1)[:, None]
    ns = rng.normal(size=(n, 3))
    ns /= np.linalg.norm(ns, axis=1)[:, None]
    ns[:50] = -vd[:50]  # head-on (cosine 1), grazing and behind (clamped to GGX_COS_MIN)
    ns[50:100] = np.cross(vd[50:100], [0.0, 0.0, 1.0])
    ns[100:150] = vd[100:150]
    ns[150] = np.nan  # (a NaN normal gives ggx_albedo's NaN)
    roughness = np.concatenate([[0.0, 1e-8, 1e-3, 1.0, 0.5], rng.uniform(0.0, 1.0, 25)])
    ior = np.concatenate([[1.0, 1.5, 1.45, 0.7, 2.0, 1.0 / 1.5], rng.uniform(0.3, 3.0, 24)])
    model = np.full(30, MODEL_PRINCIPLED, np.int32)
    model[3] = MODEL_PRINCIPLED + 1  # another model: not written
    mat = rng.integers(-1, 30, n).astype(np.int32)  # (-1: a miss, not written)
    diffuse = rng.uniform(0.0, 1.0, (30, 3))
    diffuse[[7, 8]] = 0.0  # a metal's or a glass's: no diffuse part, the albedo never read
    diffuse[9] = (0.0, 0.0, 0.3)
    out = np.full(n, -7.0)
    dielectric_albedos(vd, ns, mat, model, roughness, ior, diffuse, out, 0, 1)
    written = (mat >= 0) & (model[np.maximum(mat, 0)] == MODEL_PRINCIPLED)
    assert np.all(out[~written] == -7.0) and written.sum() > 4000
    dark = written & np.isin(mat, [7, 8])
    assert dark.sum() > 200 and np.all(out[dark] == 0.0)
    for i in np.flatnonzero(written & ~dark):
        m = mat[i]
        c = -dot3(vd[i, 0], vd[i, 1], vd[i, 2], ns[i, 0], ns[i, 1], ns[i, 2])
        want = ggx_albedo(c, roughness[m], ior[m])[1]
        assert np.float64(want).tobytes() == np.float64(out[i]).tobytes(), (i, want, out[i])


def test_the_albedos_are_striped_as_the_shade_kernel_is(monkeypatch):
    """Each stripe writes its own points' albedos (the same bits as one pass), and the shade
    level runs the kernel on every stripe's thread (:func:`~rstrace_engine.stripes.run`),
    not in the calling thread alone: there it added its whole cost to each batch's wall
    time on a many-core machine, where inside the shade kernel every thread shared it."""
    from rstrace_engine import stripes
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.scenes import build
    from rstrace_engine.session import Session
    from rstrace_engine.tracing import whitted

    rng = np.random.default_rng(9)
    n = 1000
    vd = rng.normal(size=(n, 3))
    vd /= np.linalg.norm(vd, axis=1)[:, None]
    ns = -vd + 0.3 * rng.normal(size=(n, 3))
    mat = rng.integers(-1, 3, n).astype(np.int32)
    model = np.full(3, MODEL_PRINCIPLED, np.int32)
    roughness, ior = np.array([0.1, 0.4, 0.9]), np.array([1.5, 1.33, 2.2])
    diffuse = np.array([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [0.1, 0.2, 0.3]])
    whole = np.full(n, -7.0)
    dielectric_albedos(vd, ns, mat, model, roughness, ior, diffuse, whole, 0, 1)
    parts = np.full(n, -7.0)
    for first in range(3):
        part = np.full(n, -7.0)
        dielectric_albedos(vd, ns, mat, model, roughness, ior, diffuse, part, first, 3)
        own = (np.arange(n) // stripes.BLOCK) % 3 == first
        assert np.all(part[~own] == -7.0)
        parts[own] = part[own]
    assert parts.tobytes() == whole.tobytes()

    ran = []
    real = stripes.run
    monkeypatch.setattr(stripes, "run", lambda k, *a: ran.append(k) or real(k, *a))
    Session(build("rough_materials", 16, 12), RenderSettings(max_depth=1)).render()
    assert whitted.dielectric_albedos in ran and whitted._shade_kernel in ran


def test_points_without_a_dielectric_layer_or_a_diffuse_part_skip_the_quadrature():
    """A specular IOR of 1 or a diffuse albedo of 0 (rough_materials' floor, box, metal and
    glass) skips the 8 x 4 quadrature and writes 0 (the shade kernel reads the albedo only
    as ``(1 - E)`` times the diffuse albedo); the same points with a diffuse part get their
    albedo. On main every Principled point with a specular IOR other than 1 ran it."""
    rng = np.random.default_rng(3)
    n = 200_000
    vd = rng.normal(size=(n, 3))
    vd /= np.linalg.norm(vd, axis=1)[:, None]
    ns = -vd
    mat = rng.integers(0, 3, n).astype(np.int32)
    model = np.full(3, MODEL_PRINCIPLED, np.int32)
    roughness, ior = np.array([0.3, 0.3, 0.3]), np.array([1.0, 1.5, 1.5])
    out = np.full(n, -7.0)
    dark = np.array([[0.6, 0.6, 0.6], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    lit = np.array([[0.6, 0.6, 0.6], [0.2, 0.2, 0.2], [0.2, 0.2, 0.2]])
    dielectric_albedos(vd, ns, mat, model, roughness, ior, dark, out, 0, 1)
    assert np.all(out == 0.0)
    dielectric_albedos(vd, ns, mat, model, roughness, ior, lit, out, 0, 1)
    assert np.all(out[mat == 0] == 0.0) and np.all(out[mat > 0] > 0.0)


def test_a_frame_is_the_same_with_the_skipped_albedos_computed(monkeypatch):
    """The skip's premise, on a whole frame: the shade kernel reads the albedo only times
    the diffuse albedo. With every skipped point's albedo computed anyway (a white diffuse
    given to the quadrature) the frame is the same bit for bit: a rough metal and glass, a
    black plastic under its dielectric layer, a textured specular tint above 1 on a black
    base, lights with an extent and a world that lights (the diffuse part's closed form)."""
    scene = scenes.glossy(24, 18)
    ids = {m.name: i for i, m in enumerate(scene.materials) if m is not None}
    scene.set_material(ids["plastic"], principled_material("plastic", (0.0, 0.0, 0.0))[0])
    hdr = np.full((4, 4, 3), 3.0)
    hdr[0, 0] = 0.0
    scene.set_material(ids["green"], principled_material(
        "green", (0.0, 0.0, 0.0), roughness=0.05, texture=hdr, texture_flags=TEX_SPECULAR)[0])
    st = RenderSettings(samples=2, glossy_samples=2, max_depth=3)
    skipped = Session(scene.copy(), st).render()
    real = whitted.dielectric_albedos
    read = []

    def every_point(VD, NS, MAT, model, rough, ior, diffuse, out, first, step):
        real(VD, NS, MAT, model, rough, ior, np.ones_like(diffuse), out, first, step)
        own = (np.arange(len(MAT)) // stripes.BLOCK) % step == first
        m = np.maximum(MAT, 0)
        dark = own & (MAT >= 0) & (model[m] == MODEL_PRINCIPLED) & (ior[m] != 1.0) & np.all(
            diffuse[m] == 0.0, axis=1)
        read.append(out[dark])

    monkeypatch.setattr(whitted, "dielectric_albedos", every_point)
    full = Session(scene.copy(), st).render()
    assert np.concatenate(read).max() > 0.1  # (what the skip writes 0 for)
    assert full.radiance.tobytes() == skipped.radiance.tobytes()
