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


def _tutorial_planner(tmp_path) -> Path:
  """docs/add-a-planner.md's planner, saved as the page says."""
  page = (ROOT / "docs" / "add-a-planner.md").read_text(encoding="utf-8")
  path = tmp_path / "my_planner.py"
  path.write_text(re.search(r"```python\n(.*?)```", page, re.S).group(1))
  return path


def test_the_tutorial_planner_is_a_plugin_the_cli_lists_and_checks(tmp_path, monkeypatch, capsys):
  """The page's planner, from a user's file: ``--plugin`` registers it, ``run --help`` and
  ``jaxplore settings`` list it and its weight, and a weight out of its declared range is
  refused before compute."""
  from jaxplore import cli
  from jaxplore.config import ConfigError
  from jaxplore.planners import base
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec
  path = _tutorial_planner(tmp_path)
  # setenv, not delenv: the --plugin below writes the variable, and monkeypatch restores only
  # what it recorded (a delenv of an absent variable records nothing), so the planner would come
  # back for the next test of this process that reads the registry
  monkeypatch.setenv(base.PLUGINS_ENV, "")
  try:
    assert cli.main(["--plugin", str(path), "settings", "--planner", "far_frontier"]) == 0
    out = capsys.readouterr().out
    assert "planner far_frontier:" in out and "reach_m" in out and "> 0" in out
    with pytest.raises(SystemExit):
      cli.main(["run", "--help"])
    assert "far_frontier" in capsys.readouterr().out
    with pytest.raises(ConfigError, match="'far_frontier': weight reach_m must be > 0, got -1"):
      resolve(RunSpec.create(world="lab", planner="far_frontier", robots=1, max_steps=5,
                             params={"reach_m": -1.0}))
  finally:
    base.unregister("far_frontier")
    base._loaded_plugins.clear()
  (tmp_path / "broken.py").write_text("raise RuntimeError('not a planner')\n")
  monkeypatch.setenv(base.PLUGINS_ENV, str(tmp_path / "broken.py"))
  try:
    with pytest.raises(ConfigError, match="broken.py' could not be loaded: RuntimeError"):
      base.load_plugins()
  finally:
    base._loaded_plugins.clear()


@pytest.mark.slow  # a run and the conformance tests of one planner (~2 min on 2 cores)
def test_the_tutorial_planner_runs_and_passes_the_conformance_tests(tmp_path):
  """The page's commands as written: ``jaxplore --plugin my_planner.py run`` and the
  conformance tests of ``far_frontier`` with ``JAXPLORE_PLUGINS``."""
  path = _tutorial_planner(tmp_path)
  run = subprocess.run(
      [sys.executable, "-m", "jaxplore", "--plugin", str(path), "run", "--planner",
       "far_frontier", "--robots", "2", "--max-steps", "60", "--reach-m", "5", "--world", "lab",
       "--no-progress", "--devices", "1"], cwd=tmp_path, capture_output=True, text=True,
      timeout=600)
  assert run.returncode == 0, run.stdout + run.stderr
  assert "robot-steps/s" in run.stdout
  check = subprocess.run(
      [sys.executable, "-m", "pytest", "-q", "-o", "addopts=", "-p", "no:cacheprovider",
       str(ROOT / "tests" / "planners" / "test_conformance.py"), "-k", "far_frontier"],
      cwd=ROOT, capture_output=True, text=True, timeout=900,
      env={**os.environ, "JAXPLORE_PLUGINS": str(path)})
  assert check.returncode == 0, check.stdout[-3000:] + check.stderr[-3000:]
  assert re.search(r"\b[1-9]\d* passed", check.stdout), check.stdout[-500:]


def test_the_tutorial_sensor_runs_in_the_engine_as_written(tmp_path, monkeypatch):
  """docs/add-a-sensor.md's sensor, saved as the page says: it is a sensor object the settings
  take, the resolver records it by name, and a scan loses returns at about its rate."""
  import jax
  import jax.numpy as jnp
  import numpy as np

  from jaxplore import sensor
  from jaxplore.config import make_params
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec
  page = (ROOT / "docs" / "add-a-sensor.md").read_text(encoding="utf-8")
  (tmp_path / "my_sensor.py").write_text(re.search(r"```python\n(.*?)```", page, re.S).group(1))
  monkeypatch.syspath_prepend(str(tmp_path))
  from my_sensor import DropoutLidar
  resolved = resolve(RunSpec(world="lab", robots=2, max_steps=10,
                             params={"sensor": DropoutLidar(dropout=0.3)}))
  assert resolved.config.sensor == DropoutLidar(0.3)
  assert resolved.describe()["sim_config"]["sensor"] == "dropout_lidar"
  occupied = np.zeros((40, 40), bool)
  occupied[[0, -1], :] = occupied[:, [0, -1]] = True
  params = make_params(res=0.1, r_max=5.0, fov=2 * np.pi)
  angles = sensor.beam_angles(jnp.float32(0.0), params.fov, 2000)
  scan = jax.jit(lambda k: DropoutLidar(dropout=0.3).measure(
      sensor.frame_truth(jnp.asarray(occupied)), (40, 40), jnp.float32(20.5), jnp.float32(20.5),
      angles, params, 0.1, 51, k, jnp.bool_(True), sensor.directions(angles)))(
          jax.random.PRNGKey(0))
  lost = ~np.asarray(scan.hit)  # every beam ends on the room's walls within 5 m
  assert abs(lost.mean() - 0.3) < 0.04 and (np.asarray(scan.ranges)[lost] == 0).all()
