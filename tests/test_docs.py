"""The documentation: the MkDocs site builds in strict mode, and README.md's links resolve."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# [text](target) and ![alt](target); the text may not span lines (the README never does).
_LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def test_site_builds_strict(tmp_path):
  # No -q: at -q MkDocs drops warnings before strict mode counts them (a broken link passes).
  proc = subprocess.run(
      [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
      cwd=ROOT, capture_output=True, text=True, timeout=120,
      env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
  assert proc.returncode == 0, proc.stdout + proc.stderr
  warnings = [line for line in proc.stderr.splitlines() if line.startswith("WARNING")]
  assert not warnings, "\n".join(warnings)
  assert (tmp_path / "site" / "index.html").is_file()


def _relative_links(text):
  for target in _LINK.findall(text):
    if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
      continue  # http(s)://, mailto:, an anchor on the same page
    yield target


def test_readme_links_resolve():
  readme = ROOT / "README.md"
  links = list(_relative_links(readme.read_text(encoding="utf-8")))
  assert links, "README.md has no relative links: the pattern no longer matches"
  missing = [t for t in links if not (readme.parent / t.split("#", 1)[0]).exists()]
  assert not missing, f"README.md links to files that do not exist: {missing}"


@pytest.mark.slow  # one compile and a 50-step run (~40 s on 2 cores): `pytest -m slow`
def test_the_readme_python_example_runs_as_written(tmp_path, monkeypatch, capsys):
  """README.md's Python block, pasted as it stands (its tiny budget is already in it)."""
  block = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"),
                    re.S).group(1)
  monkeypatch.chdir(tmp_path)
  namespace = {}
  exec(compile(block, "README.md", "exec"), namespace)
  episodes = namespace["result"].episodes
  assert len(episodes) == 2 and set(episodes["reason"]) <= {"complete", "exhausted", "timeout"}
  assert "robot_steps_per_s" in capsys.readouterr().out
