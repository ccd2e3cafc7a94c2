"""Li's effective radius R_e from the lidar (Eq 5-6), and li2020 deriving it in config_for; the
execution strategy, its automatic default and the planner being told it."""

import dataclasses
import math

import jax
import numpy as np
import pytest

from jaxplore.config import (STRATEGIES, ConfigError, SimConfig, config_for, make_params,
                             resolve_strategy)
from jaxplore.planners import get_planner
from jaxplore.planners.li2020 import LI2020, Settings, effective_radius


def eq6_by_search(spacing, beam_step):
  """The largest D with S_dpi(D) = 1 / (D·tan θ) > dpi_min = 1 / spacing, by bisection on Eq 5."""
  lo, hi = 0.0, 1e4
  for _ in range(200):
    mid = 0.5 * (lo + hi)
    lo, hi = (mid, hi) if 1.0 / (mid * math.tan(beam_step)) > 1.0 / spacing else (lo, mid)
  return lo


def test_effective_radius_is_eq6s_largest_distance():
  li_step = math.radians(190) / 189  # Li's simulated 15 m / 190° laser, 190 beams
  for res in (0.05, 0.1, 0.2):
    np.testing.assert_allclose(effective_radius(res, math.radians(190), 190),
                               eq6_by_search(res, li_step), rtol=1e-9)
  # Li's Table 1 maps are 0.05 m/cell: R_e ≈ 2.85 m; on this project's 0.1 m maps ≈ 5.70 m.
  assert effective_radius(0.05, math.radians(190), 190) == pytest.approx(2.849, abs=1e-3)
  assert effective_radius(0.1, math.radians(190), 190) == pytest.approx(5.698, abs=1e-3)
  # a full circle does not repeat its first beam: 360 beams are 1° apart
  np.testing.assert_allclose(effective_radius(0.1, 2 * math.pi, 360),
                             eq6_by_search(0.1, math.radians(1.0)), rtol=1e-9)
  # dpi_min: 20 beams per metre = one beam per 0.05 m
  assert effective_radius(0.1, math.radians(190), 190, dpi_min=20.0) == pytest.approx(2.849, abs=1e-3)
  with pytest.raises(ConfigError):
    effective_radius(0.1, math.radians(190), 1)


def li_settings(shape, res, params, preset="li2020", **given):
  """li2020's settings as config_for sizes them, ``given`` the user's."""
  planner = LI2020.with_settings(**given) if given else "li2020"
  return config_for(shape, res, params, preset=preset, planner=planner,
                    planner_given=tuple(given)).planner.settings


def test_config_for_has_li2020_derive_r_e_from_the_preset_unless_given():
  params = make_params("li2020", res=0.1)
  derived = li_settings((50, 60), 0.1, params)
  assert derived.r_e == pytest.approx(5.698, abs=1e-3)
  assert derived.max_update_radius_cells == math.ceil(1.5 * derived.r_e / 0.1 - 1e-6)
  # On a coarse grid Eq 6 would reach past the lidar: R_e stops at its range.
  assert effective_radius(0.5, math.radians(190), 190) > float(params.r_max)
  coarse = li_settings((50, 60), 0.5, make_params("li2020", res=0.5))
  assert coarse.r_e == pytest.approx(float(params.r_max))
  assert li_settings((50, 60), 0.1, params, dpi_min=1e-30).r_e == pytest.approx(float(params.r_max))
  assert li_settings((50, 60), 0.1, params, r_e=0.75).r_e == 0.75  # given, though the default
  assert li_settings((50, 60), 0.1, params, dpi_min=20.0).r_e == pytest.approx(2.849, abs=1e-3)
  assert li_settings((50, 60), 0.1, params, preset=None).r_e == Settings().r_e  # no preset
  bound = li_settings((50, 60), 0.1, make_params("li2020", res=0.1, planner={"alpha": 2.0}),
                      max_update_radius_cells=200)
  assert bound.max_update_radius_cells == 200  # given: kept
  # Other planners have nothing sized: the config holds the registered object.
  assert config_for((50, 60), 0.1, params, preset="li2020").planner is get_planner(
      "nearest_frontier")


