"""Tests for jaxplore.graph.dijkstra against SciPy's Dijkstra on the same 8-connected graphs."""

import functools
import math
import re

import chex
import hypothesis
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from conftest import EAGER_AND_JIT
from scipy.sparse.csgraph import dijkstra

from jaxplore.graph import ShortestPaths
from jaxplore.graph import extract_path
from jaxplore.graph import shortest_paths
from jaxplore.graph import shortest_paths_batched
from jaxplore.graph.dijkstra import TILES_AFTER_ROUNDS, default_max_sweeps

RTOL, ATOL = 1e-5, 1e-6


# --- the oracle ------------------------------------------------------------------------------


def grid_graph(node_cost: np.ndarray) -> scipy.sparse.csr_matrix:
  """The 8-connected grid graph: edge u -> v weighs step(u, v) * node_cost[v]; inf = no edge.

  Zero weights are kept as explicit entries, which csgraph treats as edges.
  """
  height, width = node_cost.shape
  index = np.arange(height * width).reshape(height, width)
  flat_cost = np.asarray(node_cost, np.float64).ravel()
  tails, heads, weights = [], [], []
  for dr in (-1, 0, 1):
    for dc in (-1, 0, 1):
      if dr == dc == 0:
        continue
      tail = index[max(0, -dr) : height - max(0, dr), max(0, -dc) : width - max(0, dc)].ravel()
      head = tail + dr * width + dc
      weight = math.hypot(dr, dc) * flat_cost[head]
      keep = np.isfinite(weight)
      tails.append(tail[keep])
      heads.append(head[keep])
      weights.append(weight[keep])
  n = height * width
  return scipy.sparse.csr_matrix(
      (np.concatenate(weights), (np.concatenate(tails), np.concatenate(heads))), shape=(n, n)
  )


