"""The GP/BO planner (Bai et al.; Li's "Method 29"): candidate geometry against NumPy, the chosen
goal against the rules that make a candidate valid, and its mutual information against a NumPy
ray caster and SciPy's Dijkstra. The planner is jitted once and shared by the tests."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from jaxplore import mapping
from jaxplore.config import make_params
from jaxplore.graph import labels
from jaxplore.planners import base, gpbo
from test_virtual_scan import _reference_gain, _reference_observation

H, W, RES = 40, 44, 0.1
FREE, OCC, UNK = 0, 1, 2


SETTINGS = gpbo.Settings(n_test=256, n_beams=48)
CTX = base.PlannerContext(height=H, width=W, res=RES, path_capacity=128, dijkstra_max_sweeps=128,
                          max_inflation_cells=2, max_steps=1000, settings=SETTINGS)
PARAMS = make_params("li2020", r_robot=0.15, r_max=2.5, planner=gpbo.DEFAULTS)
PLAN = jax.jit(lambda view, robot, params, key, memory: gpbo.plan_gpbo(CTX, view, robot, params, key, memory))


def belief():
  """Two rooms: the left one mapped, a door into the right one, unknown beyond."""
  state = np.full((H, W), UNK)
  state[:, :24] = FREE
  state[0, :] = state[-1, :] = state[:, 0] = state[:, -1] = OCC
  state[:, 24] = OCC
  state[14:22, 24] = FREE  # the door
  state[8:12, 6:14] = OCC  # a pillar
  return state


def make_view(state, params=PARAMS):
  l = np.where(state == FREE, -3.0, np.where(state == OCC, 3.0, 0.0)).astype(np.float32)
  free, occ, unk = mapping.classify(jnp.asarray(l), params)
  inflated = mapping.inflate(occ, params.r_robot / RES, CTX.max_inflation_cells)
  return base.BeliefView(logodds=jnp.asarray(l), free=free, occupied=occ, unknown=unk,
                         inflated=inflated, traversable=free & ~inflated,
                         frontier=mapping.frontier(free, unk, occ), blacklist=jnp.zeros((H, W), bool))


def robot_at(cell, theta=0.0):
  return base.RobotView(pose=jnp.asarray([(cell[1] + 0.5) * RES, (cell[0] + 0.5) * RES, theta], jnp.float32),
                        cell=jnp.asarray(cell, jnp.int32), cov=jnp.eye(3, dtype=jnp.float32) * 1e-4)


def scipy_distances(traversable, source):
  """Path length (m) over 8-connected traversable cells, unit node cost per cell step."""
  idx = np.arange(H * W).reshape(H, W)
  rows, cols, data = [], [], []
  for di in (-1, 0, 1):
    for dj in (-1, 0, 1):
      if (di, dj) == (0, 0):
        continue
      a = traversable[max(0, -di):H - max(0, di), max(0, -dj):W - max(0, dj)]
      b = traversable[max(0, di):H - max(0, -di) or None, max(0, dj):W - max(0, -dj) or None]
      ok = a & b
      src = idx[max(0, -di):H - max(0, di), max(0, -dj):W - max(0, dj)][ok]
      dst = idx[max(0, di):H - max(0, -di) or None, max(0, dj):W - max(0, -dj) or None][ok]
      rows += src.tolist()
      cols += dst.tolist()
      data += [math.hypot(di, dj)] * len(src)
  graph = coo_matrix((data, (rows, cols)), shape=(H * W, H * W)).tocsr()
  return dijkstra(graph, indices=source[0] * W + source[1]).reshape(H, W) * RES


def test_candidate_poses_face_their_reference_from_every_radius():
  reference = jnp.asarray([[10, 20], [3, 4]], jnp.int32)
  cells, yaws, group = jax.jit(lambda f: gpbo.candidate_poses(f, SETTINGS, RES))(reference)
  assert cells.shape == (2 * 30 * 9, 2)
  cells, yaws, group = np.asarray(cells), np.asarray(yaws), np.asarray(group)
  for i in range(0, cells.shape[0], 7):
    g = group[i]
    j, k = divmod(i % (30 * 9), 9)
    psi, radius = 2 * math.pi * j / 30, 1.0 + 0.5 * k
    assert abs(yaws[i] - psi) < 1e-6
    x = (float(reference[g, 1]) + 0.5) * RES - radius * math.cos(psi)
    y = (float(reference[g, 0]) + 0.5) * RES - radius * math.sin(psi)
    assert (cells[i] == [math.floor(y / RES + 1e-9), math.floor(x / RES + 1e-9)]).all() or \
        np.abs(cells[i] - [y / RES, x / RES]).max() < 1 + 1e-4  # a coordinate on a cell edge


def test_reference_cell_is_the_cluster_cell_nearest_its_centroid():
  view = make_view(belief())
  found, reference = jax.jit(lambda f: (lambda c: (c, gpbo.reference_cells(c)))(
      labels.clusters(f, SETTINGS.max_groups)))(view.frontier)
  reference = np.asarray(reference)
  ids = np.asarray(found.ids)
  for k in np.nonzero(np.asarray(found.valid))[0]:
    cells = np.argwhere(ids == k)
    centroid = cells.mean(0)
    d2 = ((cells - centroid) ** 2).sum(1)
    assert ids[tuple(reference[k])] == k
    assert ((reference[k] - centroid) ** 2).sum() <= d2.min() + 1e-6


def _numpy_mi(state, goal, reference, robot_cell, params):
  """MI per metre for every heading/radius that puts a candidate of ``reference`` on ``goal``."""
  l = np.where(state == FREE, -3.0, np.where(state == OCC, 3.0, 0.0)).astype(np.float32)
  trav = np.asarray(make_view(state).traversable)
  path = scipy_distances(trav, robot_cell)[tuple(goal)]
  values = []
  for j in range(30):
    psi = 2 * math.pi * j / 30
    for k in range(9):
      radius = (1.0 + 0.5 * k) / RES
      v = reference[0] + 0.5 - radius * math.sin(psi)
      u = reference[1] + 0.5 - radius * math.cos(psi)
      if (math.floor(v), math.floor(u)) != tuple(goal):
        continue
      fov = float(params.fov)
      angles = psi - fov / 2 + fov / 47 * np.arange(48)
      seen, _ = _reference_observation(l, goal[1] + 0.5, goal[0] + 0.5, angles, float(params.r_max) / RES)
      values.append(_reference_gain(l, seen, 0, RES) / max(path, 0.25))
  return values, path


def test_plan_goes_to_a_valid_candidate_with_the_mi_numpy_computes():
  state = belief()
  view = make_view(state)
  robot = robot_at((30, 5))
  plan, memory = PLAN(view, robot, PARAMS, jax.random.key(0), gpbo.init_memory(CTX, PARAMS))
  assert bool(plan.valid)
  goal = np.asarray(plan.goal)
  trav, frontier = np.asarray(view.traversable), np.asarray(view.frontier)
  assert trav[tuple(goal)]
  # >= 0.3 m from every frontier cell, >= 0.25 m from the robot
  assert ndimage.distance_transform_edt(~frontier)[tuple(goal)] * RES > 0.3 - 1e-6
  assert np.hypot(*(goal - [30, 5])) * RES >= 0.25
  # A path of 8-neighbour steps over traversable cells from the robot to the goal.
  cells = np.asarray(plan.waypoints)[: int(plan.length)]
  assert (cells[0] == [30, 5]).all() and (cells[-1] == goal).all()
  assert np.abs(np.diff(cells, axis=0)).max() <= 1 and trav[cells[:, 0], cells[:, 1]].all()
  values, path = _numpy_mi(state, goal, np.asarray(plan.look_at), (30, 5), PARAMS)
  np.testing.assert_allclose(float(plan.cost), path, rtol=1e-5)
  assert values and min(abs(v - float(plan.gain)) / v for v in values) < 0.02, (values, float(plan.gain))
  assert np.all(np.isfinite(np.asarray(memory.raw)))
  assert not np.allclose(memory.raw, gpbo.init_memory(CTX, PARAMS).raw) and int(memory.turns) == 0


def test_a_mapped_room_without_frontiers_ends_the_exploration():
  state = belief()
  state[:, 24:] = OCC
  state[:, 24:] = np.where(np.arange(W)[24:] < W - 1, FREE, OCC)
  state[0, :] = state[-1, :] = OCC
  view = make_view(state)
  assert not np.asarray(view.frontier).any()
  memory = gpbo.init_memory(CTX, PARAMS)
  plan, new_memory = PLAN(view, robot_at((30, 5)), PARAMS, jax.random.key(1), memory)
  assert not bool(plan.valid) and int(plan.length) == 0 and int(plan.n_candidates) == 0
  # No frontier group left: no turn in place either.
  np.testing.assert_array_equal(np.asarray(new_memory.raw), np.asarray(memory.raw))
  assert int(new_memory.turns) == 0


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
def test_gpbo_explores_a_box_world_with_rooms_to_completion():
  from conftest import box_world
  from jaxplore import sim
  from jaxplore.config import config_for
  # Three rooms off a corridor, 1 m doors.
  grid = box_world(40, 60, walls=((14, 15, 0, 18), (14, 15, 28, 60), (15, 40, 30, 31),
                                  (15, 26, 15, 16), (30, 40, 15, 16)))
  params = make_params(res=grid.res, r_max=2.5, fov=2 * math.pi, r_robot=0.1, planner=gpbo.DEFAULTS)
  # plan_chunk=1: the engine compiles the planner once, unbatched (the conformance test runs it
  # vmapped).
  config = config_for(grid.shape, grid.res, params, max_steps=300, n_beams=72,
                      planner=gpbo.GPBO.with_settings(SETTINGS), plan_window=0, plan_chunk=1)
  world = sim.make_world(grid, 0.1)
  robots = 2
  state, records = sim.rollout(config, world, sim.broadcast_params(params, robots),
                               jax.random.split(jax.random.key(5), robots))
  reasons = [sim.REASONS[int(r)] for r in np.asarray(state.reason)]
  assert reasons == ["complete"] * robots, (reasons, np.asarray(state.steps))


def pocket(radius=3):
  """A robot's first look: a small free pocket around (20, 20), unknown all around it."""
  state = np.full((H, W), UNK)
  state[20 - radius:21 + radius, 20 - radius:21 + radius] = FREE
  return state


