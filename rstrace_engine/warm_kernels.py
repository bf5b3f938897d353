"""Warm numba's kernel cache: compile (or load) every render kernel, render nothing.

``python -m rstrace_engine warm-cache`` and the add-on's
``addon.runtime.warm_cache()`` run :func:`warm`. A render-farm worker (or a user after
installing the extension) runs it once, so that the first frame of every later process loads
compiled kernels instead of compiling them (a minute or more on a small machine).

numba compiles a kernel for the argument *types* it is called with, so the only way to
compile exactly the kernels a render uses is to call them: :func:`warm` drives the renderer
through a tiny scene made for the purpose (64x48 pixels, just enough for interpolant cells;
every material feature, point, sun and spot lights, perspective and orthographic cameras)
in every available mode and accelerator, through the steps the viewport and an animation
take (the viewport's coarse image in tiles, a first frame, a camera move, a moved object, an
incremental frame, an interpolant memory cap small enough to evict). The add-on's background
warm-up (``addon/kernels.py``) runs the same :func:`warm` for the chosen mode only, so there
is one way to compile the kernels.
No image is written; the frames are discarded. What it reports (``kernel_cache.counts``)
says how many kernels were compiled and how many loaded, and names any render kernel it
did not reach.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import time

import numpy as np

from . import child_python, kernel_cache

log = logging.getLogger(__name__)

#: Modules whose kernels a render never calls (benchmark helpers).
NOT_RENDER_KERNELS = ("rstrace_engine.bench",)

#: At most this many identical first frames in the RI-tree step (:func:`_warm_ri_trees`).
RI_WARM_FRAMES = 8


def warm_scene(width: int = 64, height: int = 48, ortho: bool = False,
               eye=(0.0, -6.0, 3.0), glossy_at=(-1.2, 0.3, 0.8), textured: bool = True,
               rough: bool | None = None):
    """A tiny scene with every feature the kernels branch on (``textured=False``: its floor
    without its texture, for ``warm-cache --no-textures``). ``rough``: with a rough metal
    (glossy rays; default: the orthographic variant only; :func:`warm` asks it of the
    perspective one when it leaves the orthographic steps out)."""
    from .geometry import shapes
    from .geometry.scene import Camera, Light, Material, Scene

    s = Scene()
    checker = np.indices((4, 4)).sum(axis=0) % 2
    texture = np.repeat(checker[..., None], 3, axis=2).astype(np.float32) * 0.6 + 0.2
    floor = s.add_material(Material("floor", diffuse=(0.6, 0.6, 0.6),
                                    texture=texture if textured else None))
    glossy = s.add_material(Material("glossy", diffuse=(0.5, 0.2, 0.1), specular=(0.3,) * 3,
                                     roughness=0.2))
    mirror = s.add_material(Material("mirror", diffuse=(0.05,) * 3, mirror=(0.9,) * 3))
    glass = s.add_material(Material("glass", diffuse=(0.0,) * 3, mirror=(0.05,) * 3,
                                    transmission=(0.9,) * 3, ior=1.5))
    glow = s.add_material(Material("glow", diffuse=(0.2,) * 3, emission=(2.0, 1.5, 1.0)))
    ground = s.add_mesh(shapes.plane(8.0, divisions=2, name="ground"))
    sphere = s.add_mesh(_as_exported(shapes.uv_sphere(12, 6, name="sphere")))
    ico = s.add_mesh(shapes.icosphere(1, name="ico"))
    box = s.add_mesh(_flat_shaded(shapes.box((0.8, 0.8, 0.8), name="box")))
    torus = s.add_mesh(shapes.torus(0.6, 0.2, 12, 6, name="torus"))
    s.add_instance(ground, np.eye(4), [floor], name="Ground")
    s.add_instance(sphere, shapes.transform(glossy_at), [glossy], name="Glossy")
    s.add_instance(ico, shapes.transform((0.9, -0.4, 0.8)), [mirror], name="Mirror")
    s.add_instance(box, shapes.transform((0.0, 1.2, 0.4), 1.0, 30.0), [glass], name="Glass")
    s.add_instance(torus, shapes.transform((1.6, 1.4, 0.3), 1.0, 20.0, 70.0), [glow],
                   name="Glow")
    # the orthographic variant has soft light (a sphere light, a sun with an angle, a
    # spot with a radius, an area light, a world that lights): its kernels warm too; the
    # perspective one keeps hard light, whose cells reach the predicate's light tests
    soft = 0.1 if ortho else 0.0
    rough = ortho if rough is None else rough
    if rough:  # and a rough metal: glossy rays (issue 24)
        from .geometry.principled import principled_material

        metal, _ = principled_material("rough", (0.8, 0.6, 0.4), metallic=1.0, roughness=0.4)
        s.add_instance(ico, shapes.transform((-0.4, -1.4, 0.3), 0.3), [s.add_material(metal)],
                       name="Rough")
    # (the sphere without soft falloff, the spot's with: both shapes the mirror sees)
    s.add_light(Light("Point", "POINT", power=800.0, position=(-2.0, -3.0, 4.0),
                      radius=soft, soft_falloff=not ortho))
    s.add_light(Light("Sun", "SUN", power=1.0, direction=(0.3, 0.2, -1.0), angle=soft))
    s.add_light(Light("Spot", "SPOT", power=900.0, position=(2.0, -2.0, 3.0),
                      direction=(-0.4, 0.4, -1.0), radius=soft))
    if ortho:
        s.add_light(Light("Area", "AREA", power=300.0, position=(0.0, 0.0, 3.0),
                          direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(1.0, 0.5)))
    s.set_world_color((0.05, 0.06, 0.08), lights=ortho)
    matrix = shapes.look_at(eye, (0.0, 0.3, 0.5))
    if ortho:
        s.set_camera(Camera(matrix=matrix, kind="ORTHO", ortho_scale=6.0, width=width,
                            height=height))
    else:
        s.set_camera(Camera(matrix=matrix, lens=35.0, width=width, height=height))
    return s


def _flat_shaded(mesh):
    """``mesh`` with each triangle's own normal at its corners, computed as the add-on's
    export of a flat-shaded Blender mesh computes them (float32 vertices, the
    ``flat_triangle_normals`` kernel): the warm-up reaches that kernel too."""
    from dataclasses import replace

    from .geometry.mesh_math import flat_triangle_normals

    verts = np.ascontiguousarray(mesh.vertices, np.float32)
    tris = np.ascontiguousarray(mesh.triangles, np.int32)
    normals = np.zeros((len(tris), 3, 3), np.float32)
    flat_triangle_normals(verts, tris, normals)
    return replace(mesh, corner_normals=normals)


def _as_exported(mesh):
    """``mesh`` as the add-on hands a smooth Blender mesh over: float32 vertices, float32
    normals per vertex (Blender's POINT domain: each vertex's from the mesh's own corner
    normals) and ``owned`` arrays, so the warm-up reaches the kernels of that path too
    (:mod:`~.geometry.mesh_check`: its checks read float32 vertices as they are)."""
    from dataclasses import replace

    from .geometry.mesh_math import gather_corners

    # (the export gathers its triangles' vertices from their corners: that kernel too)
    flat = np.asarray(mesh.triangles, np.int32).reshape(-1)
    tris, _ = gather_corners(flat, np.arange(len(flat), dtype=np.int32).reshape(-1, 3))
    vn = np.zeros((len(mesh.vertices), 3), np.float32)
    vn[tris.reshape(-1)] = np.asarray(mesh.corner_normals, np.float32).reshape(-1, 3)
    return replace(mesh, vertices=np.asarray(mesh.vertices, np.float32), triangles=tris,
                   corner_normals=None, vertex_normals=vn, owned=True)


def _modes() -> tuple[str, ...]:
    from .session import AVAILABLE_MODES

    return tuple(AVAILABLE_MODES)


def _accelerators() -> tuple[str, ...]:
    from .accel import embree

    return ("BVH", "VISIBILITY_FIELD") + (("EMBREE",) if embree.available() else ())


def _yield(lock) -> None:
    """Between two steps: a thread waiting for ``lock`` gets it (Python's locks are not
    fair; without a pause the warm-up would take it straight back)."""
    if lock is not None:
        time.sleep(0.005)


class Cancelled(Exception):
    """``cancel()`` said stop (between two steps of :func:`warm`)."""


def _check(cancel) -> None:
    if cancel is not None and cancel():
        raise Cancelled


def _animate(session, ortho: bool, cancel=None, textured: bool = True,
             rough: bool | None = None) -> None:
    """What the viewport and the frames of an animation do: a coarse view image (the
    viewport's first image, in tiles), render, move the camera, move an object (a full frame
    when the scene box grows, an incremental one when it does not), render."""
    from .interactive import coarse_camera, trace_view

    trace_view(session, coarse_camera(session.scene.camera, 4), session.settings,
               cancel=cancel)
    steps = [None, dict(eye=(0.5, -5.8, 3.1)),
             dict(eye=(0.5, -5.8, 3.1), glossy_at=(-0.9, 0.1, 0.9)),
             # the same camera and scene box: an incremental frame (dirty-pixel queries)
             dict(eye=(0.5, -5.8, 3.1), glossy_at=(-0.6, 0.1, 0.9))]
    for step in steps:
        _check(cancel)
        if step is not None:
            session.update_scene(warm_scene(ortho=ortho, textured=textured, rough=rough,
                                            **step))
        session.render(cancel=cancel)
    # light edits: the first makes BASE keep its per-light terms (a full frame), then it
    # relights (a moved light is shaded again, a power change recombines); between them an
    # object moved with those terms kept: under soft light (the orthographic variant, BASE)
    # the lights whose shadow rays alone it crosses are shaded again, from the samples'
    # visibility bits of that full frame (a moved light drops them)
    from dataclasses import replace

    from .geometry import shapes
    from .geometry.edits import LightSet, ObjectTransform

    spot = session.scene.lights[session.scene.light_slot("Spot")]
    for edit in ([LightSet("Spot", replace(spot, power=spot.power * 0.8))],
                 [ObjectTransform("Glossy", shapes.transform((-0.5, 0.1, 0.9)))],
                 [LightSet("Spot", replace(spot, position=(1.8, -2.0, 3.2)))],
                 [LightSet("Spot", replace(spot, position=(1.8, -2.0, 3.2),
                                           power=spot.power * 0.9))]):
        _check(cancel)
        session.apply(edit)
        session.render(cancel=cancel)


def _warm_edited_interpolants(progress=None, cancel=None, textured: bool = True) -> None:
    """Interpolants that pass the error predicate (their tunnels go into the ray segment
    trees and the membership index), then an edit that queries and invalidates them. The
    warm scene is too small and too hard (textures, a spot, occluders) for any cell to pass."""
    from dataclasses import replace

    from . import scenes
    from .frame import RenderSettings
    from .geometry import shapes
    from .geometry.edits import LightSet, ObjectTransform
    from .geometry.scene import Light
    from .session import Session

    message = "warming kernels: interpolants and an edit"
    log.info(message)
    if progress is not None:
        progress(message)
    # two samples per pixel: the second pass reprojects from the first (the demo's frames
    # at 4 samples call reproject._reproject_rays; one sample never did, and a fresh
    # warm-cache left it for the demo's interpolated frame to compile)
    settings = RenderSettings(mode="INTERPOLANT", max_depth=3, epsilon=0.02, depth_cap=5,
                              samples=2)
    scene = scenes.three_spheres(128, 96, subdivisions=2)
    # a textured floor: samples of cells whose root hit is textured split their radiance
    # into R + texel * D (the warm scene's floor is textured too, but its cells' samples
    # never reached texture_split: a fresh warm-cache left _root_texels uncompiled)
    if textured:
        floor = [m.name for m in scene.materials].index("floor")
        checker = np.indices((8, 8)).sum(axis=0) % 2
        texture = np.repeat(checker[..., None], 3, axis=2).astype(np.float32) * 0.5 + 0.3
        scene.materials[floor] = replace(scene.materials[floor], texture=texture).validated()
    session = Session(scene, settings)
    # every cell built and checked (the measured fallback could defer them all in a frame
    # this small: the predicate's kernels would stay cold; _animate runs the fallback)
    session.interpolants.auto_fallback = False
    session.render(cancel=cancel)
    # a camera step: the next frame splats this one's interpolants into its pixels and
    # reprojects from them (reproject._splat; the warm scene's steps have none to splat)
    _check(cancel)
    moved = copy.copy(scene)
    moved.set_camera(replace(scene.camera, matrix=shapes.look_at((0.15, -8.5, 3.6),
                                                                  (0.0, 0.3, 0.8))))
    session.update_scene(moved)
    session.render(cancel=cancel)
    _check(cancel)
    session.apply([ObjectTransform("RedSphere", shapes.transform((-1.4, 0.5, 1.0)))])
    session.render(cancel=cancel)
    # the dependency lists' compaction (a long edit session frees more entries than stay
    # live; too many for a tiny scene to reach): forced once, with what the edit freed
    cache = session.interpolants.cache
    if cache is not None:
        cache.deps.compact(cache.pool, cache.trees, force=True)
    # a light added: the cells take its term where it is proven (added_light.py: their
    # samples shaded with it alone, its shafts added), in a session that keeps the light
    # terms from its first frame (its cells keep their test lines; untextured: a textured
    # root the light reaches fails its cell)
    _check(cancel)
    session = Session(scenes.three_spheres(128, 96, subdivisions=2), settings)
    session.interpolants.auto_fallback = False
    session.light_terms = True
    session.render(cancel=cancel)
    session.apply([LightSet("WarmAdded", Light("WarmAdded", "POINT", power=300.0,
                                               position=(0.5, -1.0, 4.0)))])
    session.render(cancel=cancel)


def _warm_ri_trees(accelerators, progress=None, cancel=None) -> None:
    """RI-trees that are built, queried, pruned, invalidated by an edit and walked for the
    thickness view (exact and interpolated). The warm scene's objects are too small for a
    tree (``MIN_TRIANGLES``): a 40x30 glass sphere and a mirror torus, with coarse RI
    settings so that the step stays short."""
    from dataclasses import replace

    from .frame import RenderSettings
    from .geometry import shapes
    from .geometry.edits import LightDelete, ObjectTransform
    from .geometry.scene import Light, Material
    from .session import Session

    s = warm_scene(40, 30, eye=(0.3, -2.2, 1.2))  # close: the RI objects fill the view
    glass = s.add_material(Material("ri_glass", diffuse=(0.0,) * 3, mirror=(1.0,) * 3,
                                    specular=(0.1,) * 3, transmission=(0.9,) * 3, ior=1.5,
                                    roughness=0.05, model="PRINCIPLED"))
    chrome = s.add_material(Material("ri_chrome", diffuse=(0.05,) * 3, mirror=(0.9,) * 3))
    s.add_instance(s.add_mesh(shapes.icosphere(2, 0.6, name="ri_ball")),
                   shapes.transform((-0.2, -0.6, 0.9)), [glass], name="RIGlass")
    s.add_instance(s.add_mesh(shapes.torus(0.5, 0.18, 24, 12, name="ri_torus")),
                   shapes.transform((0.8, 0.6, 0.9), 1.0, 30.0), [chrome], name="RIMirror")
    s.add_light(Light("Gone", "POINT", power=100.0, position=(0.0, 0.0, 5.0)))
    for accel in accelerators:
        message = f"warming kernels: RI-trees, {accel}"
        log.info(message)
        if progress is not None:
            progress(message)
        # (an exit-ray test of 1 deg: at the default 0.025 deg, or 0.1, no cell of these
        # coarse trees passes in RI_WARM_FRAMES frames, and the kernels of interpolated
        # rays would not be reached)
        settings = RenderSettings(mode="RI_TREE", accelerator=accel, max_depth=3,
                                  ri_dist_thresh=0.25, ri_depth=16, ri_cache_mb=0.05,
                                  ri_probe_angle=1.0)
        # first frames under a roomy cache, until a ray was interpolated: the kernels that
        # run only on final leaves (finalize, the two-class test, surface interpolation)
        # are reached only once enough queries reached a leaf (the cost rule). Seen from
        # the warm scene's own camera the two objects cover too few of the 40x30 pixels
        # for any leaf to become final, and a fresh warm-cache left those kernels
        # uncompiled (hence the close camera); a repeated frame adds its queries to the
        # same leaves' visit counts
        session = Session(s, replace(settings, ri_cache_mb=8.0))
        # keep the trees whatever this machine's timings say (ri_tree.fallback): the
        # warm-up must reach the tree kernels of every frame
        session.ri_tree.auto_fallback = False
        for _ in range(RI_WARM_FRAMES):
            frame = session.render(cancel=cancel)
            if frame.stats.get("interpolated_fraction", 0.0) > 0.0:
                break
        # then the tiny cap (mid-batch pruning, overflow traced)
        session.update_settings(settings)
        session.render(cancel=cancel)
        session.apply([ObjectTransform("RIGlass", shapes.transform((-0.1, -0.6, 0.9))),
                       LightDelete("Gone")])
        session.render(cancel=cancel)
        for mode in ("RI_TREE", "BASE"):
            session.update_settings(replace(settings, mode=mode, thickness_view=True))
            session.render(cancel=cancel)


def _warm_large_bvh(progress=None, cancel=None) -> None:
    """A first frame of a mesh just past ``bvh_build.PARALLEL_MIN`` triangles: the BVH
    builder's parallel kernels (``LARGE_BUILD_KERNELS``) run only for such meshes, so
    without this step a user's first heavy scene compiled them (and the shipped cache
    lacked them). A 182x182 grid: 66,248 triangles, a fraction of a second to build."""
    from .accel.bvh_build import PARALLEL_MIN
    from .frame import RenderSettings
    from .geometry import shapes
    from .geometry.scene import Material
    from .session import Session

    message = "warming kernels: a large mesh's BVH build"
    log.info(message)
    if progress is not None:
        progress(message)
    s = warm_scene(16, 12)
    grid = shapes.plane(6.0, divisions=182, name="large_grid")
    assert len(grid.triangles) >= PARALLEL_MIN
    grey = s.add_material(Material("large", diffuse=(0.5,) * 3))
    s.add_instance(s.add_mesh(grid), shapes.transform((0.0, 0.0, -0.5)), [grey],
                   name="LargeGrid")
    Session(s, RenderSettings(mode="BASE", accelerator="BVH", samples=1,
                              max_depth=1)).render(cancel=cancel)
    # the interpolants' query scenes (interpolants/shafts.py) gather such a mesh's
    # vertices in parallel (bvh_mesh.gather_triangles_into) and build its binary tree
    # packed (bvh_build.pack_nodes, which the mesh BVH above does not run: it collapses
    # the unpacked nodes)
    from .accel import bvh_build, bvh_mesh
    from .interpolants.shafts import binary_bvh

    sa = s.arrays()
    tv = bvh_mesh.mesh_triangles(sa, int(np.argmax(np.diff(sa.mesh_tri_start))))
    binary_bvh(tv.min(axis=1), tv.max(axis=1), bvh_build.MAX_LEAF)


#: What each of ``warm-cache``'s two parts compiles before its units
#: (:func:`~.warm_kernels.units`), in this order: the first the viewport's first image (the
#: tracer's stages, the traversal, the BVH build: ``make demo``'s own first frame compiles
#: the build meanwhile, the claims share it out, then waits for the stages), the second,
#: when INTERPOLANT is warmed, the error predicate's chain (the longest compile, ~80 s of
#: CPU in one process) from the start, beside them (before: the traversal and the build,
#: then its units, which reached the chain last, after the interpolants' own kernels).
PART_HEADS = (("tracer", "traversal", "build"), ("predicate",))
#: :data:`PART_HEADS` when INTERPOLANT is not warmed (no predicate; ``make demo``: its
#: INTERPOLANT frame on a cold cache is the base tracer's, ``interpolants.build_beside``):
#: the second part compiles the traversal, the first image's longest compile, while the
#: first compiles the tracer's stages and the build
BASE_PART_HEADS = (("tracer", "build"), ("traversal",))


def part_heads(modes=("INTERPOLANT",)) -> tuple:
    """The heads of ``warm-cache``'s parts for ``modes``."""
    return PART_HEADS if "INTERPOLANT" in (modes or ("INTERPOLANT",)) else BASE_PART_HEADS


