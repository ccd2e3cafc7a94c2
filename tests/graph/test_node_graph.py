"""The dense node-graph Dijkstra against SciPy's Dijkstra on random graphs."""

import jax
import numpy as np
import scipy.sparse
from conftest import EAGER_AND_JIT
from scipy.sparse.csgraph import dijkstra as scipy_dijkstra

from jaxplore.graph import node_graph

N = 24


def random_graph(rng, n, density):
  """Symmetric random weights (inf = no edge), with some isolated nodes and zero-length edges."""
  weights = np.where(rng.random((n, n)) < density, rng.uniform(0.1, 5.0, (n, n)), np.inf)
  weights[rng.random((n, n)) < 0.02] = 0.0
  weights = np.minimum(weights, weights.T)
  np.fill_diagonal(weights, np.inf)
  isolated = rng.choice(n, 3, replace=False)
  weights[isolated, :] = weights[:, isolated] = np.inf
  return weights.astype(np.float32)


def scipy_oracle(weights, source):
  finite = np.isfinite(weights)
  rows, cols = np.nonzero(finite)
  # csgraph drops explicit zeros from a dense matrix; from coordinates it keeps them as edges.
  matrix = scipy.sparse.csr_matrix((weights[rows, cols].astype(np.float64), (rows, cols)),
                                   shape=weights.shape)
  return scipy_dijkstra(matrix, indices=source)


@EAGER_AND_JIT
def test_distances_and_predecessors_match_scipy(transform):
  rng = np.random.default_rng(3)
  solve = transform(node_graph.dijkstra)
  hops = transform(jax.vmap(node_graph.first_hop, in_axes=(None, None, 0)))
  for density, source in ((0.08, 0), (0.3, 13)):
    weights = random_graph(rng, N, density)
    dist, pred = (np.asarray(a) for a in solve(weights, source))
    expected = scipy_oracle(weights, source)
    np.testing.assert_allclose(dist, expected, rtol=1e-5)
    reach = np.isfinite(expected)
    assert pred[source] == -1 and np.all(pred[~reach] == -1)
    first = np.asarray(hops(pred, source, np.arange(N)))
    for v in np.nonzero(reach)[0]:
      if v == source:
        continue
      u = pred[v]
      assert u >= 0 and np.isfinite(weights[u, v])
      np.testing.assert_allclose(dist[u] + weights[u, v], dist[v], rtol=1e-5)
      # The first hop is the node after the source on the walk back from v.
      walk = [v]
      while pred[walk[-1]] != source:
        walk.append(pred[walk[-1]])
      assert first[v] == walk[-1]
    assert first[source] == source and np.all(first[~reach] == -1)


def test_under_vmap_matches_one_by_one():
  rng = np.random.default_rng(4)
  weights = np.stack([random_graph(rng, N, 0.15) for _ in range(3)])
  sources = np.array([0, 5, 9])
  dist, _ = jax.vmap(node_graph.dijkstra)(weights, sources)
  for k in range(3):
    np.testing.assert_allclose(np.asarray(dist[k]), scipy_oracle(weights[k], sources[k]), rtol=1e-5)