def edge_weight(node_cost: np.ndarray, tail: np.ndarray, head: np.ndarray) -> np.ndarray:
  """Weights of edges between flat cell indices (assumed 8-neighbours)."""
  width = node_cost.shape[1]
  diagonal = (tail // width != head // width) & (tail % width != head % width)
  return np.where(diagonal, math.sqrt(2.0), 1.0) * np.asarray(node_cost, np.float64).ravel()[head]


def roots(pred: np.ndarray) -> np.ndarray:
  """For every cell, the cell reached by following pred until a cell with pred -1.

  Pointer jumping: ceil(log2(H * W)) + 1 squarings cover chains of any length up to H * W; a
  cell on (or leading into) a cycle ends on a cell whose pred is not -1.
  """
  flat = pred.ravel()
  jump = np.where(flat >= 0, flat, np.arange(flat.size))
  for _ in range(max(1, math.ceil(math.log2(flat.size))) + 1):
    jump = jump[jump]
  return jump


def assert_shortest_paths(node_cost, source, result: ShortestPaths):
  """dist equals SciPy's; pred is a tree of tight edges rooted at the source."""
  node_cost = np.asarray(node_cost, np.float32)
  height, width = node_cost.shape
  source_flat = int(source[0]) * width + int(source[1])
  chex.assert_shape([result.dist, result.pred], (height, width))
  chex.assert_type(
      [result.dist, result.pred, result.sweeps, result.converged],
      [jnp.float32, jnp.int32, jnp.int32, bool],
  )
  assert bool(result.converged)

  expected = dijkstra(grid_graph(node_cost), indices=source_flat)
  dist = np.asarray(result.dist, np.float64).ravel()
  np.testing.assert_allclose(dist, expected, rtol=RTOL, atol=ATOL)

  pred = np.asarray(result.pred).ravel()
  reachable = np.isfinite(expected)
  reachable[source_flat] = False
  assert np.all(pred[~reachable] == -1), "pred must be -1 at the source and unreachable cells"
  cells = np.flatnonzero(reachable)
  parents = pred[cells]
  assert np.all((parents >= 0) & (parents < height * width))
  row_step = np.abs(parents // width - cells // width)
  col_step = np.abs(parents % width - cells % width)
  assert np.all(np.maximum(row_step, col_step) == 1), "pred must be an 8-neighbour"
  arrival = dist[parents] + edge_weight(node_cost, parents, cells)
  np.testing.assert_allclose(arrival, dist[cells], rtol=RTOL, atol=ATOL, err_msg="pred edge not tight")
  assert np.all(roots(result.pred)[cells] == source_flat), "following pred must reach the source"


# --- worlds ----------------------------------------------------------------------------------


def random_costs(rng, height, width, p_zero=0.2, p_blocked=0.2, integer=False):
  cost = rng.integers(1, 9, (height, width)) if integer else rng.uniform(0.0, 4.0, (height, width))
  cost = cost.astype(np.float32)
  cost[rng.random((height, width)) < p_zero] = 0.0
  cost[rng.random((height, width)) < p_blocked] = np.inf
  return cost


def room_world(rng, size=48, min_room=12):
  """bool[size, size], True = wall: recursive splits with 1-cell walls and 2-4 cell doors."""
  wall = np.zeros((size, size), bool)
  wall[[0, -1], :] = wall[:, [0, -1]] = True

  def split(r0, r1, c0, c1):
    if max(r1 - r0, c1 - c0) < 2 * min_room:
      return
    door = int(rng.integers(2, 5))
    if r1 - r0 >= c1 - c0:
      at = int(rng.integers(r0 + min_room, r1 - min_room + 1))
      opening = int(rng.integers(c0, c1 - door))
      wall[at, c0:c1] = True
      wall[at, opening : opening + door] = False
      split(r0, at, c0, c1)
      split(at + 1, r1, c0, c1)
    else:
      at = int(rng.integers(c0 + min_room, c1 - min_room + 1))
      opening = int(rng.integers(r0, r1 - door))
      wall[r0:r1, at] = True
      wall[opening : opening + door, at] = False
      split(r0, r1, c0, at)
      split(r0, r1, at + 1, c1)

  split(1, size - 1, 1, size - 1)
  return wall


def maze_world(rng, cells=12, corridor=1):
  """A perfect maze (recursive backtracker), bool, True = wall; walls are 1 cell thick."""
  pitch = corridor + 1
  size = cells * pitch + 1
  wall = np.ones((size, size), bool)
  visited = np.zeros((cells, cells), bool)
  stack = [(0, 0)]
  visited[0, 0] = True
  wall[1 : 1 + corridor, 1 : 1 + corridor] = False
  while stack:
    r, c = stack[-1]
    options = [(r + dr, c + dc) for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))
               if 0 <= r + dr < cells and 0 <= c + dc < cells and not visited[r + dr, c + dc]]
    if not options:
      stack.pop()
      continue
    nr, nc = options[int(rng.integers(len(options)))]
    visited[nr, nc] = True
    top, left = 1 + min(r, nr) * pitch, 1 + min(c, nc) * pitch
    bottom, right = 1 + max(r, nr) * pitch + corridor, 1 + max(c, nc) * pitch + corridor
    wall[top:bottom, left:right] = False
    stack.append((nr, nc))
  return wall


def free_cell(rng, wall):
  free = np.argwhere(~wall)
  return free[rng.integers(len(free))].astype(np.int32)


def costs_from_walls(rng, wall, integer=False):
  cost = rng.integers(1, 5, wall.shape) if integer else rng.uniform(0.5, 2.0, wall.shape)
  return np.where(wall, np.inf, cost).astype(np.float32)


# --- shortest_paths --------------------------------------------------------------------------