@pytest.mark.parametrize("theta", [0.0, 2.5, -1.2])
def test_too_few_candidates_with_frontiers_left_turn_the_robot_in_place(theta):
  # Every candidate lies >= 1 m (10 cells) from a frontier of the 7x7 pocket: in unknown space.
  view = make_view(pocket())
  assert np.asarray(view.frontier).any()
  memory = gpbo.init_memory(CTX, PARAMS)
  plan, new_memory = PLAN(view, robot_at((20, 20), theta), PARAMS, jax.random.key(2), memory)
  assert bool(plan.valid) and int(plan.length) == 1 and int(plan.n_candidates) < SETTINGS.min_valid
  np.testing.assert_array_equal(np.asarray(plan.goal), [20, 20])
  np.testing.assert_array_equal(np.asarray(plan.waypoints[0]), [20, 20])
  # The look-at cell is where heading + 60° points (x = column, y = row), inside the grid.
  look = np.asarray(plan.look_at)
  assert 0 <= look[0] < H and 0 <= look[1] < W
  bearing = math.atan2(look[0] + 0.5 - 20.5, look[1] + 0.5 - 20.5)
  error = (bearing - theta - PARAMS.planner["rescan_angle"] + math.pi) % (2 * math.pi) - math.pi
  assert abs(error) < math.radians(3), (look, math.degrees(error))
  assert int(new_memory.turns) == 1
  np.testing.assert_array_equal(np.asarray(new_memory.raw), np.asarray(memory.raw))


