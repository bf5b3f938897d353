"""What the meshes of a scene cost in memory, checked from their counts before anything is
allocated: a mesh too large for the memory available is refused with a message that names
it, instead of the host running out of memory half way through a build.

Per unique triangle (a mesh's, however many objects use it) rstrace holds the packed scene
arrays and the BVH: about 75 bytes on a smooth closed mesh (``bench scale``,
docs/bench-scale.md: 30 + 45), up to about 145 where its normals and uvs vary per corner
(:mod:`.attributes`); a BVH build needs about 190 bytes more while it runs (primitive
boxes, the binary tree and its working arrays), and the host's per-corner arrays are held
while the mesh is validated: the peak is what is checked.

The scene's meshes also hold at most :data:`MAX_TRIANGLES` triangles in all, whatever the
memory (:func:`check_count`): the BVH's leaf codes hold a triangle id in 28 bits.
"""

from __future__ import annotations

import os

from .elements import SceneError

#: Peak bytes per unique triangle (held, plus the build's working arrays).
BYTES_PER_TRIANGLE = 600
#: Bytes per vertex (the validated mesh and the packed copy, float64 xyz each).
BYTES_PER_VERTEX = 48
#: Most triangles the scene's meshes may hold in all (each mesh's once, however many
#: objects use it): a BVH leaf code is ``~(start << 3 | kind)`` in an int32, its ``start``
#: a global triangle id or a row of the leaves' triangle list (:mod:`..accel.bvh`), so
#: both stay below 2^28 (the paired build's int32 item starts, 2^31, are then safe too).
MAX_TRIANGLES = (1 << 28) - 1


def available_memory() -> int | None:
    """Bytes of memory available to this process now (Linux: ``MemAvailable``; else the
    free physical pages where the system reports them), or None when unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def estimate(triangles: int, vertices: int) -> int:
    """Peak bytes for a mesh of these counts."""
    return triangles * BYTES_PER_TRIANGLE + vertices * BYTES_PER_VERTEX


def _gib(b: float) -> str:
    return f"{b / 2 ** 30:.2f} GiB" if b >= 2 ** 30 else f"{b / 2 ** 20:.1f} MiB"


def check_fits(name: str, triangles: int, vertices: int, others: int,
               limit: int | None) -> None:
    """Raise :class:`SceneError` naming mesh ``name`` when it (``triangles``,
    ``vertices``), with the ``others`` bytes the scene's other meshes already need, would
    need more than ``limit`` bytes (None: :func:`available_memory`, nothing checked when
    that is unknown)."""
    if limit is None:
        limit = available_memory()
        if limit is None:
            return
        limit += others  # what the other meshes hold is already taken from "available"
    need = estimate(triangles, vertices)
    if need + others > limit:
        raise SceneError(
            f"mesh '{name}': {triangles:,} triangles need about {_gib(need)} to render"
            + (f" (with the scene's other meshes {_gib(need + others)})" if others else "")
            + f", more than the {_gib(limit)} of memory available: decimate it, lower its "
            f"subdivision level, or render it in parts")


def check_count(name: str, triangles: int, others: int) -> None:
    """Raise :class:`SceneError` naming mesh ``name`` when its ``triangles``, with the
    ``others`` the scene's other meshes hold, are more than :data:`MAX_TRIANGLES` (read
    when called)."""
    if triangles + others > MAX_TRIANGLES:
        raise SceneError(
            f"mesh '{name}': {triangles:,} triangles"
            + (f" (with the scene's other meshes {triangles + others:,})" if others else "")
            + f" are more than the {MAX_TRIANGLES:,} a scene can hold (the BVH's 28-bit "
            f"triangle ids): decimate it, lower its subdivision level, or render it in parts")
