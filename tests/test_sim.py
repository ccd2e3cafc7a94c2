"""The engine end to end on tiny worlds: termination reasons, determinism, no retrace, no collision."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import box_world
from jaxplore import sim
from jaxplore.config import config_for, make_params

ROBOTS = 4  # tests/test_reference_numpy.py's four starts: rooms_run's program serves it too


def setup(grid, max_steps=300, r_max=3.0, pose_noise=False, **overrides):
  params = make_params("li2020", res=grid.res, r_max=r_max, **overrides)
  config = config_for(grid.shape, grid.res, params, max_steps=max_steps, replan_every=6,
                      pose_noise=pose_noise)
  world = sim.make_world(grid, float(params.r_robot))
  return config, world, sim.broadcast_params(params, ROBOTS)


@pytest.fixture(scope="module")
def rooms():
  # Two rooms joined by a 1 m door.
  return box_world(40, 60, 0.1, walls=((1, 39, 29, 31),)).__class__(
      _with_door(), 0.1, (0.0, 0.0), "rooms")


def _with_door():
  occ = box_world(40, 60, 0.1, walls=((1, 39, 29, 31),)).occupied.copy()
  occ[15:25, 29:31] = False
  return occ


@pytest.fixture(scope="module")
def rooms_run(rooms):
  config, world, params = setup(rooms)
  keys = jax.random.split(jax.random.PRNGKey(0), ROBOTS)
  state, records = sim.rollout(config, world, params, keys)
  return config, world, params, keys, state, records


def test_every_robot_completes_two_rooms(rooms_run):
  config, world, _, _, state, records = rooms_run
  assert np.all(np.asarray(state.reason) == sim.COMPLETE), np.asarray(state.reason)
  final = np.asarray(records.coverage)[-1]
  assert np.all(final >= 0.99)
  chex.assert_shape(records.coverage, (config.max_steps, ROBOTS))
  chex.assert_tree_all_finite(jax.tree.map(lambda r: r[:, :], records.distance))
  # coverage is monotone while running and distance never decreases
  assert np.all(np.diff(np.asarray(records.distance), axis=0) >= -1e-6)


def test_running_metrics_match_a_full_recount(rooms_run):
  _, world, params, _, state, _ = rooms_run
  from jaxplore import mapping
  l = np.asarray(state.logodds)
  h = np.asarray(mapping.entropy_of_logodds(jnp.asarray(l))).sum(axis=(1, 2))
  np.testing.assert_allclose(np.asarray(state.entropy), h, rtol=1e-4)
  free = l < np.asarray(mapping.logit(params.p_free))[:, None, None]
  covered = (free & np.asarray(world.reachable)[None]).sum(axis=(1, 2))
  np.testing.assert_allclose(np.asarray(state.covered), covered)


def test_robots_never_enter_occupied_cells(rooms, rooms_run):
  _, _, _, _, _, records = rooms_run
  rows = np.floor(np.asarray(records.y) / rooms.res).astype(int)
  cols = np.floor(np.asarray(records.x) / rooms.res).astype(int)
  assert not rooms.occupied[rows, cols].any()


def test_same_keys_same_numbers(rooms, rooms_run):
  config, world, params, keys, state, records = rooms_run
  state2, records2 = sim.rollout(config, world, params, keys)
  chex.assert_trees_all_equal(records, records2)
  chex.assert_trees_all_equal(state.logodds, state2.logodds)


@pytest.fixture(scope="module")
def strategy_runs(rooms):
  """3 noisy robots (sensor and odometry noise, so every key matters), 12 steps with a budget
  of 12, planned one at a time (``per_robot``) and in lockstep: the final state of each."""
  robots = 3
  params = make_params("li2020", res=rooms.res, r_max=3.0, range_noise=0.05)
  world = sim.make_world(rooms, float(params.r_robot))
  params = sim.broadcast_params(params, robots)
  keys = jax.random.split(jax.random.PRNGKey(5), robots)
  finals, state = {}, None
  for strategy in ("per_robot", "lockstep"):
    config = config_for(rooms.shape, rooms.res, params, max_steps=12, replan_every=6,
                        pose_noise=True, plan_window=32, plan_chunk=1, strategy=strategy,
                        planner="nearest_frontier")
    if state is None:  # one reset for both (a compile less): the slow test below resets each
      state = sim.reset_batch(config, world, params, keys)
    finals[strategy] = sim.advance(config, world, params, state, 2)[0]
  return finals


def assert_same_across_strategies(per_robot, lockstep):
  """Bit for bit, the map-entropy metric apart: the lockstep strategy's whole-grid belief update
  sums a scan's entropy change in another order than the tile loop (see
  ``mapping.integrate_observation``)."""
  chex.assert_trees_all_equal(per_robot.replace(entropy=lockstep.entropy), lockstep)
  np.testing.assert_allclose(np.asarray(lockstep.entropy), np.asarray(per_robot.entropy),
                             rtol=1e-5)


def test_lockstep_and_per_robot_strategies_end_in_the_same_states(strategy_runs):
  """The strategy choice, forced on CPU: planned one at a time and in lockstep (the robots that
  plan gathered in one padded chunk, shortest paths by relaxation, the belief update a plain
  vmap on the whole grid), the robots end in the same states, keys included (the entropy metric
  up to summation order). The slow test below adds chunking and
  li2020."""
  assert int(np.asarray(strategy_runs["per_robot"].steps).min()) == 12
  assert_same_across_strategies(strategy_runs["per_robot"], strategy_runs["lockstep"])


def test_step_budget_ends_in_timeout(strategy_runs):
  state = strategy_runs["per_robot"]
  assert np.all(np.asarray(state.reason) == sim.TIMEOUT)
  assert np.all(np.asarray(state.steps) == 12)


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
def test_a_robots_run_does_not_depend_on_how_plans_are_chunked(rooms):
  """With sensor and odometry noise every robot's key matters; 5 robots planned one at a time,
  in chunks of 3 (the second chunk padded) and in lockstep (the accelerator strategy: one padded
  chunk, shortest paths by relaxation; the belief update a plain vmap) must end in the same
  states, keys included. The plans go through a window: whole-grid leftovers plan one by one,
  unpadded (in lockstep: in a second padded chunk)."""
  robots = 5
  params = make_params("li2020", res=rooms.res, r_max=3.0, range_noise=0.05)
  world = sim.make_world(rooms, float(params.r_robot))
  params = sim.broadcast_params(params, robots)
  keys = jax.random.split(jax.random.PRNGKey(3), robots)
  finals = []
  for chunk, strategy in ((1, "per_robot"), (3, "per_robot"), (4, "lockstep")):
    config = config_for(rooms.shape, rooms.res, params, max_steps=36, replan_every=6, pose_noise=True,
                        plan_window=32, plan_chunk=chunk, strategy=strategy)
    assert sim.uses_window(config)
    state = sim.reset_batch(config, world, params, keys)
    finals.append(sim.advance(config, world, params, state, 6)[0])
  assert int(np.asarray(finals[0].steps).min()) == 36  # every robot ran (and planned) throughout
  chex.assert_trees_all_equal(finals[0], finals[1])
  assert_same_across_strategies(finals[0], finals[2])


@pytest.mark.slow  # two li2020 programs: ~1 min to compile on 2 cores
def test_li2020_plans_alike_in_both_strategies(rooms):
  """li2020 (entropy map, visible gains, no window) with sensor and odometry noise: 6 robots
  end 12 steps in the same states planned one at a time and in lockstep (its chunks of 4 or 6,
  by how many robots need a plan)."""
  from jaxplore.planners import get_planner
  robots = 6
  params = make_params("li2020", res=rooms.res, r_max=3.0, range_noise=0.05,
                       planner=get_planner("li2020").defaults)
  world = sim.make_world(rooms, float(params.r_robot))
  params = sim.broadcast_params(params, robots)
  keys = jax.random.split(jax.random.PRNGKey(7), robots)
  finals = []
  for strategy in ("per_robot", "lockstep"):
    config = config_for(rooms.shape, rooms.res, params, max_steps=12, replan_every=4,
                        pose_noise=True, strategy=strategy,
                        planner=get_planner("li2020").with_settings(max_update_radius_cells=30),
                        planner_given=("max_update_radius_cells",))
    state = sim.reset_batch(config, world, params, keys)
    finals.append(sim.advance(config, world, params, state, 3)[0])
  assert int(np.asarray(finals[0].steps).min()) == 12
  assert_same_across_strategies(finals[0], finals[1])


def test_a_room_behind_a_gap_narrower_than_the_robot_is_not_counted_and_the_run_completes():
  # Right room reachable only through a 0.2 m slit: the 0.2 m-radius robot cannot pass. Coverage
  # counted the room, so every such run ended `exhausted` (0.51-0.65 on real maps); it is now of
  # the free area the robot's disc can reach.
  grid = box_world(40, 60, 0.1, walls=((1, 39, 29, 31),))
  occ = grid.occupied.copy()
  occ[20:22, 29:31] = False
  grid = grid.__class__(occ, 0.1, (0.0, 0.0), "slit")
  # rooms_run's config (same shapes and budget, a lidar buffer for 3 m): its compiled program
  # serves; the shorter range is a traced parameter.
  config, world, _ = setup(grid)
  params = sim.broadcast_params(make_params("li2020", res=grid.res, r_max=1.5), ROBOTS)
  starts = jnp.tile(jnp.asarray([1.0, 2.0, 0.0]), (ROBOTS, 1))
  state, records = sim.rollout(config, world, params, jax.random.split(jax.random.PRNGKey(2), ROBOTS), starts)
  reachable = np.asarray(world.reachable)
  assert reachable[:, :29].sum() == np.asarray(grid.free)[:, :29].sum()  # the left room, whole
  assert not reachable[:, 35:].any()  # the right room: at most a sliver through the slit
  assert np.all(np.asarray(state.reason) == sim.COMPLETE), np.asarray(state.reason)
  assert np.all(np.asarray(records.coverage)[-1] >= 0.99)


def test_step_eager_equals_jit(rooms):
  config, world, params = setup(rooms)  # rooms_run's config: programs compiled for it serve
  keys = jax.random.split(jax.random.PRNGKey(4), ROBOTS)
  state = sim.reset_batch(config, world, params, keys)
  state = jax.jit(jax.vmap(lambda p, s: sim.plan(config, world, p, s)))(params, state)
  one = jax.tree.map(lambda x: x[0], state)
  p0 = jax.tree.map(lambda x: x[0], params)
  eager = sim.step(config, world, p0, one)
  jitted = jax.jit(lambda p, s: sim.step(config, world, p, s))(p0, one)
  chex.assert_trees_all_close(eager, jitted, atol=1e-5)


def test_pose_noise_drifts_and_relocalisation_bounds_it(rooms):
  config, world, params = setup(rooms, max_steps=120, pose_noise=True, odom_noise_d=0.2,
                                odom_noise_phi=0.2)
  starts = jnp.tile(jnp.asarray([1.5, 2.0, 0.0]), (ROBOTS, 1))
  keys = jax.random.split(jax.random.PRNGKey(5), ROBOTS)
  _, records = sim.rollout(config, world, params, keys, starts)
  assert float(np.asarray(records.pose_error).max()) > 0.0
  # Without relocalisation (an impossible hit count) Σ only grows (Eq 14).
  never = params.replace(reloc_min_hits=jnp.full((ROBOTS,), 1e9, jnp.float32))
  _, grown = sim.rollout(config, world, never, keys, starts)
  det = np.asarray(grown.det_cov)
  assert np.all(np.diff(det, axis=0) >= -1e-12 * np.abs(det[:-1]).max())
  assert np.asarray(records.det_cov).max() < det.max()


def test_start_inside_wall_or_outside_is_refused(rooms):
  from jaxplore.config import ConfigError
  with pytest.raises(ConfigError, match="inside a wall"):
    sim.make_world(rooms, 0.2, (3.0, 0.05))
  with pytest.raises(ConfigError, match="outside the map"):
    sim.make_world(rooms, 0.2, (30.0, 1.0))
  with pytest.raises(ConfigError, match="closer than the robot radius"):
    sim.make_world(rooms, 0.2, (0.15, 2.0))


def test_robot_inside_newly_inflated_walls_can_drive_out(rooms):
  # The belief says a wall is right next to the robot (inside its radius): it must still be able
  # to drive out of the inflated zone instead of ending `exhausted`.
  from jaxplore.graph.dijkstra import shortest_paths
  config, world, params = setup(rooms)  # rooms_run's config: programs compiled for it serve
  starts = jnp.tile(jnp.asarray([1.05, 2.05, 0.0]), (ROBOTS, 1))
  state = sim.reset_batch(config, world, params, jax.random.split(jax.random.PRNGKey(6), ROBOTS), starts)
  state = state.replace(logodds=state.logodds.at[:, 20, 11].set(5.0))  # a believed wall 0.1 m away
  planned = jax.jit(jax.vmap(lambda p, s: sim.plan(config, world, p, s)))(params, state)
  assert not np.asarray(planned.done).any()
  one, p0 = jax.tree.map(lambda x: x[0], state), jax.tree.map(lambda x: x[0], params)
  robot = sim.robot_view(config, world, one)
  view = sim.belief_view(config, p0, one, robot.cell)
  assert bool(view.inflated[20, 10]) and bool(view.traversable[20, 10])
  sp = shortest_paths(jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32), robot.cell)
  clear = np.asarray(view.free & ~view.inflated)
  reached = np.isfinite(np.asarray(sp.dist)) & clear
  assert reached.sum() > 0.9 * clear.sum()  # everything clear of walls is reachable from inside


def test_random_starts_avoid_a_closet_behind_a_door_narrower_than_the_robot():
  # A 1-cell door in a wall at column 40: a 0.2 m robot at 0.1 m cells cannot pass it, so no
  # start lands in the closet beyond, and coverage counts no more of it than the door's sliver.
  grid = box_world(40, 60, walls=((0, 20, 40, 41), (21, 40, 40, 41)))
  world = sim.make_world(grid, 0.2)
  reachable, start_ok = np.asarray(world.reachable), np.asarray(world.start_ok)
  assert reachable[:, 41:43].any() and not reachable[:, 43:59].any()
  assert start_ok[:, :40].any() and not start_ok[:, 41:].any()
  params = make_params("li2020", res=grid.res)
  config = config_for(grid.shape, grid.res, params, max_steps=8)
  keys = jax.random.split(jax.random.PRNGKey(0), 64)
  state = sim.reset_batch(config, world, sim.broadcast_params(params, 64), keys)
  assert np.all(np.asarray(state.pose[:, 0]) < 4.0)  # every start west of the wall (x < 4 m)
