"""First use: the viewport's first image as soon as its own kernels are ready.

A cold start (a fresh install, or a numba cache of other sources) compiles every kernel a
session touches. The viewport's first image is the base tracer's *coarse* frame
(:func:`~rstrace_engine.interactive.trace_view`, in every mode), which needs only
:data:`FIRST_IMAGE_KERNELS`: the BVH build, the camera rays, the BVH traversal (and the
hard shadow rays' occlusion kernel) and the tracer's surface, shadow and shade stages.
:func:`warm_viewport` compiles those first, then lets a waiting viewport render, then
compiles (or loads) the rest of the mode's kernels
through :func:`~rstrace_engine.warm_kernels.warm`, one step at a time under the render lock,
so the viewport's own frames interleave with it.

Two processes: the traversal kernel alone is about as long to compile as all the other
first-image kernels together (numba compiles one kernel at a time, on one core), so
:func:`first_image` starts a helper process (``sys.executable``, Blender's own Python in
the add-on) that compiles it (and the hard shadow rays' occlusion kernel) into the shared
numba cache (:mod:`.kernel_cache` makes that safe across processes) while this process
compiles the rest, then loads them. The helper's kernels are compiled from zero-length
calls whose argument types are exactly those of a render's (a test checks that a render
afterwards compiles no new signature), and this process compiles the tracer's stages
against a stand-in for the traversal (:class:`_FixedHits`), so neither waits for the
other. Without a helper (``processes=1``, or it cannot start) this process compiles
everything itself.
"""

from __future__ import annotations

import contextlib
import logging
import subprocess
import time
from types import SimpleNamespace

import numpy as np

from . import child_python, kernel_cache

log = logging.getLogger(__name__)

#: The kernels of the viewport's first (coarse) image, as ``module.function`` under
#: rstrace_engine; the traversal's (:data:`HELPER_KERNELS`) compile in the helper process.
FIRST_IMAGE_KERNELS = ("accel.bvh_build.split_top", "accel.bvh_build.build_subtree",
                       "accel.bvh_mesh.collapse4",
                       "accel.bvh_mesh.direct_leaves", "accel.bvh_mesh.place_child",
                       "accel.bvh_mesh.place_tri",
                       "geometry.cameras.generate_rays", "accel.bvh.trace_kernel",
                       "tracing.whitted._surface_kernel", "tracing.whitted._shadow_kernel",
                       "tracing.whitted._shade_kernel", "tracing.batches.scatter_add",
                       "tracing.batches.accumulate", "accel.content_hash._nh_blocks",
                       "tracing.dielectric_albedo.dielectric_albedos",
                       "accel.bvh_occlusion.occluded_kernel")
HELPER_KERNELS = ("accel.bvh.trace_kernel", "accel.bvh_occlusion.occluded_kernel")
_HELPER_CODE = "from rstrace_engine.warm_first import compile_traversal; compile_traversal()"


def compile_traversal() -> None:
    """Compile (or load) the BVH traversal kernels for the argument types of every query
    (closest and any hit, all rays or one instance; hard lights' shadow rays, the
    occlusion kernel), with zero rays: the helper's part."""
    from .accel import bvh
    from .accel.accelerators import BVHAccelerator

    f4, f8, i4 = np.float32, np.float64, np.int32
    sb = bvh.SceneBVH(np.zeros((0, 24), f8), np.zeros((0, 4), i4), np.zeros(0, i4),
                      np.zeros((0, 24), f4), np.zeros((0, 4), i4), np.zeros((0, 3), f8),
                      np.zeros((0, 3), i4), np.zeros(0, i4), np.zeros(0, i4),
                      np.zeros(0, i4), np.zeros((0, 4, 4), f8))
    acc = BVHAccelerator.__new__(BVHAccelerator)  # no scene: only its query path is used
    acc.stats, acc.sb = {}, sb
    none = np.zeros((0, 3))
    acc.closest_hit(none, none, 0.0, np.inf)
    acc.any_hit(none, none, np.zeros(0), np.full(0, np.inf))
    acc.occluded(none, none, np.zeros(0))


def part_head(k: int, n: int, modes=("INTERPOLANT",)) -> list[str]:
    """Compile (or load) part ``k`` of ``n``'s :func:`part_heads` (none when ``n`` is 1).
    Returns the names done."""
    from .warm_kernels import part_heads, warm_scene

    heads = part_heads(modes)
    if n < 2 or k >= len(heads):
        return []
    scene = warm_scene()
    steps = {"tracer": lambda: _compile_tracer(scene, build=False),
             "traversal": compile_traversal, "predicate": lambda: compile_predicate(scene),
             "build": lambda: compile_build(scene)}
    done = []
    for name in heads[k]:
        steps[name]()
        done.append(name)
    return done


