"""The scan_matching model's back end (jaxplore.slam.model.optimise): a loop edge that disagrees
with the rest of the graph at the optimum is revoked, and the graph optimised without it, against
GTSAM's optimum of the graph without that edge."""

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import posegraph
from jaxplore.slam import model
from tests.conftest import EAGER_AND_JIT
from tests.slam.test_optimiser import (
  Graph,
  _between,
  _information,
  assert_poses_close,
  gtsam_optimum,
  square_graph,
)

N_CAP, M_CAP = 64, 32
CONFIG = types.SimpleNamespace(slam_iterations=30)


def with_false_loop(graph: Graph, older=5, newer=47, off=(1.0, 0.0, 0.0)) -> Graph:
  """``graph`` and one more loop edge from ``older`` to ``newer`` measured ``off`` (m, m, rad) from
  the truth: an aliased place taken for the one it resembles, as confident as the true loops."""
  truth = square_graph(noise=0.0).init
  measured = _between(truth[older], truth[newer]) + np.asarray(off)
  info = _information(np.random.default_rng(1), np.array([0.02, 0.02, 0.01]))
  return Graph(graph.init, np.append(graph.src, older), np.append(graph.dst, newer),
               np.vstack([graph.measured, measured]), np.concatenate([graph.information, [info]]))


def pose_graph(graph: Graph):
  """A scan_matching :class:`~jaxplore.posegraph.PoseGraph` holding ``graph`` (its chain as the
  odometry edges i − 1 -> i, the rest as loop edges in order)."""
  n = graph.n
  g = posegraph.init(graph.init[0], N_CAP, M_CAP, beams=1)
  chain = graph.dst == graph.src + 1
  assert np.array_equal(np.sort(graph.dst[chain]), np.arange(1, n))
  order = np.argsort(graph.dst[chain])
  chain_measured = np.zeros((N_CAP, 3), np.float32)
  chain_info = np.tile(np.eye(3, dtype=np.float32), (N_CAP, 1, 1))
  chain_measured[1:n] = graph.measured[chain][order]
  chain_info[1:n] = graph.information[chain][order]
  m = int(np.sum(~chain))
  loops = np.zeros((M_CAP, 2), np.int32)
  loops[:m] = np.stack([graph.src[~chain], graph.dst[~chain]], axis=1)
  loop_measured = np.zeros((M_CAP, 3), np.float32)
  loop_measured[:m] = graph.measured[~chain]
  loop_info = np.tile(np.eye(3, dtype=np.float32), (M_CAP, 1, 1))
  loop_info[:m] = graph.information[~chain]
  poses = np.zeros((N_CAP, 3), np.float32)
  poses[:n] = graph.init
  return g.replace(poses=jnp.asarray(poses), n_nodes=jnp.int32(n), n_loops=jnp.int32(m),
                   chain_measured=jnp.asarray(chain_measured), chain_info=jnp.asarray(chain_info),
                   loops=jnp.asarray(loops), loop_measured=jnp.asarray(loop_measured),
                   loop_info=jnp.asarray(loop_info),
                   loop_w=jnp.asarray(np.arange(M_CAP) < m, jnp.float32))


def without(graph: Graph, edge: int) -> Graph:
  keep = np.arange(len(graph.src)) != edge
  return Graph(graph.init, graph.src[keep], graph.dst[keep], graph.measured[keep],
               graph.information[keep])


def optimise(transform, graph, gate):
  params = types.SimpleNamespace(loop_revoke_chi2=jnp.float32(gate))
  return transform(lambda g: model.optimise(CONFIG, params, g))(graph)


@EAGER_AND_JIT
def test_a_false_loop_is_revoked_and_the_rest_optimised_as_gtsam_does(transform):
  clean = square_graph()
  graph = with_false_loop(clean)
  m = int(np.sum(graph.dst != graph.src + 1))
  out = optimise(transform, pose_graph(graph), 16.27)
  revoked = np.asarray(out.loop_revoked)
  assert revoked[m - 1], f"the false loop's χ² was {float(out.loop_chi2[m - 1]):.1f}"
  assert not revoked[:m - 1].any(), f"true loops revoked: {np.flatnonzero(revoked[:m - 1])}"
  assert float(out.loop_w[m - 1]) == 0.0 and np.all(np.asarray(out.loop_w[:m - 1]) == 1.0)
  assert int(out.optimisations) == 1
  want, _ = gtsam_optimum(without(graph, len(graph.src) - 1))
  assert_poses_close(np.asarray(out.poses)[:graph.n], want)
  # At the optimum without it, every true loop agrees with the graph within the gate.
  assert float(jnp.max(out.loop_chi2[:m - 1])) <= 16.27


@EAGER_AND_JIT
def test_with_the_gate_off_every_loop_stays(transform):
  graph = with_false_loop(square_graph())
  out = optimise(transform, pose_graph(graph), 0.0)
  assert not np.asarray(out.loop_revoked).any()
  want, _ = gtsam_optimum(graph)
  assert_poses_close(np.asarray(out.poses)[:graph.n], want)
  m = int(np.sum(graph.dst != graph.src + 1))
  # loop_chi2 is each edge's r^T Ω r at those poses: the false loop's stands out.
  assert int(np.argmax(np.asarray(out.loop_chi2))) == m - 1


def test_true_loops_after_a_long_drift_stay():
  """Three laps dead-reckoned with odometry three times noisier than its edges claim: the true
  loops pull the chain a long way, and every one of them stays."""
  graph = square_graph(seed=3, noise=3.0)
  start = np.asarray(graph.init)
  out = optimise(jax.jit, pose_graph(graph), 16.27)
  assert not np.asarray(out.loop_revoked).any(), np.asarray(out.loop_chi2)
  truth = square_graph(seed=3, noise=0.0).init
  drift = np.max(np.hypot(*(start[:, :2] - truth[:, :2]).T))
  assert drift > 1.0, f"the test's chain drifted only {drift:.2f} m"
  want, _ = gtsam_optimum(graph)
  assert_poses_close(np.asarray(out.poses)[:graph.n], want)


@pytest.mark.parametrize("count", [2, 4])
def test_several_false_loops_are_revoked_up_to_the_limit(count):
  """Each pass revokes the worst edge; at most MAX_REVOCATIONS in one back-end run."""
  graph = square_graph()
  for k in range(count):
    graph = with_false_loop(graph, older=3 + 4 * k, newer=45 + 2 * k, off=(0.0, 1.2, 0.0))
  m = int(np.sum(graph.dst != graph.src + 1))
  out = optimise(jax.jit, pose_graph(graph), 16.27)
  revoked = np.asarray(out.loop_revoked)[:m]
  assert revoked.sum() == min(count, model.MAX_REVOCATIONS)
  assert revoked[m - count:].sum() == min(count, model.MAX_REVOCATIONS)
