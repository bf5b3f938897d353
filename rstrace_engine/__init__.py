"""rstrace_engine: the core of rstrace, an interactive ray tracer (no Blender imports).

Subpackages, in import order (a module imports only from its own layer or lower ones):

1. ``tolerances``, ``frame`` (settings, modes, pixel classes), ``image``, ``cancel`` (a
   cancel flag the kernels poll): shared leaves;
   ``kernel_cache`` (numba's disk cache made safe to share between processes, counted).
2. ``geometry``: the scene model, cameras, shapes, mesh topology.
3. ``accel``: the batch ray-query interface and its accelerators (BVH, Embree, brute force).
4. ``tracing``: shading and the wavefront Whitted base tracer.
5. ``interpolants``: radiance interpolants (linetrees, samples, predicate, shafts, cache,
   interpolated frames).
6. ``session``: the persistent render session a host (the Blender add-on) holds per scene.
7. ``scenes`` (benchmark scenes), ``warm_cache`` (compile every kernel, render nothing),
   ``warm_first`` (the viewport's first image's kernels first, in two processes),
   ``bench``, ``__main__``: tools on top.
"""

__version__ = "0.1.0"

from . import kernel_cache  # noqa: E402  (before any kernel is compiled: shared-cache lock)

kernel_cache.install()