def units(modes, accelerators, soft: bool = True) -> list[tuple]:
    """The warm-up's steps in the order :func:`warm_parallel` deals them out to its
    processes: ``("step", mode, accelerator, orthographic)`` accelerator by accelerator,
    camera by camera, every mode in turn (so that the processes start on different modes,
    i.e. different kernels), then ``("ri_trees",)`` (RI-trees on the first accelerator)
    when their mode is warmed, and ``("large_bvh",)`` (a large mesh's parallel BVH build)
    with the BVH. When INTERPOLANT is warmed, its first step and ``("interpolants",)`` (an
    edit of interpolants that pass) come first: the first process (the first image's
    kernels, ``warm-cache --part``: :data:`PART_HEADS`) then renders the INTERPOLANT
    step while the second (the error predicate's chain) renders the interpolants that pass,
    so that the kernels
    both need are shared out by whichever gets to each first (the compile claims), and
    the error predicate's (a fifth of the demo's compile) are compiled beside the BASE
    step's. Before, the first process compiled 229 s of the demo's 287 s of CPU and the
    second waited for it. A part runs its units in the order dealt.
    ``soft=False`` leaves out the orthographic steps (the warm scene's variant with soft
    light, an area light and a world that lights: kernels a scene of hard lights never
    calls; ``make demo``) and the large BVH."""
    cameras = (False, True) if soft else (False,)
    out = [("step", m, a, o) for a in accelerators for o in cameras for m in modes]
    if "INTERPOLANT" in modes:
        first = ("step", "INTERPOLANT", accelerators[0], False)
        out.remove(first)
        out[:0] = [first, ("interpolants",)]
    if "RI_TREE" in modes:
        out.append(("ri_trees",))
    if soft and "BVH" in accelerators:  # (not for make demo: its meshes are small)
        out.append(("large_bvh",))
    return out


