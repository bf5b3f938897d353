"""numba's OpenMP threads wait passively unless the user says otherwise (``rstrace_engine``
sets ``OMP_WAIT_POLICY`` before numba loads libgomp; docs/bench-frame.md, "Where the rough
frame's time and error go")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _policy_in_child(env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if env_value is not None:
        env["OMP_WAIT_POLICY"] = env_value
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    code = "import os, rstrace_engine; print(os.environ.get('OMP_WAIT_POLICY'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, cwd=ROOT)
    return out.stdout.strip().splitlines()[-1]


def test_passive_by_default_and_the_users_value_kept():
    assert _policy_in_child(None) == "PASSIVE"
    assert _policy_in_child("ACTIVE") == "ACTIVE"
