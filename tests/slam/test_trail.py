"""The way back along a robot's own trail: under SLAM a wall drawn a cell off closes a narrow
door to the inflated belief, and a robot that came through it must still be able to leave
(``SimConfig.trail``, :func:`jaxplore.planning.trail_cells`, the planner's retry on the trail)."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from jaxplore import planning, sim
from jaxplore.config import ConfigError, SimConfig, make_params
from jaxplore.robot import EXHAUSTED, RUNNING
from tests.conftest import box_world

RES = 0.2
# Two rooms, a wall along column 15 with a door of three cells (rows 8-10) between them.
GRID = box_world(20, 30, RES, walls=((1, 8, 15, 16), (11, 19, 15, 16)))
PARAMS = make_params(res=RES, r_max=1.0, fov=math.pi, r_robot=0.2)
CONFIG = SimConfig(height=20, width=30, res=RES, n_beams=16, max_range_cells=6, max_steps=20,
                   path_capacity=40, planner="nearest_frontier", max_inflation_cells=2,
                   graph_nodes=8, graph_loops=4, slam="scan_matching")
WORLD = sim.make_world(GRID, RES)
RESET = jax.jit(sim.reset, static_argnums=0)
PLAN = jax.jit(sim.plan, static_argnums=0)
STEP = jax.jit(sim.step, static_argnums=0)
TRAIL = [(9, 8), (9, 15), (9, 22)]  # the keyframes of a robot that came east through the door


def centre(cell):
  return np.array([(cell[1] + 0.5) * RES, (cell[0] + 0.5) * RES], np.float32)


def belief(false_wall=True):
  """The truth's walls and free cells, the west end of the west room (columns 1-5) unknown, and
  a wall drawn a cell off in the door's south cell (10, 15), which inflates its middle one."""
  logodds = np.where(GRID.occupied, PARAMS.l_max, PARAMS.l_min).astype(np.float32)
  logodds[1:19, 1:6] = 0.0
  if false_wall:
    logodds[10, 15] = PARAMS.l_max
  return jnp.asarray(logodds)


def robot_after(trail, config=CONFIG, false_wall=True):
  """A robot at ``trail``'s last cell, its pose graph holding ``trail`` as keyframes."""
  pose = jnp.asarray([*centre(trail[-1]), math.pi], jnp.float32)
  state = RESET(config, WORLD, PARAMS, jax.random.PRNGKey(0), pose)
  poses = np.zeros((config.graph_nodes, 3), np.float32)
  poses[:len(trail), :2] = [centre(c) for c in trail]
  graph = state.graph.replace(poses=jnp.asarray(poses), n_nodes=jnp.int32(len(trail)))
  return state.replace(logodds=belief(false_wall), graph=graph)


@pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["eager", "jit"])
def test_the_trail_is_the_cells_of_the_keyframe_segments(transform):
  state = robot_after(TRAIL)
  cells = np.asarray(transform(lambda s: planning.trail_cells(CONFIG, WORLD, s))(state))
  used = cells[(cells >= 0).all(axis=1)]
  # Unused keyframe slots give (-1, -1); the used ones: the three segments (the last one, from
  # the last keyframe to the estimate, is a point here).
  assert len(cells) == CONFIG.graph_nodes * planning.TRAIL_SAMPLES
  assert len(used) == len(TRAIL) * planning.TRAIL_SAMPLES
  drawn = np.zeros(GRID.shape, bool)
  drawn[used[:, 0], used[:, 1]] = True
  # A plain NumPy reading: the cells that points every 1/100 of a cell along the segments fall in.
  dense = np.zeros(GRID.shape, bool)
  for a, b in zip(TRAIL[:-1], TRAIL[1:]):
    t = np.linspace(0.0, 1.0, 100 * 8)[:, None]
    xy = centre(a)[None] + t * (centre(b) - centre(a))[None]
    dense[np.floor(xy[:, 1] / RES).astype(int), np.floor(xy[:, 0] / RES).astype(int)] = True
  np.testing.assert_array_equal(drawn, dense)
  # A diagonal segment: its cells form one 8-connected chain from one keyframe to the next.
  diagonal = robot_after([(3, 3), (8, 10)])
  cells = np.asarray(planning.trail_cells(CONFIG, WORLD, diagonal))
  chain = np.zeros(GRID.shape, bool)
  chain[tuple(cells[(cells >= 0).all(axis=1)].T)] = True
  assert chain[3, 3] and chain[8, 10] and ndimage.label(chain, np.ones((3, 3)))[1] == 1


def test_the_trail_makes_the_door_traversable_to_the_planners_view_only_on_free_cells():
  state = robot_after(TRAIL)
  cell = jnp.asarray(TRAIL[-1], jnp.int32)
  without = planning.belief_view(CONFIG, PARAMS, state, cell)
  with_trail = planning.belief_view(CONFIG, PARAMS, state, cell,
                                    planning.trail_cells(CONFIG, WORLD, state))
  assert not bool(without.traversable[9, 15]) and bool(with_trail.traversable[9, 15])
  # Only trail cells change, and a believed wall on the trail stays untraversable.
  changed = np.asarray(with_trail.traversable != without.traversable)
  assert changed.sum() > 0 and not changed[~np.asarray(with_trail.free)].any()
  walled = state.replace(logodds=state.logodds.at[9, 12].set(PARAMS.l_max))
  view = planning.belief_view(CONFIG, PARAMS, walled, cell,
                              planning.trail_cells(CONFIG, WORLD, walled))
  assert not bool(view.traversable[9, 12])


