"""The run specification: one set of defaults, checks before any compute, the JSON edge, and every
setting reachable from ``run``, ``sweep``, their command lines and TOML files alike."""

import dataclasses
import textwrap
import types

import pytest

from jaxplore import cli, runner, sweeps
from jaxplore.config import ConfigError
from jaxplore.resolve import split_planner_params
from jaxplore.runspec import (FIELDS, RUN_TOML_KEYS, SHARED, RunSpec, is_static, kind_of,
                              load_run_config, merge_settings)
from jaxplore.sweeps import schedule, settings

FLAG_OF = {"params": "set", "planner_params": "planner_set"}  # the command line's table flags


def test_create_takes_none_as_the_default_and_json_round_trips():
  assert RunSpec.create(world=None, robots=None, preset=None) == RunSpec()
  spec = RunSpec.create(world="lab", robots=3, start="1,2", params={"alpha": 1.5},
                        planner_params={"k1": (0.1, 0.2, 0.3)}, planner="li2020")
  assert spec.start == (1.0, 2.0, 0.0) and spec.planner_params["alpha"] == 1.5  # li2020's
  assert RunSpec.from_json(spec.to_json()) == spec
  assert RunSpec.create(robot_seeds=[4, 9]).robots == 2  # one robot per seed
  with pytest.raises(dataclasses.FrozenInstanceError):
    spec.robots = 4


@pytest.mark.parametrize("settings, match", [
    (dict(seed=2**32), r"seed must be an integer in \[0, 2\*\*32\)"),
    (dict(seed=-1), "seed must be"),
    (dict(seed=2**64), "seed must be"),
    (dict(robot_seeds=[0, 2**32]), "robot seed must be"),
    (dict(robots=2, robot_seeds=[1, 2, 3]), "3 seeds for 2 robots"),
    (dict(robots=0), "robots must be a positive integer"),
    (dict(params={"r_max": float("nan")}), "r_max.*finite"),
    (dict(params={"warp": 1.0}), "unknown parameter.*warp"),
    (dict(params={"sigma_d": 1.0}), "'sigma_d' was removed: .* set 'odom_noise_d'"),
    (dict(robots=2, params={"r_max": (1.0, 2.0, 3.0)}), "r_max has 3 values for 2 robots"),
    (dict(plan_window=-8), "plan_window"),
    (dict(preset="hubble"), "preset must be one of li2020, .*, got 'hubble'"),
    (dict(start="abc"), "start must be"),
    (dict(max_steps=0), "max_steps must be a positive integer"),
    (dict(rate_interval=0.0), "rate_interval"),
    (dict(robotz=3), r"unknown setting\(s\) \['robotz'\]"),
])
def test_bad_settings_are_refused_naming_them(settings, match):
  with pytest.raises(ConfigError, match=match):
    RunSpec.create(**settings)


def test_a_setting_is_named_without_saying_whose_it_is(capsys):
  """A planner's weight or word-valued setting among the simulator's parameters (``--set``), or
  a simulator parameter among the planner's, goes where it belongs; a name given to both, or to
  nobody, is refused naming it."""
  spec = RunSpec.create(planner="li2020", params={"k1": 0.2, "region": "disc", "r_max": 5.0,
                                                 "alpha": 2.0, "r_e": 1.0},
                        planner_params={"v_max": 0.3})
  # (and li2020's own SLAM model: test_an_active_slam_planner_brings_...)
  assert dict(spec.params) == {"r_max": 5.0, "v_max": 0.3, "slam": "scan_matching"}
  assert dict(spec.planner_params) == {"k1": 0.2, "region": "disc", "alpha": 2.0, "r_e": 1.0}
  same = RunSpec.create(planner="li2020", params={"r_max": 5.0, "v_max": 0.3},
                        planner_params={"k1": 0.2, "region": "disc", "alpha": 2.0, "r_e": 1.0})
  assert spec == same
  # Li's entropy map is li2020's: another planner has no alpha, and is told whose it is.
  with pytest.raises(ConfigError, match=r"unknown parameter\(s\) \['alpha'\].*of planner "
                     r"'nearest_frontier': none.*alpha: planner li2020's"):
    RunSpec.create(planner="nearest_frontier", params={"alpha": 2.0})
  with pytest.raises(ConfigError, match="k1 is given twice"):
    RunSpec.create(planner="li2020", params={"k1": 0.2}, planner_params={"k1": 0.3})
  with pytest.raises(ConfigError, match=r"unknown parameter.*warp'\]; valid: .*; of planner "
                     r"'li2020': alpha, det_sigma_max, .*region.* \(jaxplore settings --planner li2020"):
    RunSpec.create(planner="li2020", params={"warp": 1.0})
  with pytest.raises(ConfigError, match=r"no parameter\(s\) \['r_max'\].*r_max: the simulator's"):
    split_planner_params("nearest_frontier", {"r_max": 5.0})  # RunSpec(...) does not reroute
  assert cli.main(["settings", "warp"]) == 2
  assert "no setting(s) ['warp']" in capsys.readouterr().err


