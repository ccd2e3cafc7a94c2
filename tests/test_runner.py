"""``jaxplore.run`` and the ``jaxplore`` command: outputs, reproducibility, clear errors on bad input."""

import json
import re

import numpy as np
import pandas as pd
import pytest
from conftest import tiny_office

import jaxplore
from jaxplore import cli
from jaxplore.config import ConfigError
from jaxplore.maps import MapError
from jaxplore.runspec import RunSpec

# The world and settings of tests/test_animate.py's run (see conftest.tiny_office): its engine
# program serves both modules (~20 s a compile). Worlds by name: tests/test_smoke.py and
# tests/maps/test_worlds.py.
SMALL = dict(world=tiny_office(), robots=2, max_steps=40, replan_every=5, progress=False,
             quiet=True, params={"r_max": 3.0})


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
  out = tmp_path_factory.mktemp("run")
  return jaxplore.run(out=out, **SMALL), out


def test_run_writes_every_output(small_run):
  result, out = small_run
  for name in ("config.json", "timing.json", "episodes.parquet", "curves.parquet", "maps.npz",
               "map.png", "entropy_distance.png", "coverage_time.png"):
    assert (out / name).exists(), name
  config = json.loads((out / "config.json").read_text())
  assert config["seed"] == 0 and config["sim_config"]["max_steps"] == 40
  assert config["params"]["r_max"] == pytest.approx(3.0)
  episodes = pd.read_parquet(out / "episodes.parquet")
  assert len(episodes) == 2 and set(episodes.reason) <= {"complete", "exhausted", "timeout"}
  for column in ("entropy_reduction", "distance_m", "E_r", "Std_E_r", "coverage_m2", "t90_s", "reason"):
    assert column in episodes
  curves = pd.read_parquet(out / "curves.parquet")
  assert set(curves.robot) == {0, 1}
  assert (curves.groupby("robot").step.max() <= 40).all()


def test_same_command_same_numbers(small_run):
  result, _ = small_run
  again = jaxplore.run(**SMALL)
  pd.testing.assert_frame_equal(result.episodes, again.episodes)
  pd.testing.assert_frame_equal(result.curves, again.curves)


def test_episode_metrics_follow_their_definitions(small_run):
  result, _ = small_run
  for _, row in result.episodes.iterrows():
    curve = result.curves[result.curves.robot == row.robot]
    assert row.distance_m == pytest.approx(curve.distance.iloc[-1])
    assert row.entropy_reduction == pytest.approx(row.entropy_initial - curve.entropy.iloc[-1])
    if row.distance_m > 0:
      assert row.E_r == pytest.approx(row.entropy_reduction / row.distance_m)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(world="atlantis"), MapError, "atlantis.*office"),
    (dict(world="/nonexistent/map.yaml"), MapError, "map.yaml"),
    (dict(planner="teleport"), ConfigError, "unknown planner 'teleport'"),
    (dict(params={"v_max": float("nan")}), ConfigError, "v_max"),
    (dict(params={"fov": 7.0}), ConfigError, "fov"),
    (dict(params={"r_robot": -1.0}), ConfigError, "r_robot"),
    (dict(params={"warp": 1.0}), ConfigError, "warp"),
    (dict(preset="hubble"), ConfigError, "hubble"),
    (dict(start="0.0,0.0"), ConfigError, "inside a wall"),
    (dict(start="100,5"), ConfigError, "outside the map"),
    (dict(start="1,nan"), ConfigError, "start"),
    (dict(robots=0), ConfigError, "robots"),
    (dict(planner_params={"k9": 1.0}), ConfigError, "k9"),
    (dict(plan_window=-8), ConfigError, "plan_window"),
    (dict(path_capacity=1), ConfigError, "path_capacity must be an integer >= 2"),
])
def test_bad_input_is_refused_before_compute(kwargs, error, match):
  settings = dict(SMALL, **kwargs)
  with pytest.raises(error, match=match):
    jaxplore.run(**settings)


