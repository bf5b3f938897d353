"""Operators: ``rstrace.warm_cache`` (compile every kernel into the numba cache).

Farm workers and fresh installs run it once, from the command line::

    blender -b --python-expr "import bpy; bpy.ops.rstrace.warm_cache()"

or from *Render > Warm RSTrace Kernel Cache* in the top bar (also found by F3 search). It
blocks until done (minutes on a cold cache, a few seconds on a warm one) and reports how
many kernels it compiled and loaded.

Layer: imports ``runtime`` only.
"""

from __future__ import annotations

import logging

import bpy

from . import runtime

log = logging.getLogger(__name__)


class RSTRACE_OT_warm_cache(bpy.types.Operator):
    """Compile every RSTrace kernel into the kernel cache without rendering, so that later
    renders (and render-farm workers sharing the cache) start at once"""

    bl_idname = "rstrace.warm_cache"
    bl_label = "Warm RSTrace Kernel Cache"

    def execute(self, context):
        try:
            result = runtime.warm_cache()
        except Exception as exc:  # never let an exception escape into Blender
            log.exception("RSTrace: warming the kernel cache failed")
            self.report({"ERROR"}, f"RSTrace: warming the kernel cache failed: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"RSTrace: kernel cache {result['cache_dir']} warm in "
                              f"{result['seconds']:.1f} s ({result['compiled']} compiled, "
                              f"{result['loaded']} loaded)")
        return {"FINISHED"}


def _render_menu(self, context) -> None:
    """An entry in the top bar's Render menu, while RSTrace is the scene's engine."""
    if context.scene is not None and context.scene.render.engine == "RSTRACE":
        self.layout.separator()
        self.layout.operator(RSTRACE_OT_warm_cache.bl_idname, icon="FILE_REFRESH")


classes = (RSTRACE_OT_warm_cache,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_render.append(_render_menu)


def unregister() -> None:
    bpy.types.TOPBAR_MT_render.remove(_render_menu)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
