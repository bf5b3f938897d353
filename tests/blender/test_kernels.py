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
    with runtime.RENDER_LOCK:  # a render in progress: the warm-up waits its turn
        assert kernels.start_warmup("BASE")
        assert not kernels.start_warmup("BASE")  # one at a time
        done, total = kernels.counts("BASE")
        assert (kernels.progress_text() is None) == (done == total)
        counts = kernels.counts
        kernels.counts = lambda mode: (3, 15)  # as on a fresh install
        try:
            text = kernels.progress_text()
        finally:
            kernels.counts = counts
        assert text is not None and re.fullmatch(r"(compiling|loading) kernels 3/15", text)
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
