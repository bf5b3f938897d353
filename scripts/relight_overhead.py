"""First-frame cost of keeping the per-light records (docs/RELIGHT.md): museum BASE full
frames with the light terms kept (``Session.light_terms = True``, as after a session's first
light edit) and not, alternated; CPU seconds of the process (the machine is shared: wall time
drifts). ``python scripts/relight_overhead.py WIDTH HEIGHT REPEATS``."""

import sys
import time

from rstrace_engine import scenes
from rstrace_engine.frame import RenderSettings
from rstrace_engine.session import Session


def main(width: int, height: int, repeats: int) -> None:
    base = RenderSettings(mode="BASE", max_depth=5)
    res: dict = {"on": [], "off": []}
    for _ in range(repeats):
        for key, keep in (("on", True), ("off", False)):
            sess = Session(scenes.museum(width, height), base)
            sess.light_terms = keep
            t0 = time.process_time()
            frame = sess.render()
            dt = time.process_time() - t0
            res[key].append(dt)
            sys.stdout.write(f"{key} {dt:.2f} CPU s, light records "
                             f"{frame.stats['light_records_mb']:.1f} MB\n")
    best = {k: min(v) for k, v in res.items()}
    sys.stdout.write(f"best: on {best['on']:.2f} s, off {best['off']:.2f} s, "
                     f"ratio {best['on'] / best['off']:.2f}\n")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
