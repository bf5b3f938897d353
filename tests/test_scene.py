"""Scene validation: bad input is rejected with a message that names the offending object."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import (
    TEX_CLIP,
    TEX_EXTEND,
    TEX_GENERATED,
    TEX_OBJECT,
    Camera,
    Light,
    Material,
    Mesh,
    Scene,
    SceneError,
    check_matrix,
)
from rstrace_engine.tracing import shading, whitted

TRI = np.array([[0, 1, 2]], np.int32)
VERTS = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def scene_with_mesh(mesh: Mesh | None = None) -> Scene:
    s = Scene()
    s.add_material(Material("m"))
    s.add_mesh(mesh or Mesh("tri", VERTS, TRI))
    return s


# ----------------------------------------------------------------------------- meshes


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_vertices_rejected(bad):
    v = VERTS.copy()
    v[1, 2] = bad
    with pytest.raises(SceneError, match="Teapot.*NaN or infinite"):
        Scene().add_mesh(Mesh("Teapot", v, TRI))


def test_nonfinite_normals_and_uvs_rejected():
    n = np.zeros((1, 3, 3), np.float32)
    n[0, 0, 0] = np.nan
    with pytest.raises(SceneError, match="Normals"):
        Scene().add_mesh(Mesh("Normals", VERTS, TRI, corner_normals=n))
    uv = np.zeros((1, 3, 2))
    uv[0, 1, 1] = np.inf
    with pytest.raises(SceneError, match="Uvs"):
        Scene().add_mesh(Mesh("Uvs", VERTS, TRI, corner_uvs=uv))
    with pytest.raises(SceneError, match="Short.*corner normal"):
        Scene().add_mesh(Mesh("Short", VERTS, TRI, corner_normals=np.zeros((2, 3, 3))))


def test_empty_and_malformed_meshes_rejected():
    with pytest.raises(SceneError, match="Empty.*no triangles"):
        Scene().add_mesh(Mesh("Empty", np.zeros((0, 3)), np.zeros((0, 3), np.int32)))
    with pytest.raises(SceneError, match="NoFaces.*no triangles"):
        Scene().add_mesh(Mesh("NoFaces", VERTS, np.zeros((0, 3), np.int32)))
    with pytest.raises(SceneError, match="OutOfRange.*index out of range"):
        Scene().add_mesh(Mesh("OutOfRange", VERTS, np.array([[0, 1, 3]])))
    with pytest.raises(SceneError, match="Floats.*integers"):
        Scene().add_mesh(Mesh("Floats", VERTS, np.array([[0.0, 1.0, 2.0]])))
    with pytest.raises(SceneError, match="Flat2D"):
        Scene().add_mesh(Mesh("Flat2D", VERTS[:, :2], TRI))
    with pytest.raises(SceneError, match="Huge.*exceed"):
        Scene().add_mesh(Mesh("Huge", VERTS * 1e13, TRI))


def test_degenerate_triangles_dropped_and_counted():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 1, 0]], float)
    tris = np.array([[0, 1, 2],  # fine
                     [0, 1, 3],  # collinear: zero area
                     [2, 2, 4],  # repeated vertex
                     [1, 4, 2]])  # fine
    s = Scene()
    s.add_material(Material("m"))
    mid = s.add_mesh(Mesh("Sliver", v, tris))
    assert s.stats["degenerate_triangles"] == 2
    assert any("Sliver" in w and "2 degenerate" in w for w in s.warnings)
    s.add_instance(mid, np.eye(4), [0], name="Obj")
    sa = s.arrays()
    assert len(sa.tris) == 2
    # the count reaches the frame statistics, and the mesh still renders
    s.add_light(Light("Sun", "SUN", power=1.0))
    s.set_camera(Camera(matrix=shapes.look_at((0.5, 0.3, 3.0), (0.5, 0.3, 0.0)), width=8,
                        height=6))
    frame = whitted.render(s, RenderSettings(max_depth=0),
                           accel=create_accelerator("BRUTE_FORCE", s.arrays()))
    assert frame.stats["degenerate_triangles"] == 2
    assert any("Sliver" in w for w in frame.stats["warnings"])
    assert np.isfinite(frame.radiance).all()


def test_all_degenerate_mesh_rejected():
    v = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2]], float)
    with pytest.raises(SceneError, match="Needle.*degenerate"):
        Scene().add_mesh(Mesh("Needle", v, TRI))


# ----------------------------------------------------------------------------- matrices


@pytest.mark.parametrize("kind", ["nan", "inf", "zero_scale", "singular", "projective",
                                  "shape", "huge"])
def test_bad_world_matrix_rejected(kind):
    m = np.eye(4)
    if kind == "nan":
        m[0, 3] = np.nan
    elif kind == "inf":
        m[1, 1] = np.inf
    elif kind == "zero_scale":
        m[2, 2] = 0.0
    elif kind == "singular":
        m[:3, :3] = [[1, 0, 0], [0, 1, 0], [1, 1, 0]]  # columns coplanar
    elif kind == "projective":
        m[3, 0] = 0.5
    elif kind == "shape":
        m = np.eye(3)
    elif kind == "huge":
        m[0, 3] = 1e13
    s = scene_with_mesh()
    with pytest.raises(SceneError, match="Statue"):
        s.add_instance(0, m, [0], name="Statue")
    assert s.instances == []


def test_moving_an_instance_to_a_bad_matrix_is_rejected():
    s = scene_with_mesh()
    s.add_instance(0, np.eye(4), [0], name="Statue")
    with pytest.raises(SceneError, match="Statue.*singular"):
        s.set_instance_matrix(0, np.diag([1.0, 0.0, 1.0, 1.0]))
    np.testing.assert_array_equal(s.instances[0]["matrix"], np.eye(4))


def test_tiny_but_regular_scale_accepted():
    m = np.diag([1e-6, 1e-6, 1e-6, 1.0])
    np.testing.assert_array_equal(check_matrix("Small", m), m)


def test_instance_references_checked():
    s = scene_with_mesh()
    with pytest.raises(SceneError, match="Ghost.*unknown mesh"):
        s.add_instance(5, np.eye(4), [0], name="Ghost")
    with pytest.raises(SceneError, match="Ghost.*unknown material"):
        s.add_instance(0, np.eye(4), [3], name="Ghost")


# ----------------------------------------------------------------------------- materials


@pytest.mark.parametrize("field,value,msg", [
    ("diffuse", (1.2, 0.5, 0.5), "diffuse"),
    ("diffuse", (-0.1, 0.5, 0.5), "diffuse"),
    ("diffuse", (np.nan, 0.5, 0.5), "diffuse"),
    ("specular", (0.5, 0.5), "specular"),
    ("mirror", (2.0, 0.0, 0.0), "mirror"),
    ("transmission", (0.0, -1.0, 0.0), "transmission"),
    ("emission", (-1.0, 0.0, 0.0), "emission"),
    ("emission", (np.inf, 0.0, 0.0), "emission"),
    ("roughness", 0.0, "roughness"),
    ("roughness", 1.5, "roughness"),
    ("roughness", np.nan, "roughness"),
    ("ior", 0.5, "IOR"),
    ("ior", np.inf, "IOR"),
])
def test_out_of_range_material_values_rejected(field, value, msg):
    mat = Material("Brass", **{field: value})
    with pytest.raises(SceneError, match=f"Brass.*{msg}|{msg}.*Brass"):
        Scene().add_material(mat)


def test_energy_creating_material_rejected():
    with pytest.raises(SceneError, match="Glow.*exceeds 1"):
        Scene().add_material(Material("Glow", diffuse=(0.6,) * 3, mirror=(0.5,) * 3))
    # exactly 1 is fine
    Scene().add_material(Material("Ok", diffuse=(0.5,) * 3, transmission=(0.5,) * 3))


def test_bad_texture_rejected():
    tex = np.zeros((4, 4, 3), np.float32)
    tex[1, 1, 1] = np.nan
    with pytest.raises(SceneError, match="Checker"):
        Scene().add_material(Material("Checker", texture=tex))
    with pytest.raises(SceneError, match="Stripe.*texture"):
        Scene().add_material(Material("Stripe", texture=np.zeros((4, 4))))


def test_bad_texture_flags_and_map_rejected():
    tex = np.zeros((4, 4, 3), np.float32)
    with pytest.raises(SceneError, match="Flags.*texture flags"):
        Scene().add_material(Material("Flags", texture=tex, texture_flags=TEX_EXTEND | TEX_CLIP))
    with pytest.raises(SceneError, match="Flags.*texture flags"):
        Scene().add_material(Material("Flags", texture=tex, texture_flags=1 << 12))
    with pytest.raises(SceneError, match="Map.*texture map"):
        Scene().add_material(Material("Map", texture=tex, texture_map=((1.0, 0.0), (0.0, 1.0))))
    with pytest.raises(SceneError, match="Map.*texture map"):
        Scene().add_material(Material("Map", texture=tex,
                                      texture_map=((np.nan, 0, 0, 0), (0, 1, 0, 0))))


@pytest.mark.parametrize("flags", [0, TEX_OBJECT, TEX_GENERATED])
def test_texture_coordinates_of_a_hit(flags):
    """UV, Object and Generated texture coordinates through the texture map, against the
    same computed in numpy (Generated: Blender's automatic texture space, the bounding box
    of the mesh, a flat axis given half-size 1)."""
    verts = np.array([[1.0, 2.0, 0.5], [3.0, 2.5, 0.5], [1.5, 4.0, 0.5], [2.0, 3.0, 0.5]])
    tris = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
    uvs = np.array([[[0.1, 0.2], [0.9, 0.3], [0.4, 0.8]]] * 2, np.float32)
    tmap = ((0.5, -0.25, 0.1, 0.3), (0.2, 0.7, 0.0, -0.1))
    s = Scene()
    s.add_material(Material("Tex", texture=np.ones((2, 2, 3), np.float32),
                            texture_flags=flags, texture_map=tmap))
    s.add_mesh(Mesh("other", VERTS, TRI))  # a first mesh: the hit is on the second
    mid = s.add_mesh(Mesh("quad", verts, tris, corner_uvs=uvs))
    s.add_instance(mid, np.eye(4))
    sa = s.arrays()
    tri, b1, b2 = 2, 0.3, 0.25  # the second mesh's second triangle
    w = np.array([1.0 - b1 - b2, b1, b2])
    if flags == 0:
        x = np.append(w @ uvs[1], 0.0)
    else:
        x = w @ verts[tris[1]]
        if flags == TEX_GENERATED:
            lo, hi = verts.min(axis=0), verts.max(axis=0)
            half = np.where(hi == lo, 1.0, (hi - lo) / 2)
            x = (x - ((lo + hi) / 2 - half)) / (2 * half)
            assert x[2] == pytest.approx(0.5)
    want = np.array(tmap) @ np.append(x, 1.0)
    got = shading.texture_uv(sa, 0, tri, b1, b2)
    assert got == pytest.approx(tuple(want), abs=1e-6)


# ----------------------------------------------------------------------------- lights, camera


@pytest.mark.parametrize("light,msg", [
    (Light("Lamp", "TUBE"), "unknown kind"),
    (Light("Lamp", power=-1.0), "power"),
    (Light("Lamp", power=np.nan), "power"),
    (Light("Lamp", position=(0.0, np.nan, 0.0)), "position"),
    (Light("Lamp", "SUN", direction=(0.0, 0.0, 0.0)), "direction"),
    (Light("Lamp", "SPOT", spot_size=0.0), "spot size"),
    (Light("Lamp", "SPOT", spot_blend=1.5), "blend"),
    (Light("Lamp", color=(1.0, -1.0, 1.0)), "colour"),
])
def test_bad_lights_rejected(light, msg):
    with pytest.raises(SceneError, match=f"Lamp.*{msg}|{msg}.*Lamp"):
        Scene().add_light(light)


def test_light_direction_normalised():
    s = Scene()
    s.add_light(Light("Sun", "SUN", direction=(0.0, 0.0, -5.0)))
    assert s.lights[0].direction == pytest.approx((0.0, 0.0, -1.0))


@pytest.mark.parametrize("kw,msg", [
    (dict(lens=0.0), "lens"),
    (dict(kind="PANO"), "unsupported"),
    (dict(sensor_fit="DIAGONAL"), "sensor fit"),
    (dict(clip_start=2.0, clip_end=1.0), "clip end"),
    (dict(width=0), "resolution"),
    (dict(matrix=np.full((4, 4), np.nan)), "matrix"),
    (dict(ortho_scale=-1.0, kind="ORTHO"), "ortho scale"),
])
def test_bad_camera_rejected(kw, msg):
    with pytest.raises(SceneError, match=f"camera.*{msg}"):
        Scene().set_camera(Camera(**kw))


def test_empty_scene_cannot_be_packed():
    with pytest.raises(SceneError, match="no objects"):
        Scene().arrays()
    s = scene_with_mesh()
    with pytest.raises(SceneError, match="no objects"):
        s.arrays()


def test_spot_cone_cosines_packed():
    s = scene_with_mesh()
    s.add_instance(0, np.eye(4), [0], name="Obj")
    s.add_light(Light("Spot", "SPOT", spot_size=math.radians(60.0), spot_blend=0.25))
    s.add_light(Light("Point", "POINT"))
    sa = s.arrays()
    assert sa.light_cos_outer[0] == pytest.approx(math.cos(math.radians(30.0)))
    assert sa.light_cos_outer[0] < sa.light_cos_inner[0] < 1.0
    assert sa.light_intensity[1] == pytest.approx([1000.0 / (4 * math.pi)] * 3)


def test_flat_normals_kernel_matches_the_numpy_formula():
    """``flat_triangle_normals`` (the add-on's flat-shaded export, one kernel pass) gives
    bit for bit what ``np.cross`` / ``np.linalg.norm`` over float64 differences give, and
    leaves a degenerate triangle's normals as they were."""
    from rstrace_engine.geometry import mesh_math

    rng = np.random.default_rng(9)
    v = (rng.normal(size=(3_000, 3)) * 10.0 ** rng.integers(-3, 4, (3_000, 1))).astype(
        np.float32)
    t = rng.integers(0, 3_000, (20_000, 3)).astype(np.int32)
    t[::11, 2] = t[::11, 1]  # zero area: kept as given
    start = rng.normal(size=(len(t), 3, 3)).astype(np.float32)
    want = start.copy()
    a = v[t[:, 0]].astype(np.float64)
    n = np.cross(v[t[:, 1]] - a, v[t[:, 2]] - a)
    length = np.linalg.norm(n, axis=1)
    ok = length > 0.0
    want[ok] = (n[ok] / length[ok, None])[:, None, :].astype(np.float32)
    got = start.copy()
    mesh_math.flat_triangle_normals(v, t, got)
    assert np.array_equal(got.view(np.int32), want.view(np.int32))
    assert np.array_equal(got[::11], start[::11]) and 0 < ok.sum() < len(ok)


def test_area_test_kernel_matches_the_numpy_formula():
    """``proper_triangles`` (a kernel over chunks) keeps exactly the triangles the numpy
    formula keeps, near-degenerate slivers and repeated vertices included."""
    from rstrace_engine import tolerances as tol
    from rstrace_engine.geometry import mesh_math

    rng = np.random.default_rng(5)
    v = rng.normal(size=(400, 3)) * 10.0 ** rng.integers(-3, 4, (400, 1))
    v[300:] = v[:100] + 1e-13 * rng.normal(size=(100, 3))  # near-copies
    t = rng.integers(0, 400, (20_000, 3)).astype(np.int32)
    t[::7, 2] = t[::7, 1]  # repeated vertex: zero area
    line = rng.integers(0, 400, 3000)
    v2 = np.concatenate([v, v[line[:1000]] * 0.5 + v[line[1000:2000]] * 0.5])  # midpoints
    t2 = np.concatenate([t, np.stack([line[:1000], line[1000:2000],
                                      400 + np.arange(1000)], 1).astype(np.int32)])
    tv = v2[t2]
    e0, e1, e2 = tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0], tv[:, 2] - tv[:, 1]
    area2 = np.linalg.norm(np.cross(e0, e1), axis=1)
    longest = np.max(np.stack([(e * e).sum(axis=1) for e in (e0, e1, e2)]), axis=0)
    want = (area2 > tol.DEGENERATE_AREA_REL * longest) & (longest > 0)
    got = mesh_math.proper_triangles(v2, t2)
    assert np.array_equal(got, want)
    assert 0 < got.sum() < len(got)