def warm(modes=None, accelerators=None, progress=None, cancel=None,
         report_unreached: bool = True, lock=None, part: tuple[int, int] | None = None,
         soft: bool = True, textures: bool = True) -> dict:
    """Compile or load every render kernel; return counts and the time taken.

    ``progress(message)`` is called before each step. ``cancel() -> bool`` is polled
    between steps and inside each frame (the add-on's background warm-up stops when Blender
    unregisters it); a cancelled warm-up returns ``cancelled=True``. Returns
    ``kernel_cache.counts()`` of this warm-up only (compiles earlier in the process are not
    counted) plus ``seconds``, ``modes``, ``accelerators``, ``cancelled``
    and ``unreached``: render kernels with nothing in the disk cache afterwards (kernels
    inlined into their callers never have their own code and are not listed; empty when
    ``report_unreached`` is False, as for a warm-up of one mode). ``lock``: held around each
    step (not the whole warm-up), so that a viewport sharing it renders between steps.
    ``part=(k, n)``: only the units (:func:`units`) ``k``, ``k + n``, ... (one of ``n``
    processes of :func:`warm_parallel`; ``python -m
    rstrace_engine warm-cache --part k/n`` first compiles :data:`PART_HEADS`: the
    viewport's first image in part 0, the error predicate's chain in part 1).
    ``soft=False``: no orthographic, soft-light steps (:func:`units`). ``textures=False``:
    no textured surfaces (the kernels that apply a texture to interpolated rays or split a
    sample's radiance by its texel: ``make demo``'s scene has no texture).
    """
    from .frame import RenderSettings
    from .session import Session

    t0 = time.perf_counter()
    since = kernel_cache.mark()
    modes = tuple(modes or _modes())
    accelerators = tuple(accelerators or _accelerators())
    mine = units(modes, accelerators, soft)
    if part is not None:
        mine = mine[part[0]::part[1]]
    if part is None:  # mode by mode (the add-on's warm-up: its mode's steps first)
        steps = [(m, a, o) for m in modes for a in accelerators for o in (False, True)
                 if ("step", m, a, o) in mine]
    else:  # in the order dealt (units)
        steps = [u[1:] for u in mine if u[0] == "step"]
    cancelled = False
    held = lock if lock is not None else contextlib.nullcontext()
    try:
        if part is not None and mine and mine[0] == ("interpolants",):
            _check(cancel)  # this part's first unit: first
            with held:
                _warm_edited_interpolants(progress, cancel, textures)
            mine = mine[1:]
        for i, (mode, accel, ortho) in enumerate(steps):
            _check(cancel)
            message = f"warming kernels {i + 1}/{len(steps)}: {mode}, {accel}" + (
                ", orthographic" if ortho else "")
            log.info(message)
            if progress is not None:
                progress(message)
            settings = RenderSettings(mode=mode, accelerator=accel, samples=2, max_depth=3,
                                      epsilon=0.02, depth_cap=3)
            if ortho:
                settings.samples, settings.memory_cap_mb = 1, 0.01  # the LRU evicts
            with held:
                # without the orthographic steps (soft=False: make demo), the perspective
                # scene has their rough metal: its glossy rays' kernels (the strata, the
                # roulette, a convex ball's own-instance skip: the demo's rough spheres
                # call them) are in the cache the warm-up leaves (in a cold make demo the
                # demo's first frame still reaches them first: docs/first-render.md)
                rough = None if soft else True
                session = Session(warm_scene(ortho=ortho, textured=textures, rough=rough),
                                  settings)
                # cells wherever the rays need them: which kernels a frame reaches must not
                # depend on the measured fallback's timings (it traces where its allowance
                # is spent: a slow machine's warm-up would leave the predicate's cold)
                session.interpolants.auto_fallback = False
                _animate(session, ortho, cancel, textures, rough)
            _yield(lock)
        if ("interpolants",) in mine:
            _check(cancel)
            with held:
                _warm_edited_interpolants(progress, cancel, textures)
            _yield(lock)
        if ("ri_trees",) in mine:
            _check(cancel)
            with held:
                _warm_ri_trees(accelerators[:1], progress, cancel)
        if ("large_bvh",) in mine:
            _check(cancel)
            with held:
                _warm_large_bvh(progress, cancel)
        _check(cancel)
    except Cancelled:
        cancelled = True
        log.info("kernel warm-up cancelled")
    render_kernels()  # every kernel module imported: counted (and listed when unreached)
    result = kernel_cache.counts(since=since)
    unreached = [kernel_name(d) for d in render_kernels()
                 if not kernel_cache.cached_signatures(d)] if report_unreached else []
    result.update(seconds=time.perf_counter() - t0, modes=list(modes),
                  accelerators=list(accelerators), unreached=unreached, cancelled=cancelled)
    log.info("kernel cache warm in %.1f s: %d compiled, %d loaded, %d unreached",
             result["seconds"], result["compiled"], result["loaded"], len(unreached))
    return result


