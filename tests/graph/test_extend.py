"""Extension of a shortest-path field into non-traversable cells, against a plain NumPy loop."""

import math

import jax
import numpy as np
import pytest

from jaxplore.graph.extend import extend_into

VARIANTS = pytest.mark.parametrize("variant", [lambda f: f, jax.jit], ids=["eager", "jit"])


def reference(dist, pred, allowed, steps):
  """``steps`` Jacobi rounds: every unreached allowed cell takes its best 8-neighbour (first in
  row-major neighbour order on ties) plus the step length, read from the previous round."""
  h, w = dist.shape
  target = allowed & ~np.isfinite(dist)
  dist, pred = dist.copy(), pred.copy()
  for _ in range(steps):
    new_dist, new_pred = dist.copy(), pred.copy()
    for r in range(h):
      for c in range(w):
        if not target[r, c]:
          continue
        for dr in (-1, 0, 1):
          for dc in (-1, 0, 1):
            rr, cc = r + dr, c + dc
            if (dr, dc) == (0, 0) or not (0 <= rr < h and 0 <= cc < w):
              continue
            cand = np.float32(dist[rr, cc] + np.float32(math.sqrt(2.0) if dr and dc else 1.0))
            if cand < new_dist[r, c]:
              new_dist[r, c], new_pred[r, c] = cand, rr * w + cc
    dist, pred = new_dist, new_pred
  return dist, pred


@VARIANTS
@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("steps", [1, 2, 4])
def test_matches_numpy_loop(variant, seed, steps):
  rng = np.random.default_rng(seed)
  h, w = 12, 15
  reached = rng.random((h, w)) < 0.4
  dist = np.where(reached, rng.integers(0, 20, (h, w)).astype(np.float32), np.inf).astype(np.float32)
  pred = np.where(reached, rng.integers(0, h * w, (h, w)), -1).astype(np.int32)
  allowed = rng.random((h, w)) < 0.6
  fn = variant(lambda d, p, a: extend_into(d, p, a, steps))
  got_dist, got_pred = (np.asarray(x) for x in fn(dist, pred, allowed))
  want_dist, want_pred = reference(dist, pred, allowed, steps)
  np.testing.assert_array_equal(got_dist, want_dist)
  np.testing.assert_array_equal(got_pred, want_pred)
  # Reached cells never change, and no cell outside `allowed` is reached by extension.
  np.testing.assert_array_equal(got_dist[reached], dist[reached])
  assert np.all(np.isinf(got_dist[~reached & ~allowed]))