def test_kinds_of_names_route_weights_and_static_settings():
  @dataclasses.dataclass(frozen=True)
  class Knobs:
    nodes: int = 64

  planner = types.SimpleNamespace(defaults={"k1": 0.0}, settings=Knobs())
  assert [kind_of(n, planner) for n in ("r_max", "slam", "k1", "nodes", "gamma")] == [
      "param", "static", "weight", "setting", None]
  assert is_static("slam", planner) and is_static("nodes", planner)
  assert not is_static("r_max", planner) and not is_static("k1", planner)
  bare = types.SimpleNamespace(defaults={})  # a planner with no static settings
  assert kind_of("nodes", bare) is None


def test_every_run_setting_is_a_flag_and_a_toml_key_of_run_and_sweep():
  parser = cli.build_parser()
  subparsers = next(a for a in parser._actions if a.dest == "command").choices
  run_flags = {a.dest for a in subparsers["run"]._actions}
  sweep_flags = {a.dest for a in subparsers["sweep"]._actions}
  for name in FIELDS:
    assert FLAG_OF.get(name, name) in run_flags, name
    assert FLAG_OF.get(name, name) in RUN_TOML_KEYS, name
  for name in SHARED:  # every row of a sweep shares these
    assert FLAG_OF.get(name, name) in sweep_flags, name
    assert FLAG_OF.get(name, name) in settings.SWEEP_TOML_KEYS, name
    assert name in sweeps.RUN_KEYS, name
  # the rest are the sweep's axes: worlds, planners and seeds (one robot per row)
  assert set(FIELDS) - set(SHARED) == {"world", "planner", "robots", "seed", "robot_seeds"}
  assert {"world", "planner", "seeds"} <= sweep_flags


def test_run_config_file_and_flags(tmp_path, monkeypatch):
  toml = tmp_path / "run.toml"
  toml.write_text(textwrap.dedent("""
      world = "lab"
      planner = "li2020"
      robot_seeds = [3, 5]
      plan_window = 0
      rate_interval = 2.0
      chunk_epochs = 4
      [set]
      r_max = 4.0
      [planner_set]
      k1 = 0.1
  """))
  assert load_run_config(toml)["robot_seeds"] == [3, 5]
  seen = {}
  monkeypatch.setattr(runner, "run", lambda **kwargs: seen.update(kwargs) or 1 / 0)
  with pytest.raises(ZeroDivisionError):  # stop once the settings reached jaxplore.run
    cli.main(["run", "--config", str(toml), "--max-steps", "9", "--k2", "0.8", "--set",
              "alpha=1.25", "--devices", "1", "--no-progress"])
  assert seen["world"] == "lab" and seen["robot_seeds"] == [3, 5] and seen["plan_window"] == 0
  assert seen["max_steps"] == 9 and seen["rate_interval"] == 2.0 and seen["chunk_epochs"] == 4
  assert seen["params"] == {"r_max": 4.0, "alpha": 1.25}
  assert seen["planner_params"] == {"k1": 0.1, "k2": 0.8}
  spec = RunSpec.create(**{k: v for k, v in seen.items()
                           if k not in ("out", "devices", "progress")})
  assert spec.robots == 2 and spec.plan_window == 0
  bad = tmp_path / "bad.toml"
  bad.write_text("grid = 3\n")
  with pytest.raises(ConfigError, match="unknown key 'grid'"):
    load_run_config(bad)


