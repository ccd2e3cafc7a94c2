"""The package is clean under the rules in pyproject.toml ([tool.ruff]: line length, imports,
pyflakes, pycodestyle, bugbear, pyupgrade)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_check_passes():
  """``ruff check jaxplore`` finds nothing under the project's configuration."""
  result = subprocess.run([sys.executable, "-m", "ruff", "check", "jaxplore"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
  assert result.returncode == 0, result.stdout + result.stderr
