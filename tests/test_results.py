"""Results folders: atomic writes, a planner's memory and static settings saved generically,
``--out`` and seeds checked before any compute."""

import dataclasses
import json
import types

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import jaxplore
from conftest import box_world
from jaxplore import cli, plot, results, runner, sweeps
from jaxplore.config import ConfigError
from jaxplore.planners import base, frontier
from jaxplore.resolve import resolve
from jaxplore.runspec import RunSpec
from jaxplore.sweeps import schedule


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


@dataclasses.dataclass(frozen=True)
class ProbeSettings:
  plan_increment: int = 1


def _init_memory(ctx, params):
  return {"plans": jnp.int32(0)}


def _plan_probe(ctx, view, robot, params, key, memory):
  plan = frontier.plan_nearest_frontier(ctx, view, robot, params, key)
  return plan, dict(memory, plans=memory["plans"] + ctx.settings.plan_increment)


def _plans_as_graph(arrays, res, origin):
  """The probe's memory drawn as a graph: one node per plan counted, in a row."""
  count = int(arrays["plans"])
  nodes = np.asarray(origin, np.float32) + res * np.stack([np.arange(count), np.zeros(count)], -1)
  return types.SimpleNamespace(nodes=nodes.astype(np.float32), edges=np.zeros((0, 2), np.int32),
                               lsr=None, open=None, current=0, overflow=False)


@pytest.fixture(scope="module")
def probe():
  """Nearest frontier that counts its plans (times a static setting) in a per-robot memory, and
  draws that memory as a graph."""
  base.register("host_probe", summary="test probe", settings=ProbeSettings(),
                init_memory=_init_memory, memory_graph=_plans_as_graph)(_plan_probe)
  yield "host_probe"
  base.unregister("host_probe")


def test_a_planners_memory_and_settings_reach_the_results_folder(probe, tmp_path):
  """What ``jaxplore.run`` writes: the resolved settings (config.json) and the final state's
  memory (memory.npz); the engine carrying the memory is tested with the planner contract."""
  resolved = resolve(RunSpec(world=box_world(30, 40), planner=probe, robots=6, max_steps=12,
                             planner_params={"plan_increment": 3}))
  described = resolved.describe()
  assert resolved.config.planner.settings == ProbeSettings(3)
  assert described["planner_settings"] == {"plan_increment": 3}
  assert described["sim_config"]["planner_settings"] == {"plan_increment": 3}
  plans = np.arange(6, dtype=np.int32) * 3
  state = types.SimpleNamespace(logodds=np.zeros((6, 30, 40), np.float32),
                                memory={"plans": plans})
  curves = pd.DataFrame({"robot": [0, 0], "step": [1, 2], "time": [0.4, 0.8],
                         "distance": [0.1, 0.2], "entropy": [2.0, 1.0],
                         "coverage": [0.1, 0.2], "x": [1.0, 1.1], "y": [1.0, 1.0]})
  out = results.write_run(tmp_path / "run", described, {}, pd.DataFrame({"robot": [0]}), curves,
                          resolved.grid, state)
  assert json.loads((out / "config.json").read_text())["planner_settings"] == {"plan_increment": 3}
  with np.load(out / "memory.npz") as saved:
    assert saved.files == ["plans"]
    np.testing.assert_array_equal(saved["plans"], plans[:4])  # the first robots
  # the planner's own drawing of its memory reaches the map figure (plot names no planner)
  graph = plot.saved_memory_graph(out, resolved.grid.res, resolved.grid.origin, robot=2)
  assert len(graph.nodes) == 6 and graph.nodes[1, 0] == np.float32(resolved.grid.origin[0]
                                                                    + resolved.grid.res)
  assert plot.saved_memory_graph(out, 0.1, (0, 0), robot=0).nodes.shape == (0, 2)
  # a planner without memory (its memory is an empty tree) leaves none, nor an earlier one
  results.write_run(out, described, {}, pd.DataFrame({"robot": [0]}), curves, resolved.grid,
                    types.SimpleNamespace(logodds=state.logodds, memory=()))
  assert not (out / "memory.npz").exists() and (out / "maps.npz").exists()


def test_a_swept_static_setting_makes_a_group_per_value(probe):
  grids = {}  # the GridMap worlds of the sweep
  spec = sweeps.make_spec({"plan_increment": [1, 3], "fov": [3.0, 6.0]}, None, None, 0, [0, 1],
                          box_world(30, 40), [probe, "nearest_frontier"],
                          RunSpec(max_steps=12, params={"r_max": 1.2}), grids)
  made, resolved = schedule.make_schedule(spec, None, grids, None, 1)
  assert [(g.planner, g.names, len(g.rows)) for g in made.groups] == [
      (probe, ("plan_increment", "fov"), 4), (probe, ("plan_increment", "fov"), 4),
      ("nearest_frontier", ("fov",), 4)]
  assert [r.config.planner.settings for r in resolved[:2]] == [ProbeSettings(1), ProbeSettings(3)]
  assert resolved[0].config != resolved[1].config  # two compiled programs
  with pytest.raises(ConfigError, match="plan_increment must be an integer, got 2.5"):
    resolve(RunSpec(world=box_world(30, 40), planner=probe, planner_params={"plan_increment": 2.5}))
  with pytest.raises(ConfigError, match="plan_increment fixes the compiled program"):
    schedule.resolve_group(spec, dataclasses.replace(
        made.groups[0], rows=made.groups[0].rows + made.groups[1].rows), None, grids)


def test_the_summary_warns_when_loop_closures_were_dropped():
  episodes = pd.DataFrame({"reason": ["complete", "timeout", "complete"], "time_s": [1.0, 2.0, 3.0],
                           "loops_dropped": [0, 12, 30]})
  text = results.summary_table(episodes)
  assert "loop list filled up for 2 of 3 robots" in text and "max 30" in text
  assert "--graph-loops" in text
  assert "warning" not in results.summary_table(episodes.assign(loops_dropped=0))
  assert "warning" not in results.summary_table(episodes.drop(columns="loops_dropped"))


def test_the_summary_warns_when_a_robots_slam_lost_track():
  episodes = pd.DataFrame({"reason": ["complete", "exhausted", "exhausted"],
                           "ate_m": [0.04, 15.8, 1.2]})
  text = results.summary_table(episodes)
  assert "SLAM lost track on 2 of 3 robots" in text and "worst 15.8 m" in text
  assert "lost track" not in results.summary_table(episodes.assign(ate_m=[0.04, 0.9, 1.0]))
  # the oracle's rows have no ATE (NaN) and no such column at all
  assert "lost track" not in results.summary_table(episodes.assign(ate_m=float("nan")))
  assert "lost track" not in results.summary_table(episodes.drop(columns="ate_m"))
