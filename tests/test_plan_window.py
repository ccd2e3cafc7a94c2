"""Planning on a window around the robot (sim.plan_where_needed with SimConfig.plan_window).

The oracle is the same planner on the whole grid: a certified window plan must have the whole
grid's nearest-frontier cost, and a window that cannot certify must hand over to the whole grid.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import frontiers, planning, sim
from jaxplore.config import auto_plan_window, config_for, make_params, plan_reach_cells
from jaxplore.maps import generate
from jaxplore.planners import base

ROBOTS = 8
WINDOW = 64


@pytest.fixture(scope="module")
def explored():
  """Robots part-way through an office with a 1.5 m lidar (planned on the whole grid)."""
  grid = generate.office(24.0, 16.0, 0.1, seed=3)
  params = make_params("li2020", res=grid.res, r_max=1.5, fov=2 * np.pi)
  config = config_for(grid.shape, grid.res, params, max_steps=400, replan_every=4, plan_window=0)
  world = sim.make_world(grid, float(params.r_robot))
  params = sim.broadcast_params(params, ROBOTS)
  keys = jax.random.split(jax.random.PRNGKey(1), ROBOTS)
  states = sim.reset_batch(config, world, params, keys)
  states, _ = sim.advance(config, world, params, states, 12)
  return config, world, params, states


def full_and_window_plans(config, world, params, states, window):
  def both(p, s):
    robot = sim.robot_view(config, world, s)
    key = jax.random.PRNGKey(0)
    full = config.planner.plan(sim.planner_context(config),
                                                 sim.belief_view(config, p, s, robot.cell),
                                                 robot, p, key)
    origin = planning._window_origin(config, robot.cell, window)
    local, _, certified = planning._propose(config, p, sim.crop_maps(s, origin, (window, window)),
                                            robot, origin, key)
    view = sim.belief_view(config, p, s, robot.cell)
    node_cost = jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32)
    dist, _ = frontiers.reachable_paths(sim.planner_context(config), view, robot, node_cost)
    return full, local, certified, view, dist

  return jax.jit(jax.vmap(both))(params, states)


@pytest.mark.parametrize("planner", ["nearest_frontier", "fd"])
def test_certified_window_plans_cost_what_the_whole_grid_plan_costs(explored, planner):
  config, world, params, states = explored
  config = dataclasses.replace(config, planner=planner)
  full, local, certified, view, _ = jax.tree.map(np.asarray, full_and_window_plans(
      config, world, params, states, WINDOW))
  assert certified.sum() >= ROBOTS // 2  # the test must exercise certified plans
  for b in np.flatnonzero(certified):
    np.testing.assert_allclose(local.cost[b], full.cost[b], rtol=1e-5)
    goal = local.goal[b]
    assert view.frontier[b][goal[0], goal[1]] and not view.blacklist[b][goal[0], goal[1]]
    cells = local.waypoints[b][: local.length[b]]
    assert local.length[b] >= 1
    assert np.array_equal(cells[0], np.asarray(sim.cell_of(states.pose_est[b, :2], world.origin,
                                                           config.res)))  # starts at the robot
    assert np.all(np.abs(np.diff(cells, axis=0)).max(axis=1) == 1)  # 8-connected steps
    assert np.all(view.traversable[b][cells[1:, 0], cells[1:, 1]])
  # An uncertified plan never claims a cost below the distance bound it failed.
  assert np.all(~certified | local.valid)


def test_window_without_its_nearest_frontier_is_not_certified(explored):
  config, world, params, states = explored
  # Everything known and free except an unknown strip along the far right edge.
  cells = jax.vmap(lambda xy: sim.cell_of(xy, world.origin, config.res))(states.pose_est[:, :2])
  robot_col = np.asarray(cells)[:, 1]
  logodds = np.where(np.asarray(world.occupied), 3.0, -3.0).astype(np.float32)
  logodds[:, -3:] = 0.0
  states = states.replace(logodds=jnp.broadcast_to(logodds, states.logodds.shape))
  full, local, certified, _, _ = jax.tree.map(np.asarray, full_and_window_plans(
      config, world, params, states, WINDOW))
  far = config.width - 3 - robot_col > WINDOW
  assert far.any()
  assert not certified[far].any()
  assert full.valid[far].all()


def test_plan_where_needed_with_a_window_plans_like_the_whole_grid(explored):
  config, world, params, states = explored
  states = states.replace(busy=jnp.zeros_like(states.busy))  # everyone plans
  windowed = dataclasses.replace(config, plan_window=WINDOW)
  assert sim.uses_window(windowed) and not sim.uses_window(config)
  run = jax.jit(sim.plan_where_needed, static_argnums=0)
  with_window = jax.tree.map(np.asarray, run(windowed, world, params, states))
  whole = jax.tree.map(np.asarray, run(config, world, params, states))
  # Goals equally near on the whole grid (ties between frontiers may break either way).
  full, _, _, _, dist = jax.tree.map(np.asarray, full_and_window_plans(config, world, params, states,
                                                                       WINDOW))
  assert np.all(full.valid)
  for b in range(ROBOTS):
    goal = with_window.goal[b]
    np.testing.assert_allclose(dist[b][goal[0], goal[1]], full.cost[b], rtol=1e-5)
  np.testing.assert_array_equal(with_window.done, whole.done)
  np.testing.assert_array_equal(with_window.key, whole.key)


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
def test_episode_with_a_window_completes_like_the_whole_grid():
  grid = generate.office(14.0, 10.0, 0.1, seed=3)
  params = make_params("li2020", res=grid.res, r_max=1.5, fov=2 * np.pi)
  config = config_for(grid.shape, grid.res, params, max_steps=2000, replan_every=4)
  world = sim.make_world(grid, float(params.r_robot))
  params = sim.broadcast_params(params, 2)
  keys = jax.random.split(jax.random.PRNGKey(1), 2)
  steps = {}
  for window in (0, 48):
    state, _ = sim.rollout(dataclasses.replace(config, plan_window=window), world, params, keys)
    np.testing.assert_array_equal(state.reason, sim.COMPLETE)
    steps[window] = np.asarray(state.steps)
  np.testing.assert_allclose(steps[48], steps[0], rtol=0.1)


def test_auto_window_follows_the_sensor_range_up_to_the_plan_reach():
  assert plan_reach_cells(35, 0.1) == 35  # Explore-Bench: 3.5 m at 0.1 m
  assert plan_reach_cells(150, 0.1) == 35  # a 15 m lidar: capped at PLAN_REACH_M
  assert plan_reach_cells(75, 0.2) == 18
  assert auto_plan_window(250, 250, 35, 1) == 88  # Explore-Bench
  assert auto_plan_window(200, 200, 35, 2) == 96  # `open` with the li2020 preset
  assert auto_plan_window(130, 170, 35, 2) == 96  # `lab`: the window has 0.42 of its cells
  assert auto_plan_window(120, 120, 35, 2) == 0  # the window would have over half the grid
  assert auto_plan_window(160, 240, 15, 2) == 56
  params = make_params("li2020")
  assert config_for((200, 200), 0.1, params).plan_window == 96
  assert config_for((200, 200), 0.1, params.replace(r_max=2.0)).plan_window == 64
