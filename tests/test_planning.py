"""The planner's view of a belief (planning.belief_view): inflation and the escape route out of
it, against SciPy's distance transform and a plain breadth-first search."""

import dataclasses
from collections import deque

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from conftest import EAGER_AND_JIT, box_world
from jaxplore import mapping, sim
from jaxplore.config import SimConfig, config_for, make_params
from jaxplore.planners import base

FREE, OCCUPIED, UNKNOWN = -3.0, 3.0, 0.0


def escape_oracle(free, occupied, start, radius, steps):
  """Free cells within ``radius`` of a believed wall that a walk of at most ``steps`` 8-connected
  steps from ``start`` reaches, every step onto a cell no closer to the walls (SciPy distances)."""
  distance = ndimage.distance_transform_edt(~occupied)
  zone = free & (distance <= radius + 1e-6)
  reached = np.zeros_like(zone)
  if not zone[start]:
    return reached
  reached[start] = True
  queue = deque([(start, 0)])
  while queue:
    (i, j), depth = queue.popleft()
    if depth == steps:
      continue
    for di in (-1, 0, 1):
      for dj in (-1, 0, 1):
        n = (i + di, j + dj)
        if (0 <= n[0] < zone.shape[0] and 0 <= n[1] < zone.shape[1] and zone[n] and not reached[n]
            and distance[n] >= distance[i, j] - 1e-9):
          reached[n] = True
          queue.append((n, depth + 1))
  return reached


def belief_state(config, world, params, logodds, start_xy):
  state = sim.reset(config, world, params, jax.random.PRNGKey(0),
                    jnp.asarray([start_xy[0], start_xy[1], 0.0]))
  logodds = jnp.asarray(logodds, jnp.float32)
  return state.replace(logodds=logodds, entropy=jnp.sum(mapping.entropy_of_logodds(logodds)))


@EAGER_AND_JIT
def test_distance_sq_within_is_scipys_distance_and_gives_the_inflation(transform):
  rng = np.random.default_rng(3)
  mask = rng.random((19, 26)) < 0.07
  ours = np.asarray(transform(lambda m: mapping.distance_sq_within(m, 3))(jnp.asarray(mask)))
  reference = np.rint(ndimage.distance_transform_edt(~mask) ** 2)
  near = reference <= 9
  np.testing.assert_array_equal(ours[near], reference[near])
  assert np.all(ours[~near] > 9)
  for radius in (0.0, 1.0, 1.5, 2.2, 3.0):
    np.testing.assert_array_equal(
        ours <= radius * radius + 1e-6,
        np.asarray(mapping.inflate(jnp.asarray(mask), jnp.float32(radius), 3)))


@pytest.mark.parametrize("seed", [0, 1, 2])
@EAGER_AND_JIT
def test_escape_route_never_leads_closer_to_a_wall(transform, seed):
  # Random believed walls around a robot standing inside their inflation: the traversable cells
  # are the cells clear of the walls plus exactly the breadth-first oracle's escape route.
  rng = np.random.default_rng(seed)
  grid = box_world(24, 24, res=0.1)
  params = make_params(res=0.1, r_robot=0.3, r_max=0.5)
  config = config_for(grid.shape, grid.res, params, max_steps=4)
  world = sim.make_world(grid, 0.3, (1.2, 1.2))
  occupied = rng.random(grid.shape) < 0.06
  occupied[10:14, 10:14] = False
  occupied[10, 11] = True  # a wall 2.2 cells from the robot's cell (12, 12), inside its 3 cells
  logodds = np.where(occupied, OCCUPIED, FREE)
  logodds[rng.random(grid.shape) < 0.05] = UNKNOWN
  state = belief_state(config, world, params, logodds, (1.25, 1.25))
  cell = jnp.asarray([12, 12], jnp.int32)
  view = transform(lambda s, c: sim.belief_view(config, params, s, c))(state, cell)
  free, occupied = np.asarray(view.free), np.asarray(view.occupied)
  distance = ndimage.distance_transform_edt(~occupied)
  assert distance[12, 12] <= 3.0  # the robot stands in the inflated zone
  np.testing.assert_array_equal(np.asarray(view.inflated), distance <= 3.0 + 1e-6)
  escape = escape_oracle(free, occupied, (12, 12), 3.0, config.max_inflation_cells + 1)
  assert escape.sum() > 1
  np.testing.assert_array_equal(np.asarray(view.traversable),
                                (free & (distance > 3.0 + 1e-6)) | escape)


