"""What the per-light records' cap does (docs/RELIGHT.md, "More than 64 lights"): museum
BASE at WIDTH x HEIGHT with N lights (:func:`relight_memory.museum_with`), depth 5, under
each cap CAP (MB, ``RenderSettings.relight_memory_mb``): the first frame's records and
what was dropped, then a power edit and a 0.5 m move of light slot SLOT (wall seconds,
relit or pixels re-traced).
``python scripts/relight_cap.py WIDTH HEIGHT N SLOT CAP [CAP ...]``."""

import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from relight_memory import museum_with  # noqa: E402

from rstrace_engine.frame import RenderSettings  # noqa: E402
from rstrace_engine.geometry.edits import LightSet  # noqa: E402
from rstrace_engine.session import Session  # noqa: E402


def main(width: int, height: int, n: int, slot: int, caps: list) -> None:
    for cap in caps:
        sess = Session(museum_with(width, height, n),
                       RenderSettings(mode="BASE", max_depth=5, relight_memory_mb=cap))
        sess.light_terms = True
        t0 = time.perf_counter()
        f = sess.render()
        st = f.stats
        sys.stdout.write(
            f"cap {cap:g} MB: first frame {time.perf_counter() - t0:.1f} s, light records "
            f"{st['light_records_mb']:.1f} MB, pixel records {st['records_mb']:.1f} MB, "
            f"relight_off {st.get('relight_off')!r}, moves_off "
            f"{st.get('relight_moves_off')!r}\n")
        sys.stdout.flush()
        li = sess.scene.lights[slot]
        x, y, z = li.position
        for name, new in (("power", replace(li, power=li.power * 2.0)),
                          ("move", replace(li, power=li.power * 2.0,
                                           position=(x + 0.5, y, z)))):
            sess.apply([LightSet(li.name, new)])
            t0 = time.perf_counter()
            st = sess.render().stats
            sys.stdout.write(
                f"  {name} of slot {slot}: {time.perf_counter() - t0:.2f} s, relit "
                f"{bool(st.get('relit'))}, traced pixels {st['traced_pixels']}, light "
                f"records {st['light_records_mb']:.1f} MB\n")
            sys.stdout.flush()


if __name__ == "__main__":
    a = sys.argv[1:]
    main(int(a[0]), int(a[1]), int(a[2]), int(a[3]), [float(c) for c in a[4:]])
