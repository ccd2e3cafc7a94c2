"""The engine's pose graph (sim.State.graph): passive, bounded, recorded, summarised."""

import dataclasses

import jax
import numpy as np
import pytest

from jaxplore import metrics, posegraph, runner, sim
from jaxplore.config import ConfigError, config_for, make_params, validate_params
from tests.conftest import box_world

GRID = box_world(24, 36, 0.1, walls=((8, 16, 12, 14),))


@pytest.fixture(scope="module")
def runs():
  """The same two robots with and without a pose graph (nearest frontier, li2020 preset)."""
  out = {}
  for graph in (False, True):
    out[graph] = runner.run(world=GRID, planner="fd", robots=2, seed=3, max_steps=80, pose_graph=graph,
                            graph_loops=8, progress=False, quiet=True, params={"r_max": 2.0})
  return out


def test_the_graph_is_passive(runs):
  off, on = runs[False], runs[True]
  assert off.state.graph is None and "graph_nodes" not in off.curves
  for name in ("x", "y", "coverage", "entropy"):
    np.testing.assert_array_equal(off.curves[name].to_numpy(), on.curves[name].to_numpy())


def test_graph_within_its_bound_and_recorded(runs):
  on = runs[True]
  config = on.config["sim_config"]
  params = make_params("li2020", res=0.1, r_max=2.0)
  assert config["graph_nodes"] == posegraph.keyframe_bound(80, params.v_max, params.w_max, params.dt,
                                                            params.kf_dist, params.kf_rot)
  graph = on.state.graph
  for b in range(2):
    n, m = int(graph.n_nodes[b]), int(graph.n_loops[b])
    assert 2 <= n <= config["graph_nodes"]
    curve = on.curves[on.curves.robot == b]
    assert curve.graph_nodes.iloc[-1] == n and curve.graph_edges.iloc[-1] == n - 1 + m
    assert np.all(np.diff(curve.graph_nodes.to_numpy()) >= 0)
    weights = np.concatenate([graph.chain_w[b, 1:n], graph.loop_w[b, :m]])
    np.testing.assert_allclose(curve.dopt_mean.iloc[-1], weights.mean(), rtol=1e-5)
    # Keyframe poses lie on the robot's recorded (exact, noise-free) trajectory.
    xy = curve[["x", "y"]].to_numpy()
    for pose in graph.poses[b, 1:n]:
      assert np.min(np.hypot(*(xy - pose[:2]).T)) < 1e-4
    row = on.episodes.iloc[b]
    want = metrics.graph_metrics(graph.chain_w[b], graph.loops[b], graph.loop_w[b], n, m,
                                 int(graph.loops_dropped[b]))
    for key, value in want.items():
      np.testing.assert_allclose(row[key], value, rtol=1e-9)
    got = metrics.map_quality(on.state.logodds[b], GRID.occupied)
    assert row["ssim"] == got["ssim"] and row["rmse"] == got["rmse"]


def test_a_graph_too_small_for_the_run_is_refused():
  params = make_params("li2020", res=0.1)
  config = dataclasses.replace(config_for(GRID.shape, 0.1, params, max_steps=500), graph_nodes=100)
  with pytest.raises(ConfigError, match="holds 100 keyframes.*500 steps"):
    validate_params(params, config)
