"""Host-side metrics (jaxplore.metrics) against scikit-image, NetworkX and NumPy."""

import math

import networkx as nx
import numpy as np
import pytest
from skimage.metrics import structural_similarity

from jaxplore import metrics


def random_pose_graph(rng, n, m):
  chain_w = np.zeros(n + 3)
  chain_w[1:n] = rng.uniform(100.0, 4000.0, n - 1)
  pairs = set()
  while len(pairs) < m:
    a = int(rng.integers(0, n - 16))
    pairs.add((a, int(rng.integers(a + 15, n))))
  loops = np.zeros((m + 2, 2), np.int32)
  loops[:m] = sorted(pairs)
  loop_w = np.zeros(m + 2)
  loop_w[:m] = 1 / 0.018**2
  return chain_w, loops, loop_w


def to_networkx(chain_w, loops, loop_w, n, m):
  g = nx.Graph()
  g.add_nodes_from(range(n))
  for k in range(1, n):
    g.add_edge(k - 1, k, weight=chain_w[k])
  for (a, b), w in zip(loops[:m], loop_w[:m]):
    g.add_edge(int(a), int(b), weight=w)
  return g


@pytest.mark.parametrize("n,m", [(40, 6), (900, 120)], ids=["dense", "sparse"])
def test_graph_metrics_match_networkx(n, m):
  rng = np.random.default_rng(n)
  chain_w, loops, loop_w = random_pose_graph(rng, n, m)
  got = metrics.graph_metrics(chain_w, loops, loop_w, n, m, loops_dropped=3)
  g = to_networkx(chain_w, loops, loop_w, n, m)
  assert got["graph_nodes"] == n and got["graph_edges"] == g.number_of_edges()
  assert got["loops_dropped"] == 3
  np.testing.assert_allclose(got["avg_degree"], np.mean([d for _, d in g.degree()]))
  want_l2 = nx.algebraic_connectivity(g, weight="weight", method="tracemin_lu", tol=1e-12)
  np.testing.assert_allclose(got["lambda2"], want_l2, rtol=1e-5)
  lap = nx.laplacian_matrix(g, weight="weight").toarray()
  sign, logdet = np.linalg.slogdet(lap[1:, 1:])
  assert sign > 0
  np.testing.assert_allclose(got["logdet"], logdet, rtol=1e-9)
  np.testing.assert_allclose(got["tau_hat"], logdet / ((n - 2) * math.log(n)), rtol=1e-9)
  weights = [w for _, _, w in g.edges(data="weight")]
  np.testing.assert_allclose(got["dopt_mean"], np.mean(weights))
  if n < 60:
    trees = nx.number_of_spanning_trees(g, weight="weight")
    np.testing.assert_allclose(got["logdet"], math.log(trees), rtol=1e-9)


def test_map_quality_is_skimage_ssim_and_numpy_rmse():
  rng = np.random.default_rng(0)
  truth = rng.random((40, 50)) < 0.3
  logodds = np.where(truth, 2.0, -2.0) + rng.normal(0, 1.5, truth.shape)
  logodds[:10] = 0.0  # unknown: P = 0.5
  got = metrics.map_quality(logodds.astype(np.float32), truth)
  p = 1 / (1 + np.exp(-logodds.astype(np.float32).astype(np.float64)))
  want = structural_similarity(p, truth.astype(float), data_range=1.0)
  assert got["ssim"] == pytest.approx(want, rel=1e-9)
  assert got["rmse"] == pytest.approx(math.sqrt(np.mean((p - truth) ** 2)), rel=1e-9)
  perfect = metrics.map_quality(np.where(truth, 50.0, -50.0), truth)
  assert perfect["ssim"] == pytest.approx(1.0) and perfect["rmse"] == pytest.approx(0.0, abs=1e-12)


def test_dopt_range():
  got = metrics.dopt_range([np.nan, 4000.0, 3000.0, 3500.0, 2000.0, 2500.0])
  assert got == {"dopt_max": 4000.0, "dopt_min": 2000.0, "dopt_R": 50.0}
  assert all(math.isnan(v) for v in metrics.dopt_range([np.nan]).values())
