"""The ``RenderEngine``: a dispatcher. Every method is one line into a session object.

Layer: imports ``session`` (and through it everything below); nothing imports this but the
package ``__init__`` and ``ui``.
"""

from __future__ import annotations

import bpy

from . import session


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
        self.session = session.FrameRenderer(self)

    def render(self, depsgraph):
        self.session.render(depsgraph)

    def update_render_passes(self, scene=None, renderlayer=None):
        self.session.update_render_passes(scene, renderlayer)


classes = (RSTraceRenderEngine,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
