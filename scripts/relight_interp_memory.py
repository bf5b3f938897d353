"""Memory of the interpolants' per-light shares (docs/RELIGHT.md, "INTERPOLANT"): one
INTERPOLANT frame of a bench scene at WIDTH x HEIGHT (epsilon 0.01, the measured fallback
off so that cells are built wherever the predicate allows), once without the shares and once
with them, twice each, alternating (the first run of a process loads the kernels); prints
the live interpolants, the samples kept after the compaction an edit does (with the shares:
the test lines' too), the shares' bytes and the cache's, and the frames' CPU times.
``PYTHONPATH=. python scripts/relight_interp_memory.py SCENE WIDTH HEIGHT``."""

import sys
import time

from rstrace_engine.bench.edit import setup
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.session import Session


def main() -> None:
    name, width, height = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    InterpolantRenderer.auto_fallback = False
    for terms in (False, True, False, True):
        scene, _ = setup(name, width, height)
        sess = Session(scene, RenderSettings(mode="INTERPOLANT", epsilon=0.01))
        sess.light_terms = terms
        t0 = time.process_time()
        frame = sess.render()
        cpu = time.process_time() - t0
        c = sess.interpolants.cache
        c.compact_samples()  # what an edit keeps (the frame's test lines, failed cells go)
        L = len(c.sa.light_kind)
        tests = c.pool.tests[c.pool.live]
        sys.stdout.write(
              f"{name} {width}x{height} L={L} shares={'on' if terms else 'off'}: "
              f"interpolants {c.pool.n_live}, samples {c.samples.n} (test lines kept "
              f"{int((tests >= 0).sum())}), nodes {c.samples.n_nodes}, shares "
              f"{c.samples.share_bytes / 1e6:.2f} MB ({24 * L} B/sample), samples "
              f"{c.samples.memory_bytes / 1e6:.2f} MB, cache {c.memory_bytes / 1e6:.2f} MB, "
              f"interpolated {100 * frame.stats['interpolated_fraction']:.1f}%, "
              f"frame CPU {cpu:.2f} s\n")


if __name__ == "__main__":
    main()