def test_sweep_takes_the_run_settings_on_its_command_line(monkeypatch):
  seen = {}
  monkeypatch.setattr(sweeps, "sweep", lambda **kwargs: seen.update(kwargs) or 1 / 0)
  with pytest.raises(ZeroDivisionError):
    cli.main(["sweep", "--planner", "li2020", "nearest_frontier", "--plan-window", "0",
              "--path-capacity", "64", "--start", "1,1", "--rate-interval", "0.5", "--alpha", "1.5",
              "--k1", "0.2", "--chunk-epochs", "2", "--devices", "1", "--no-progress"])
  assert seen["plan_window"] == 0 and seen["path_capacity"] == 64 and seen["start"] == "1,1"
  assert seen["rate_interval"] == 0.5 and seen["chunk_epochs"] == 2
  assert not seen["params"] and seen["planner_params"] == {"alpha": 1.5, "k1": 0.2}


def test_a_sweeps_plan_window_reaches_its_static_config():
  spec = sweeps.make_spec({"fov": [3.0, 6.0]}, None, None, 0, [0], "open", "nearest_frontier",
                          RunSpec(res=0.5, max_steps=30, plan_window=24))
  made, resolved = schedule.make_schedule(spec, None, {}, None, 1)
  assert made.groups[0].sim_config["plan_window"] == 24 and resolved[0].config.plan_window == 24
  auto = dataclasses.replace(spec, base=RunSpec(res=0.5, max_steps=30))  # too big a window: off
  assert schedule.make_schedule(auto, None, {}, None, 1)[0].groups[0].sim_config["plan_window"] == 0


def test_merge_gives_explicit_values_precedence_and_merges_tables():
  merged = merge_settings({"res": 0.2, "params": {"alpha": 1.0, "r_max": 3.0}, "out": "a"},
                          {"res": None, "params": {"alpha": 2.0}, "out": "b"})
  assert merged == {"res": 0.2, "params": {"alpha": 2.0, "r_max": 3.0}, "out": "b"}


def test_shape_settings_are_refused_naming_them_before_compute(capsys):
  from jaxplore import cli
  base = ["run", "--world", "open", "--res", "0.5", "--robots", "1", "--no-progress"]
  for flags, match in ((["--set", "r_max=1e6"], "parameter r_max"),
                       (["--path-capacity", "1000000000"], "path_capacity 1000000000 is more "
                        "waypoints than the 40x40 grid has cells"),
                       (["--max-steps", "100000000000"], "mostly for the per-step records of "
                        "max_steps=100000000000"),
                       (["--start", "abc"], "start must be"), (["--alpha", "nan"], "alpha")):
    assert cli.main(base + flags) == 2, flags
    err = capsys.readouterr().err
    assert err.startswith("jaxplore: error: ") and match in err, err


def test_a_planners_text_setting_is_reachable_from_flags_toml_and_the_api(tmp_path, monkeypatch):
  """li2020's ``region`` and ``eq21`` are words: ``--planner-set region=disc``, ``--region disc``
  and a TOML ``[planner_set]`` reach the planner's settings; a word for a weight, a simulator
  parameter or a numeric setting is refused naming it."""
  from jaxplore.resolve import resolve
  seen = {}
  monkeypatch.setattr(runner, "run", lambda **kwargs: seen.update(kwargs) or 1 / 0)
  toml = tmp_path / "run.toml"
  toml.write_text('[planner_set]\neq21 = "cell"\n')
  with pytest.raises(ZeroDivisionError):  # stop once the settings reached jaxplore.run
    cli.main(["run", "--planner", "li2020", "--config", str(toml), "--planner-set", "region=disc",
              "--k1", "0.1", "--devices", "1", "--no-progress"])
  assert seen["planner_params"] == {"eq21": "cell", "region": "disc", "k1": 0.1}
  seen.clear()
  with pytest.raises(ZeroDivisionError):
    cli.main(["run", "--planner", "li2020", "--region", "disc", "--devices", "1", "--no-progress"])
  assert seen["planner_params"] == {"region": "disc"}
  settings = resolve(RunSpec(world="lab", planner="li2020", robots=1, max_steps=5,
                             planner_params={"region": "disc", "eq21": "cell"})).config.planner
  settings = settings.settings
  assert (settings.region, settings.eq21) == ("disc", "cell")
  for planner_params, match in [({"k1": "abc"}, "weight k1 must be a number, got 'abc'"),
                                ({"region": "wall"}, "region must be one of beams, visible, disc"),
                                ({"road_mark_m": "far"}, "setting road_mark_m must be a float")]:
    with pytest.raises(ConfigError, match=match):
      resolve(RunSpec(world="lab", planner="li2020", robots=1, max_steps=5,
                      planner_params=planner_params))
  with pytest.raises(ConfigError, match=r"params\['r_max'\] must be a number"):
    RunSpec(params={"r_max": "high"})
  with pytest.raises(ConfigError, match=r"planner 'li2020': weight alpha must be a number"):
    resolve(RunSpec.create(planner="li2020", params={"alpha": "high"}))
  assert cli.main(["run", "--planner", "li2020", "--alpha", "high", "--no-progress"]) == 2


