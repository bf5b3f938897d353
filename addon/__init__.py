"""RSTrace for Blender: the add-on / extension package (glue only).

The renderer is the ``rstrace_engine`` package (numpy + numba, no Blender imports); this
package turns Blender data into its calls and its frames back into render passes.

Module layers, lower never importing higher:
``runtime`` (numba set-up) < ``kernels`` (background compile) < ``properties`` <
``materials`` < ``meshes`` / ``lights`` / ``cameras`` / ``snapshot`` (per-datablock caches,
the snapshot of one walk) / ``journal`` (what the depsgraph said changed between renders)
< ``export`` < ``depsgraph_diff``
(depsgraph -> edits) < ``sync`` (the one path from Blender to a scene's core session) <
``session`` (per-scene state, F12) < ``viewport`` < ``engine`` < ``ui``; ``operators`` (the
kernel-cache warm-up) imports ``runtime`` only.

:func:`last_render_stats` (``session.last_render_stats``) gives a script the statistics of
a scene's last F12 / animation render.

``runtime.configure`` runs before anything imports ``rstrace_engine`` kernels, so numba
caches them in the extension's user directory. Used as a plain package (scripts, tests)::

    import addon
    addon.register()
"""

from . import runtime

runtime.configure(__package__)

from . import (  # noqa: E402  (after numba set-up)
    depsgraph_diff,
    engine,
    export,
    journal,
    kernels,
    operators,
    properties,
    session,
    sync,
    ui,
    viewport,
)
from .session import last_render_stats  # noqa: E402

__all__ = ["depsgraph_diff", "engine", "export", "journal", "kernels", "last_render_stats",
           "operators", "properties", "register", "runtime", "session", "sync", "ui", "unregister",
           "viewport"]

#: Registered in this order, unregistered in reverse.
_MODULES = (properties, journal, session, viewport, engine, operators, ui)


def register() -> None:
    for module in _MODULES:
        module.register()
    import bpy

    bpy.app.timers.register(_warm_if_selected, first_interval=0.5)


def _warm_if_selected():
    """After enabling: compile/load the kernels if a scene already renders with RSTrace."""
    import bpy

    scenes = getattr(bpy.data, "scenes", ())
    modes = {s.rstrace.mode for s in scenes if s.render.engine == "RSTRACE"}
    if modes:
        kernels.start_warmup("INTERPOLANT" if "INTERPOLANT" in modes else "BASE")
    return None


def unregister() -> None:
    import bpy

    if bpy.app.timers.is_registered(_warm_if_selected):
        bpy.app.timers.unregister(_warm_if_selected)
    kernels.stop()
    runtime.stop_host_compile()
    from rstrace_engine.interpolants import build_beside

    build_beside.stop()  # the cell build's background compile
    for module in reversed(_MODULES):
        module.unregister()
