import importlib
import sys

from . import BENCHMARKS


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in BENCHMARKS:
        print(f"usage: python -m rstrace_engine.bench {{{','.join(BENCHMARKS)}}} [--json]",
              file=sys.stderr)
        return 2
    module = importlib.import_module(f"{__package__}.{argv[0]}")
    return module.main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
