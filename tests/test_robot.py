"""One robot's motion step: its disc never touches the truth, and what it bumps into it learns."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import EAGER_AND_JIT, box_world
from jaxplore import mapping, robot, sim
from jaxplore.config import ConfigError, config_for, make_params
from jaxplore.maps import GridMap

R_ROBOT = 0.25
# One compiled motion step per config, shared by the tests (the world and parameters traced).
STEP = jax.jit(sim.step, static_argnums=0)


def gap_world():
  """A 3 m x 2 m box split by a wall at x = 1.5 m with a 0.2 m gap (narrower than the robot's
  0.5 m disc)."""
  grid = box_world(20, 30, res=0.1, walls=((0, 9, 15, 16), (11, 20, 15, 16)))
  return grid


def on_straight_path_believing_all_free(config, world, params, start_xy, row, cols):
  """A robot at ``start_xy`` whose belief is all free, following a straight path along ``row``
  over ``cols`` (the walls ahead unmapped), at its first waypoint's successor."""
  state = sim.reset(config, world, params, jax.random.PRNGKey(0),
                    jnp.asarray([start_xy[0], start_xy[1], 0.0]))
  path = np.stack([np.full(len(cols), row), cols], axis=1).astype(np.int32)
  padding = config.path_capacity - len(path)
  waypoints = np.concatenate([path, np.repeat(path[-1:], padding, axis=0)])
  believed_free = jnp.full((config.height, config.width), -3.0, jnp.float32)
  return state.replace(logodds=believed_free,
                       entropy=jnp.sum(mapping.entropy_of_logodds(believed_free)),
                       waypoints=jnp.asarray(waypoints), path_len=jnp.int32(len(path)),
                       path_idx=jnp.int32(1), look_at=jnp.asarray(path[-1]))


def row_4_path_past_a_wall_cell(wall, r_robot):
  """A 12 x 20 box at 0.2 m with one wall cell ``wall``; a robot at (0.5, 0.9) on a straight
  path along row 4 (columns 2-18) that its all-free belief let it plan."""
  grid = box_world(12, 20, res=0.2, walls=((wall[0], wall[0] + 1, wall[1], wall[1] + 1),))
  params = make_params(res=0.2, r_robot=r_robot, r_max=0.3, fov=0.1)
  # The config of test_a_robot_two_cells_wide_does_not_enter_a_two_cell_gap: one program.
  config = config_for(grid.shape, grid.res, params, max_steps=40, n_beams=4, path_capacity=24)
  world = sim.make_world(grid, 0.2, (0.5, 0.9))
  state = on_straight_path_believing_all_free(config, world, params, (0.5, 0.9), 4,
                                              np.arange(2, 19))
  return config, world, params, state


@EAGER_AND_JIT
def test_touched_cells_are_the_occupied_cells_within_the_radius(transform):
  grid = gap_world()
  params = make_params(res=0.1, r_robot=R_ROBOT)
  config = config_for(grid.shape, grid.res, params, max_steps=10)
  world = sim.make_world(grid, R_ROBOT)
  rng = np.random.default_rng(0)
  touched = transform(lambda xy: robot.touched_cells(config, world, params, xy))
  for xy in rng.uniform([0.0, 0.0], [3.0, 2.0], (12, 2)).astype(np.float32):
    cells, touching = jax.tree.map(np.asarray, touched(jnp.asarray(xy)))
    # Brute force over a wide frame: outside the map counts as occupied.
    framed = np.pad(grid.occupied, 5, constant_values=True)
    rows, cols = np.nonzero(framed)
    centres = np.stack([(cols - 5 + 0.5) * 0.1, (rows - 5 + 0.5) * 0.1], axis=1)
    near = np.linalg.norm(centres - xy, axis=1) <= R_ROBOT
    expected = {(r - 5, c - 5) for r, c in zip(rows[near], cols[near])}
    assert {tuple(c) for c in cells[touching]} == expected


