"""Results folders: atomic writes, planner memory saved generically, ``--out`` checked before any
compute."""

import json

import numpy as np
import pytest

import jaxplore
from jaxplore import cli, results, runner
from jaxplore.config import ConfigError


def test_atomic_write_leaves_no_temporary(tmp_path):
  path = results.write_json(tmp_path / "a.json", {"x": 1})
  assert json.loads(path.read_text()) == {"x": 1} and not list(tmp_path.glob("*.tmp"))


def test_planner_memory_of_the_first_robots_is_saved_by_its_tree_paths(tmp_path):
  memory = {"graph": {"nodes": np.arange(6 * 5 * 2).reshape(6, 5, 2), "count": np.arange(6)},
            "visits": [np.ones((6, 3)), np.zeros(6, bool)]}
  path = results.write_memory(tmp_path / "memory.npz", memory, shown=4)
  with np.load(path) as saved:
    assert sorted(saved.files) == ["graph.count", "graph.nodes", "visits.0", "visits.1"]
    np.testing.assert_array_equal(saved["graph.nodes"], memory["graph"]["nodes"][:4])
    assert saved["visits.1"].dtype == bool and saved["visits.0"].shape == (4, 3)
  # a planner without memory writes nothing
  assert results.write_memory(tmp_path / "none.npz", None) is None
  assert results.write_memory(tmp_path / "empty.npz", {}) is None
  assert not (tmp_path / "none.npz").exists() and not (tmp_path / "empty.npz").exists()


@pytest.fixture
def no_compute(monkeypatch):
  """Makes any resolution (map loading, sizing, compiling) fail the test."""
  def refuse(*args, **kwargs):
    raise AssertionError("resolved and computed before refusing")
  monkeypatch.setattr(runner, "resolve", refuse)


def test_run_out_is_checked_before_any_compute(tmp_path, no_compute, capsys):
  a_file = tmp_path / "results.txt"
  a_file.write_text("mine")
  with pytest.raises(ConfigError, match="is a file"):
    jaxplore.run(world="lab", out=a_file, progress=False)
  for name in ("sweep_schedule.json", "sweep_plan.json"):  # a sweep folder, new or old
    folder = tmp_path / name.split(".")[0]
    folder.mkdir()
    (folder / name).write_text("{}")
    with pytest.raises(ConfigError, match="holds a sweep"):
      jaxplore.run(world="lab", out=folder, progress=False)
  busy = tmp_path / "busy"
  busy.mkdir()
  (busy / "notes.txt").write_text("mine")
  with pytest.raises(ConfigError, match="not empty and holds no jaxplore run results"):
    jaxplore.run(world="lab", out=busy, progress=False)
  assert cli.main(["run", "--world", "lab", "--out", str(a_file), "--no-progress"]) == 2
  assert capsys.readouterr().err.startswith("jaxplore: error: --out")
  # an earlier run's folder, an empty folder and a new one are fine
  earlier = tmp_path / "earlier"
  earlier.mkdir()
  (earlier / "config.json").write_text(json.dumps({"sim_config": {}}))
  for ok in (earlier, tmp_path / "empty", tmp_path / "new"):
    if ok.name == "empty":
      ok.mkdir()
    assert results.check_run_out(ok) == ok


@pytest.mark.parametrize("settings", [dict(seed=2**32), dict(seed=-1), dict(seed=2**64),
                                      dict(robot_seeds=[0, 2**32])])
def test_seeds_outside_uint32_are_refused_before_compute(settings, no_compute):
  with pytest.raises(ConfigError, match="seed must be an integer in"):
    jaxplore.run(world="lab", progress=False, **settings)


def test_cli_refuses_an_aliasing_seed_in_one_line(no_compute, capsys):
  assert cli.main(["run", "--world", "lab", "--seed", "4294967296", "--no-progress"]) == 2
  err = capsys.readouterr().err
  assert err.startswith("jaxplore: error: seed must be an integer in [0, 2**32)"), err