@pytest.mark.parametrize("cell", [(-1, 5), (5, -1)])
def test_a_robot_cell_off_the_grid_starts_no_escape_route(cell):
  """An estimate off the top or left edge (pose noise) puts the robot on no cell: there is no
  escape route, only the cells clear of the walls are traversable (a wrapped index started the
  route at the far edge's cell, here inside the inflation of a wall 3 cells from it)."""
  grid = box_world(24, 24, res=0.1)
  params = make_params(res=0.1, r_robot=0.3, r_max=0.5)
  config = config_for(grid.shape, grid.res, params, max_steps=4)
  world = sim.make_world(grid, 0.3, (1.2, 1.2))
  logodds = np.full(grid.shape, FREE)
  logodds[20, :] = logodds[:, 20] = OCCUPIED
  state = belief_state(config, world, params, logodds, (1.25, 1.25))
  view = jax.jit(lambda s, c: sim.belief_view(config, params, s, c))(state, jnp.asarray(cell))
  occupied = logodds == OCCUPIED
  clear = ~occupied & (ndimage.distance_transform_edt(~occupied) > 3.0 + 1e-6)
  assert not clear[23, 5] and not clear[5, 23]  # the wrapped cells lie in the inflation
  np.testing.assert_array_equal(np.asarray(view.traversable), clear)


def test_nearest_frontier_does_not_follow_a_notch_deeper_into_the_inflated_zone():
  # A 1-cell notch in a wall, its end unknown, is the nearest frontier to a robot standing two
  # cells from the wall (inside its 0.2 m radius). The notch is narrower than the robot: the plan
  # must not lead into it (each such plan took the robot further into the notch, until no plan
  # led out), but to the open room's other frontier.
  grid = box_world(30, 30, res=0.1)
  params = make_params(res=0.1, r_robot=0.2, r_max=0.5)
  config = config_for(grid.shape, grid.res, params, max_steps=4, planner="nearest_frontier")
  world = sim.make_world(grid, 0.2, (1.45, 2.0))
  logodds = np.full(grid.shape, FREE)
  logodds[grid.occupied] = OCCUPIED
  logodds[:10, :] = OCCUPIED
  logodds[7:10, 14] = FREE  # the notch
  logodds[6, 14] = UNKNOWN
  logodds[26:29, 26:29] = UNKNOWN  # the room's far corner
  state = belief_state(config, world, params, logodds, (1.35, 1.15))
  robot = sim.robot_view(config, world, state)
  assert tuple(np.asarray(robot.cell)) == (11, 13)
  view = sim.belief_view(config, params, state, robot.cell)
  plan = jax.jit(lambda v, r: base.get_planner("nearest_frontier").plan(
      sim.planner_context(config), v, r, params, jax.random.PRNGKey(0)))(view, robot)
  assert bool(plan.valid)
  distance = ndimage.distance_transform_edt(~np.asarray(view.occupied))
  path = np.asarray(plan.waypoints)[:int(plan.length)]
  assert len(path) > 1
  assert np.all(distance[path[:, 0], path[:, 1]] >= distance[11, 13] - 1e-9)
  assert np.asarray(plan.goal)[0] >= 25  # the far corner's frontier


@pytest.mark.parametrize(("batch", "chunk", "needing", "size"), [
    (6, 6, 0, 4), (6, 6, 1, 4), (6, 6, 4, 4), (6, 6, 5, 6), (3, 64, 3, 3), (64, 64, 16, 16),
    (64, 64, 17, 64), (300, 75, 16, 16), (300, 75, 40, 64), (300, 75, 65, 75),
    (1024, 128, 20, 64), (4096, 512, 100, 256), (4096, 512, 257, 512)])
def test_lockstep_chunks_by_need_are_the_smallest_that_holds_every_robot_that_needs_a_plan(
    monkeypatch, batch, chunk, needing, size):
  """Which chunk size ``_plan_robots_by_need`` plans in (``_plan_robots`` replaced by a stand-in
  that returns the size it was given), traced with the count of robots needing a plan, under
  the default ``SimConfig.lockstep_small_chunks``."""
  from jaxplore import planning

  def stand_in(config, world, params, state, need, window, chunk):
    assert window == 0
    return state + chunk, need

  monkeypatch.setattr(planning, "_plan_robots", stand_in)
  need = jnp.arange(batch) < needing
  planned = jax.jit(lambda need: planning._plan_robots_by_need(
      SimConfig(height=8, width=8, res=0.1), None, None, jnp.int32(0), need, chunk)[0])(need)
  assert int(planned) == size


