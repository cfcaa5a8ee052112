"""The code passes the linter: ``ruff check`` (configured in ruff.toml, pinned in
requirements.txt) over the package, the tests, the benchmarks, the scripts and the launch files."""

import importlib.util
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PATHS = ("rbc_registration", "test", "benchmarks", "scripts", "launch")


def test_ruff_check_passes():
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed here (it is pinned in requirements.txt)")
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", *PATHS],
                          cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
