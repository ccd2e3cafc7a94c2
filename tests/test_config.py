"""Static configuration: the execution strategy and its automatic default."""

import dataclasses

import jax
import pytest

from jaxplore.config import STRATEGIES, ConfigError, SimConfig, resolve_strategy


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
