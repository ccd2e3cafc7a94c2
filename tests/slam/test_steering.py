"""How a robot with a SLAM estimate moves: it steers by its estimate along straight runs of its
path (pure pursuit), a bump stops only a move nearer to a true wall, and a bump its belief
already explains blocks the waypoint it drove to."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import mapping, planning, posegraph, robot, sim
from jaxplore.config import ConfigError, SimConfig, make_params
from tests.conftest import box_world

RES = 0.2
GRID = box_world(20, 30, RES)
PARAMS = make_params(res=RES, r_max=1.0, fov=math.pi, r_robot=0.2)
CONFIG = SimConfig(height=20, width=30, res=RES, n_beams=16, max_range_cells=6, max_steps=20,
                   path_capacity=12, planner="nearest_frontier", max_inflation_cells=2,
                   graph_nodes=posegraph.keyframe_bound(21, PARAMS.v_max, PARAMS.w_max, PARAMS.dt,
                                                        PARAMS.kf_dist, PARAMS.kf_rot),
                   graph_loops=4, slam="scan_matching")
WORLD = sim.make_world(GRID, RES)
STEP = jax.jit(sim.step, static_argnums=0)
RESET = jax.jit(sim.reset, static_argnums=0)


def centre(cell):
  return np.array([(cell[1] + 0.5) * RES, (cell[0] + 0.5) * RES], np.float32)


def on_path(cells, estimate, truth=None):
  """A SLAM robot following ``cells`` (its first waypoint is its own cell) whose estimate is
  ``estimate`` and true pose ``truth`` (default: the estimate)."""
  truth = estimate if truth is None else truth
  state = RESET(CONFIG, WORLD, PARAMS, jax.random.PRNGKey(0), jnp.asarray(truth, jnp.float32))
  path = np.asarray(cells, np.int32)
  waypoints = np.concatenate([path, np.repeat(path[-1:], CONFIG.path_capacity - len(path), 0)])
  return state.replace(pose_est=jnp.asarray(estimate, jnp.float32),
                       waypoints=jnp.asarray(waypoints), path_len=jnp.int32(len(path)),
                       path_idx=jnp.int32(1), look_at=jnp.asarray(path[-1]))


STRAIGHT = [(10, c) for c in range(5, 12)]


@pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["eager", "jit"])
def test_the_lookahead_is_the_farthest_waypoint_of_the_straight_run_within_reach(transform):
  lookahead = transform(lambda s: robot._lookahead(CONFIG, WORLD, s))
  # At its own cell's centre: two cells ahead (LOOKAHEAD_CELLS), waypoint index 2.
  assert int(lookahead(on_path(STRAIGHT, [*centre((10, 5)), 0.0]))) == 2
  # An estimate corrected 1.2 cells forward by a match: index 3 is now within reach.
  assert int(lookahead(on_path(STRAIGHT, [*(centre((10, 5)) + [1.2 * RES, 0]), 0.0]))) == 3
  # A corner one cell ahead: the lookahead stops at it (the planner measured clearance there).
  corner = [(10, 5), (10, 6), (11, 6), (12, 6)]
  assert int(lookahead(on_path(corner, [*centre((10, 5)), 0.0]))) == 1
  # Nothing within reach (the robot far off its path): the next waypoint.
  assert int(lookahead(on_path(STRAIGHT, [*(centre((10, 5)) + [0, 3 * RES]), 0.0]))) == 1


def test_an_estimate_corrected_past_its_waypoint_drives_on_instead_of_turning_back():
  """The estimate jumped 0.6 cell ahead of the robot's own cell's centre (a keyframe match):
  the waypoint one cell ahead is now 0.4 cell ahead, and steering to it alone would have been
  fine; but one 0.2 cell ahead of a 0.3 cell sideways jump would lie at 56 degrees. With the
  lookahead the robot turns by less than 20 degrees and drives a whole cell."""
  start = centre((10, 5))
  estimate = [start[0] + 0.8 * RES, start[1] + 0.3 * RES, 0.0]
  state = on_path(STRAIGHT, estimate, truth=[*start, 0.0])
  after, _ = STEP(CONFIG, WORLD, PARAMS, state)
  turned = abs(float(after.pose[2] - state.pose[2]))
  assert turned < math.radians(20)
  assert float(after.distance) == pytest.approx(RES, rel=1e-4)
  # The true pose moved by the command that moved the estimate (no collision here).
  assert int(after.collisions) == 0


@pytest.mark.parametrize("start, end, stops", [
    ((10, 2), (10, 1), True),  # toward the west wall: within its radius and nearer
    ((10, 1), (10, 2), False),  # away from it (a robot its estimate put against the wall)
    ((9, 1), (10, 1), False),  # along it at the same distance
    ((10, 3), (10, 4), False),  # nowhere near
])
def test_a_bump_stops_only_a_move_nearer_to_a_touched_true_wall(start, end, stops):
  _, bumps = robot._bumps(CONFIG, WORLD, PARAMS, jnp.asarray(centre(start)),
                          jnp.asarray(centre(end)))
  assert bool(jnp.any(bumps)) == stops


def test_a_bump_the_belief_already_explains_blocks_the_waypoint_driven_to():
  """The robot believes itself at (10, 5) beside a wall it mapped along row 11, and drives east
  beside it (no nearer: the planner's escape route); truly it stands at (16, 5), and the true
  wall cell (17, 7) is in its way. What the bumper feels lies where the belief already holds a
  wall, so that adds nothing: the waypoint it drove to becomes occupied instead, and the next
  plan cannot send it there again."""
  world = sim.make_world(box_world(20, 30, RES, walls=((17, 18, 7, 8),)), RES)
  state = on_path([(10, 5), (10, 6), (10, 7)], [*centre((10, 5)), 0.0], [*centre((16, 5)), 0.0])
  state = state.replace(logodds=state.logodds.at[11, 3:10].set(PARAMS.l_max))
  after, _ = STEP(CONFIG, world, PARAMS, state)
  assert int(after.collisions) == 1
  np.testing.assert_allclose(np.asarray(after.pose), np.asarray(state.pose))
  assert float(after.logodds[10, 7]) == pytest.approx(float(PARAMS.l_max))
  assert int(after.path_len) == int(after.path_idx)  # the path ended
  # Without the wall in the belief, the bumper's cells are learnt and the waypoint is not.
  fresh = on_path([(10, 5), (10, 6), (10, 7)], [*centre((10, 5)), 0.0], [*centre((16, 5)), 0.0])
  after, _ = STEP(CONFIG, world, PARAMS, fresh)
  assert int(after.collisions) == 1
  assert float(after.logodds[11, 7]) == pytest.approx(float(PARAMS.l_max))
  assert float(after.logodds[10, 7]) < float(PARAMS.l_max)


def test_specks_of_unknown_enclosed_by_known_cells_border_no_frontier():
  """A wall cell with evidence both ways (unknown) inside a mapped room is a hole in the map:
  with ``map_hole_cells`` (the scan_matching default) no frontier borders it; the unexplored
  space beyond the map's edge still has its frontier."""
  free = np.ones((12, 14), bool)
  free[:, 10:] = False  # unexplored beyond column 10, reaching the grid's edge
  unknown = ~free
  unknown[5, 4] = True  # the hole
  free[5, 4] = False
  occupied = np.zeros_like(free)
  frontier = lambda cfg: np.asarray(mapping.frontier(
      jnp.asarray(free), planning.unexplored(cfg, jnp.asarray(unknown)), jnp.asarray(occupied)))
  with_holes = frontier(CONFIG)
  without = frontier(dataclasses.replace(CONFIG, map_hole_cells=0))
  assert CONFIG.map_hole_cells == 4
  assert not with_holes[4:7, 3:6].any() and without[4:7, 3:6].sum() == 8
  np.testing.assert_array_equal(with_holes[:, 9], np.ones(12, bool))
  np.testing.assert_array_equal(without[:, 9], np.ones(12, bool))


def test_map_hole_cells_defaults_by_slam_model_and_is_checked():
  assert SimConfig(height=4, width=4, res=RES).map_hole_cells == 0
  assert SimConfig(height=4, width=4, res=RES, map_hole_cells=2).map_hole_cells == 2
  with pytest.raises(ConfigError, match="map_hole_cells"):
    SimConfig(height=4, width=4, res=RES, map_hole_cells=-3)
