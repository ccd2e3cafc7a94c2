"""The engine honours what a planner declares: per-robot memory carried between plans, goal
commitment, the per-step hook, static settings and their sizing; it keeps no map of a paper's.

A probe planner (nearest frontier that counts its plans in its memory, and whose step hook
counts the steps in which the robot moved), an object the tests hand the engine without
registering it.
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import sim
from jaxplore.config import ConfigError, config_for, make_params
from jaxplore.planners import base, frontier
from conftest import box_world

ROBOTS = 2


@dataclasses.dataclass(frozen=True)
class ProbeSettings:
  plan_increment: int = 1


def init_memory(ctx, params):
  return {"plans": jnp.int32(0), "moved": jnp.int32(0)}


def plan_probe(ctx, view, robot, params, key, memory):
  plan = frontier.plan_nearest_frontier(ctx, view, robot, params, key)
  return plan, dict(memory, plans=memory["plans"] + ctx.settings.plan_increment)


def count_moves(ctx, params, memory, robot, logodds, moved):
  return dict(memory, moved=memory["moved"] + moved.astype(jnp.int32))


# Planner objects, never registered: the engine is handed them, as a user's own planner.
PROBES = {name: base.planner(name, plan_probe, summary="test probe", settings=ProbeSettings(),
                             init_memory=init_memory, commits=commits, step_hook=count_moves)
          for name, commits in (("probe_commit", True), ("probe_replan", False))}


@functools.lru_cache(maxsize=None)
def rollout(planner, settings=ProbeSettings(), steps=48):
  grid = box_world(30, 40, walls=((0, 18, 20, 22),))
  params = make_params(res=grid.res, r_max=1.2, fov=2 * np.pi, r_robot=0.1)
  config = config_for(grid.shape, grid.res, params, max_steps=steps, replan_every=2, n_beams=72,
                      planner=PROBES[planner].with_settings(settings), plan_window=0)
  world = sim.make_world(grid, 0.1)
  params = sim.broadcast_params(params, ROBOTS)
  keys = jax.random.split(jax.random.PRNGKey(3), ROBOTS)
  state, _ = sim.rollout(config, world, params, keys)
  return jax.tree.map(np.asarray, state)


COMMITTED = ("probe_commit", ProbeSettings(plan_increment=3))


def test_memory_is_carried_and_the_step_hook_runs_every_moving_step():
  state = rollout(*COMMITTED)
  moved = state.steps - state.idle_steps + 1  # the reset's first scan counts as moving
  np.testing.assert_array_equal(state.memory["moved"], moved)
  assert (state.memory["plans"] >= 3).all()


def test_a_committed_planner_replans_only_when_its_path_is_done_or_blocked():
  committed, replanning = rollout(*COMMITTED), rollout("probe_replan")
  # A committed robot plans at reset's first step and after each idle step (arrival or block).
  assert (committed.memory["plans"] // 3 <= committed.idle_steps + 1).all()
  # The same robots replanning every 2 steps plan far more often than they stop.
  assert (replanning.memory["plans"] > replanning.idle_steps + 1).all()


def test_static_settings_reach_the_planner():
  state = rollout(*COMMITTED)  # each plan adds the setting's increment, 3 (1 by default)
  assert (state.memory["plans"] % 3 == 0).all() and (state.memory["plans"] > 0).all()


def test_settings_resolve_from_user_values_and_unknown_names_are_refused():
  spec = PROBES["probe_commit"]
  assert spec.resolve_settings({"plan_increment": "4"}) == ProbeSettings(plan_increment=4)
  assert spec.split_overrides({"plan_increment": 2}) == ({}, {"plan_increment": 2})
  with pytest.raises(ValueError, match="no parameter"):
    spec.split_overrides({"plan_incremnt": 2})
  with pytest.raises(ValueError, match="must be a int"):
    spec.resolve_settings({"plan_increment": "x"})


def test_a_planner_object_runs_without_being_registered():
  """A user's own planner object goes to the resolver as it is: its settings are resolved into a
  new object, the results name it, and nothing lists it under its name."""
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec
  resolved = resolve(RunSpec(world=box_world(30, 40), planner=PROBES["probe_commit"], robots=2,
                             max_steps=8, planner_params={"plan_increment": 2}))
  assert resolved.config.planner == PROBES["probe_commit"].with_settings(plan_increment=2)
  assert resolved.config.planner != PROBES["probe_commit"]
  assert hash(resolved.config.planner) == hash(PROBES["probe_commit"].with_settings(
      ProbeSettings(2)))
  assert resolved.describe()["sim_config"]["planner"] == "probe_commit"
  assert resolved.describe()["planner_settings"] == {"plan_increment": 2}
  assert "probe_commit" not in base.planner_names()
  with pytest.raises(ConfigError, match="unknown planner 'probe_commit'"):
    base.get_planner("probe_commit")


def test_li2020_keeps_its_entropy_map_in_its_memory_and_no_other_planner_has_one():
  grid = box_world(20, 24)
  world = sim.make_world(grid, 0.2)
  for planner, kept in (("nearest_frontier", False), ("li2020", True)):
    params = make_params(res=grid.res, r_max=1.0, planner=base.get_planner(planner).defaults)
    config = config_for(grid.shape, grid.res, params, max_steps=8, planner=planner)
    state = jax.eval_shape(lambda: sim.reset(config, world, params, jax.random.PRNGKey(0)))
    assert not hasattr(state, "entropy_map")
    memory = state.memory if isinstance(state.memory, dict) else {}
    assert ("entropy_map" in memory) == kept
    if kept:
      assert memory["entropy_map"].shape == grid.shape


def test_a_config_built_by_hand_gives_the_planner_its_registered_settings():
  """``config_for`` with a planner's name (not through the resolver): the config holds the
  registered planner object and the engine hands the planner its registered settings (reg and
  ahmed read them while tracing); another planner's settings, and a pose-graph planner without a
  graph, are refused by name."""
  grid = box_world(20, 24)
  params = make_params(res=grid.res, r_max=1.0)
  with_settings = [name for name in base.planner_names() if base.get_planner(name).settings]
  assert {"li2020", "gpbo", "reg", "ahmed"} <= set(with_settings)
  for name in base.planner_names():
    spec = base.get_planner(name)
    graph = {"graph_nodes": 16} if spec.needs_pose_graph else {}
    config = config_for(grid.shape, grid.res, params, max_steps=8, planner=name, **graph)
    if spec.size_settings is not None:  # li2020 sizes the bound of its update radius
      spec = spec.with_settings(spec.size_settings(spec.settings, frozenset(), config, params,
                                                   None))
      assert config.planner == spec
    else:
      assert config.planner is spec
    assert sim.planner_context(config).settings == spec.settings
    assert sim.planner_context(config, (8, 8)).settings == spec.settings
  ahmed_settings = base.get_planner("ahmed").settings
  with pytest.raises(ConfigError, match="'reg': settings must be a jaxplore.planners.reg"):
    base.get_planner("reg").with_settings(ahmed_settings)
  config = config_for(grid.shape, grid.res, params, max_steps=8, planner="ahmed")
  with pytest.raises(ConfigError, match="'ahmed' plans on the SLAM pose graph.*graph_nodes is 0"):
    sim.planner_context(config)
