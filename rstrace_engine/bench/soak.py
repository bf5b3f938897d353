"""Random edit sequences: the generator behind the property test and the edit soak.

:class:`EditGenerator` turns a seed into a sequence of edit batches of every kind
(:mod:`~rstrace_engine.geometry.edits`): moving, adding, deleting, hiding and re-meshing
objects, changing their materials, material parameters, mesh data, lights (power, colour,
position, cone, extent, added, deleted), the world colour and the camera. It keeps its own copy of
the scene in step so every edit is valid, and keeps the number of objects, lights and meshes
bounded (slots are reused). :data:`SOAK_SCENES` are small scenes with mirrors and glass
whose boxes the edits stay inside (so most frames are incremental).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .. import scenes
from ..geometry import shapes
from ..geometry.edits import (
    CameraChange,
    LightDelete,
    LightSet,
    MaterialDelete,
    MaterialSet,
    MeshDelete,
    MeshSet,
    ObjectAdd,
    ObjectDelete,
    ObjectGeometry,
    ObjectMaterials,
    ObjectTransform,
    ObjectVisibility,
    WorldColor,
    apply_edits,
)
from ..geometry.elements import MAX_LIGHTS
from ..geometry.principled import principled_material
from ..geometry.scene import Camera, Light, Material, Scene
from ..tracing.whitted import has_glossy


def room(width: int = 64, height: int = 48) -> Scene:
    """A floor and two walls (one a mirror), boxes, a small cube, a glass ball; point,
    spot and sun lights."""
    s = Scene()
    s.add_material(Material("wall", diffuse=(0.7, 0.68, 0.6)), key="wall")
    s.add_material(Material("red", diffuse=(0.7, 0.15, 0.1), specular=(0.2,) * 3,
                            roughness=0.2), key="red")
    s.add_material(Material("mirror", diffuse=(0.03,) * 3, mirror=(0.9,) * 3), key="mirror")
    s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(0.9,) * 3, ior=1.5),
                   key="glass")
    s.add_material(Material("blue", diffuse=(0.1, 0.2, 0.7)), key="blue")
    s.add_mesh(shapes.plane(12.0, name="floor"), key="floor")
    s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="cube"), key="cube")
    s.add_mesh(shapes.icosphere(2, 0.5, name="ball"), key="ball")
    s.add_mesh(shapes.plane(1.0, name="panel"), key="panel")
    mid = s.mesh_id
    mat = s.material_id
    s.add_instance(mid("floor"), np.eye(4), [mat("wall")], name="Floor")
    s.add_instance(mid("panel"), shapes.transform((0.0, 5.5, 2.0), (10.0, 4.0, 1.0), 0, 90),
                   [mat("mirror")], name="Mirror")
    s.add_instance(mid("panel"), shapes.transform((-5.5, 0.0, 2.0), (10.0, 4.0, 1.0), 90, 90),
                   [mat("wall")], name="Wall")
    s.add_instance(mid("cube"), shapes.transform((-1.5, 1.0, 0.5)), [mat("red")], name="Box")
    s.add_instance(mid("cube"), shapes.transform((1.0, -0.5, 0.15), 0.3), [mat("blue")],
                   name="Small")
    s.add_instance(mid("ball"), shapes.transform((1.5, 1.5, 0.6)), [mat("glass")],
                   name="Glass")
    s.add_light(Light("Lamp", "POINT", power=900.0, position=(-2.0, -2.0, 3.5)))
    s.add_light(Light("Spot", "SPOT", power=1500.0, position=(3.0, -3.0, 3.0),
                      direction=(-0.5, 0.6, -0.6), spot_size=math.radians(60)))
    s.add_light(Light("Sun", "SUN", power=0.8, direction=(0.3, 0.5, -1.0)))
    s.set_world_color((0.05, 0.05, 0.08), lights=False)  # a background only
    s.set_camera(Camera(matrix=shapes.look_at((0.5, -7.0, 3.0), (0.0, 0.5, 0.8)), lens=28.0,
                        width=width, height=height))
    return s


def spheres(width: int = 64, height: int = 48) -> Scene:
    """The paper's three spheres (one a mirror) on a plane, coarse tessellation."""
    return scenes.three_spheres(width, height, subdivisions=2)


def tori(width: int = 64, height: int = 48) -> Scene:
    """Smooth non-convex objects (tori, one a mirror), a point light and a sun."""
    return scenes.tori(width, height)


