"""The repository's own scripts and examples, loaded as modules by the tests that check
their pure parts (``scripts/`` and ``examples/`` are not packages)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_module(relpath: str, name: str):
    """The file ``relpath`` (from the repository's root) executed as module ``name``."""
    spec = importlib.util.spec_from_file_location(name, ROOT / relpath)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
