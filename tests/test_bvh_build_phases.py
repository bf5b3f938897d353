"""``scripts/bvh_build_phases.py``'s per-thread CPU: each phase's busiest thread is what its
wall would be on an idle machine (docs/bench-scale.md, "Session 37 (threads)"), so the
reading must see every thread of the process, a worker's as well as the caller's."""

import threading

from repo_files import load_module


def test_thread_cpu_sees_each_threads_own_cpu():
    s = load_module("scripts/bvh_build_phases.py", "bvh_build_phases")
    ready, done = threading.Event(), threading.Event()
    ident = {}

    def spin():
        ident["tid"] = str(threading.get_native_id())
        ready.set()
        x = 0
        while not done.is_set():
            x += 1

    before = s._thread_cpu()
    t = threading.Thread(target=spin)
    t.start()
    ready.wait()
    mid = s._thread_cpu()
    while s._thread_cpu()[ident["tid"]] <= mid.get(ident["tid"], 0.0):
        pass  # (until the worker has run a tick more)
    after = s._thread_cpu()
    done.set()
    t.join()
    me = str(threading.get_native_id())
    assert me in before and me in after
    assert ident["tid"] in after and ident["tid"] not in before
    assert after[ident["tid"]] > mid[ident["tid"]] > 0.0
    assert after[me] >= before[me]
