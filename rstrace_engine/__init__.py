"""rstrace_engine: the core of rstrace, an interactive ray tracer (no Blender imports).

Scene model in :mod:`.scene`, accelerators in :mod:`.accelerators`, the base Whitted tracer
in :mod:`.whitted`, benchmarks in :mod:`.bench`.
"""

__version__ = "0.1.0"
