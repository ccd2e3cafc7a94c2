"""The GP of the GP/BO planner against scikit-learn: posterior, marginal likelihood, fitted
hyper-parameters (plain Euclidean Matérn, where the yaw wrap does not matter), and the yaw
distance on its own (periodic, near the wrapped difference, a positive definite kernel)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

from conftest import EAGER_AND_JIT
from jaxplore import gp


def _data(seed=0, n=40, noise=0.1):
  """Poses in a 4 m x 4 m square with headings in [0, 1.5] rad, a smooth target plus noise,
  normalised to mean 0 and std 1 (float64)."""
  rng = np.random.default_rng(seed)
  x = np.column_stack([rng.uniform(0, 4, n), rng.uniform(0, 4, n), rng.uniform(0, 1.5, n)])
  y = np.sin(1.3 * x[:, 0]) + 0.5 * np.cos(x[:, 1]) + 0.8 * x[:, 2] + noise * rng.standard_normal(n)
  return x, (y - y.mean()) / y.std()


def _sklearn_fixed(signal_var, length_scale, noise_var):
  """sklearn's GP with our kernel, fixed: C·Matérn(ν = 3/2) with σ_n² (and our jitter) on the
  diagonal of the training covariance."""
  kernel = ConstantKernel(signal_var, "fixed") * Matern(length_scale, "fixed", nu=1.5)
  return GaussianProcessRegressor(kernel, alpha=noise_var + gp.JITTER * signal_var, optimizer=None)


@EAGER_AND_JIT
def test_posterior_matches_sklearn_with_the_same_fixed_kernel(transform):
  x, y = _data(0, 30)
  rng = np.random.default_rng(1)
  x_test = np.column_stack([rng.uniform(-1, 5, 50), rng.uniform(-1, 5, 50), rng.uniform(0, 1.5, 50)])
  hyper = (1.7, 0.9, 0.05)
  reference = _sklearn_fixed(*hyper).fit(x, y)
  mean_ref, std_ref = reference.predict(x_test, return_std=True)
  # Capacity 36 with 6 masked-out junk points: they must change nothing.
  junk = rng.uniform(0, 4, (6, 3))
  xs = jnp.asarray(np.vstack([x[:10], junk, x[10:]]), jnp.float32)
  ys = jnp.asarray(np.concatenate([y[:10], rng.uniform(-9, 9, 6), y[10:]]), jnp.float32)
  mask = jnp.asarray(np.r_[np.ones(10), np.zeros(6), np.ones(20)].astype(bool))
  post = transform(lambda raw, a, b, m, t: gp.posterior(raw, a, b, m, t, wrap_yaw=False))
  mean, var = post(gp.unconstrain(*hyper), xs, ys, mask, jnp.asarray(x_test, jnp.float32))
  np.testing.assert_allclose(np.asarray(mean), mean_ref, atol=2e-3)
  np.testing.assert_allclose(np.sqrt(np.asarray(var)), std_ref, atol=2e-3)


def test_loss_is_sklearns_negative_log_marginal_likelihood():
  x, y = _data(2, 25)
  mask = jnp.ones(25, bool)
  loss = jax.jit(lambda raw: gp.neg_log_marginal_likelihood(
      raw, jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), mask, wrap_yaw=False))
  for hyper in [(1.0, 1.0, 0.01), (0.3, 2.5, 0.2), (4.0, 0.4, 0.001)]:
    reference = _sklearn_fixed(*hyper).fit(x, y).log_marginal_likelihood_value_
    np.testing.assert_allclose(float(loss(gp.unconstrain(*hyper))), -reference, rtol=1e-4, atol=1e-3)


def test_masked_points_do_not_change_the_loss():
  x, y = _data(3, 20)
  xs = jnp.asarray(np.vstack([x, np.full((5, 3), 7.0)]), jnp.float32)
  ys = jnp.asarray(np.r_[y, np.full(5, 5.0)], jnp.float32)
  raw = gp.unconstrain(1.2, 1.1, 0.03)
  loss = jax.jit(gp.neg_log_marginal_likelihood)
  full = loss(raw, jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), jnp.ones(20, bool))
  masked = loss(raw, xs, ys, jnp.arange(25) < 20)
  np.testing.assert_allclose(float(masked), float(full), rtol=1e-5)


def test_closed_form_gradient_is_autodiffs():
  x, y = _data(5, 18)
  args = (jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), jnp.arange(18) < 15)
  both = jax.jit(lambda raw: (gp.loss_and_grad(raw, *args),
                              jax.value_and_grad(gp.neg_log_marginal_likelihood)(raw, *args)))
  for hyper in [(1.3, 0.8, 0.05), (0.2, 3.0, 0.5)]:
    (loss, grad), (loss_ad, grad_ad) = both(gp.unconstrain(*hyper))
    np.testing.assert_allclose(float(loss), float(loss_ad), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(grad), np.asarray(grad_ad), rtol=2e-3, atol=1e-4)


FIT = jax.jit(lambda raw, x, y, m: gp.fit(raw, x, y, m, steps=100, learning_rate=0.05, wrap_yaw=False))


def test_fitted_hyperparameters_near_sklearns_fit():
  x, y = _data(4, 40)
  kernel = (ConstantKernel(1.0) * Matern(1.0, nu=1.5)
            + WhiteKernel(0.01, noise_level_bounds=(1e-5, 1e1)))
  reference = GaussianProcessRegressor(kernel, alpha=1e-10, random_state=0).fit(x, y)
  k = reference.kernel_
  expected = np.array([k.k1.k1.constant_value, k.k1.k2.length_scale, k.k2.noise_level])
  xs, ys, mask = jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), jnp.ones(40, bool)
  raw = gp.unconstrain(1.0, 1.0, 0.01)
  losses = []
  # Warm-started 100-step fits, as successive planning rounds on a fixed data set would run them.
  for _ in range(2):
    raw, loss = FIT(raw, xs, ys, mask)
    losses.append(float(loss))
  assert losses[0] < float(gp.neg_log_marginal_likelihood(gp.unconstrain(1.0, 1.0, 0.01), xs, ys, mask,
                                                          wrap_yaw=False))
  np.testing.assert_allclose(np.asarray(gp.constrain(raw)), expected, rtol=0.1)
  assert losses[-1] <= -reference.log_marginal_likelihood_value_ + 0.02


def test_yaw_chord_is_periodic_and_near_the_wrapped_difference():
  a = jnp.linspace(-7.0, 7.0, 57)
  b = jnp.float32(0.4)
  chord = np.asarray(gp.yaw_chord(a, b))
  wrapped = np.abs(np.angle(np.exp(1j * (np.asarray(a, np.float64) - 0.4))))
  np.testing.assert_allclose(np.asarray(gp.yaw_chord(a + 2 * math.pi, b)), chord, atol=1e-5)
  np.testing.assert_allclose(np.asarray(gp.yaw_chord(b, a)), chord, atol=1e-6)
  # 2 sin(d/2) = d (1 − d²/24 + ...): within d³/24 of the wrapped difference, never above it.
  assert np.all(chord <= wrapped + 1e-5)
  assert np.all(wrapped - chord <= wrapped**3 / 24 + 1e-5)
  # Poses differing by a full turn are the same pose.
  p = jnp.asarray([[1.0, 2.0, 0.3]], jnp.float32)
  q = p.at[0, 2].add(2 * math.pi)
  assert float(gp.sq_distances(p, q)[0, 0]) < 1e-10
  assert float(gp.sq_distances(p, q, wrap_yaw=False)[0, 0]) > 39.0


def test_kernel_over_headings_is_positive_definite():
  headings = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)
  x = jnp.asarray(np.column_stack([np.zeros(64), np.zeros(64), headings]), jnp.float32)
  for length_scale in (0.5, 2.0, 5.0):
    k = np.asarray(gp.matern32(gp.sq_distances(x, x), 1.0, length_scale), np.float64)
    assert np.linalg.eigvalsh(k).min() > -1e-5
  # The arc-length (wrapped difference) distance would not be: the reason for the chord.
  arc = np.abs(np.angle(np.exp(1j * (headings[:, None] - headings[None, :]))))
  k_arc = (1 + math.sqrt(3) * arc / 2.0) * np.exp(-math.sqrt(3) * arc / 2.0)
  assert np.linalg.eigvalsh(k_arc).min() < -0.1


def test_ucb_beta_and_acquisition():
  beta = gp.ucb_beta(1024, 2, 0.01)
  np.testing.assert_allclose(float(beta), 2 * math.log(1024 * 4 * math.pi**2 / 0.06), rtol=1e-6)
  mean, var = jnp.asarray([1.0, 0.5]), jnp.asarray([0.0, 0.25])
  np.testing.assert_allclose(np.asarray(gp.ucb(mean, var, 4.0)), [1.0, 1.5], rtol=1e-6)