def kernel_name(d) -> str:
    return f"{d.py_func.__module__}.{d.py_func.__qualname__}"


def render_kernels() -> list:
    """Every render kernel with its own compiled code (kernels inlined into their callers
    and benchmark helpers left out), its module imported."""
    import importlib

    for name in ("accel.bvh", "accel.bvh_build", "accel.bvh_mesh", "accel.triangle",
                 "accel.accelerators", "tracing.whitted", "tracing.shader",
                 "tracing.shading", "tracing.light_records", "interpolants.render",
                 "interpolants.interpolant_cache",
                 "geometry.mesh_topology", "geometry.mesh_math", "geometry.cameras",
                 "ri_tree.render",
                 "ri_tree.tree_cache", "ri_tree.candidates", "ri_tree.sampling", "ri_tree.patches",
                 "ri_tree.surfaces",
                 "ri_tree.kdtree",
                 "ri_tree.thickness"):
        importlib.import_module(f"{__package__}.{name}")
    return [d for d in kernel_cache.dispatchers()
            if d.targetoptions.get("inline") != "always"
            and not d.py_func.__module__.startswith(NOT_RENDER_KERNELS)]


def cache_progress(kernels=None) -> tuple[int, int]:
    """(render kernels in memory or in the disk cache, render kernels)."""
    kernels = render_kernels() if kernels is None else kernels
    done = sum(1 for d in kernels if d.signatures or kernel_cache.cached_signatures(d))
    return done, len(kernels)


