"""The ``RenderEngine``: a dispatcher. Every method is one line into ``final`` (F12 and
animation: :class:`.session.FrameRenderer`) or ``viewport`` (:class:`.viewport.ViewportRenderer`).

Layer: imports ``session`` and ``viewport`` (and through them everything below); nothing
imports this but the package ``__init__`` and ``ui``.
"""

from __future__ import annotations

import bpy

from . import session, viewport


class RSTraceRenderEngine(bpy.types.RenderEngine):
    """RSTrace: interactive ray-traced scene editing (Whitted tracing, radiance
    interpolants, ray segment trees)."""

    bl_idname = "RSTRACE"
    bl_label = "RSTrace"
    # Material and light previews are declined: Blender shows no preview for this engine.
    bl_use_preview = False
    # Principled materials stay editable in the stock shader editor and panels.
    bl_use_shading_nodes_custom = False
    # Material Preview shading in the viewport uses EEVEE.
    bl_use_eevee_viewport = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.final = session.FrameRenderer(self)
        self.viewport = viewport.ViewportRenderer()

    def __del__(self):
        # Blender frees the engine (rendered shading left, file closed, engine switched):
        # the viewport's worker thread must not outlive it
        viewport.free(self)

    def render(self, depsgraph):
        self.final.render(depsgraph)

    def view_update(self, context, depsgraph):
        self.viewport.view_update(context, depsgraph)

    def view_draw(self, context, depsgraph):
        self.viewport.view_draw(self, context, depsgraph)

    def update_render_passes(self, scene=None, renderlayer=None):
        self.final.update_render_passes(scene, renderlayer)


classes = (RSTraceRenderEngine,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
