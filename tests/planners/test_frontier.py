"""Nearest frontier against a SciPy Dijkstra oracle on hand-made beliefs."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from jaxplore import mapping
from jaxplore.config import make_params
from jaxplore.planners import base, get_planner


def grid_graph(passable):
  """8-connected graph over passable cells, edge weight = step length (cells)."""
  h, w = passable.shape
  rows, cols, weights = [], [], []
  idx = np.arange(h * w).reshape(h, w)
  for di in (-1, 0, 1):
    for dj in (-1, 0, 1):
      if (di, dj) == (0, 0):
        continue
      a = idx[max(0, -di):h - max(0, di), max(0, -dj):w - max(0, dj)]
      b = idx[max(0, di):h - max(0, -di) or h, max(0, dj):w - max(0, -dj) or w]
      ok = passable.ravel()[a.ravel()] & passable.ravel()[b.ravel()]
      rows.append(a.ravel()[ok])
      cols.append(b.ravel()[ok])
      weights.append(np.full(ok.sum(), math.sqrt(2) if di and dj else 1.0))
  return coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
                    shape=(h * w, h * w)).tocsr()


def make_view(state, params, config):
  """BeliefView from a 0 free / 1 occupied / 2 unknown grid."""
  l = np.where(state == 0, -3.0, np.where(state == 1, 3.0, 0.0)).astype(np.float32)
  free, occ, unk = mapping.classify(jnp.asarray(l), params)
  inflated = mapping.inflate(occ, params.r_robot / config.res, config.max_inflation_cells)
  return base.BeliefView(logodds=jnp.asarray(l), free=free, occupied=occ,
                         unknown=unk, inflated=inflated, traversable=free & ~inflated,
                         frontier=mapping.frontier(free, unk, occ), blacklist=jnp.zeros(l.shape, bool))


def random_belief(rng, h, w):
  state = np.full((h, w), 2)
  state[2:h - 2, 2:w // 2 + 3] = 0  # a known free block
  state[rng.random((h, w)) < 0.06] = 1
  state[0, :] = state[-1, :] = state[:, 0] = state[:, -1] = 1
  return state


@pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["eager", "jit"])
def test_goal_is_the_nearest_frontier_by_scipy_dijkstra(transform):
  rng = np.random.default_rng(0)
  plan = get_planner("nearest_frontier").plan
  config = base.PlannerContext(height=24, width=30, res=0.1, max_inflation_cells=0, path_capacity=128)
  params = make_params(r_robot=0.0)
  plan_fn = transform(lambda v, r: plan(config, v, r, params, jax.random.PRNGKey(0)))
  for trial in range(4):
    state = random_belief(rng, 24, 30)
    start = (int(rng.integers(3, 20)), int(rng.integers(3, 15)))
    state[start] = 0
    view = make_view(state, params, config)
    robot = base.RobotView(pose=jnp.zeros(3), cell=jnp.asarray(start, jnp.int32), cov=jnp.eye(3))
    result = plan_fn(view, robot)
    dist = dijkstra(grid_graph(np.asarray(view.traversable)), indices=start[0] * 30 + start[1]).reshape(24, 30)
    frontier = np.asarray(view.frontier)
    best = np.min(np.where(frontier, dist, np.inf))
    if not np.isfinite(best):
      assert not bool(result.valid)
      continue
    assert bool(result.valid)
    goal = tuple(np.asarray(result.goal))
    assert frontier[goal]
    np.testing.assert_allclose(float(result.cost), best * config.res, rtol=1e-5)
    n = int(result.length)
    cells = np.asarray(result.waypoints)[:n]
    assert tuple(cells[0]) == start and tuple(cells[-1]) == goal
    assert np.all(np.abs(np.diff(cells, axis=0)).max(axis=1) == 1)
    assert np.asarray(view.traversable)[cells[:, 0], cells[:, 1]].all()


def test_frontier_next_to_a_wall_is_reached_from_the_nearest_standing_cell():
  config = base.PlannerContext(height=12, width=20, res=0.1, max_inflation_cells=2, path_capacity=64)
  params = make_params(r_robot=0.2)
  state = np.full((12, 20), 0)
  state[0, :] = state[-1, :] = state[:, 0] = state[:, -1] = 1
  state[1:11, 15:] = 2  # unknown right part
  state[6, 14] = 1  # a wall cell right at the frontier
  view = make_view(state, params, config)
  robot = base.RobotView(pose=jnp.zeros(3), cell=jnp.asarray([6, 4], jnp.int32), cov=jnp.eye(3))
  result = get_planner("nearest_frontier").plan(config, view, robot, params, jax.random.PRNGKey(0))
  assert bool(result.valid)
  cells = np.asarray(result.waypoints)[: int(result.length)]
  assert np.asarray(view.traversable)[cells[:, 0], cells[:, 1]].all()
  assert np.asarray(view.unknown)[tuple(np.asarray(result.look_at))]


def test_no_frontier_means_no_plan():
  config = base.PlannerContext(height=10, width=10, res=0.1, max_inflation_cells=0, path_capacity=32)
  params = make_params(r_robot=0.0)
  state = np.zeros((10, 10), int)
  state[0, :] = state[-1, :] = state[:, 0] = state[:, -1] = 1
  view = make_view(state, params, config)
  robot = base.RobotView(pose=jnp.zeros(3), cell=jnp.asarray([5, 5], jnp.int32), cov=jnp.eye(3))
  result = get_planner("nearest_frontier").plan(config, view, robot, params, jax.random.PRNGKey(0))
  assert not bool(result.valid) and int(result.length) == 0


def test_plans_finished_tile_by_tile_are_the_same_plans():
  """``dijkstra_tiles_after_rounds`` reaches the planner's solver: down a serpentine corridor
  whose end opens on unknown space, planning tile by tile after one round gives the plan of the
  sweeps alone, bit for bit, at SciPy's cost."""
  params = make_params(r_robot=0.0)
  state = np.ones((40, 40), int)
  for r in range(1, 38, 2):
    state[r, 1:38] = 0
    if r < 37:
      state[r + 1, 37 if r % 4 == 1 else 1] = 0
  state[37, 38] = 2  # the corridor's far end opens on unknown cells
  start = (1, 1)
  plans = []
  for tiles_after_rounds in (0, 1):
    config = base.PlannerContext(height=40, width=40, res=0.1, max_inflation_cells=0,
                                 path_capacity=1024, dijkstra_tiles_after_rounds=tiles_after_rounds)
    view = make_view(state, params, config)
    robot = base.RobotView(pose=jnp.zeros(3), cell=jnp.asarray(start, jnp.int32), cov=jnp.eye(3))
    plan = get_planner("nearest_frontier").plan
    plan_fn = lambda v, r: plan(config, v, r, params, jax.random.PRNGKey(0))
    plans.append(jax.jit(plan_fn)(view, robot))
    # The tile steps pick their tiles with top_k; the sweeps alone never call it.
    assert ("top_k" in str(jax.make_jaxpr(plan_fn)(view, robot))) == bool(tiles_after_rounds)
  jax.tree.map(np.testing.assert_array_equal, plans[0], plans[1])
  dist = dijkstra(grid_graph(np.asarray(view.traversable)), indices=start[0] * 40 + start[1])
  goal = tuple(np.asarray(plans[1].goal))
  assert bool(plans[1].valid) and np.asarray(view.frontier)[goal]
  np.testing.assert_allclose(float(plans[1].cost), dist[goal[0] * 40 + goal[1]] * 0.1, rtol=1e-5)
