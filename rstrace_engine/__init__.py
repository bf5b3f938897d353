"""rstrace_engine: the core of rstrace, an interactive ray tracer (no Blender imports).

Subpackages, in import order (a module imports only from its own layer or lower ones):

1. ``tolerances``, ``errors`` (:class:`~.errors.SceneError`), ``frame`` (settings and the
   structures' limits on them, modes, pixel classes), ``image``, ``cancel`` (a cancel flag
   the kernels poll): shared leaves;
   ``kernel_cache`` (numba's disk cache made safe to share between processes, counted),
   ``shipped_kernels`` (the portable build that ships in the extension, seeding the cache),
   ``numba_inline`` (numba's inliner without its per-block copies), ``numba_overloads_cached``
   (numba's own ``np.empty`` & co cached on disk too),
   ``views`` (a parallel kernel's loop reads only the struct fields it needs), ``heap``
   (glibc's heap kept between a frame's batches), ``stripes`` (parallel loops as threads
   over serial ``nogil`` kernels), ``linalg`` (small inverses without waking OpenBLAS's
   idle threads), ``child_python`` (a Python process sharing this one's kernel cache).
2. ``geometry``: the scene model, cameras, shapes, mesh topology.
3. ``accel``: the batch ray-query interface and its accelerators (BVH, Embree, brute force,
   visibility field).
4. ``tracing``: shading and the wavefront Whitted base tracer.
5. ``interpolants``: radiance interpolants (linetrees, samples, predicate, shafts, cache,
   interpolated frames); ``ri_tree``: the RI-tree mode (on the linetrees' face pairs);
   ``interactive``: the viewport's progressive tracing.
6. ``session``: the persistent render session a host (the Blender add-on) holds per scene.
7. ``scenes`` (benchmark scenes), ``warm_kernels`` (compile every kernel, render nothing),
   ``warm_first`` (the viewport's first image's kernels first, in two processes),
   ``bench``, ``__main__``: tools on top.

``tests/test_imports.py`` checks this order, and that no import (deferred ones included)
closes a circle.
"""

__version__ = "0.1.0"

import os  # noqa: E402

# numba's OpenMP threading layer (libgomp, which reads this when numba first loads it) spins
# its idle threads between parallel regions: on a machine whose cores are busy (Blender's own
# threads beside ours, other processes) the spinning threads take the cores from the working
# ones, and a frame of a few dozen regions took 2-3x its time (docs/bench-frame.md,
# "Where the rough frame's time and error go"). Passive waiting puts them to sleep; the
# images are the same bit for bit. A value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from . import kernel_cache  # noqa: E402  (before any kernel is compiled: shared-cache lock)

kernel_cache.install()

from . import numba_overloads_cached  # noqa: E402

numba_overloads_cached.install()  # numba's np.empty & co cached on disk as our kernels are