def test_a_robot_never_drives_its_disc_into_a_gap_narrower_than_itself():
  """The belief says everything is free (the gap's walls unmapped): the path runs straight
  through the gap. The robot must stop before the waypoint where its disc would touch the wall,
  count the collision, learn the touched cells as occupied, and end its path there; then its
  planner sees the gap closed."""
  grid = gap_world()
  params = make_params(res=0.1, r_robot=R_ROBOT, r_max=0.3, fov=0.1)
  config = config_for(grid.shape, grid.res, params, max_steps=40, n_beams=4, path_capacity=32)
  world = sim.make_world(grid, R_ROBOT, (0.55, 1.05))
  state = on_straight_path_believing_all_free(config, world, params, (0.55, 1.05), 10,
                                              np.arange(5, 30))
  step = lambda s: STEP(config, world, params, s)
  occupied_centres = np.argwhere(grid.occupied)[:, ::-1] * 0.1 + 0.05
  for _ in range(30):
    state, _ = step(state)
    xy = np.asarray(state.pose[:2])
    assert np.linalg.norm(occupied_centres - xy, axis=1).min() >= R_ROBOT - 1e-6
  assert int(state.collisions) == 1  # one contact taught it the wall
  # What it learned closes the gap (rows 9-10 of the wall's column) for its planner.
  view = sim.belief_view(config, params, state, sim.robot_view(config, world, state).cell)
  assert not np.asarray(view.traversable)[9:11, 14:17].any()
  assert float(state.pose[0]) < 1.5 - R_ROBOT + 0.05  # it stopped before the wall
  assert int(state.path_len) < 25  # the path ended at the collision
  believed_occupied = np.asarray(state.logodds) > float(mapping.logit(params.p_occ))
  assert believed_occupied[:, 15].any()  # the wall it touched is in its belief now
  h = np.asarray(mapping.entropy_of_logodds(state.logodds)).sum()
  np.testing.assert_allclose(float(state.entropy), h, rtol=1e-4)


@EAGER_AND_JIT
def test_a_robot_as_wide_as_whole_cells_stands_only_where_the_inflation_lets_it(transform):
  """With ``r_robot`` a whole number of cells, a wall cell centre exactly ``r_robot`` away
  touches the disc, as the planner's inflation counts it: the cells where the disc touches no
  wall are those whose distance to the nearest occupied centre (SciPy's exact Euclidean
  distance transform, outside the map occupied) exceeds the radius."""
  from scipy import ndimage
  rng = np.random.default_rng(3)
  occupied = rng.random((14, 16)) < 0.12
  grid = GridMap(occupied, 0.2, (0.0, 0.0), "speckle")
  config = config_for(grid.shape, grid.res, make_params(res=0.2, r_robot=0.4), max_steps=10)
  world = sim.make_world(grid, 0.2)
  clearance = ndimage.distance_transform_edt(np.pad(~occupied, 1))[1:-1, 1:-1]
  free_cells = np.argwhere(~occupied)
  for r_robot in (0.2, 0.4):
    params = make_params(res=0.2, r_robot=r_robot)
    touch = transform(jax.vmap(lambda xy: jnp.any(
        robot.touched_cells(config, world, params, xy)[1])))
    centres = jnp.asarray((free_cells[:, ::-1] + 0.5) * 0.2, jnp.float32)
    touches = np.asarray(touch(centres))
    expected = clearance[free_cells[:, 0], free_cells[:, 1]] <= r_robot / 0.2 + 1e-9
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(touches, expected)


def test_a_robot_two_cells_wide_does_not_enter_a_two_cell_gap():
  """r_robot = res = 0.2 m (the li2020 preset at 0.2 m cells): the gap in the wall is two cells
  (0.4 m) wide, which the planner's inflation closes once its walls are mapped. With the walls
  unmapped the path runs through it; the robot must collide at the gap's first cell (its disc
  reaches the jambs' centres), learn them, and stay on the near side, from where it can still
  plan (it is not left inside an inflated neck it cannot plan out of)."""
  grid = box_world(12, 20, res=0.2, walls=((0, 5, 10, 11), (7, 12, 10, 11)))
  params = make_params(res=0.2, r_robot=0.2, r_max=0.3, fov=0.1)
  config = config_for(grid.shape, grid.res, params, max_steps=40, n_beams=4, path_capacity=24)
  world = sim.make_world(grid, 0.2, (0.5, 1.1))
  state = on_straight_path_believing_all_free(config, world, params, (0.5, 1.1), 5,
                                              np.arange(2, 19))
  step = lambda s: STEP(config, world, params, s)
  occupied_centres = np.argwhere(grid.occupied)[:, ::-1] * 0.2 + 0.1
  for _ in range(40):
    state, _ = step(state)
    xy = np.asarray(state.pose[:2])
    assert np.linalg.norm(occupied_centres - xy, axis=1).min() > 0.2 + 1e-3
  assert int(state.collisions) >= 1
  assert float(state.pose[0]) < 2.0  # the wall's face is at x = 2.0 m: it stayed before it
  believed_occupied = np.asarray(state.logodds) > float(mapping.logit(params.p_occ))
  assert believed_occupied[4, 10]  # the jamb it touched
  view = sim.belief_view(config, params, state, sim.robot_view(config, world, state).cell)
  assert np.asarray(view.traversable)[tuple(sim.robot_view(config, world, state).cell)]


