"""jaxplore.linalg against NumPy/SciPy, and the shape of its CPU calls: one matrix per LAPACK call
(a batched call splits over XLA:CPU's thread pool and deadlocks two host devices)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from jaxplore import linalg
from tests.conftest import EAGER_AND_JIT, lapack_calls


def _spd(batch=(2, 3), n=5, seed=0):
  a = np.random.default_rng(seed).normal(size=(*batch, n, n)).astype(np.float32)
  return a @ np.swapaxes(a, -1, -2) + n * np.eye(n, dtype=np.float32)


@EAGER_AND_JIT
def test_factorisations_match_numpy_and_scipy_under_nested_vmap(transform):
  m = _spd()
  chol = transform(jax.vmap(jax.vmap(linalg.cholesky)))(m)
  np.testing.assert_allclose(chol, np.linalg.cholesky(m), rtol=1e-5, atol=1e-5)
  np.testing.assert_allclose(transform(jax.vmap(jax.vmap(linalg.eigvalsh)))(m),
                             np.linalg.eigvalsh(m), rtol=1e-5, atol=1e-4)
  np.testing.assert_allclose(transform(jax.vmap(jax.vmap(linalg.inv)))(m), np.linalg.inv(m),
                             rtol=1e-4, atol=1e-5)
  l = np.asarray(chol)
  b = np.random.default_rng(1).normal(size=(2, 3, 5, 4)).astype(np.float32)
  for lower, factor in ((True, l), (False, np.swapaxes(l, -1, -2))):
    got = transform(jax.vmap(jax.vmap(lambda a, b: linalg.solve_triangular(a, b, lower=lower))))(
        factor, b)
    want = np.stack([[scipy.linalg.solve_triangular(factor[i, j], b[i, j], lower=lower)
                      for j in range(3)] for i in range(2)])
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
  np.testing.assert_allclose(linalg.det3(_spd(n=3)), np.linalg.det(_spd(n=3)), rtol=1e-5)


@pytest.mark.parametrize("name", ["cholesky", "eigvalsh", "inv", "solve_triangular"])
def test_a_batch_reaches_lapack_one_matrix_per_call_on_cpu(name):
  fn = getattr(linalg, name)
  m = jnp.asarray(_spd(batch=(4,)))
  args = (m, m) if name == "solve_triangular" else (m,)
  wrapped = (lambda a, b: fn(a, b, lower=True)) if name == "solve_triangular" else fn
  text = jax.jit(jax.vmap(wrapped)).lower(*args).as_text()
  calls = lapack_calls(text)
  assert calls, "no LAPACK call found: the test no longer sees what it checks"
  assert all(batch_dims == "0" for _, batch_dims in calls), calls