def warm_parallel(jobs: int | None = None, modes=None, accelerators=None, progress=None,
                  cancel=None, report_unreached: bool = True, poll_s: float = 1.0,
                  soft: bool = True, textures: bool = True) -> dict:
    """:func:`warm` in ``jobs`` processes (default: one per core) sharing this process's
    cache (``kernel_cache`` keeps concurrent writers safe), each warming its part of the
    units; this process waits and reports ``progress("kernels 57/180")`` whenever the
    number of render kernels in the cache grows (of all render kernels: a warm-up of some
    modes stops short of the total). It compiles nothing itself. Falls back to
    :func:`warm` here when no Python can be started. Returns :func:`warm`'s keys, the parts'
    ``compiled`` and ``loaded`` summed, plus ``jobs``."""
    import json
    import os
    import subprocess
    import tempfile

    t0 = time.perf_counter()
    modes = tuple(modes or _modes())
    accelerators = tuple(accelerators or _accelerators())
    # as many parts as units, or as heads where they serve (the BASE heads compile the BVH's
    # kernels: a warm-up of other accelerators has no use for a part that only does that)
    heads = len(part_heads(modes)) if "INTERPOLANT" in modes or "BVH" in accelerators else 0
    jobs = max(1, min(jobs or kernel_cache.usable_cores(),
                      max(len(units(modes, accelerators, soft)), heads)))
    exe = child_python.python()
    if exe is None:
        return dict(warm(modes, accelerators, progress, cancel, report_unreached, soft=soft,
                         textures=textures), jobs=1)
    env = child_python.environment()
    env["RSTRACE_WARM_PARENT"] = str(os.getpid())  # the parts end with this process
    # The parts write to files, not pipes: this process reads nothing until they end, and a
    # part whose warnings filled a pipe (64 KiB) would block on it forever.
    logs = [(tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")) for _ in range(jobs)]
    procs = [subprocess.Popen(
        [exe, "-m", f"{__package__}", "warm-cache", "--json", "--jobs", "1",
         "--part", f"{k}/{jobs}", "--modes", *modes, "--accelerators", *accelerators]
        + ([] if soft else ["--no-soft-light"]) + ([] if textures else ["--no-textures"]),
        env=env, stdin=subprocess.DEVNULL, stdout=logs[k][0], stderr=logs[k][1],
        text=True) for k in range(jobs)]
    kernels, shown, cancelled = render_kernels(), None, False
    outputs = {}
    try:
        while any(p.poll() is None for p in procs):
            if cancel is not None and cancel():
                cancelled = True
                for p in procs:
                    p.terminate()
                break
            done, total = cache_progress(kernels)
            if progress is not None and (done, total) != shown:
                shown = (done, total)
                progress(f"kernels {done}/{total} in the cache")
            time.sleep(poll_s)
    finally:
        for k, p in enumerate(procs):
            p.wait()
            for f in logs[k]:
                f.seek(0)
            outputs[k] = tuple(f.read() for f in logs[k])
            for f in logs[k]:
                f.close()
    result = dict(kernel_cache.counts(), compiled=0, loaded=0, compiled_kernels={})
    failed = []
    for k, p in enumerate(procs):
        out, err = outputs[k]
        try:
            part = json.loads(out)
        except ValueError:
            if not cancelled:
                failed.append(f"part {k}/{jobs} (rc {p.returncode}): {err[-400:]}")
            continue
        result["compiled"] += part["compiled"]
        result["loaded"] += part["loaded"]
        for name, sigs in part["compiled_kernels"].items():
            result["compiled_kernels"].setdefault(name, []).extend(sigs)
    if failed:
        raise RuntimeError("kernel warm-up failed in " + "; ".join(failed))
    done, total = cache_progress(kernels)
    if progress is not None and (done, total) != shown:
        progress(f"kernels {done}/{total} in the cache")
    unreached = [kernel_name(d) for d in kernels if not kernel_cache.cached_signatures(d)
                 ] if report_unreached else []
    result.update(seconds=time.perf_counter() - t0, modes=list(modes),
                  accelerators=list(accelerators), unreached=unreached, cancelled=cancelled,
                  jobs=jobs)
    log.info("kernel cache warm in %.1f s in %d processes: %d compiled, %d loaded",
             result["seconds"], jobs, result["compiled"], result["loaded"])
    return result
