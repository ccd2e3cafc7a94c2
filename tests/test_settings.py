"""Every setting declared once (jaxplore.settings): the declarations, the checks derived from
them, and the listing and documentation page made from them."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from jaxplore import cli
from jaxplore.config import (PARAM_SETTINGS, STATIC_SETTINGS, ConfigError, Params, SimConfig,
                             validate_params)
from jaxplore.planners import get_planner, planner_names
from jaxplore.settings import Setting, declared, setting

DOCS = Path(__file__).resolve().parents[1] / "docs" / "settings.md"


def test_a_setting_checks_its_range_bounds_whole_numbers_and_words():
  open_unit = Setting(0.5, "p", owner="x", low=0.0, low_open=True, high=1.0, high_open=True,
                      name="p")
  assert open_unit.range_text == "in (0, 1)"
  for bad in (0.0, 1.0, math.nan, math.inf, "0.5", True):
    with pytest.raises(ConfigError, match="parameter p "):
      open_unit.check(bad)
  open_unit.check(np.array([0.1, 0.9]))
  with pytest.raises(ConfigError, match=r"must be in \(0, 1\), got 1.5, 2$"):
    open_unit.check(np.array([0.1, 1.5, 2.0, 2.0]))  # the bad values named, once each
  turn = Setting(1.0, "t", owner="x", low=0.0, high=math.pi, name="t")
  assert turn.range_text == "in [0, π]"
  turn.check(np.float32(math.pi))  # float32 π lies above float64 π
  with pytest.raises(ConfigError):
    turn.check(3.2)
  count = Setting(3, "n", owner="x", low=1, integer=True, name="n")
  assert count.convert(4.0) == 4 and isinstance(count.convert(4.0), int)
  with pytest.raises(ConfigError, match="must be a positive integer, got 2.5"):
    count.convert(2.5)
  word = Setting("a", "w", owner="x", choices=("a", "b"), name="w")
  assert word.convert("b") == "b" and word.range_text == "one of a, b"
  with pytest.raises(ConfigError, match="w must be one of a, b, got 'c'"):
    word.check("c", "w")
  with pytest.raises(TypeError):
    setting(1.0, "both lower bounds", owner="x", gt=0, ge=0)


def test_every_simulator_parameter_is_declared_with_its_default_and_help():
  """Params' fields are exactly its declarations (the planner's weights aside), each with help,
  an owner and a default inside its own range; the same for SimConfig's named settings."""
  fields = [f.name for f in dataclasses.fields(Params) if f.name != "planner"]
  assert list(PARAM_SETTINGS) == fields
  defaults = Params()
  for name, s in {**PARAM_SETTINGS, **STATIC_SETTINGS}.items():
    assert s.name == name and s.help and s.owner, name
    s.check(s.default)
  for name, s in PARAM_SETTINGS.items():
    assert getattr(defaults, name) == s.default and not s.static
  assert all(s.static for s in STATIC_SETTINGS.values())
  assert declared(SimConfig) == STATIC_SETTINGS


def _just_outside(s: Setting) -> float | None:
  if s.low is not None:
    return s.low if s.low_open else s.low - 0.5 * max(abs(s.low), 1e-3)
  if s.high is not None:
    return s.high if s.high_open else s.high + 0.5 * max(abs(s.high), 1e-3)
  return None


def test_validation_is_derived_from_the_declarations():
  """For every bounded traced parameter, a value at an open bound or past a closed one is
  refused by validate_params naming it, whatever its neighbours; NaN too."""
  config = SimConfig(height=50, width=50, res=0.1, max_range_cells=200)
  base = Params(r_max=2.0, dt=0.4)
  validate_params(base, config)
  checked = 0
  for name, s in PARAM_SETTINGS.items():
    value = _just_outside(s)
    if value is None:
      continue
    checked += 1
    with pytest.raises(ConfigError, match=f"parameter {name} "):
      validate_params(base.replace(**{name: value}), config)
    with pytest.raises(ConfigError, match=f"parameter {name} is NaN"):
      validate_params(base.replace(**{name: math.nan}), config)
  assert checked == len(PARAM_SETTINGS)  # every traced parameter has a range