def test_map_with_no_free_cell_is_refused(tmp_path):
  from jaxplore.maps import GridMap
  with pytest.raises((MapError, ConfigError), match="no free cell"):
    jaxplore.run(**dict(SMALL, world=GridMap(np.ones((10, 10), bool), 0.1, name="solid")))


def test_absurd_batch_is_refused_with_the_numbers():
  with pytest.raises(ConfigError, match="GiB"):
    jaxplore.run(**dict(SMALL, robots=10_000_000))


def test_a_program_that_compiles_too_large_is_refused_before_it_runs(small_run, tmp_path,
                                                                     monkeypatch):
  """Where the memory model is short of what XLA compiles (forced lockstep on a CPU), the
  compiled program's own numbers refuse the run before its first chunk; nothing is written."""
  from jaxplore import memory
  monkeypatch.setattr(memory, "estimate_bytes", lambda config, robots: 0)  # the model passes it
  monkeypatch.setattr(memory, "available_bytes", lambda: 1 << 10)
  out = tmp_path / "too_large"
  with pytest.raises(ConfigError, match="2 robots on a .* compiled to a program that allocates"):
    jaxplore.run(out=out, **SMALL)
  assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
def test_cli_run_and_maps(tmp_path, capsys):
  out = tmp_path / "cli"
  code = cli.main(["run", "--world", "lab", "--robots", "2", "--max-steps", "20", "--replan-every", "5",
                   "--set", "r_max=3", "--out", str(out), "--no-progress", "--devices", "1"])
  assert code == 0
  assert (out / "episodes.parquet").exists()
  printed = capsys.readouterr().out
  assert "termination:" in printed and "results in" in printed
  assert cli.main(["maps"]) == 0
  assert "office" in capsys.readouterr().out
  assert cli.main(["maps", "--render", "lab", "--out", str(tmp_path / "lab.png")]) == 0
  assert (tmp_path / "lab.png").exists()
  assert cli.main(["plot", str(out)]) == 0


def test_the_progress_bar_shows_the_compile_then_the_steps(small_run, capsys):
  """The bar is up before the compile (a minute on a GPU), saying so, then counts the steps."""
  jaxplore.run(**dict(SMALL, progress=True, quiet=False))
  printed = capsys.readouterr()
  label = f"{RunSpec().planner} x2 on tiny_office"
  assert f"{label} (compiling):" in printed.err
  assert f"{label}: 100%" in printed.err and "40/40" in printed.err and "done=" in printed.err
  assert "termination:" in printed.out


def test_python_dash_m_runs_the_command():
  """``python -m jaxplore`` is the ``jaxplore`` command (for an environment whose scripts folder
  is not on the PATH): its exit code and output, here the world list and a refusal."""
  import subprocess
  import sys
  from conftest import REPO, subprocess_env
  listed = subprocess.run([sys.executable, "-m", "jaxplore", "maps"], cwd=REPO, capture_output=True,
                          env=subprocess_env(), timeout=120, text=True)
  assert listed.returncode == 0, listed.stderr[-2000:]
  assert "office" in listed.stdout and "lab" in listed.stdout
  refused = subprocess.run([sys.executable, "-m", "jaxplore", "run", "--world", "atlantis"],
                           cwd=REPO, capture_output=True, env=subprocess_env(), timeout=120,
                           text=True)
  assert refused.returncode == 2 and "atlantis" in refused.stderr


def test_cli_errors_are_one_clear_line(capsys):
  assert cli.main(["run", "--world", "atlantis", "--no-progress"]) == 2
  err = capsys.readouterr().err
  assert err.startswith("jaxplore: error:") and "atlantis" in err


