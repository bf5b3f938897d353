"""What Blender said changed between renders: the add-on's record of ``depsgraph.updates``,
so that an F12 or animation frame (whose fresh render depsgraph says nothing) re-reads only
the meshes that may have changed (used by :mod:`.export`'s reader).

A ``depsgraph_update_post`` handler (registered with the add-on) numbers every batch of
updates and records, per ``session_uid``, the batch that last touched an object's geometry
or a data-block (mesh, shape keys, curve, ...): :attr:`Journal.changed`. A mesh read from
Blender is stamped with the journal's number at the time (:meth:`Journal.stamp`); at the
next render its cache entry is taken as it is, without reading or fingerprinting the mesh,
when :meth:`Journal.unchanged` says so, which relies on exactly this:

1. every change of a mesh's data, and of whatever an object's modifiers read, reaches
   Blender's depsgraph as an update of the object (geometry flag) or of its data-block
   (checked in bpy for edit-mode edits, operators, RNA property sets and ``foreach_set``,
   which Blender 5.0 tags itself, and shape keys; ``tests/blender/test_journal.py``), and the
   render operator flushes those updates through ``depsgraph_update_post`` before it
   renders (checked for ``bpy.ops.render.render``); a render's reads are stamped with the
   number at ``render_pre``, before Blender builds its render depsgraph (an edit made while
   it renders is newer than what it read);
2. the handler has seen every batch since the entry was read: it is registered, and no
   file load, undo or redo came between (they may replace data without updates that name
   it: :meth:`gap`), and the updates came from the depsgraph of the scene and view layer
   being rendered (a batch from another view layer is a gap: that layer's depsgraph may
   hold edits not yet reported);
3. the mesh does not depend on the frame: an unmodified mesh object without shape keys or
   animation data is the same at every frame; one with modifiers (or made by an instancer)
   is trusted only at the frame it was read at, and only when no node group, image or
   texture (which modifiers may read) changed since;
4. its vertex count is still the one read (a last, free check).

Whenever one of these fails, the reader falls back to the exact check it always had: the
raw-attribute fingerprint (:func:`.meshes.mesh_fingerprint`), then a full read.

Layer: imported by ``export``; registered by the add-on's ``__init__``; no other add-on
module.
"""

from __future__ import annotations

from collections.abc import Hashable

#: ID types whose updates never change a mesh's contents (a material, a light or a camera
#: has its own path; a Scene or Collection update changes the set of instances, which every
#: render walks anyway).
_NO_GEOMETRY = {"Scene", "Collection", "Material", "Light", "Camera", "World",
                "WindowManager", "Screen", "WorkSpace", "Brush", "Palette", "Text", "Sound",
                "Library", "Workspace", "PaintCurve", "Mask", "MovieClip", "Speaker",
                "Action"}
#: ID types whose change may reach any modifier's result (geometry nodes, displacement).
_MODIFIER_INPUTS = {"Image", "Texture"}


