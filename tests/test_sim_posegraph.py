"""The engine's pose graph (robot.State.graph): bounded, recorded, summarised."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import metrics, posegraph, results, robot, sim
from jaxplore.config import ConfigError, SimConfig, make_params, validate_params
from tests.conftest import box_world

GRID = box_world(24, 40, 0.1, walls=((8, 16, 16, 18),))
PARAMS = make_params(res=0.1, r_max=2.0, loop_min_age=5.0, loop_radius=2.0)
STEPS = 100
# Once around the wall (east along row 5, north, west along row 19, south) and east again along
# row 5, where the keyframes close loops to the first ones (same heading).
ROUTE = ([(5, c) for c in range(4, 25)] + [(r, 24) for r in range(6, 20)]
         + [(19, c) for c in range(23, 3, -1)] + [(r, 4) for r in range(18, 5, -1)]
         + [(5, c) for c in range(4, 14)])


def drive(graph_nodes: int):
  """One robot following ROUTE for STEPS steps (no planner), with or without a pose graph."""
  config = SimConfig(height=24, width=40, res=0.1, n_beams=32, max_range_cells=20,
                     max_steps=STEPS + 1,
                     path_capacity=len(ROUTE), planner="nearest_frontier", max_inflation_cells=2,
                     graph_nodes=graph_nodes, graph_loops=16, max_loop_cells=20)
  world = sim.make_world(GRID, 0.2)

  @jax.jit
  def run(params):
    start = jnp.asarray([0.45, 0.55, 0.0])
    state = robot.reset(config, world, params, jax.random.PRNGKey(0), start)
    state = state.replace(waypoints=jnp.asarray(ROUTE, jnp.int32), path_len=jnp.int32(len(ROUTE)),
                          path_idx=jnp.int32(1), look_at=jnp.asarray(ROUTE[-1], jnp.int32))
    return jax.lax.scan(lambda s, _: robot.step(config, world, params, s), state, None,
                        length=STEPS)

  return config, world, jax.tree.map(np.asarray, run(PARAMS))


@pytest.fixture(scope="module")
def drives():
  bound = posegraph.keyframe_bound(STEPS + 1, PARAMS.v_max, PARAMS.w_max, PARAMS.dt,
                                   PARAMS.kf_dist, PARAMS.kf_rot)
  return {True: drive(bound)}


def test_graph_within_its_bound_recorded_and_closing_the_loop(drives):
  config, _, (state, rec) = drives[True]
  graph = state.graph
  n, m = int(graph.n_nodes), int(graph.n_loops)
  assert 10 <= n <= config.graph_nodes and m >= 1
  assert rec.graph_nodes[-1] == n and rec.graph_edges[-1] == n - 1 + m
  assert np.all(np.diff(rec.graph_nodes) >= 0) and np.all(np.diff(rec.graph_nodes) <= 1)
  weights = np.concatenate([graph.chain_w[1:n], graph.loop_w[:m]])
  np.testing.assert_allclose(rec.dopt_mean[-1], weights.mean(), rtol=1e-5)
  for a, b in graph.loops[:m]:
    assert b - a >= 5 and np.hypot(*(graph.poses[a, :2] - graph.poses[b, :2])) <= 2.0 + 1e-5
  # Keyframes sit on the estimated trajectory (the true one within the pose error).
  xy = np.stack([rec.x, rec.y], -1)
  for pose in graph.poses[1:n]:
    assert np.min(np.hypot(*(xy - pose[:2]).T)) < 0.05


def test_episode_columns_from_the_final_graph_and_map(drives):
  config, world, (state, rec) = drives[True]
  batch = lambda tree: jax.tree.map(lambda x: None if x is None else np.asarray(x)[None], tree)
  records = jax.tree.map(lambda x: np.asarray(x)[:, None], rec)
  episodes, curves = results.tables(config, GRID, world, batch(state), records, 1.0)
  row = episodes.iloc[0]
  g = state.graph
  want = metrics.graph_metrics(g.chain_w, g.loops, g.loop_w, int(g.n_nodes), int(g.n_loops),
                               int(g.loops_dropped))
  want.update(metrics.dopt_range(rec.dopt_mean))
  want.update(metrics.map_quality(state.logodds, GRID.occupied))
  for key, value in want.items():
    np.testing.assert_allclose(row[key], value, rtol=1e-9)
  steps = int(np.argmax(rec.done)) + 1 if rec.done.any() else len(rec.done)  # rows up to the end
  np.testing.assert_array_equal(curves.graph_nodes.to_numpy(), rec.graph_nodes[:steps])
  np.testing.assert_allclose(curves.dopt_mean.to_numpy(), rec.dopt_mean[:steps], rtol=1e-6)


def test_a_graph_too_small_for_the_run_is_refused():
  config = SimConfig(height=24, width=40, res=0.1, max_steps=500, max_loop_cells=20)
  config = dataclasses.replace(config, graph_nodes=100)
  with pytest.raises(ConfigError, match="holds 100 keyframes.*500 steps"):
    validate_params(PARAMS, config)