def _no_bvh(lo, hi, max_leaf):
    """:func:`.interpolants.shafts.binary_bvh`'s arrays (types) for no cells: no BVH built,
    so that the predicate's chain does not wait for the BVH build's compile."""
    return (np.zeros((0, 12)), np.zeros((0, 2), np.int32),
            np.arange(len(lo), dtype=np.int32))


def compile_predicate(scene) -> None:
    """Compile (or load) the error predicate's chain (``predicate._check_cells`` and its
    callees, the longest single compile of the demo: ~80 s of CPU in one process) for
    ``scene``'s interpolants, with no cells: the argument types of
    ``InterpolantCache._build``'s call. Its query structures (``shafts.query_scene``) have
    ``scene``'s mesh topology and no BVHs (:func:`_no_bvh`). Without it the
    chain was reached only after the interpolants' own kernels (a render's cells, samples,
    walks), and a ``make demo`` waited for it with one core idle (docs/first-render.md,
    session 34)."""
    from .geometry.mesh_topology import mesh_topology_cached
    from .interpolants.linetree import expanded_boxes
    from .interpolants.predicate import N_TEST_ALL, check_cells
    from .interpolants.sampled_term import per_pixel_query
    from .interpolants.samples import SampleStore
    from .interpolants.shafts import query_scene

    sa = scene.arrays()
    qs = per_pixel_query(query_scene(sa, mesh_topology_cached(sa), _no_bvh), sa)
    i4, i8, f8 = np.int32, np.int64, np.float64
    check_cells(qs, expanded_boxes(sa, float(sa.scene_extent)),
                SampleStore(len(sa.light_kind)).view(), np.zeros(0, i4), np.zeros(0, np.int8),
                np.zeros(0, i8), np.zeros((0, 4), i8), np.zeros((0, 16 + N_TEST_ALL), i4),
                np.zeros(0, i4), np.zeros(0, i4), np.zeros(0, np.int8), np.zeros(0, f8),
                np.zeros(0, f8), np.zeros(0, i4))


def compile_cell_build() -> None:
    """What :mod:`.interpolants.build_beside`'s background process runs: the error
    predicate's chain (:func:`compile_predicate`), then interpolants built, walked and
    edited for real (``warm_kernels._warm_edited_interpolants``: cells built and checked, a
    camera step that splats and reprojects them, an object edit, an added light), so that
    the first frame with cells after it only loads its kernels (with the chain alone it
    still compiled 53 signatures, 15.8 s of CPU: the walk, the linetrees, the ray segment
    trees, the samples, reprojection; docs/first-render.md, session 44 (review))."""
    from .warm_kernels import _warm_edited_interpolants, warm_scene

    compile_predicate(warm_scene())
    _warm_edited_interpolants()


def compile_build(scene) -> None:
    """Compile (or load) the BVH build's kernels: build ``scene``'s BVH."""
    from .accel.accelerators import create_accelerator

    create_accelerator("BVH", scene.arrays())


class _FixedHits:
    """Stands in for the BVH while its traversal compiles elsewhere: every ray hits the
    first triangle of instance 0 at ``t = 1`` and nothing occludes a shadow ray. The hits
    have the types of the BVH's (:func:`~.accel.accelerators.empty_hits`), so the tracer's
    kernels compile exactly the signatures a render uses."""

    name = "fixed"

    def __init__(self, sa) -> None:
        self.sa = sa
        self.tri = int(sa.mesh_tri_start[sa.inst_mesh[0]])

    @contextlib.contextmanager
    def cancellable(self, cancel):
        yield self

    def closest_hit(self, origins, directions, tmin, tmax, skip=None):
        from .accel.accelerators import check_rays, empty_hits

        o, _, _, _ = check_rays(origins, directions, tmin, tmax)
        h = empty_hits(len(o))
        h.t[:], h.inst[:], h.prim[:], h.u[:], h.v[:] = 1.0, 0, self.tri, 0.25, 0.25
        return h

    def any_hit(self, origins, directions, tmin, tmax, skip=None):
        from .accel.accelerators import check_rays

        return np.zeros(len(check_rays(origins, directions, tmin, tmax)[0]), bool)


def _compile_tracer(scene, cancel=None, build: bool = True) -> None:
    """This process's part: the BVH build (a real one, of ``scene``; not with
    ``build=False``: :func:`compile_build` elsewhere), the camera rays and the tracer's
    stages of a coarse view image (against :class:`_FixedHits`); ``cancel()`` is polled
    between the two (and between the tracer's stages)."""
    from .accel.accelerators import create_accelerator
    from .frame import RenderSettings
    from .interactive import trace_view

    sa = scene.arrays()
    if build:
        create_accelerator("BVH", sa)
    if cancel is not None and cancel():
        return
    stand_in = SimpleNamespace(scene=scene, accel=_FixedHits(sa))
    trace_view(stand_in, scene.camera, RenderSettings(max_depth=2), cancel=cancel)


def _kernel(name: str):
    import importlib

    module, _, attr = name.rpartition(".")
    return getattr(importlib.import_module(f"{__package__}.{module}"), attr)