def test_a_robot_stops_before_a_wall_mapped_after_it_planned():
  """r_robot = res = 0.2 m. The path along row 4 was planned when the wall cell (3, 10) was not
  mapped; now the belief holds it, so the waypoint (4, 10) (one cell from it) is inside the
  robot's radius: the robot must end its path before it (no collision: the wall is known) rather
  than drive on beside the wall into cells its planner no longer plans through."""
  config, world, params, state = row_4_path_past_a_wall_cell((3, 10), r_robot=0.2)
  state = state.replace(logodds=state.logodds.at[3, 10].set(params.l_max))
  step = lambda s: STEP(config, world, params, s)
  for _ in range(20):
    state, _ = step(state)
    xy = np.asarray(state.pose[:2])
    assert np.hypot(xy[0] - 2.1, xy[1] - 0.7) > 0.2 + 1e-3  # never within r of the wall's centre
  assert int(state.collisions) == 0
  assert int(state.path_idx) == int(state.path_len) == 8  # ended before waypoint 8, (4, 10)
  np.testing.assert_allclose(np.asarray(state.pose[:2]), [1.9, 0.9], atol=1e-5)


@pytest.mark.parametrize("cells, moves", [
    ([(11, 15), (12, 15), (13, 15)], True),  # straight away from the wall
    ([(11, 15), (11, 16), (11, 17)], True),  # along it, no nearer (d² 1 -> 2 -> 5)
    ([(12, 15), (11, 15), (11, 14)], False),  # toward it (d² 4 -> 1)
])
def test_a_robot_inside_its_radius_of_a_known_wall_may_step_away_but_not_nearer(cells, moves):
  """r_robot = 2 cells; the belief holds a wall at (10, 15) (pose noise can put a robot inside
  its radius of one): a path may lead it out, never closer."""
  grid = box_world(30, 30, res=0.1)
  params = make_params(res=0.1, r_robot=0.2, r_max=0.3, fov=0.1)
  config = config_for(grid.shape, grid.res, params, max_steps=4, n_beams=4, path_capacity=8)
  start = (cells[0][1] * 0.1 + 0.05, cells[0][0] * 0.1 + 0.05)
  world = sim.make_world(grid, 0.2, start)
  path = np.asarray(cells)
  state = on_straight_path_believing_all_free(config, world, params, start, 0, np.arange(3))
  waypoints = np.concatenate([path, np.repeat(path[-1:], config.path_capacity - 3, axis=0)])
  state = state.replace(logodds=state.logodds.at[10, 15].set(params.l_max),
                        waypoints=jnp.asarray(waypoints, jnp.int32), look_at=jnp.asarray(path[-1]))
  state = state.replace(pose=state.pose.at[2].set(
      np.arctan2(cells[1][0] - cells[0][0], cells[1][1] - cells[0][1])))
  state, _ = sim.step(config, world, params, state)
  moved = not np.allclose(np.asarray(state.pose[:2]), start, atol=1e-6)
  assert moved == moves
  assert int(state.path_len) == (3 if moves else 1)


def test_starts_count_the_map_edge_as_a_wall():
  grid = box_world(20, 30, res=0.1)
  edgeless = grid.__class__(np.zeros((20, 30), bool), 0.1, (0.0, 0.0), "open")
  with pytest.raises(ConfigError, match="closer than the robot radius"):
    sim.make_world(edgeless, 0.2, (0.05, 1.0))
  tiny = grid.__class__(np.zeros((3, 3), bool), 0.1, (0.0, 0.0), "tiny")
  with pytest.raises(ConfigError, match="clearance"):
    sim.make_world(tiny, 0.4)
  sim.make_world(edgeless, 0.2, (1.5, 1.0))  # far from every edge: fine


def _start_verdict(grid, r_robot, xy):
  try:
    sim.make_world(grid, r_robot, xy)
    return True
  except ConfigError:
    return False


def test_a_start_is_judged_alike_at_every_edge_and_wall_as_the_disc_collision_would():
  """Outside the map counts as occupied the same way on every edge: a start ``d`` from the
  left, right, bottom or top edge, or from an interior wall, gets one verdict, and it is the
  motion model's (no occupied cell centre closer than ``r_robot``, :func:`touched_cells`)."""
  h, w, res, r = 20, 30, 0.1, 0.12
  edgeless = GridMap(np.zeros((h, w), bool), res, (0.0, 0.0), "open")
  walled = np.zeros((h, w), bool)
  walled[:, 15:] = True  # an interior wall whose face is at x = 1.5 m
  walled = GridMap(walled, res, (0.0, 0.0), "walled")
  verdicts = []
  for d in np.arange(0.02, 0.4, 0.01):
    at = [_start_verdict(edgeless, r, xy) for xy in
          ((d, 1.0), (w * res - d, 1.0), (1.5, d), (1.5, h * res - d))]
    at.append(_start_verdict(walled, r, (1.5 - d, 1.0)))
    assert len(set(at)) == 1, (d, at)
    # the oracle: each start lies on a cell boundary across the edge, so the nearest occupied
    # centres are half a cell to either side, d + res / 2 beyond it
    nearest = math.hypot(d + res / 2, res / 2)
    verdicts.append(at[0])
    assert at[0] == (nearest >= r), (d, at[0], nearest)
  assert not all(verdicts) and any(verdicts)


