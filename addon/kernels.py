"""First use: compile (or load from numba's cache) the kernels in the background.

On a fresh install the first render compiles every kernel it touches, which takes a minute
or more on two cores. :func:`start_warmup` starts that work on a background thread as soon
as the add-on is enabled with RSTrace as a scene's engine, the engine is selected, or a
viewport starts: it renders a tiny built-in scene in the chosen mode only (BASE touches the
tracer's kernels; INTERPOLANT adds the interpolant kernels) through
``runtime.warm_cache`` (``rstrace_engine.warm_kernels.warm``, the same warm-up as the
``rstrace.warm_cache`` operator and ``python -m rstrace_engine warm-cache``, restricted to
that mode and the BVH), so the kernels are compiled (or loaded) once and a real render
afterwards only runs them. The kernels of the viewport's first (coarse) image come first
(``rstrace_engine.warm_first``: the BVH traversal compiles in a helper process, Blender's
Python, while this one compiles the rest); then the render lock is let go so a waiting
viewport shows its first image, and the rest is warmed a step at a time under the lock;
on a cold cache the rest first compiles in one process per core
(``rstrace_engine.warm_kernels.warm_parallel``) and is then loaded here. With every kernel
of the mode in the cache (the compiled kernels the extension ships, ``runtime``; a second
process) nothing is compiled and no tiny scene rendered: the thread only imports the
renderer and loads the mode's kernels from the cache (:data:`PRELOAD`, a first F12's
first: :func:`_preload`), without the render lock, so that a first F12 that comes later
does not pay them (about 1 s of CPU at 1M triangles, ``docs/bench-scale-bpy.md``) and one
that comes meanwhile runs what is loaded and loads the rest itself (numba loads each
kernel once, under its compiler lock).
:func:`progress_text` ("compiling kernels 12/40") is shown in the viewport and the status
bar; it counts the kernels of :data:`MODE_KERNELS` compiled in this process or in the disk
cache; the console shows the same progress (``RSTrace: kernels 57/173 in the cache``).

The thread never touches ``bpy``; :func:`stop` asks it to stop between kernels and joins it
(unregister).

Layer: imports ``runtime`` (and ``rstrace_engine``); imported by ``session``, ``viewport``
and the package ``__init__``.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time

from . import runtime

log = logging.getLogger(__name__)

#: The kernels a mode's frames call (each compiles the njit helpers it inlines): what a
#: viewport session of that mode runs on its first image, its first full frame and its
#: first edit. Listed as ``package.module.function`` under rstrace_engine (a test checks
#: that every name exists); the progress counts these.
_BASE = ("accel.content_hash._nh_blocks", "geometry.mesh_math._gather_corners",
         "accel.bvh_build.split_top",
         "accel.bvh_build.build_subtree",
         "accel.bvh_mesh.collapse4", "accel.bvh_collapse.collapse_tasks",
         "accel.bvh_collapse.collapse4_parallel", "accel.bvh.trace_kernel",
         "accel.bvh_occlusion.occluded_kernel",
         "geometry.cameras.generate_rays", "tracing.shader._surface_kernel",
         "tracing.shader._shadow_kernel", "tracing.shader._shade_kernel",
         "tracing.dielectric_albedo.dielectric_albedos",
         "tracing.whitted._light_masks", "tracing.batches.scatter_add",
         "tracing.batches.accumulate", "tracing.pixel_records._encode_nodes",
         "tracing.pixel_records._mark_rays", "tracing.pixel_records._query_secondary",
         "tracing.record_queries._query_tiles", "tracing.record_codes._secondary_rays",
         "tracing.record_codes._mark_used",
         "tracing.light_records._recombine_primary",
         "tracing.light_records._recombine_secondary",
         "tracing.light_reshade._one_light_states", "tracing.light_nodes.count_terms",
         "tracing.light_nodes.fill_terms", "tracing.light_nodes.replace_entries",
         "tracing.light_nodes.detach_terms", "tracing.light_nodes._splice_start",
         "tracing.light_nodes._splice_entries", "tracing.light_nodes._splice_geo",
         "tracing.pixel_records._light_bit_changes",
         "tracing.whitted._child_tags", "tracing.glossy_strata._pixel_seeds",
         "tracing.glossy_strata._lattices", "tracing.glossy_strata._next_paths",
         "tracing.shaft_skip._prove_groups", "tracing.shaft_skip._own_kernel",
         "tracing.shaft_skip._own_reflections", "tracing.glossy_rays._roulette",
         "tracing.sample_rays.query_light_bits", "tracing.sample_rays.query_world",
         "tracing.sample_proofs.drop_lights", "tracing.sample_proofs.drop_world",
         "geometry.mesh_math._proper_kernel", "geometry.mesh_math.flat_triangle_normals",
         "geometry.mesh_check._vertex_stats", "geometry.mesh_check._index_range",
         "geometry.mesh_check._non_finite32", "geometry.attributes._all_flat_vertex",
         "accel.bvh_mesh.direct_leaves", "accel.bvh_mesh.place_child", "accel.bvh_mesh.place_tri")
_INTERPOLANT = ("geometry.mesh_topology._edge_pass", "geometry.mesh_topology._is_convex",
                "interpolants.walk.group_active", "interpolants.interpolant_cache._pixel_lines",
                "interpolants.walk.settle", "interpolants.walk.walk_level",
                "interpolants.linetree._assign_roots", "interpolants.linetree._collapse_pass",
                "interpolants.linetree._free_subtrees", "interpolants.linetree._init_children",
                "interpolants.membership._valid", "interpolants.ray_segment_tree.live_tunnels",
                "interpolants.ray_segment_tree.query_list", "interpolants.pixel_sums._finish",
                "interpolants.pixel_sums._to_trace", "interpolants.samples._glossy_nodes",
                "interpolants.samples._far_lit_roots")
MODE_KERNELS = {"BASE": _BASE, "INTERPOLANT": _BASE + _INTERPOLANT}

#: What a warm process loads first, before the rest of :data:`MODE_KERNELS`: the kernels an
#: F12 runs in the order it runs them (the export's, a large mesh's BVH build -- the
#: parallel phases of ``accel.bvh_build``, run past ``PARALLEL_MIN`` triangles --, the
#: render with its soft-light seeds and secondary rays); measured as the kernels a first F12
#: of a 1M-triangle scene loaded at ray depth 0 and 5 (``tests/blender/test_kernels.py``
#: checks that a first F12 after the preload loads none). The rest of the mode's kernels
#: load after them, while no render runs.
PRELOAD = ("accel.content_hash._nh_blocks", "geometry.mesh_math._gather_corners",
           "geometry.mesh_check._vertex_stats",
           "geometry.mesh_check._index_range",
           "geometry.mesh_check._non_finite32", "geometry.attributes._all_flat_vertex",
           "geometry.mesh_math.flat_triangle_normals", "geometry.mesh_math._proper_kernel",
           "geometry.attributes._coarsest", "geometry.attributes._all_flat",
           "accel.bvh_mesh.indexed_boxes", "accel.bvh_cluster.pair_items",
           "accel.bvh_build.split_top",
           "accel.bvh_build.build_subtrees", "accel.bvh_build.build_subtree",
           "accel.bvh_cluster.item_leaves", "accel.bvh_cluster.open_items",
           "accel.bvh_mesh.collapse4", "accel.bvh_collapse.collapse_tasks",
           "accel.bvh_collapse.collapse4_parallel", "accel.bvh_mesh.direct_leaves",
           "accel.bvh_mesh.place_child", "accel.bvh_mesh.place_tri",
           "geometry.cameras.generate_rays", "accel.bvh.trace_kernel",
           "tracing.shader._surface_kernel", "tracing.whitted._light_masks",
           "tracing.soft_lights._sample_seeds", "tracing.shader._shadow_kernel",
           "accel.bvh_occlusion.occluded_kernel",
           "tracing.dielectric_albedo.dielectric_albedos", "tracing.shader._shade_kernel",
           "tracing.batches.scatter_add",
           "tracing.batches.accumulate", "tracing.record_codes._encode_nodes",
           "tracing.record_codes._mark_used", "tracing.whitted._child_tags",
           "tracing.soft_lights._node_seeds", "tracing.shaft_skip._own_kernel",
           "tracing.shaft_skip._own_reflections", "tracing.glossy_rays._roulette",
           "tracing.glossy_strata._pixel_seeds", "tracing.glossy_strata._lattices",
           "tracing.glossy_strata._next_paths")

_state = {"thread": None, "modes_done": set(), "mode": None, "stop": False,
          "started_at": None, "seconds": {}, "error": None}
_lock = threading.Lock()


def dispatchers(mode: str, names=None) -> list:
    """The numba dispatchers of :data:`MODE_KERNELS` for ``mode`` (or of ``names``; missing
    names skipped)."""
    found = []
    for name in names if names is not None else MODE_KERNELS.get(mode,
                                                                  MODE_KERNELS["INTERPOLANT"]):
        module, _, attr = name.rpartition(".")
        try:
            mod = importlib.import_module(f"rstrace_engine.{module}")
        except ImportError:
            continue
        d = getattr(mod, attr, None)
        if d is not None and hasattr(d, "signatures"):
            found.append(d)
    return found


def counts(mode: str = "BASE") -> tuple[int, int]:
    """(kernels compiled or loaded in this process or in the disk cache, kernels ``mode``
    uses): on a cold cache the warm-up compiles in other processes
    (``warm_kernels.warm_parallel``), whose kernels land in the cache."""
    from rstrace_engine import kernel_cache

    ds = dispatchers(mode)
    return sum(1 for d in ds if d.signatures or kernel_cache.cached_signatures(d)), len(ds)


def ready(mode: str = "BASE") -> bool:
    return mode in _state["modes_done"]


def progress_text() -> str | None:
    """"compiling kernels 12/40" while a warm-up runs; None when none is running."""
    t = _state["thread"]
    if t is None or not t.is_alive():
        return None
    done, total = counts(_state["mode"])
    if done >= total:
        return None  # all compiled: only loading and the tiny warm-up frames are left
    verb = "compiling" if runtime.kernel_status() and "compiling" in runtime.kernel_status() \
        else "loading"
    return f"{verb} kernels {done}/{total}"


def _warm(mode: str) -> None:
    """Compile (or load) every kernel ``mode`` uses, the viewport's first image's first
    (``rstrace_engine.warm_first.warm_viewport``: the traversal kernel in a helper process
    meanwhile; then ``rstrace_engine.warm_kernels.warm`` for that mode and the BVH, the
    farm's warm-up restricted to one mode, a step at a time under the render lock)."""
    stop = lambda: _state["stop"]  # noqa: E731
    if stop():
        return
    t0 = time.perf_counter()
    done, total = counts(mode)
    if done == total:
        # every kernel of the mode is in the disk cache (a second process, a shipped cache):
        # nothing to compile. The warm-up's tiny renders would hold the render lock while
        # the user's first render waits (measured: a second process's F12 took 3x as
        # long); loading the kernels, an F12's first, takes no lock.
        loaded = _preload(mode, stop)
        if not stop():
            _state["modes_done"].add(mode)
            _state["seconds"][mode] = time.perf_counter() - t0
            log.info("RSTrace: %s kernels all cached (%d): %d signatures loaded in %.2f s",
                     mode, total, loaded, time.perf_counter() - t0)
        return
    result = runtime.warm_viewport(mode, cancel=stop, progress=_console)
    if not result.get("cancelled") and not stop():
        _state["modes_done"].add(mode)
        _state["seconds"][mode] = result["seconds"]
        log.info("RSTrace: %s kernels ready in %.1f s (%d compiled, %d loaded)", mode,
                 result["seconds"], result["compiled"], result["loaded"])


def _preload(mode: str, stop) -> int:
    """Load the cached kernels of ``mode`` into memory, :data:`PRELOAD` first (the renderer's
    modules imported on the way), compiling and rendering nothing; ``stop()`` is asked
    between kernels. The kernels after :data:`PRELOAD` are loaded only while no render runs
    (once one holds the render lock the rest is left to load on first use: the CPU is the
    render's). Returns the signatures loaded."""
    import rstrace_engine.session  # noqa: F401  (what an F12 imports first)
    from rstrace_engine import kernel_cache

    first = dispatchers(mode, PRELOAD)
    loaded = 0
    seen: set = set()
    for i, d in enumerate(first + dispatchers(mode)):
        if stop():
            break
        if id(d) in seen:
            continue
        seen.add(id(d))
        if i >= len(first) and runtime.RENDER_LOCK.locked():
            break
        loaded += kernel_cache.load_cached(d, stop)
    return loaded


def _console(message: str) -> None:
    """The warm-up's progress on the console (``kernels 57/173`` as they land)."""
    if message != _state.get("last_message"):
        _state["last_message"] = message
        print(f"RSTrace: {message}", flush=True)  # noqa: T201


def _run(modes: list[str]) -> None:
    for mode in modes:
        if _state["stop"]:
            return
        _state["mode"] = mode
        try:
            _warm(mode)
        except Exception as exc:  # the real render will report it properly
            _state["error"] = f"{type(exc).__name__}: {exc}"
            log.exception("RSTrace kernel warm-up failed")
            return


def start_warmup(mode: str = "BASE") -> bool:
    """Start compiling/loading the kernels ``mode`` uses (BASE first), unless done or
    running. Returns True when a thread was started."""
    modes = ["BASE"] + (["INTERPOLANT"] if mode == "INTERPOLANT" else [])
    todo = [m for m in modes if m not in _state["modes_done"]]
    with _lock:
        t = _state["thread"]
        if not todo or (t is not None and t.is_alive()):
            return False
        _state["stop"] = False
        _state["started_at"] = time.perf_counter()
        t = threading.Thread(target=_run, args=(todo,), name="rstrace-kernels", daemon=True)
        _state["thread"] = t
        t.start()
    return True


def skip_warmup(modes=("BASE", "INTERPOLANT")) -> None:
    """No background warm-up for ``modes``: the caller warmed the cache itself (``make
    demo`` runs ``warm-cache`` for the kernels of its scene first); a render compiles or
    loads what it uses."""
    _state["modes_done"].update(modes)


def wait(timeout: float | None = None) -> bool:
    """Block until the warm-up thread is done; True when it is."""
    t = _state["thread"]
    if t is not None:
        t.join(timeout)
        return not t.is_alive()
    return True


def stop(timeout: float = 60.0) -> bool:
    """Ask the warm-up to stop (it finishes the kernel being compiled) and join it."""
    _state["stop"] = True
    return wait(timeout)