def soft_room(width: int = 64, height: int = 48) -> Scene:
    """The room lit as a Blender user lights it: an area light, a sphere light, a sun
    with an angle and a world that lights."""
    s = room(width, height)
    s.set_light(s.light_slot("Lamp"), Light("Lamp", "POINT", power=900.0,
                                            position=(-2.0, -2.0, 3.5), radius=0.3))
    s.set_light(s.light_slot("Sun"), Light("Sun", "SUN", power=0.8,
                                           direction=(0.3, 0.5, -1.0), angle=0.1))
    s.add_light(Light("Area", "AREA", power=600.0, position=(0.5, 0.0, 3.8),
                      direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(1.5, 0.8)))
    s.set_world_color((0.05, 0.05, 0.08), lights=True)
    return s


def rough_room(width: int = 64, height: int = 48) -> Scene:
    """The room with rough Principled materials (issue 24): the mirror wall a rough metal,
    the glass ball rough glass, the red box Blender's default plastic; its edits draw
    rough materials too (:class:`EditGenerator`)."""
    s = room(width, height)
    for key, kw in (("mirror", dict(base=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.3)),
                    ("glass", dict(base=(1.0, 1.0, 1.0), transmission=1.0, roughness=0.25)),
                    ("red", dict(base=(0.7, 0.15, 0.1), roughness=0.5))):
        mat, _ = principled_material(key, **kw)
        s.set_material(s.material_id(key), mat)
    return s


def rough_soft_room(width: int = 64, height: int = 48) -> Scene:
    """:func:`rough_room`'s materials under :func:`soft_room`'s lights: soft shadows seen
    in rough reflections and through rough glass (object edits re-shade them at secondary
    hits, :mod:`~..tracing.shadow_reshade`)."""
    s = soft_room(width, height)
    r = rough_room(width, height)
    for key in ("mirror", "glass", "red"):
        s.set_material(s.material_id(key), r.materials[r.material_id(key)])
    return s


SOAK_SCENES = {"room": room, "spheres": spheres, "tori": tori, "soft_room": soft_room,
               "rough_room": rough_room, "rough_soft_room": rough_soft_room}


def soft_room_unlit_world(width: int = 64, height: int = 48) -> Scene:
    """:func:`soft_room` with the world a background only: its area light, sphere light
    and sun with an angle are what the interpolants can prove (the world's light is not
    proven over any cell: docs/INTERPOLANTS.md, "Soft light")."""
    s = soft_room(width, height)
    s.set_world_color((0.05, 0.05, 0.08), lights=False)
    return s


#: Scenes of the INTERPOLANT soak (:func:`interpolant_soak`): interpolated under soft light.
INTERPOLANT_SOAK_SCENES = {"soft_room_unlit_world": soft_room_unlit_world, "room": room}