class Journal:
    """The numbered record of depsgraph updates (see the module docstring)."""

    def __init__(self) -> None:
        self.seq = 0  # the number of the last batch (or gap)
        self.trusted_from = 1  # entries stamped before this are not trusted (a gap since)
        self.changed: dict[Hashable, int] = {}  # session_uid -> last batch touching it
        self.modifier_inputs = 0  # last batch changing a node group, image or texture
        self.view: tuple | None = None  # (scene uid, view layer name) of the last batch
        self.listening = False  # the handler is registered
        #: the number when the last render started (``render_pre``, before Blender builds
        #: its render depsgraph): an edit made after it may be missing from what that
        #: render reads, so its reads are stamped no later than this
        self.render_started: int | None = None

    # -- recording -------------------------------------------------------------------------

    def gap(self) -> None:
        """Something may have changed unseen (a file load, undo, redo, the handler off):
        nothing read before now is trusted."""
        self.seq += 1
        self.trusted_from = self.seq
        self.changed.clear()

    def note(self, depsgraph) -> None:
        """Record one batch of ``depsgraph.updates`` (a viewport depsgraph's; a render
        depsgraph's updates say nothing and are not recorded)."""
        if getattr(depsgraph, "mode", "VIEWPORT") != "VIEWPORT":
            return
        view = (depsgraph.scene.original.session_uid, depsgraph.view_layer.name)
        if view != self.view:
            self.gap()  # (another layer's depsgraph: what was not reported meanwhile)
            self.view = view
        self.seq += 1
        seq = self.seq
        for u in depsgraph.updates:
            idb = u.id
            kind = type(idb).__name__
            if kind in _NO_GEOMETRY or getattr(idb, "is_embedded_data", False):
                continue
            if kind == "Object":
                if u.is_updated_geometry:
                    self.changed[idb.original.session_uid] = seq
            elif kind in _MODIFIER_INPUTS or kind.endswith("NodeTree"):
                self.modifier_inputs = seq
            elif u.is_updated_geometry:  # mesh, shape keys, curve, ... (as the viewport's
                # dirty_from_updates: a material's users come with the shading flag only)
                self.changed[idb.original.session_uid] = seq

    # -- asking ----------------------------------------------------------------------------

    def stamp(self) -> int:
        """The number a read made now is stamped with (during a render: when it started)."""
        started = self.render_started
        return self.seq if started is None else min(started, self.seq)

    def trusted(self, stamp: int, frame, view: tuple, static: bool, frame_now) -> bool:
        """True when the journal saw everything a mesh read at ``stamp`` (at ``frame``)
        depends on since: see the module docstring. ``static``: it does not depend on the
        frame (an unmodified mesh without shape keys or animation); ``view``: (scene uid,
        view layer name) of the render."""
        if not self.listening or stamp < self.trusted_from or view != self.view:
            return False
        return static or (frame == frame_now and self.modifier_inputs <= stamp)

    def touched(self, stamp: int, uids) -> bool:
        """Whether an update since ``stamp`` named one of ``uids`` (the object, its data,
        the instancer making it): the mesh is read again (a fingerprint would only say
        so after reading the same arrays)."""
        return any(self.changed.get(u, -1) > stamp for u in uids)


JOURNAL = Journal()


def _on_update(_scene, depsgraph) -> None:
    JOURNAL.note(depsgraph)


def _on_gap(*_args) -> None:
    JOURNAL.gap()


def _on_render_pre(*_args) -> None:
    JOURNAL.render_started = JOURNAL.seq


def _on_render_end(*_args) -> None:
    JOURNAL.render_started = None


def _on_load_post(*_args) -> None:
    """A file loaded: a gap, and the window's view layer is the one the updates will come
    from (a first evaluation reports nothing)."""
    JOURNAL.gap()
    JOURNAL.view = context_view()


def context_view() -> tuple | None:
    """(scene uid, view layer name) of ``bpy.context``; None off the main thread or
    without a window's scene."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    import bpy

    scene = getattr(bpy.context, "scene", None)
    layer = getattr(bpy.context, "view_layer", None)
    if scene is None or layer is None:
        return None
    return (scene.session_uid, layer.name)


_HANDLERS = (_on_update, _on_gap, _on_load_post, _on_render_pre, _on_render_end)


def _lists():
    import bpy

    h = bpy.app.handlers
    return ((h.depsgraph_update_post, _on_update), (h.load_pre, _on_gap),
            (h.load_post, _on_load_post), (h.undo_post, _on_gap), (h.redo_post, _on_gap),
            (h.render_pre, _on_render_pre), (h.render_post, _on_render_end),
            (h.render_cancel, _on_render_end))


def register() -> None:
    import bpy

    h = bpy.app.handlers
    for fn in _HANDLERS:
        h.persistent(fn)  # (marks it: kept across file loads)
    JOURNAL.gap()
    JOURNAL.view = context_view()
    for handlers, fn in _lists():
        if fn not in handlers:
            handlers.append(fn)
    JOURNAL.listening = True


def unregister() -> None:
    for handlers, fn in _lists():
        if fn in handlers:
            handlers.remove(fn)
    JOURNAL.listening = False
    JOURNAL.gap()


def listening() -> bool:
    """The handler is registered (a script may have cleared the handler lists)."""
    if not JOURNAL.listening:
        return False
    import bpy

    if _on_update not in bpy.app.handlers.depsgraph_update_post:
        JOURNAL.listening = False
        JOURNAL.gap()
        return False
    return True