def test_a_planner_brings_its_papers_preset_unless_one_is_named():
  """``--planner ereg`` with no preset was refused (the default lidar is longer than REG's LSR
  radius); the REG family now runs with Toriz's preset unless the user names another."""
  assert RunSpec.create(planner="ereg").preset == "toriz"
  assert RunSpec.create(planner="srt", preset="godoy_office").preset == "godoy_office"
  assert RunSpec.create(planner="nearest_frontier").preset == RunSpec.preset == "li2020"
  assert RunSpec.create(planner="no_such_planner").preset == "li2020"  # refused later, by name
  from jaxplore.sweeps import _planners_preset
  assert _planners_preset(["ereg", "reg"]) == "toriz" and _planners_preset("srg") == "toriz"
  assert _planners_preset(["ereg", "li2020"]) is None and _planners_preset(None) is None


def test_an_active_slam_planner_brings_the_scan_matching_model_unless_one_is_named():
  """The papers of li2020, ahmed/ags and the REG family are about active SLAM: their authors ran
  Karto or slam_toolbox, so the planners run on ``scan_matching`` unless told otherwise; a sweep
  of planners from different papers runs them all on the project's default, on equal terms."""
  assert RunSpec.create(planner="ahmed").params["slam"] == "scan_matching"
  for name in ("li2020", "ags", "ereg", "reg", "srg", "srt"):
    assert RunSpec.create(planner=name).params["slam"] == "scan_matching", name
  assert RunSpec.create(planner="ahmed", slam="oracle").params["slam"] == "oracle"
  assert RunSpec.create(planner="li2020", params={"slam": "oracle"}).params["slam"] == "oracle"
  for name in ("nearest_frontier", "fd", "frt", "ig", "gpbo", "no_such_planner"):
    assert "slam" not in RunSpec.create(planner=name).params, name
  from jaxplore.resolve import resolve
  assert resolve(RunSpec.create(world="lab", planner="ags", robots=1)).config.slam == \
      "scan_matching"
  assert resolve(RunSpec.create(world="lab", planner="ags", robots=1,
                                slam="oracle")).config.slam == "oracle"
  from jaxplore.sweeps import _planners_slam
  assert _planners_slam(["ereg", "ahmed"]) == "scan_matching"
  assert _planners_slam(["ereg", "nearest_frontier"]) is None and _planners_slam(None) is None


def test_the_default_budget_follows_the_walls_of_a_cluttered_map():
  """The default step budget: the longer of three sweeps of the free area and 1.5 times the
  wall faces' length (counted here cell by cell), over the step length, plus 1000."""
  from conftest import box_world
  from jaxplore.config import make_params
  from jaxplore.resolve import default_max_steps
  pillars = tuple((r, r + 1, c, c + 1) for r in range(3, 37, 3) for c in range(3, 57, 3))
  params = make_params("li2020", res=0.1)
  step_m = float(params.v_max) * float(params.dt)
  for grid in (box_world(40, 60), box_world(40, 60, walls=pillars)):
    occupied = grid.occupied
    faces = sum(occupied[i, j] != occupied[i + di, j + dj]
                for i in range(40) for j in range(60) for di, dj in ((1, 0), (0, 1))
                if i + di < 40 and j + dj < 60) * grid.res
    area = 3.0 * grid.free_area / 6.0
    assert default_max_steps(grid, params) == int(max(area, 1.5 * faces) / step_m) + 1000
  assert 1.5 * faces > area  # the pillars' walls set the cluttered room's budget