def test_auto_strategy_is_per_robot_on_cpu_and_lockstep_on_accelerators():
  assert resolve_strategy("auto", backend="cpu") == "per_robot"
  assert resolve_strategy("auto", backend="gpu") == "lockstep"
  assert resolve_strategy("auto", backend="tpu") == "lockstep"
  for forced in ("per_robot", "lockstep"):
    assert resolve_strategy(forced, backend="cpu") == resolve_strategy(forced, backend="gpu") == forced


def test_sim_config_resolves_auto_on_construction_and_refuses_unknown_strategies():
  config = SimConfig(height=8, width=8, res=0.1)
  assert config.strategy == resolve_strategy("auto", jax.default_backend())
  assert config.strategy in STRATEGIES and config.strategy != "auto"
  # "auto" and what it stands for here are one static setting: one jit cache entry.
  assert config == dataclasses.replace(config, strategy=config.strategy)
  assert dataclasses.replace(config, strategy="lockstep").strategy == "lockstep"
  with pytest.raises(ConfigError, match="strategy must be one of"):
    SimConfig(height=8, width=8, res=0.1, strategy="gpu")


@pytest.mark.parametrize("overrides, static, match", [
    ({"r_max": 1e6}, {}, "r_max: r_max = 1e[+]06 m sizes the lidar"),
    ({"r_robot": 1e3}, {}, "r_robot: r_robot = 1000 m"),
    ({"loop_radius": 1e9}, {}, "loop_radius"),
    ({"planner": {"alpha": 1e9}}, {}, "alpha: R_u = alpha [*] r_e"),
    ({"r_max": float("nan")}, {}, "r_max is NaN or infinite"),
    ({"r_robot": float("inf")}, {}, "r_robot is NaN or infinite"),
    ({"planner": {"alpha": float("nan")}}, {}, "alpha is NaN or infinite"),
    ({}, {"r_e": float("nan")}, "setting r_e must be finite"),
    ({}, {"r_e": 1e6}, "r_e: r_e = 1e[+]06 m"),
])
def test_lengths_that_size_buffers_are_refused_by_name_before_any_size(overrides, static, match):
  params = make_params("li2020", res=0.1, **overrides)
  with pytest.raises(ConfigError, match=match):
    li_settings((130, 170), 0.1, params, **static)


def test_a_refusal_names_each_bad_value_of_a_batch_once():
  """One value per robot (a sweep's batch): the refusal lists the distinct bad values only."""
  from jaxplore import sim
  from jaxplore.config import validate_params
  from jaxplore.errors import shown
  params = sim.broadcast_params(make_params("li2020", res=0.1), 6)
  config = config_for((130, 170), 0.1, make_params("li2020", res=0.1))
  bad = params.replace(v_max=np.asarray([0.5, -1.0, -1.0, 0.5, -2.0, -1.0], np.float32))
  with pytest.raises(ConfigError, match=r"parameter v_max must be > 0, got -2, -1$"):
    validate_params(bad, config)
  assert shown(np.arange(7.0)) == "0, 1, 2, 3 (and 3 more)"
  assert shown(np.float32(0.25)) == "0.25"


def test_length_limit_is_the_maps_diagonal_or_100_m():
  # a preset's 15 m lidar on a map smaller than its range is fine; on a 1 km map so is 1 km
  assert config_for((3, 3), 0.1, make_params("li2020", res=0.1)).max_range_cells == 150
  big = config_for((1000, 1000), 1.0, make_params("li2020", res=1.0, r_max=1000.0))
  assert big.max_range_cells == 1000
  with pytest.raises(ConfigError, match="at most the map's diagonal or 100 m"):
    config_for((3, 3), 0.1, make_params("li2020", res=0.1, r_max=100.5))


def test_the_planner_is_told_the_strategy_the_engine_runs():
  """A planner may shape its kernels by the strategy (li2020's visible-gain blocks): the
  context the engine builds carries it, for the whole grid and for a window."""
  from jaxplore.robot import planner_context
  for strategy in ("per_robot", "lockstep"):
    config = SimConfig(height=40, width=50, res=0.1, strategy=strategy)
    assert planner_context(config).strategy == strategy
    assert planner_context(config, (16, 16)).strategy == strategy