def test_a_waypoint_in_a_wall_believed_free_ends_the_path_and_is_learnt():
  """A disc smaller than a cell (so no disc contact comes first) on a path along row 4 through
  the wall cell (4, 10) that its belief holds free: the path ends before it, no collision is
  counted, and the cell becomes occupied in the belief (before, it stayed free and a planner
  chose it again at every plan). Jitted only: 20 eager steps cost ~30 s, and a step eager
  equals a step jitted (tests/test_sim.py::test_step_eager_equals_jit)."""
  config, world, params, state = row_4_path_past_a_wall_cell((4, 10), r_robot=0.05)
  step = lambda s: STEP(config, world, params, s)
  for _ in range(20):
    state, _ = step(state)
  assert int(state.collisions) == 0
  assert int(state.path_idx) == int(state.path_len) == 8  # ended before waypoint 8, (4, 10)
  assert float(state.logodds[4, 10]) == pytest.approx(float(params.l_max))


# One compiled scan for the tests of a robot in a mapped room (the world and parameters traced).
SENSE = jax.jit(robot._sense, static_argnums=0)


def sensed_in_a_mapped_room(truth_pose, estimate, fov):
  """A robot in a 4 m x 4 m walled room split by a wall at x = 2 m, whose belief holds every
  cell at the truth's clamp, scanned (360 beams over ``fov``, 3 m) at ``truth_pose`` while it
  believes itself at ``estimate``. Returns (grid, params, state after the scan)."""
  grid = box_world(40, 40, res=0.1, walls=((8, 32, 20, 21),))
  params = make_params(res=0.1, r_max=3.0, fov=fov)
  config = config_for(grid.shape, grid.res, make_params(res=0.1, r_max=3.0, fov=2 * math.pi),
                      max_steps=10, n_beams=360, pose_noise=True)
  world = sim.make_world(grid, float(params.r_robot), tuple(truth_pose[:2]))
  state = robot.reset(config, world, params, jax.random.PRNGKey(0), jnp.asarray(truth_pose))
  truth = jnp.asarray(grid.occupied)
  state = state.replace(
      logodds=jnp.where(truth, params.l_max, params.l_min).astype(jnp.float32),
      pose_est=jnp.asarray(estimate, jnp.float32), cov=jnp.eye(3, dtype=jnp.float32) * 0.01)
  return grid, params, SENSE(config, world, params, state, jax.random.PRNGKey(1), jnp.bool_(True))


def test_a_scan_that_relocalises_the_robot_is_integrated_at_the_corrected_pose():
  """A robot in a mapped room (its belief holds every cell at the truth's clamp) whose estimate
  is 3 degrees off in heading: the scan relocalises it, and is integrated at the corrected pose,
  as a SLAM front end matches a scan before adding it. Integrated at the pose before the
  correction, it laid the far walls' cells across the room: wall cells seen free, free cells
  seen occupied. Oracle: the truth."""
  grid, params, after = sensed_in_a_mapped_room([1.05, 2.05, 0.3],
                                                [1.05, 2.05, 0.3 + math.radians(3.0)], 2 * math.pi)
  assert abs(float(after.pose_est[2] - after.pose[2])) < math.radians(0.3)  # relocalised
  l = np.asarray(after.logodds)
  assert not np.any(grid.occupied & (l < params.l_max))  # no wall cell saw a free observation
  assert not np.any(~grid.occupied & (l > params.l_min))  # no free cell saw a hit


def test_beams_that_end_off_the_grid_do_not_relocalise_the_robot():
  """Facing the bottom wall (row 0) with a narrow fov, believed 0.12 m nearer it than it is: every
  beam ends beyond the grid's edge, at row -1, on no cell the belief knows, so the scan does not
  relocalise the robot (a wrapped index read row 39, the top wall, as a well-mapped hit of each
  beam). Believed 0.04 m nearer, the ends fall inside the wall and it does relocalise."""
  truth = [2.05, 0.45, -math.pi / 2]
  _, _, off_grid = sensed_in_a_mapped_room(truth, [2.05, 0.33, -math.pi / 2], 0.4)
  np.testing.assert_allclose(np.asarray(off_grid.pose_est), [2.05, 0.33, -math.pi / 2], atol=1e-6)
  _, _, on_grid = sensed_in_a_mapped_room(truth, [2.05, 0.41, -math.pi / 2], 0.4)
  assert abs(float(on_grid.pose_est[1]) - 0.45) < 0.02