def test_the_last_allowed_turn_without_candidates_ends_the_exploration():
  view = make_view(pocket())
  memory = gpbo.init_memory(CTX, PARAMS).replace(turns=jnp.int32(SETTINGS.rescan_turns))
  plan, new_memory = PLAN(view, robot_at((20, 20)), PARAMS, jax.random.key(2), memory)
  assert not bool(plan.valid) and int(plan.length) == 0
  assert int(new_memory.turns) == SETTINGS.rescan_turns


def test_a_plan_with_enough_candidates_resets_the_turn_count():
  memory = gpbo.init_memory(CTX, PARAMS).replace(turns=jnp.int32(3))
  plan, new_memory = PLAN(make_view(belief()), robot_at((30, 5)), PARAMS, jax.random.key(0), memory)
  assert bool(plan.valid) and int(plan.length) > 1 and int(new_memory.turns) == 0


@pytest.mark.parametrize("weights, says", [
    ({"delta": 1.0}, "weight delta must be"), ({"learning_rate": 0.0}, "weight learning_rate"),
    ({"gain_kind": 1.5}, "weight gain_kind must be"),
    ({"rescan_angle": 2 * math.pi}, "weight rescan_angle must be")])
def test_a_weight_outside_its_declared_range_is_refused_before_compute(weights, says):
  from jaxplore.config import ConfigError
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec
  with pytest.raises(ConfigError, match=f"planner 'gpbo': {says}"):
    resolve(RunSpec.create(world="lab", planner="gpbo", robots=1, params=weights))


@pytest.mark.parametrize("setting", [{"n_yaws": 0}, {"radius_min": 0.0}, {"bo_iterations": -1},
                                     {"n_beams": gpbo.MAX_BEAMS + 1}])
def test_a_static_setting_outside_its_declared_range_is_refused_naming_it(setting):
  from jaxplore.config import ConfigError
  (name,) = setting
  with pytest.raises(ConfigError, match=f"planner 'gpbo': setting {name} must be"):
    base.get_planner("gpbo").resolve_settings(setting)
