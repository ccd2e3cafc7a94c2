"""Row-wise arg-reductions against NumPy's argmin/argmax on the flattened array (the oracle)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import reductions


def grids(seed):
  """Random grids with many ties, infinities and an all-inf case (a planner's scores look so)."""
  rng = np.random.default_rng(seed)
  out = []
  for shape in [(1, 1), (1, 7), (7, 1), (5, 9), (32, 32), (17, 40)]:
    values = rng.integers(0, 4, size=shape).astype(np.float32)  # few values: ties everywhere
    values[rng.random(shape) < 0.3] = np.inf
    values[rng.random(shape) < 0.1] = -np.inf
    out.append(values)
  out.append(np.full((6, 6), np.inf, np.float32))
  out.append(np.full((6, 6), -np.inf, np.float32))
  return out


@pytest.mark.parametrize("jit", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_matches_numpy_first_extreme_in_row_major_order(seed, jit):
  for values in grids(seed):
    for ours, oracle in ((reductions.argmin, np.argmin), (reductions.argmax, np.argmax)):
      fn = jax.jit(ours) if jit else ours
      assert int(fn(jnp.asarray(values))) == int(oracle(values.ravel()))
      flat = jax.jit(ours, static_argnums=1) if jit else ours
      assert int(flat(jnp.asarray(values.ravel()), values.shape[1])) == int(oracle(values.ravel()))


def test_nan_counts_as_the_extreme_like_numpy():
  values = np.array([[3.0, 1.0, np.nan], [np.nan, 0.0, 2.0]], np.float32)
  assert int(reductions.argmin(jnp.asarray(values))) == int(np.argmin(values.ravel())) == 2
  assert int(reductions.argmax(jnp.asarray(values))) == int(np.argmax(values.ravel())) == 2


def test_batched_under_vmap():
  values = np.random.default_rng(7).integers(0, 3, size=(5, 6, 9)).astype(np.float32)
  got = jax.vmap(reductions.argmin)(jnp.asarray(values))
  np.testing.assert_array_equal(np.asarray(got), [np.argmin(v.ravel()) for v in values])


def test_flat_values_need_a_width_that_divides_them():
  with pytest.raises(ValueError, match="width"):
    reductions.argmin(jnp.zeros(10), 3)
  with pytest.raises(ValueError, match="width"):
    reductions.argmax(jnp.zeros(10))
  with pytest.raises(ValueError, match="1-D or 2-D"):
    reductions.argmin(jnp.zeros((2, 2, 2)))
