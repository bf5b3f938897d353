"""The one sync path from Blender to a scene's core session, for F12, animation frames and
the viewport alike: :func:`sync`.

One edit (an object moved), for F12 and for the viewport:
1. F12 / animation: ``FrameRenderer.render`` with the render depsgraph; viewport:
   ``view_update`` with ``depsgraph.updates``. Both call :func:`sync`, under ``state.lock``:
2. ``SceneMirror.dirty`` -> what the updates name (viewport; F12 walks everything) ->
   ``SceneMirror.read`` -> an ``export.Snapshot`` (re-reading only what changed; an F12,
   whose render depsgraph's updates say nothing, asks :mod:`.journal` -- the record of the
   viewport's updates since each mesh was read -- and checks by fingerprint only the meshes
   it cannot vouch for); Esc (``cancel``) stops it between meshes;
3. ``SceneMirror.diff`` -> ``[ObjectTransform]`` against the mirror (which has no camera);
4. ``session.submit(edits)`` (or a new ``Session`` from the snapshot, built for F12 on a
   thread of its own, :func:`build`, which Esc abandons); ``SceneMirror.commit``.
5. F12, under ``RENDER_LOCK``: ``session.apply()``, ``session.render(camera=scene camera)``.
   Viewport: ``worker.submit(session=...)``; the worker: ``session.apply()``, a coarse image,
   ``session.render(camera=view camera)``.
6. Core: ``apply_edits`` -> ``EditEffects`` -> accelerator, interpolants, RI-trees, dirty
   pixels; ``render`` adds a ``CameraChange`` when its camera differs (``same_camera``).
7. A queued batch that fails marks the session ``failed``; the next sync starts afresh.

Threads: ``state.lock`` guards the mirror and ``state.session`` (the viewport syncs on the
main thread, F12 on its render thread); :func:`sync` runs no kernels, except building a new
F12 session, for which the caller holds ``runtime.RENDER_LOCK`` (taken before
``state.lock``, never after).

A cancelled sync (:class:`export.Cancelled`) commits nothing: the session and the mirror
are as they were (the export cache keeps what it read, which is what Blender holds).

Layer: imports ``export`` and ``depsgraph_diff``; imported by ``session`` and ``viewport``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from . import export
from .depsgraph_diff import existing_objects


@dataclass
class SyncOutcome:
    """What one :func:`sync` did."""

    session: object  # the scene's rstrace_engine Session, holding the edits (queued)
    snapshot: export.Snapshot | None  # None: the updates changed nothing, nothing was read
    edits: int = 0  # edits queued (a new session: what the diff from nothing gave)
    new_session: bool = False
    seconds: float = 0.0  # reading and diffing
    stats: dict = field(default_factory=dict)  # the snapshot's and the diff's


def sync(state, depsgraph, source: str, settings, camera_object=None,
         updates: bool = False, cancel=None, progress=None, lock=None) -> SyncOutcome:
    """Bring ``state.session`` up to date with ``depsgraph``; see the module docstring.

    state : the scene's ``session.SceneState`` (``session``, ``mirror``, ``lock``)
    source : ``"RENDER"`` (F12, animation: the render depsgraph, through ``camera_object``
        or the scene's camera) or ``"VIEWPORT"`` (no camera: the view's comes per render)
    settings : the ``RenderSettings`` of a new session (an F12 session is built at once;
        a viewport one on the worker, by its first ``apply``)
    updates : read only what ``depsgraph.updates`` name (``view_update``); else walk the
        whole depsgraph
    cancel : () -> bool (F12: ``engine.test_break``), asked before each mesh read and every
        0.1 s while a new F12 session builds; True raises :class:`export.Cancelled`
    progress : (message) -> None, told what is being read or built (the status line)
    lock : the :class:`HeldLock` of ``runtime.RENDER_LOCK`` an F12 holds, handed to a
        build cancelled before it finished (which releases it once done)

    Raises :class:`SceneError` (a broken camera, nothing to render) or
    :class:`export.Cancelled`; a live session and its mirror are then as they were.
    """
    from rstrace_engine.accel.accelerators import KEPT
    from rstrace_engine.session import Session

    with state.lock:
        session = state.session
        if session is not None and session.failed is not None:
            session = None  # (the mirror counts edits it never applied)
        if session is None:
            drop_session(state)
        mirror = state.mirror
        t0 = time.perf_counter()
        dirty = None
        if updates and session is not None:
            dirty = mirror.dirty(depsgraph)
            if dirty is None:
                return SyncOutcome(session, None)
        snap = mirror.read(depsgraph, dirty, source, camera_object=camera_object,
                           with_camera=source == "RENDER", cancel=cancel, progress=progress)
        diff = mirror.diff(snap, exists=existing_objects)
        seconds = time.perf_counter() - t0
        new = session is None
        if new:
            def make(cancel=None):
                made = Session(mirror.scene(snap, cancel), settings, build=False)
                made.kept_bvhs = KEPT  # unchanged meshes take the last session's trees
                return made

            if source == "RENDER":
                triangles = sum(len(mirror.cache.mesh(r.mesh_key).triangles)
                                for r in snap.objects.values())
                session = build(make, triangles, cancel, progress, lock)
            else:
                session = make()
            state.session = session
        else:
            session.submit(diff.edits)
        mirror.commit(diff)
        return SyncOutcome(session, snap, len(diff.edits), new, seconds, diff.stats)


class HeldLock:
    """``with HeldLock(lock):`` holds ``lock`` (a ``threading.Lock``) and releases it at
    the end, unless :meth:`hand_over` gave it to another thread, which then releases it."""

    def __init__(self, lock) -> None:
        self.lock = lock
        self.handed = False

    def __enter__(self) -> HeldLock:
        self.lock.acquire()
        return self

    def __exit__(self, *_exc) -> None:
        if not self.handed:
            self.lock.release()

    def hand_over(self) -> None:
        self.handed = True


#: How often a build is checked for a cancel (s): Esc stops an F12 within this.
CANCEL_POLL_S = 0.1
#: How long a cancelled build is given to stop at the core's flag before it is left to
#: finish on its own (s).
CANCEL_JOIN_S = 0.3


def build(make, triangles: int = 0, cancel=None, progress=None,
          lock: HeldLock | None = None):
    """``make(flag)`` a new session and build its structures (the scene's arrays, its
    accelerator), saying so through ``progress`` and stopping when ``cancel()`` turns True
    (polled every :data:`CANCEL_POLL_S`); returns the built session.

    The build runs on a thread of its own. A cancel sets the core's
    :class:`~rstrace_engine.cancel.CancelFlag` (``flag``), which the scene's construction
    polls every 262,144 triangles of its area test (``Scene.add_mesh``) and the BVH build
    between levels, subtrees, hash chunks and meshes (the session stays as it was); the
    thread is joined when it stops within :data:`CANCEL_JOIN_S` (the usual case). What
    polls nothing is a single kernel between two polls (collapsing a mesh's tree to the
    4-wide layout, concatenating the scene's arrays: a few tenths of a second per million
    triangles on a loaded machine); a build caught in one is left to finish there and is
    thrown away: :class:`export.Cancelled` is raised at once, and the kernels it still runs
    hold ``lock`` (``runtime.RENDER_LOCK``, handed over: the thread releases it when done),
    so nothing else runs kernels beside it.
    """
    import threading

    import numba

    from rstrace_engine.cancel import CancelFlag, Cancelled

    if cancel is None:
        session = make(None)
        session.apply()  # (builds the accelerator; no edits are queued)
        return session
    done = threading.Event()
    guard = threading.Lock()
    out: list = []
    failed: list = []
    abandoned = [False]

    flag = CancelFlag()
    threads = numba.get_num_threads()  # (the render's setting: thread-local in numba)

    def run() -> None:
        try:
            numba.set_num_threads(threads)  # (a new thread starts at NUMBA_NUM_THREADS)
            session = make(flag)
            if flag():
                raise Cancelled
            session.apply(cancel=flag)
            out.append(session)
        except BaseException as exc:  # handed to the caller
            failed.append(exc)
        finally:
            with guard:
                done.set()
                if abandoned[0] and lock is not None:
                    lock.lock.release()

    t0 = time.perf_counter()
    worker = threading.Thread(target=run, name="rstrace-build", daemon=True)
    worker.start()
    while not done.wait(CANCEL_POLL_S):
        if progress is not None:
            progress(f"building the scene and its BVH over {triangles:,} triangles "
                     f"({time.perf_counter() - t0:.0f} s, Esc cancels)")
        if cancel():
            flag.set()
            if done.wait(CANCEL_JOIN_S):
                worker.join()
                raise export.Cancelled
            with guard:
                if not done.is_set():
                    abandoned[0] = True
                    if lock is not None:
                        lock.hand_over()
                    raise export.Cancelled
            worker.join()
            raise export.Cancelled
    worker.join()
    if failed:
        if isinstance(failed[0], Cancelled):
            raise export.Cancelled
        raise failed[0]
    return out[0]


def drop_session(state) -> None:
    """Forget the core session of ``state`` and the mirror of it (after an error, or to
    start afresh: the next :func:`sync` walks everything into a new session)."""
    with state.lock:
        state.session = None
        state.mirror.reset()