@pytest.mark.slow  # three planning programs: ~20 s to compile on 2 cores
def test_lockstep_plans_in_a_smaller_chunk_when_it_holds_every_robot_that_needs_one():
  """A planner without a window, under the lockstep strategy, 6 robots: one robot needing a plan
  falls in the chunk of 4, five in the chunk of 6. Either way the states are those of fixed
  chunks of 6 (``lockstep_small_chunks`` empty), bit for bit, and only the robots that needed a
  plan planned."""
  from jaxplore import planning
  robots = 6
  grid = box_world(30, 44, res=0.1, walls=((14, 16, 8, 30),))
  params = make_params(res=0.1, r_robot=0.15, r_max=1.0)
  config = config_for(grid.shape, grid.res, params, max_steps=8, planner="nearest_frontier",
                      plan_window=0, strategy="lockstep")
  assert not sim.uses_window(config)
  world = sim.make_world(grid, 0.15)
  params = sim.broadcast_params(params, robots)
  starts = jnp.asarray([[0.5 + 0.5 * i, 0.6 + 0.3 * (i % 2), 0.0] for i in range(robots)])
  state = sim.reset_batch(config, world, params, jax.random.split(jax.random.PRNGKey(0), robots),
                          starts)
  plan = lambda config: jax.jit(lambda s: planning._plan_where_needed_lockstep(
      config, world, params, s)).lower(state).compile()
  by_need = plan(config)
  fixed = plan(dataclasses.replace(config, lockstep_small_chunks=()))
  for needing in (1, 5):
    needs = np.arange(robots) >= robots - needing
    before = state.replace(busy=jnp.asarray(~needs), since_plan=jnp.zeros(robots, jnp.int32))
    after = by_need(before)
    chex.assert_trees_all_equal(after, fixed(before))
    planned = np.any(np.asarray(after.goal) != np.asarray(before.goal), axis=-1)
    np.testing.assert_array_equal(planned, needs)


def _notch_room():
  """The room of the notch test: its belief, and the state of a robot in it."""
  grid = box_world(30, 30, res=0.1)
  params = make_params(res=0.1, r_robot=0.2, r_max=0.5)
  config = config_for(grid.shape, grid.res, params, max_steps=4, planner="nearest_frontier")
  world = sim.make_world(grid, 0.2, (1.45, 2.0))
  logodds = np.full(grid.shape, FREE)
  logodds[grid.occupied] = OCCUPIED
  logodds[:10, :] = OCCUPIED
  logodds[26:29, 26:29] = UNKNOWN  # the room's far corner
  logodds[12:14, 26:29] = UNKNOWN  # and a nearer patch, 13 rows from it
  return config, world, params, belief_state(config, world, params, logodds, (1.35, 1.15))


def test_the_stall_watch_counts_metres_only_while_a_robot_circles_without_gaining_cells():
  from jaxplore.robot import _watch_stall
  _, _, params, state = _notch_room()
  state = state.replace(stall_box=jnp.asarray([1.0, 1.0, 1.0, 1.0]), stall_m=jnp.float32(0),
                        stall_covered=state.covered)
  loop = [(1.0, 2.0), (2.0, 2.0), (2.0, 1.0), (1.0, 1.0)] * 3  # a 1 m square, 12 m
  for x, y in loop:
    state = _watch_stall(params, state.replace(pose_est=jnp.asarray([x, y, 0.0])), 1.0)
  assert float(state.stall_m) == 12.0
  np.testing.assert_allclose(np.asarray(state.stall_box), [1.0, 1.0, 2.0, 2.0])
  gained = _watch_stall(params, state.replace(covered=state.covered + 1), 1.0)
  assert float(gained.stall_m) == 0.0 and float(gained.stall_covered) == float(state.covered) + 1
  # leaving the 3 m span (the box's diagonal) restarts the watch where the robot is
  away = _watch_stall(params, state.replace(pose_est=jnp.asarray([3.2, 3.2, 0.0])), 1.0)
  assert float(away.stall_m) == 0.0
  np.testing.assert_allclose(np.asarray(away.stall_box), [3.2, 3.2, 3.2, 3.2], rtol=1e-6)
  inside = _watch_stall(params, state.replace(pose_est=jnp.asarray([3.0, 3.0, 0.0])), 1.0)
  assert float(inside.stall_m) == 13.0  # diagonal 2.83 m: still circling


def test_a_stalled_robot_gives_its_goal_up():
  """At ``stall_m`` metres circling, the next planning round blacklists the robot's current
  goal and the cells within 5 of it (explore_lite's tolerance) and plans elsewhere; a metre
  short of it, the same goal is planned again."""
  config, world, params, state = _notch_room()
  plan = jax.jit(lambda s: sim.plan(config, world, params, s))
  first = plan(state)
  goal = tuple(np.asarray(first.goal))
  assert goal[0] <= 14 and not bool(first.blacklist[goal])  # the nearer patch
  for metres, stalled in ((params.stall_m - 1.0, False), (params.stall_m, True)):
    again = plan(first.replace(stall_m=jnp.float32(metres)))
    rows, cols = np.nonzero(np.asarray(again.blacklist))
    if stalled:
      near = (np.abs(np.arange(30)[:, None] - goal[0]) <= 5) & (
          np.abs(np.arange(30)[None, :] - goal[1]) <= 5)
      np.testing.assert_array_equal(np.asarray(again.blacklist), near)
    else:
      assert len(rows) == 0
    assert (tuple(np.asarray(again.goal)) != goal) == stalled
    assert float(again.stall_m) == (0.0 if stalled else metres)
    if stalled:  # the far corner's frontier, outside the box
      assert not near[tuple(np.asarray(again.goal))] and np.asarray(again.goal)[0] >= 25