def test_static_settings_are_converted_and_checked_on_construction():
  config = SimConfig(height=8, width=8, res=0.1, slam_steps=3.0, slam_smear=1)
  assert config.slam_steps == 3 and isinstance(config.slam_steps, int)
  assert config.slam_smear == 1.0 and isinstance(config.slam_smear, float)
  with pytest.raises(ConfigError, match="slam_steps must be a positive integer, got 2.5"):
    SimConfig(height=8, width=8, res=0.1, slam_steps=2.5)
  with pytest.raises(ConfigError, match="loop_smear must be > 0, got 0"):
    SimConfig(height=8, width=8, res=0.1, loop_smear=0.0)


def test_the_listing_names_every_setting_and_the_docs_page_is_current(capsys):
  """``jaxplore settings`` lists the simulator's settings (and with --planner a planner's);
  docs/settings.md is that listing as Markdown, regenerated with
  ``jaxplore settings --planner all --markdown > docs/settings.md``."""
  assert cli.main(["settings"]) == 0
  text = capsys.readouterr().out
  for name in [*PARAM_SETTINGS, *STATIC_SETTINGS]:
    assert f"  {name} " in text, name
  assert cli.main(["settings", "--planner", "li2020", "k1", "region"]) == 0
  lines = capsys.readouterr().out.splitlines()
  assert lines[0] == "planner li2020:" and len(lines) == 3
  assert "static" in lines[2] and "visible" in lines[2]
  page = cli.settings_listing(("all",), markdown=True)
  for planner in planner_names():
    names = [s.name for s in get_planner(planner).declared_settings()]
    assert all(f"| `{n}` |" in page for n in names)
  assert DOCS.read_text() == page, "regenerate docs/settings.md (see this test's docstring)"


def test_run_settings_are_flags_toml_keys_and_set_names_from_one_declaration(tmp_path):
  """A run setting (RunSpec's declared fields) is a flag of ``jaxplore run`` and ``sweep`` with
  its declaration's type, choices and help, a TOML key checked by the declaration, and a name
  ``--set`` takes; given twice with two values it is refused."""
  from jaxplore.runspec import RUN_SETTINGS, SHARED, RunSpec, load_run_config
  parser = cli.build_parser()
  run_help = parser.parse_known_args(["run"])[0]
  for name, s in RUN_SETTINGS.items():
    flag = "--" + name.replace("_", "-")
    assert hasattr(run_help, name), flag
    assert s.help and s.owner == "run"
    if name in SHARED:
      assert hasattr(parser.parse_known_args(["sweep"])[0], name), flag
  args = parser.parse_args(["run", "--max-steps", "40", "--strategy", "lockstep", "--pose-noise"])
  assert (args.max_steps, args.strategy, args.pose_noise) == (40, "lockstep", True)
  with pytest.raises(SystemExit):
    parser.parse_args(["run", "--strategy", "sideways"])
  path = tmp_path / "run.toml"
  path.write_text("max_steps = 40.0\npose_noise = true\n[set]\nreplan_every = 4\nr_max = 2\n")
  spec = RunSpec.create(**{k: v for k, v in load_run_config(path).items() if k != "out"})
  assert (spec.max_steps, spec.pose_noise, spec.replan_every, dict(spec.params)) == (
      40, True, 4, {"r_max": 2.0})
  path.write_text("max_steps = 0\n")
  with pytest.raises(ConfigError, match="run.toml: max_steps must be a positive integer, got 0"):
    load_run_config(path)
  with pytest.raises(ConfigError, match="max_steps is given twice"):
    RunSpec.create(max_steps=30, params={"max_steps": 40})
