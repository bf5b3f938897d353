"""First use: the kernels are compiled (or loaded) in the background with a progress count,
only for the chosen mode, and the warm-up thread is joined on stop."""

from __future__ import annotations

import re


def test_warmup_runs_in_the_background_with_progress(monkeypatch):
    import addon
    from addon import kernels, runtime

    kernels.wait(600)  # a warm-up started by an earlier test (engine selected)
    monkeypatch.setitem(kernels._state, "modes_done", set())
    monkeypatch.setitem(kernels._state, "thread", None)
    counts = kernels.counts
    # as on a fresh install (else, every kernel cached, no warm-up would run: test below);
    # patched while the lock is held: the thread looks once, before it waits for the lock
    monkeypatch.setattr(kernels, "counts", lambda mode="BASE": (3, 15))
    with runtime.RENDER_LOCK:  # a render in progress: the warm-up waits its turn
        assert kernels.start_warmup("BASE")
        assert not kernels.start_warmup("BASE")  # one at a time
        text = kernels.progress_text()
        assert text is not None and re.fullmatch(r"(compiling|loading) kernels 3/15", text)
        monkeypatch.setattr(kernels, "counts", counts)
    assert kernels.wait(600) and kernels.ready("BASE") and not kernels.ready("INTERPOLANT")
    assert kernels.progress_text() is None
    done, total = kernels.counts("BASE")
    assert done == total == len(kernels.MODE_KERNELS["BASE"])  # every listed name exists
    # BASE compiles no interpolant kernel: INTERPOLANT lists more
    assert kernels.counts("INTERPOLANT")[1] == len(kernels.MODE_KERNELS["INTERPOLANT"]) > total
    assert addon.kernels is kernels


def test_stop_joins_the_warmup(monkeypatch):
    from addon import kernels

    kernels.wait(600)
    monkeypatch.setitem(kernels._state, "modes_done", set())
    monkeypatch.setitem(kernels._state, "thread", None)
    assert kernels.start_warmup("INTERPOLANT")
    thread = kernels._state["thread"]
    assert kernels.stop(600) and not thread.is_alive()
    monkeypatch.setitem(kernels._state, "stop", False)


def test_no_warmup_when_every_kernel_of_the_mode_is_cached(monkeypatch):
    """A second process (or the shipped kernels): nothing to compile, so no warm-up loads
    every kernel and renders its scenes while the user's render waits for the lock."""
    from addon import kernels, runtime

    kernels.wait(600)
    monkeypatch.setitem(kernels._state, "modes_done", set())
    monkeypatch.setitem(kernels._state, "thread", None)
    done, total = kernels.counts("BASE")
    assert done == total  # the warm-up of the test above cached them
    with runtime.RENDER_LOCK:  # a render holds the lock: this warm-up does not wait for it
        assert kernels.start_warmup("BASE")
        assert kernels.wait(120) and kernels.ready("BASE")
    assert kernels.progress_text() is None
