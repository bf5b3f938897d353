"""Benchmarks: ``python -m rstrace_engine.bench <name> [--json]``.

Each benchmark is a module of this package with a ``main(argv) -> int`` function. Speed is
reported as ratios measured in the same run, never as absolute thresholds.
"""

BENCHMARKS = ("raycast", "frame", "trade", "edit", "accel", "viewport", "ritree", "scale")