def interpolant_soak(steps: int, epsilon: float = 0.02, width: int = 256, height: int = 192,
                     log=print) -> dict:
    """``steps`` random edit batches (every kind, the light extents of
    :attr:`EditGenerator.SOFT_KINDS`, camera moves) on :data:`INTERPOLANT_SOAK_SCENES` in
    an INTERPOLANT session, each incremental frame checked against a fresh BASE frame of
    the edited scene: the maximum display error within ``epsilon`` (float32 frames: plus
    1e-6) and every traced pixel BASE's. Raises AssertionError on the first failure."""
    from .. import image
    from ..frame import CLASS_INTERPOLATED, CLASS_REBUILT, RenderSettings
    from ..session import Session

    st = RenderSettings(mode="INTERPOLANT", epsilon=epsilon, max_depth=3, light_samples=4)
    base_st = RenderSettings(mode="BASE", max_depth=3, light_samples=4)
    worst, interpolated, done = 0.0, [], 0
    per_scene = max(1, steps // len(INTERPOLANT_SOAK_SCENES))
    for k, (name, build) in enumerate(sorted(INTERPOLANT_SOAK_SCENES.items())):
        gen = EditGenerator(build(width, height), seed=2000 + k,
                            extra=EditGenerator.EXTRA_KINDS + EditGenerator.SOFT_KINDS)
        sess = Session(gen.scene.copy(), st)
        sess.render()
        for _ in range(per_scene):
            sess.apply(gen.step())
            frame = sess.render()
            base = Session(sess.scene.copy(), base_st).render()
            err = float(image.compare(frame.radiance, base.radiance, epsilon)["max_error"])
            worst = max(worst, err)
            if err > epsilon + 1e-6:
                raise AssertionError(f"interpolant soak {name}: error {err} over epsilon")
            cls = frame.pixel_class
            traced = (cls != CLASS_INTERPOLATED) & (cls != CLASS_REBUILT)
            diff = float(np.abs(frame.radiance[traced] - base.radiance[traced]).max(
                initial=0.0))
            if diff > 1e-6:
                raise AssertionError(f"interpolant soak {name}: a traced pixel differs by "
                                     f"{diff}")
            interpolated.append(float(np.mean(~traced)))
            done += 1
        log(f"interpolant soak {name}: {per_scene} steps, kinds {gen.kinds_done}")
    return dict(steps=done, max_error=worst, epsilon=epsilon,
                mean_interpolated_fraction=float(np.mean(interpolated)) if interpolated
                else 0.0)


class EditGenerator:
    """Seeded random edit batches of every kind on a scene (a copy is kept in step)."""

    KINDS = ("move", "add", "delete", "visibility", "geometry", "materials", "material_set",
             "mesh_set", "light_power", "light_move", "light_add", "light_delete", "world",
             "camera")
    #: kinds a generator adds on request (``extra=``), so that the seeded sequences of
    #: :attr:`KINDS` stay as they were: removing a mesh or a material no object uses any
    #: more
    EXTRA_KINDS = ("mesh_delete", "material_delete")
    #: a light's extent (issue 20), extra kinds too: a point or spot light's radius and
    #: soft falloff, a sun's angle, an area light's size, shape and spread (one is added
    #: when there is none); which rays see a light with an extent directly (its camera,
    #: glossy and transmission visibility, issue 23); and light and shadow linking (the
    #: objects a light lights, those that cast its shadow)
    SOFT_KINDS = ("light_radius", "sun_angle", "area_light", "light_seen", "light_link")

    def __init__(self, scene: Scene, seed: int = 0, camera: bool = True,
                 extra: tuple = (), rough: bool | None = None) -> None:
        unknown = set(extra) - set(self.EXTRA_KINDS) - set(self.SOFT_KINDS)
        if unknown:
            raise ValueError(f"unknown extra edit kinds {sorted(unknown)}")
        self.kinds = self.KINDS + tuple(extra)
        self.scene = scene.copy()
        self.rng = np.random.default_rng(seed)
        self.camera = camera
        self.kinds_done: dict[str, int] = {}
        self.max_objects = len(scene.instances) + 4
        self.max_lights = max(len(scene.lights), 1) + 2
        self.max_meshes = len(scene.meshes) + 2
        box = scene.arrays().scene_aabb
        self.lo = box[0] + 0.2 * (box[1] - box[0])
        self.hi = box[1] - 0.2 * (box[1] - box[0])
        self.hi[2] = box[0][2] + 0.6 * (box[1][2] - box[0][2])
        self._serial = 0
        self._order: list[str] = []
        # new materials may be rough Principled ones (glossy rays); by default where the
        # scene has such a material (other scenes keep their seeded sequences)
        self.rough = has_glossy(scene.arrays()) if rough is None else bool(rough)

    # -- helpers -------------------------------------------------------------------------

    def _objects(self):
        """Keys of the movable objects (the first, a floor, stays put)."""
        first = self.scene.live_instances()[0][0]
        return [i["key"] for k, i in self.scene.live_instances() if k != first]

    def _pick(self, seq):
        return seq[int(self.rng.integers(len(seq)))]

    def _matrix(self, scale_max: float = 0.6) -> np.ndarray:
        pos = self.rng.uniform(self.lo, self.hi)
        s = self.rng.uniform(0.15, scale_max)
        return shapes.transform(pos, s, float(self.rng.uniform(0, 360)))

    def _light(self, name: str) -> Light:
        kind = self._pick(("POINT", "SPOT", "SUN"))
        if kind == "SUN":
            return Light(name, "SUN", power=float(self.rng.uniform(0.2, 1.5)),
                         direction=tuple(self.rng.normal(0, 0.4, 3) + (0.0, 0.0, -1.0)))
        pos = self.rng.uniform(self.lo, self.hi)
        pos[2] = self.hi[2] + self.rng.uniform(1.0, 3.0)
        return Light(name, kind, color=tuple(self.rng.uniform(0.6, 1.0, 3)),
                     power=float(self.rng.uniform(200, 1500)), position=tuple(pos),
                     direction=tuple(self.rng.normal(0, 0.3, 3) + (0.0, 0.0, -1.0)),
                     spot_size=float(self.rng.uniform(0.4, 1.4)),
                     spot_blend=float(self.rng.uniform(0.0, 0.5)))

    def _material(self, name: str) -> Material:
        kind = self.rng.integers(4)
        col = tuple(self.rng.uniform(0.05, 0.8, 3))
        if kind == 0:
            return Material(name, diffuse=(0.03,) * 3, mirror=(0.85,) * 3)
        if kind == 1:
            return Material(name, diffuse=(0.0,) * 3, transmission=(0.85,) * 3, ior=1.4)
        if self.rough and kind >= 2:  # rough metal (F82-tinted), glass or plastic
            metallic = float(self.rng.integers(2))
            tint = tuple(self.rng.uniform(0.3, 1.0, 3)) if metallic else None
            mat, _ = principled_material(
                name, col, metallic=metallic,
                transmission=float(self.rng.integers(2)) * 0.9,
                roughness=float(self.rng.uniform(0.05, 0.8)), metal_tint=tint)
            return mat
        return Material(name, diffuse=col, specular=(0.1,) * 3,
                        roughness=float(self.rng.uniform(0.05, 0.5)))

    # -- one batch -----------------------------------------------------------------------

    def _edit(self, kind: str):
        s, rng = self.scene, self.rng
        objects = self._objects()
        mesh_keys = list(s.mesh_keys.slot)
        mat_keys = list(s.material_keys.slot)
        light_keys = list(s.light_keys.slot)
        if kind == "move" and objects:
            key = self._pick(objects)
            m = s.instances[s.instance_slot(key)]["matrix"].copy()
            m[:3, 3] = np.clip(m[:3, 3] + rng.normal(0, 0.4, 3), self.lo, self.hi)
            return [ObjectTransform(key, m)]
        if kind == "add" and s.n_instances < self.max_objects:
            self._serial += 1
            return [ObjectAdd(f"obj{self._serial}", self._pick(mesh_keys[1:] or mesh_keys),
                              self._matrix(), (self._pick(mat_keys),))]
        if kind == "delete" and len(objects) > 2:
            return [ObjectDelete(self._pick(objects))]
        if kind == "visibility" and objects:
            key = self._pick(objects)
            return [ObjectVisibility(key, not s.instances[s.instance_slot(key)]["visible"])]
        if kind == "geometry" and objects:
            return [ObjectGeometry(self._pick(objects), self._pick(mesh_keys[1:] or mesh_keys))]
        if kind == "materials" and objects:
            return [ObjectMaterials(self._pick(objects), (self._pick(mat_keys),))]
        if kind == "material_set":
            key = self._pick(mat_keys)
            return [MaterialSet(key, self._material(str(key)))]
        if kind == "mesh_set":
            if len(mesh_keys) < self.max_meshes:
                key = f"mesh{len(mesh_keys)}"
            else:
                key = self._pick(mesh_keys[1:])
            size = tuple(rng.uniform(0.3, 1.2, 3))
            mesh = (shapes.box(size, name=str(key)) if rng.integers(2)
                    else shapes.icosphere(1, float(size[0]) * 0.6, name=str(key)))
            edits = [MeshSet(key, mesh)]
            if objects:
                edits.append(ObjectGeometry(self._pick(objects), key))
            return edits
        if kind == "mesh_delete":
            # a mesh no object uses any more (after a delete or a geometry swap); else
            # re-mesh one object so that its old mesh is left unused, and remove that
            used = {i["mesh"] for _, i in s.live_instances()}
            unused = [k for k in mesh_keys[1:] if s.mesh_id(k) not in used]
            if unused:
                return [MeshDelete(self._pick(unused))]
            if not objects:
                return None
            key = self._pick(objects)
            old = s.instances[s.instance_slot(key)]["mesh"]
            users = s.mesh_users(old)
            old_key = next(k for k, v in s.mesh_keys.slot.items() if v == old)
            others = [k for k in mesh_keys if k != old_key]
            if len(users) != 1 or old_key == mesh_keys[0] or not others:
                return None
            return [ObjectGeometry(key, self._pick(others)), MeshDelete(old_key)]
        if kind == "material_delete":
            used = {m for _, i in s.live_instances() for m in i["materials"]}
            unused = [k for k in mat_keys[1:] if s.material_id(k) not in used]
            return [MaterialDelete(self._pick(unused))] if unused else None
        if kind == "light_power" and light_keys:
            key = self._pick(light_keys)
            li = s.lights[s.light_slot(key)]
            return [LightSet(key, replace(li, color=tuple(rng.uniform(0.5, 1.0, 3)),
                                          power=li.power * float(rng.uniform(0.3, 2.0))))]
        if kind == "light_move" and light_keys:
            key = self._pick(light_keys)
            return [LightSet(key, self._light(str(key)))]
        if kind == "light_add" and s.n_lights < self.max_lights and len(s.lights) < MAX_LIGHTS:
            self._serial += 1
            return [LightSet(f"light{self._serial}", self._light(f"light{self._serial}"))]
        if kind == "light_delete" and len(light_keys) > 1:
            return [LightDelete(self._pick(light_keys))]
        if kind in ("light_radius", "sun_angle", "area_light"):
            return self._extent(kind, light_keys)
        if kind == "light_link" and light_keys:
            key = self._pick(light_keys)
            names = sorted({i["name"] for _, i in s.live_instances()})
            links = []
            for _ in range(2):  # receivers, then blockers: none, or a few objects
                pick = rng.random(len(names)) < 0.4
                links.append(() if rng.random() < 0.3 else tuple(
                    (n, bool(rng.integers(2))) for n, p in zip(names, pick, strict=True) if p))
            return [LightSet(key, replace(s.lights[s.light_slot(key)], receivers=links[0],
                                          blockers=links[1]))]
        if kind == "light_seen":
            keys = [k for k in light_keys if s.lights[s.light_slot(k)].extended]
            if not keys:
                return None
            key = self._pick(keys)
            camera, glossy, transmission = (bool(x) for x in rng.integers(2, size=3))
            return [LightSet(key, replace(s.lights[s.light_slot(key)], camera=camera,
                                          glossy=glossy, transmission=transmission))]
        if kind == "world":
            return [WorldColor(tuple(rng.uniform(0.0, 0.2, 3)))]
        if kind == "camera" and self.camera:
            cam = s.camera
            m = cam.matrix.copy()
            m[:3, 3] += rng.normal(0, 0.1, 3)
            return [CameraChange(Camera(m, cam.kind, cam.lens, cam.sensor_width,
                                        cam.sensor_height, cam.sensor_fit, cam.shift_x,
                                        cam.shift_y, cam.clip_start, cam.clip_end,
                                        cam.ortho_scale, cam.width, cam.height))]
        return None

    def _extent(self, kind: str, light_keys: list):
        """A light's extent edited (see :attr:`EXTRA_KINDS`)."""
        s, rng = self.scene, self.rng
        lights = {k: s.lights[s.light_slot(k)] for k in light_keys}
        if kind == "light_radius":
            keys = [k for k, li in lights.items() if li.kind in ("POINT", "SPOT")]
            if not keys:
                return None
            key = self._pick(keys)
            radius = 0.0 if rng.random() < 0.25 else float(rng.uniform(0.05, 0.6))
            return [LightSet(key, replace(lights[key], radius=radius,
                                          soft_falloff=bool(rng.integers(2))))]
        if kind == "sun_angle":
            keys = [k for k, li in lights.items() if li.kind == "SUN"]
            if not keys:
                return None
            key = self._pick(keys)
            angle = 0.0 if rng.random() < 0.25 else float(rng.uniform(0.01, 0.5))
            return [LightSet(key, replace(lights[key], angle=angle))]
        keys = [k for k, li in lights.items() if li.kind == "AREA"]
        shape = self._pick(("SQUARE", "RECTANGLE", "DISK", "ELLIPSE"))
        size = tuple(float(x) for x in rng.uniform(0.2, 2.0, 2))
        spread = math.pi if rng.random() < 0.5 else float(rng.uniform(0.3, math.pi))
        if keys:
            key = self._pick(keys)
            return [LightSet(key, replace(lights[key], shape=shape, size=size,
                                          spread=spread))]
        if s.n_lights >= self.max_lights or len(s.lights) >= 64:
            return None
        self._serial += 1
        pos = self.rng.uniform(self.lo, self.hi)
        pos[2] = self.hi[2] + self.rng.uniform(1.0, 3.0)
        key = f"light{self._serial}"
        return [LightSet(key, Light(key, "AREA", power=float(rng.uniform(200, 1200)),
                                    position=tuple(pos), direction=(0.0, 0.0, -1.0),
                                    shape=shape, size=size, spread=spread))]

    def step(self) -> list:
        """One batch of edits (one kind, sometimes two kinds at once), already applied to
        :attr:`scene`."""
        batch = []
        if not self._order:  # every kind once in a shuffled round, then the next round
            self._order = [k for k in self.kinds if self.camera or k != "camera"]
            self.rng.shuffle(self._order)
        first = self._order.pop()
        for n in range(1 + int(self.rng.random() < 0.2)):
            for _try in range(20):
                kind = first if n == 0 and _try == 0 else self._pick(self.kinds)
                edits = self._edit(kind)
                if edits:
                    self.scene, _ = apply_edits(self.scene, edits)
                    self.kinds_done[kind] = self.kinds_done.get(kind, 0) + 1
                    batch += edits
                    break
        return batch
