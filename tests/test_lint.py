"""The package is clean under the linter's and the type checker's rules (pyproject.toml's
[tool.ruff] and [tool.mypy])."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*command):
  return subprocess.run([sys.executable, "-m", *command], cwd=ROOT, capture_output=True,
                        text=True, timeout=600)


def test_ruff_check_passes():
  proc = _run("ruff", "check", "jaxplore")
  assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_passes():
  proc = _run("mypy")
  assert proc.returncode == 0, proc.stdout[-5000:] + proc.stderr[-2000:]
