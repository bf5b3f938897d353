import importlib
import os
import sys

#: numba's OpenMP workers (the threading layer outside Blender, which uses its own TBB)
#: spin after every parallel region before they sleep: on two shared cores the 1M-triangle
#: mesh BVH build took 0.83 s of CPU on two threads, 0.59 s with idle workers asleep
#: (``docs/bench-scale-bpy.md``). libgomp reads this when numba first starts its threads;
#: a value the environment sets wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from . import BENCHMARKS  # noqa: E402


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in BENCHMARKS:
        print(f"usage: python -m rstrace_engine.bench {{{','.join(BENCHMARKS)}}} [--json]",
              file=sys.stderr)
        return 2
    module = importlib.import_module(f"{__package__}.{argv[0]}")
    return module.main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