@pytest.mark.slow  # a whole sweep in subprocesses or through the CLI: `pytest -m slow`
def test_sweep_is_one_batch_with_parameter_columns(tmp_path):
  from jaxplore.runner import sweep
  result = sweep({"alpha": [1.0, 2.0], "k1": [0.0, 0.3]}, seeds=2, world="lab", planner="li2020",
                 max_steps=12, replan_every=4, params={"r_max": 3.0}, progress=False,
                 out=tmp_path / "sweep", quiet=True)
  episodes = result.episodes
  assert len(episodes) == 8
  assert sorted(set(zip(episodes.alpha, episodes.k1))) == [(1.0, 0.0), (1.0, 0.3), (2.0, 0.0), (2.0, 0.3)]
  assert (tmp_path / "sweep" / "sweep.png").exists()
  # the same seed starts at the same pose in every setting (common random numbers)
  first = result.curves[result.curves.step == 1].set_index("robot")
  seeds = episodes.set_index("robot").seed
  for s in (0, 1):
    robots = seeds[seeds == s].index
    assert first.loc[robots, "x"].nunique() == 1 and first.loc[robots, "y"].nunique() == 1


def test_sweep_refuses_unknown_names_and_bad_weights():
  from jaxplore.runner import sweep
  with pytest.raises(ConfigError, match="cannot sweep 'gamma'"):
    sweep({"gamma": [1.0]}, seeds=1, world="lab", planner="li2020", max_steps=10, progress=False)
  with pytest.raises(ConfigError, match="k1 < k2"):
    sweep({"k1": [0.9]}, seeds=1, world="lab", planner="li2020", max_steps=10, progress=False)


@pytest.mark.slow  # a whole sweep in subprocesses or through the CLI: `pytest -m slow`
def test_cli_takes_parameters_as_flags(tmp_path, capsys):
  from jaxplore import cli
  from conftest import box_world
  from jaxplore.maps import save_map
  yaml_path = tmp_path / "box.yaml"
  save_map(box_world(30, 40), yaml_path)
  out = tmp_path / "run"
  code = cli.main(["run", "--world", str(yaml_path), "--planner", "li2020", "--robots", "1",
                   "--max-steps", "8", "--alpha", "1.0", "--k1=0.1", "--r-max", "2.5", "--out", str(out),
                   "--no-progress"])
  assert code == 0
  config = json.loads((out / "config.json").read_text())
  assert config["params"]["alpha"] == 1.0 and config["params"]["r_max"] == 2.5
  assert abs(config["planner_params"]["k1"] - 0.1) < 1e-6
  assert cli.main(["run", "--world", str(yaml_path), "--planner", "nearest_frontier", "--k1", "0.1"]) == 2
  assert "not an option, a simulator parameter" in capsys.readouterr().err
  assert cli.main(["run", "--world", str(yaml_path), "--alpha", "fast"]) == 2
  assert "'fast' is not a number" in capsys.readouterr().err


# A batch that does not divide over the devices: tests/test_smoke.py (its two-device process).


@pytest.mark.slow  # the user guide's Python example, run for 4 steps: `pytest -m slow`
def test_the_readme_python_example_runs(tmp_path, monkeypatch):
  """The user guide's Python block, as a user would paste it, with every run cut to 4 steps and no
  progress output (its settings otherwise as written: worlds, planners, grids, seeds)."""
  from conftest import REPO
  block = re.search(r"```python\n(.*?)```", (REPO / "docs" / "user-guide.md").read_text(), re.S).group(1)
  real_run, real_sweep = jaxplore.run, jaxplore.sweep
  short = dict(max_steps=4, progress=False, quiet=True)
  monkeypatch.setattr(jaxplore, "run", lambda *a, **k: real_run(*a, **{**k, **short}),
                      raising=False)
  monkeypatch.setattr(jaxplore, "sweep",
                      lambda *a, **k: real_sweep(*a, **{**k, **(short if "resume" not in k else
                                                               dict(progress=False, quiet=True))}),
                      raising=False)
  monkeypatch.chdir(tmp_path)
  namespace = {}
  exec(compile(block, "README.md", "exec"), namespace)
  assert len(namespace["result"].episodes) == 32
  assert len(namespace["sweep"].episodes) == 2 * 2 * 4 * 4  # alpha x k1 x samples x seeds
  assert (tmp_path / "runs" / "s" / "episodes.parquet").exists()