@EAGER_AND_JIT
@hypothesis.settings(max_examples=25, deadline=None, derandomize=True)
@hypothesis.given(
    # A few shapes only: each new shape costs a compilation, and values are what varies.
    shape=st.sampled_from([(5, 24), (24, 9), (16, 16), (24, 24)]),
    p_zero=st.sampled_from([0.0, 0.3, 0.8]),
    p_blocked=st.floats(0.0, 0.45),
    integer=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
def test_random_grids_match_scipy(transform, shape, p_zero, p_blocked, integer, seed):
  height, width = shape
  rng = np.random.default_rng(seed)
  cost = random_costs(rng, height, width, p_zero, p_blocked, integer)
  source = np.array([rng.integers(height), rng.integers(width)], np.int32)
  assert_shortest_paths(cost, source, transform(shortest_paths)(cost, source))


@EAGER_AND_JIT
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_room_worlds(transform, seed):
  rng = np.random.default_rng(seed)
  wall = room_world(rng)
  cost = costs_from_walls(rng, wall, integer=seed == 2)
  source = free_cell(rng, wall)
  result = transform(shortest_paths)(cost, source)
  assert_shortest_paths(cost, source, result)
  assert int(result.sweeps) <= 10


@EAGER_AND_JIT
@pytest.mark.parametrize("cells, corridor", [(12, 1), (8, 2)])
def test_mazes(transform, cells, corridor):
  rng = np.random.default_rng(corridor)
  wall = maze_world(rng, cells=cells, corridor=corridor)
  cost = costs_from_walls(rng, wall)
  source = free_cell(rng, wall)
  result = transform(shortest_paths)(cost, source)
  assert_shortest_paths(cost, source, result)
  assert int(result.sweeps) > 5  # mazes are the hard case for sweeping: many turns


@EAGER_AND_JIT
def test_integer_costs_are_exact(transform):
  rng = np.random.default_rng(3)
  cost = rng.integers(1, 6, (24, 9)).astype(np.float32)
  cost[rng.random(cost.shape) < 0.2] = np.inf
  source = np.array([4, 7], np.int32)
  result = transform(shortest_paths)(cost, source)
  assert_shortest_paths(cost, source, result)
  expected = dijkstra(grid_graph(cost), indices=4 * 9 + 7).reshape(cost.shape)
  orthogonal_only = np.isfinite(expected) & (expected == np.round(expected))
  np.testing.assert_array_equal(np.asarray(result.dist)[orthogonal_only], expected[orthogonal_only])


@EAGER_AND_JIT
def test_blocked_source_still_plans(transform):
  cost = np.ones((16, 16), np.float32)
  cost[4, 5] = np.inf
  source = np.array([4, 5], np.int32)
  result = transform(shortest_paths)(cost, source)
  assert_shortest_paths(cost, source, result)
  assert float(result.dist[4, 5]) == 0.0 and int(result.pred[4, 5]) == -1
  assert float(result.dist[4, 6]) == 1.0


@EAGER_AND_JIT
def test_unreachable_region(transform):
  cost = np.full((16, 16), 1.5, np.float32)
  cost[6:12, 6] = cost[6:12, 11] = cost[6, 6:12] = cost[11, 6:12] = np.inf  # a closed box
  source = np.array([1, 1], np.int32)
  result = transform(shortest_paths)(cost, source)
  assert_shortest_paths(cost, source, result)
  assert np.all(np.isinf(np.asarray(result.dist)[7:11, 7:11]))
  assert np.all(np.asarray(result.pred)[7:11, 7:11] == -1)


@EAGER_AND_JIT
@pytest.mark.parametrize("shape", [(1, 13), (13, 1), (1, 1)])
def test_single_row_and_column(transform, shape):
  rng = np.random.default_rng(4)
  cost = rng.uniform(0.0, 3.0, shape).astype(np.float32)
  source = np.array([shape[0] // 2, shape[1] // 2], np.int32)
  assert_shortest_paths(cost, source, transform(shortest_paths)(cost, source))


@EAGER_AND_JIT
def test_zero_cost_plateau_is_a_tree(transform):
  cost = np.zeros((24, 24), np.float32)
  cost[:, 8] = np.inf
  cost[8, 8] = 2.0  # the only gate into the right half
  source = np.array([2, 3], np.int32)
  result = transform(shortest_paths)(cost, source)
  assert_shortest_paths(cost, source, result)
  assert np.all(np.asarray(result.dist)[:, 9:] == 2.0)


@EAGER_AND_JIT
def test_max_sweeps_reports_non_convergence(transform):
  rng = np.random.default_rng(5)
  wall = maze_world(rng, cells=12)
  cost = costs_from_walls(rng, wall)
  source = free_cell(rng, wall)
  result = transform(lambda c, s: shortest_paths(c, s, max_sweeps=1))(cost, source)
  assert int(result.sweeps) == 1 and not bool(result.converged)


# --- batching --------------------------------------------------------------------------------


def _batch(seed, batch=7, height=16, width=24):
  rng = np.random.default_rng(seed)
  costs = np.stack([random_costs(rng, height, width, p_zero=0.3) for _ in range(batch)])
  sources = np.stack([rng.integers(0, height, batch), rng.integers(0, width, batch)], axis=1)
  return costs, sources.astype(np.int32)


@EAGER_AND_JIT
@pytest.mark.parametrize("chunk", [3, 16])  # B = 7: padded, and capped at B
def test_batched_equals_per_map(transform, chunk):
  costs, sources = _batch(6)
  batched = transform(lambda c, s: shortest_paths_batched(c, s, chunk=chunk))(costs, sources)
  chex.assert_shape([batched.dist, batched.pred], costs.shape)
  chex.assert_shape([batched.sweeps, batched.converged], (costs.shape[0],))
  for i in range(costs.shape[0]):
    single = shortest_paths(costs[i], sources[i])
    chex.assert_trees_all_equal(jax.tree.map(lambda x: x[i], batched), single)
    assert_shortest_paths(costs[i], sources[i], single)


@EAGER_AND_JIT
def test_vmap_of_single_grid(transform):
  costs, sources = _batch(7)
  vmapped = transform(jax.vmap(shortest_paths))(costs, sources)
  chex.assert_trees_all_equal(vmapped, shortest_paths_batched(costs, sources))
  # One map shared by many sources (in_axes=None on the map), and nested vmap.
  shared = transform(jax.vmap(shortest_paths, in_axes=(None, 0)))(costs[0], sources)
  for i in range(sources.shape[0]):
    assert_shortest_paths(costs[0], sources[i], jax.tree.map(lambda x: x[i], shared))
  nested = transform(jax.vmap(jax.vmap(shortest_paths)))(costs[None, :4], sources[None, :4])
  first_four = jax.tree.map(lambda x: x[:4], vmapped)
  chex.assert_trees_all_equal(jax.tree.map(lambda x: x[0], nested), first_four)


def test_changing_values_does_not_retrace():
  chex.clear_trace_counter()
  solve = jax.jit(chex.assert_max_traces(shortest_paths, n=1))
  solve_batch = jax.jit(chex.assert_max_traces(shortest_paths_batched, n=1))
  walk = jax.jit(chex.assert_max_traces(lambda pred, goal: extract_path(pred, goal, 16), n=1))
  for seed in range(3):
    costs, sources = _batch(seed)
    result = solve(costs[0], sources[0])
    solve_batch(costs, sources)
    walk(result.pred, sources[1])


# --- extract_path ----------------------------------------------------------------------------


def assert_valid_path(node_cost, source, goal, dist, cells, length):
  cells, length = np.asarray(cells), int(length)
  path = cells[:length]
  np.testing.assert_array_equal(path[0], source)
  np.testing.assert_array_equal(path[-1], goal)
  steps = np.abs(np.diff(path, axis=0))
  assert np.all(steps.max(axis=1) == 1), "consecutive cells must be 8-neighbours"
  width = node_cost.shape[1]
  flat = path[:, 0] * width + path[:, 1]
  total = edge_weight(node_cost, flat[:-1], flat[1:]).sum()
  np.testing.assert_allclose(total, float(dist[goal[0], goal[1]]), rtol=RTOL, atol=ATOL)
  assert np.all(cells[length:] == -1)


@EAGER_AND_JIT
def test_extract_path_follows_shortest_path(transform):
  rng = np.random.default_rng(8)
  wall = room_world(rng)
  cost = costs_from_walls(rng, wall)
  source = free_cell(rng, wall)
  result = shortest_paths(cost, source)
  walk = transform(lambda pred, goal: extract_path(pred, goal, 200, source=source))
  for _ in range(5):
    goal = free_cell(rng, wall)
    cells, length = walk(result.pred, goal)
    chex.assert_shape(cells, (200, 2))
    chex.assert_type([cells, length], [jnp.int32, jnp.int32])
    assert_valid_path(cost, source, goal, result.dist, cells, length)
  cells, length = walk(result.pred, source)
  assert int(length) == 1 and np.all(np.asarray(cells[0]) == source)


@EAGER_AND_JIT
def test_extract_path_truncates_on_the_source_side(transform):
  rng = np.random.default_rng(9)
  wall = maze_world(rng, cells=12)
  cost = costs_from_walls(rng, wall)
  source = np.array([1, 1], np.int32)
  goal = np.array([wall.shape[0] - 2, wall.shape[1] - 2], np.int32)
  result = shortest_paths(cost, source)
  full, full_length = extract_path(result.pred, goal, wall.size)
  assert int(full_length) > 20
  cells, length = transform(lambda pred, goal: extract_path(pred, goal, 20))(result.pred, goal)
  assert int(length) == 20
  np.testing.assert_array_equal(np.asarray(cells), np.asarray(full)[:20])
  np.testing.assert_array_equal(np.asarray(cells[0]), source)


@EAGER_AND_JIT
@pytest.mark.parametrize("with_source", [False, True])
def test_extract_path_unreachable_goal(transform, with_source):
  cost = np.ones((16, 16), np.float32)
  cost[:, 5] = np.inf
  source = np.array([3, 1], np.int32)
  result = shortest_paths(cost, source)
  kwargs = dict(source=source) if with_source else {}
  walk = transform(lambda pred, goal: extract_path(pred, goal, 8, **kwargs))
  for goal in ([3, 8], [0, 5]):  # behind the wall, and on it
    cells, length = walk(result.pred, np.array(goal, np.int32))
    assert int(length) == 0 and np.all(np.asarray(cells) == -1)
  cells, length = walk(result.pred, source)
  assert int(length) == 1


@EAGER_AND_JIT
def test_extract_path_batched_with_vmap(transform):
  costs, sources = _batch(10, batch=5)
  results = shortest_paths_batched(costs, sources)
  goals = np.array([[15, 23], [0, 0], [6, 9], [15, 0], [0, 23]], np.int32)
  walk = transform(jax.vmap(lambda pred, goal, source: extract_path(pred, goal, 64, source=source)))
  cells, lengths = walk(results.pred, goals, sources)
  chex.assert_shape(cells, (5, 64, 2))
  for i in range(5):
    if np.isinf(results.dist[i][goals[i][0], goals[i][1]]):
      assert int(lengths[i]) == 0
    else:
      assert_valid_path(costs[i], sources[i], goals[i], results.dist[i], cells[i], lengths[i])


@EAGER_AND_JIT
def test_extract_path_survives_a_cyclic_pred(transform):
  pred = np.full((4, 4), -1, np.int32)
  pred[0, 0], pred[0, 1] = 1, 0  # a 2-cycle
  cells, length = transform(lambda p, g: extract_path(p, g, 5))(pred, np.array([0, 0], np.int32))
  assert int(length) == 0


def test_vmap_chunk_and_the_strategy_set_how_vmap_batches_the_solver():
  """The whole batch as one chunk (the lockstep strategy) solves every grid as chunks of 4 do;
  a planner's context batches as its execution strategy says (STRATEGY_BATCHING)."""
  from jaxplore.planners.base import PlannerContext
  costs, sources = _batch(11)
  default = jax.jit(jax.vmap(shortest_paths))(costs, sources)
  whole_fn = jax.vmap(functools.partial(shortest_paths, vmap_chunk=None))
  whole = jax.jit(whole_fn)(costs, sources)
  chex.assert_trees_all_equal(whole, default)
  # The lax.map over chunks (a scan) runs once for the whole batch, twice for 7 grids in 4s.
  whole_jaxpr = str(jax.make_jaxpr(whole_fn)(costs, sources))
  default_jaxpr = str(jax.make_jaxpr(jax.vmap(shortest_paths))(costs, sources))
  assert re.search(r"length=1\b", whole_jaxpr) and not re.search(r"length=2\b", whole_jaxpr)
  assert re.search(r"length=2\b", default_jaxpr) and not re.search(r"length=1\b", default_jaxpr)
  for strategy, length in (("per_robot", 2), ("lockstep", 1)):
    ctx = PlannerContext(height=costs.shape[1], width=costs.shape[2], res=0.1,
                         dijkstra_max_sweeps=default_max_sweeps(*costs.shape[1:]),
                         dijkstra_tiles_after_rounds=TILES_AFTER_ROUNDS, strategy=strategy)
    jaxpr = str(jax.make_jaxpr(jax.vmap(ctx.shortest_paths))(costs, sources))
    assert re.search(rf"length={length}\b", jaxpr), strategy
  with pytest.raises(ValueError, match="method"):
    shortest_paths(costs[0], sources[0], vmap_method="bellman")


# --- relaxation (the accelerator's method) ---------------------------------------------------


def _same_but_rounds(relaxed: ShortestPaths, swept: ShortestPaths):
  """Distances and predecessors bit for bit; both converged (``sweeps`` counts different things)."""
  np.testing.assert_array_equal(np.asarray(relaxed.dist), np.asarray(swept.dist))
  np.testing.assert_array_equal(np.asarray(relaxed.pred), np.asarray(swept.pred))
  assert np.all(np.asarray(relaxed.converged)) and np.all(np.asarray(swept.converged))


_relaxed = jax.jit(lambda c, s: shortest_paths_batched(c, s, chunk=8, method="relaxation"))
_swept = jax.jit(lambda c, s: shortest_paths_batched(c, s, chunk=8))


def test_relaxation_reaches_the_sweeps_distances_bit_for_bit():
  """Random costs (zeros, plateaus, blocked cells), room worlds, mazes and a zero-cost plateau
  behind a gate: relaxation passes and cone sweeps stop at the same fixed point, and SciPy agrees
  with it."""
  rng = np.random.default_rng(21)
  height = width = 25
  grids = [random_costs(rng, height, width, p_zero, p_blocked, integer)
           for p_zero, p_blocked, integer in [(0.0, 0.1, False), (0.3, 0.3, True), (0.8, 0.2, False),
                                              (0.0, 0.0, False)]]
  grids += [costs_from_walls(rng, room_world(rng, size=25, min_room=6)) for _ in range(2)]
  grids.append(costs_from_walls(rng, maze_world(rng, cells=12, corridor=1)))
  plateau = np.zeros((height, width), np.float32)
  plateau[:, 8] = np.inf
  plateau[8, 8] = 2.0
  grids.append(plateau)
  costs = np.stack(grids)
  sources = np.stack([free_cell(rng, ~np.isfinite(c)) for c in costs]).astype(np.int32)
  relaxed, swept = _relaxed(costs, sources), _swept(costs, sources)
  _same_but_rounds(relaxed, swept)
  for i in range(len(costs)):
    assert_shortest_paths(costs[i], sources[i], jax.tree.map(lambda x: x[i], relaxed))


def test_relaxation_under_vmap_and_its_bound():
  """``vmap_method="relaxation"`` makes ``vmap(shortest_paths)`` relax; a bound below the
  passes a maze needs is reported as non-convergence."""
  costs, sources = _batch(12, batch=5)
  relax = functools.partial(shortest_paths, vmap_chunk=None, vmap_method="relaxation")
  relaxed = jax.jit(jax.vmap(relax))(costs, sources)
  _same_but_rounds(relaxed, _swept(costs, sources))
  rng = np.random.default_rng(5)
  wall = maze_world(rng, cells=12)
  cost = costs_from_walls(rng, wall)[None]
  source = free_cell(rng, wall)[None]
  # max_sweeps=1 bounds relaxation at H + W passes, fewer than this maze's longest path needs.
  bounded = shortest_paths_batched(cost, source, max_sweeps=1, method="relaxation")
  assert not bool(bounded.converged[0])
  assert int(bounded.sweeps[0]) >= sum(wall.shape)


# --- finished tile by tile (mazes) -----------------------------------------------------------


def _corner_passage(size=37):
  """Walls but for a serpentine in the first 16 x 16 tile from (0, 0) to (15, 15) and an open
  room beyond (16, 16): the room is reached only by the diagonal step across the tile corner."""
  cost = np.full((size, size), np.inf, np.float32)
  for r in range(0, 16, 2):
    cost[r, :15] = 1.0
    if r < 14:
      cost[r + 1, 14 if r % 4 == 0 else 0] = 1.0
  cost[14, 15] = cost[15, 15] = 1.0
  cost[16:, 16:] = 1.0
  return cost


def _tile_worlds(seed=31, size=37):
  """37 x 37 grids (3 x 3 tiles of 16, the last row and column mostly padding): mazes with
  1- and 2-cell corridors, a maze with zero-cost stretches (plateaus), a maze whose source is
  a wall cell, random costs with zeros and walls, a room world, and a room reached only across
  a tile corner (source at (0, 0))."""
  rng = np.random.default_rng(seed)
  mazes = [costs_from_walls(rng, maze_world(rng, cells=18, corridor=1)),
           costs_from_walls(rng, maze_world(rng, cells=12, corridor=2))]
  plateaus = costs_from_walls(rng, maze_world(rng, cells=18, corridor=1))
  plateaus[np.isfinite(plateaus) & (rng.random(plateaus.shape) < 0.4)] = 0.0
  walled_source = costs_from_walls(rng, maze_world(rng, cells=18, corridor=1))
  grids = mazes + [plateaus, walled_source, random_costs(rng, size, size, p_zero=0.3),
                   costs_from_walls(rng, room_world(rng, size=size, min_room=8))]
  sources = [free_cell(rng, ~np.isfinite(g)) for g in grids]
  sources[3] = np.argwhere(~np.isfinite(walled_source[1:-1, 1:-1]))[0].astype(np.int32) + 1
  grids.append(_corner_passage(size))
  sources.append(np.zeros(2, np.int32))
  return np.stack(grids), np.stack(sources).astype(np.int32)


def test_tile_by_tile_reaches_the_sweeps_distances_bit_for_bit():
  """Finished tile by tile from the first round on, every grid ends where the sweeps alone end,
  bit for bit, and SciPy agrees; the mazes take fewer whole-grid rounds' worth of work."""
  costs, sources = _tile_worlds()
  tiled = jax.jit(lambda c, s: shortest_paths_batched(c, s, tiles_after_rounds=1))(costs, sources)
  alone = jax.jit(lambda c, s: shortest_paths_batched(c, s, tiles_after_rounds=0))(costs, sources)
  _same_but_rounds(tiled, alone)
  for i in range(len(costs)):
    assert_shortest_paths(costs[i], sources[i], jax.tree.map(lambda x: x[i], tiled))
  assert float(tiled.dist[3][tuple(sources[3])]) == 0.0
  assert np.all(np.isfinite(np.asarray(tiled.dist[-1])[16:, 16:]))
  assert np.all(np.asarray(tiled.sweeps)[:4] < np.asarray(alone.sweeps)[:4])


def test_tile_by_tile_bound_reports_non_convergence():
  """Tile steps count against ``max_sweeps`` in whole-grid rounds: one round's worth of them is
  not enough for a maze, and the result says so."""
  costs, sources = _tile_worlds()
  bounded = shortest_paths_batched(costs[:1], sources[:1], max_sweeps=2, tiles_after_rounds=1)
  assert not bool(bounded.converged[0]) and int(bounded.sweeps[0]) == 2
  with pytest.raises(ValueError, match="tiles_after_rounds"):
    shortest_paths_batched(costs[:1], sources[:1], tiles_after_rounds=-1)


def test_tile_by_tile_under_shard_map():
  """The tiles' loops keep their carries' types under ``shard_map`` (the engine shards the batch
  over host devices that way): the same distances as outside it."""
  from jax.sharding import Mesh, PartitionSpec
  costs, sources = _tile_worlds()
  mesh = Mesh(np.array(jax.devices()[:1]), ("batch",))
  spec = PartitionSpec("batch")
  solve = jax.shard_map(lambda c, s: shortest_paths_batched(c, s, tiles_after_rounds=1), mesh=mesh,
                        in_specs=(spec, spec), out_specs=spec)
  sharded = jax.jit(solve)(costs, sources)
  _same_but_rounds(sharded, shortest_paths_batched(costs, sources, tiles_after_rounds=0))


@pytest.mark.parametrize("method", ["sweeps", "relaxation"])
def test_default_bounds_of_a_large_map_fit_the_loop_counters(method):
  """The default bound on a 1,100 x 1,100 map (H * W rounds, times the tile steps or the line
  passes of a round) passes 2**31 - 1: it caps the int32 loop counters instead of failing to
  trace (it did: OverflowError on real maps of ~1,200 x 1,600 cells)."""
  shape = jax.ShapeDtypeStruct((1, 1100, 1100), jnp.float32)
  source = jax.ShapeDtypeStruct((1, 2), jnp.int32)
  result = jax.eval_shape(lambda c, s: shortest_paths_batched(c, s, method=method), shape, source)
  assert result.dist.shape == (1, 1100, 1100) and result.pred.dtype == jnp.int32