def test_a_robot_shut_in_by_a_wall_drawn_a_cell_off_plans_out_along_its_trail():
  """On its belief the east room holds no frontier and the door is shut by the margin of the
  false wall: without the trail the robot ends ``exhausted``; with it, its plan leads west
  through the door's middle cell to the frontier, and it is marked as a plan on the trail."""
  state = robot_after(TRAIL)
  off = dataclasses.replace(CONFIG, trail=0)
  stuck = PLAN(off, WORLD, PARAMS, state)
  assert bool(stuck.done) and int(stuck.reason) == EXHAUSTED
  out = PLAN(CONFIG, WORLD, PARAMS, state)
  assert not bool(out.done) and int(out.reason) == RUNNING and bool(out.on_trail)
  path = np.asarray(out.waypoints[:int(out.path_len)])
  assert (9, 15) in map(tuple, path) and path[-1][1] <= 6  # through the door, to the frontier
  # A robot whose belief is not shut in plans as it would without the trail (no retry).
  free = robot_after(TRAIL, false_wall=False)
  with_trail, without = PLAN(CONFIG, WORLD, PARAMS, free), PLAN(off, WORLD, PARAMS, free)
  assert not bool(with_trail.on_trail)
  np.testing.assert_array_equal(np.asarray(with_trail.waypoints), np.asarray(without.waypoints))


def test_a_robot_shut_in_off_its_trail_plans_through_the_free_cells_its_radius_ignored():
  """The last recovery: a robot that never came through the door (its trail lies in the east
  room) finds nothing on the inflated belief nor on its trail; through every free cell of its
  belief it plans west through the door's two free cells. A door walled shut on the belief
  stays shut (only free cells are traversable), and without the trail setting no recovery runs."""
  east = [(9, 25), (9, 22)]
  state = robot_after(east)
  cell = jnp.asarray(east[-1], jnp.int32)
  trail = planning.trail_cells(CONFIG, WORLD, state)
  assert not bool(planning.belief_view(CONFIG, PARAMS, state, cell, trail).traversable[9, 15])
  bare = planning.belief_view(CONFIG, PARAMS, state, cell, trail, inflate=False)
  np.testing.assert_array_equal(np.asarray(bare.traversable), np.asarray(bare.free))
  out = PLAN(CONFIG, WORLD, PARAMS, state)
  assert not bool(out.done) and int(out.reason) == RUNNING and bool(out.on_trail)
  path = np.asarray(out.waypoints[:int(out.path_len)])
  assert any(c == 15 and r in (8, 9) for r, c in path) and path[-1][1] <= 6
  assert bool(PLAN(dataclasses.replace(CONFIG, trail=0), WORLD, PARAMS, state).done)
  walled = state.replace(logodds=state.logodds.at[8:10, 15].set(PARAMS.l_max))
  shut = PLAN(CONFIG, WORLD, PARAMS, walled)
  assert bool(shut.done) and int(shut.reason) == EXHAUSTED


def test_a_path_on_the_trail_is_driven_through_the_margin_of_a_believed_wall():
  """Elsewhere a waypoint nearer to a believed wall than the robot's cell, within its radius,
  ends the path (it was planned before that wall was mapped); on the trail it is driven to."""
  state = robot_after(TRAIL)
  path = [(9, c) for c in range(17, 12, -1)]
  waypoints = np.concatenate([path, np.repeat(np.asarray(path[-1:]), CONFIG.path_capacity - 5, 0)])
  state = state.replace(pose=jnp.asarray([*centre(path[0]), math.pi], jnp.float32),
                        pose_est=jnp.asarray([*centre(path[0]), math.pi], jnp.float32),
                        waypoints=jnp.asarray(waypoints, jnp.int32), path_len=jnp.int32(5),
                        path_idx=jnp.int32(1), look_at=jnp.asarray(path[-1], jnp.int32))
  cut, _ = STEP(CONFIG, WORLD, PARAMS, state)
  driven, _ = STEP(CONFIG, WORLD, PARAMS, state.replace(on_trail=jnp.bool_(True)))
  assert int(cut.path_len) < 5 and float(cut.distance) == 0.0
  assert int(driven.path_len) == 5 and float(driven.distance) > 0.0
  assert int(driven.collisions) == 0


def test_the_trail_defaults_by_slam_model_and_needs_a_pose_graph():
  assert CONFIG.trail == 1
  assert SimConfig(height=4, width=4, res=RES).trail == 0
  with pytest.raises(ConfigError, match="trail=1 plans along the keyframe trajectory"):
    SimConfig(height=4, width=4, res=RES, trail=1)
  with pytest.raises(ConfigError, match="trail"):
    SimConfig(height=4, width=4, res=RES, trail=2)
  assert SimConfig(height=4, width=4, res=RES, trail=1, graph_nodes=4).trail == 1