def first_image_cached() -> bool:
    """True when every kernel of the first image is in memory or in the disk cache (a
    viewport then loads them as fast as a warm-up would: no need to go first)."""
    return all(_kernel(k).signatures or kernel_cache.cached_signatures(_kernel(k))
               for k in FIRST_IMAGE_KERNELS)


def _helper_needed() -> bool:
    """True when a traversal kernel is neither in memory nor in the disk cache."""
    return not all(_kernel(k).signatures or kernel_cache.cached_signatures(_kernel(k))
                   for k in HELPER_KERNELS)


def start_helper() -> subprocess.Popen | None:
    """Start the helper process compiling :data:`HELPER_KERNELS` into this process's numba
    cache (None when no Python interpreter can be started)."""
    return child_python.start(_HELPER_CODE)


def _wait_helper(helper, cancel) -> bool:
    """Wait for the helper; True when it compiled its kernels. Cancel: stop it."""
    while helper.poll() is None:
        if cancel is not None and cancel():
            helper.terminate()
            helper.wait()
            return False
        time.sleep(0.05)
    if helper.returncode != 0:
        err = helper.stderr.read().decode(errors="replace")[-400:] if helper.stderr else ""
        log.warning("kernel warm-up helper failed (rc %s): %s", helper.returncode, err)
        return False
    return True


def first_image(processes: int = 2, cancel=None) -> dict:
    """Compile (or load) :data:`FIRST_IMAGE_KERNELS`, the traversal in a helper process when
    ``processes`` > 1 and it is not cached; then render a tiny coarse view for real.

    Returns ``seconds``, ``helper`` (whether a helper compiled the traversal) and
    ``cancelled``.
    """
    from .interactive import coarse_camera, trace_view
    from .session import Session
    from .warm_kernels import warm_scene

    t0 = time.perf_counter()
    helper = start_helper() if processes > 1 and _helper_needed() else None
    scene = warm_scene()
    try:
        _compile_tracer(scene, cancel)
        t_own = time.perf_counter() - t0
    finally:
        ok = helper is not None and _wait_helper(helper, cancel)
        if helper is not None and helper.stderr:
            helper.stderr.close()
    t_helper = time.perf_counter() - t0
    cancelled = cancel is not None and cancel()
    if not cancelled:  # the real thing: loads the traversal the helper cached
        session = Session(scene)
        trace_view(session, coarse_camera(scene.camera, 4), session.settings, cancel=cancel)
    seconds = time.perf_counter() - t0
    log.info("first image's kernels in %.1f s (this process's part %.1f s, the helper's "
             "%s)", seconds, t_own, f"{t_helper:.1f} s" if helper is not None else "none")
    return dict(seconds=seconds, helper=bool(ok), cancelled=bool(cancelled), own_s=t_own,
                helper_s=t_helper if helper is not None else None)


def warm_viewport(mode: str = "BASE", lock=None, cancel=None, progress=None,
                  processes: int = 2, on_first_image=None) -> dict:
    """The warm-up a viewport waits on: :func:`first_image` under ``lock`` (unless its
    kernels are all cached already), then a pause
    without it (a viewport waiting for the lock renders its first image), then the rest of
    ``mode``'s kernels (:func:`~.warm_kernels.warm` for that mode and the BVH), one step at a
    time under ``lock``. ``on_first_image()`` is called between the two. On a cold cache
    (the first image's kernels were not cached) and with ``processes`` > 1, the rest is
    first compiled by :func:`~.warm_kernels.warm_parallel`, one process per core (none of
    them holds the lock; this one then only loads). Returns
    :func:`~.warm_kernels.warm`'s counts plus ``first_image_s``."""
    from .warm_kernels import warm

    lock = lock if lock is not None else contextlib.nullcontext()
    t0 = time.perf_counter()
    cold = not first_image_cached()
    if not cold:
        first = dict(seconds=0.0, helper=False, cancelled=False)
    else:
        if progress is not None:
            progress("compiling the first image's kernels")
        with lock:
            first = first_image(processes, cancel)
    if first["cancelled"]:
        return dict(kernel_cache.counts(), cancelled=True, first_image_s=first["seconds"],
                    seconds=time.perf_counter() - t0)
    if on_first_image is not None:
        on_first_image()
    time.sleep(0.05)  # a viewport waiting on the lock takes it now
    if cold and processes > 1:  # the rest compiles in other processes, then loads here
        from .warm_kernels import warm_parallel

        warm_parallel(max(processes, kernel_cache.usable_cores()), modes=(mode,),
                      accelerators=("BVH",), progress=progress, cancel=cancel,
                      report_unreached=False)
    result = warm(modes=(mode,), accelerators=("BVH",), progress=progress, cancel=cancel,
                  report_unreached=False, lock=lock)
    result.update(first_image_s=first["seconds"], helper=first["helper"],
                  seconds=time.perf_counter() - t0)
    return result
