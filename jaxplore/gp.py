"""A small Gaussian process over robot poses (x, y, ψ), for Bai et al.'s GP/BO exploration.

Bai, Wang, Chen, Englot 2016 (Li et al. 2020's "Method 29") predict the mutual information of a
candidate pose with a Gaussian process and pick the next pose by Bayesian optimisation. Here:

* Kernel: Matérn-3/2 (Rasmussen & Williams 2006, Eq 4.17),
  ``k(r) = σ_f² (1 + √3 r/ℓ) exp(−√3 r/ℓ)``, isotropic over (x, y, ψ) in metres and radians, plus
  i.i.d. observation noise ``σ_n²`` on the training targets.
* Yaw: the heading enters through the chord ``2·|sin(Δψ/2)|``, the distance between the two
  headings' points on the unit circle. It is the wrapped yaw difference ``|wrap(Δψ)|`` to second
  order and is periodic, but unlike the wrapped difference it keeps the kernel positive definite:
  Matérn kernels with ν > 1/2 on the arc-length distance of a circle are not (Gneiting 2013,
  "Strictly and non-strictly positive definite functions on spheres"; for ν = 3/2 and ℓ = 2 rad
  a 200-point grid of headings has an eigenvalue of −0.31).
* Hyper-parameters ``(σ_f², ℓ, σ_n²)`` are softplus of unconstrained values (plus small floors),
  fitted by minimising the negative log marginal likelihood (R&W Eq 2.30) with optax's Adam in
  a ``lax.scan`` (:func:`fit`).
* Acquisition: GP-UCB (Srinivas et al. 2010, Theorem 1), ``μ + √β_t·σ`` with
  ``β_t = 2 ln(|D| t² π² / (6δ))`` (:func:`ucb_beta`).

Training sets have a fixed capacity N and a mask: masked-out points are decoupled from the rest
(their kernel rows are a unit diagonal, their targets 0), so they change neither the posterior
nor, after removing their constant, the marginal likelihood. Everything is float32.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import optax

from jaxplore import linalg

# Floors under the softplus-constrained hyper-parameters (signal variance, length scale, noise
# variance) keep the Cholesky factorisation well conditioned in float32.
FLOORS = (1e-4, 1e-3, 1e-4)
JITTER = 1e-6  # relative to the signal variance, added to the training kernel's diagonal
SQRT3 = math.sqrt(3.0)


def softplus_inverse(x):
  """The unconstrained value whose softplus is ``x`` (> 0)."""
  x = jnp.asarray(x, jnp.float32)
  return x + jnp.log(-jnp.expm1(-x))


def constrain(raw):
  """(σ_f², ℓ, σ_n²) from unconstrained f32[3]: softplus plus :data:`FLOORS`."""
  return jax.nn.softplus(raw) + jnp.asarray(FLOORS, jnp.float32)


def unconstrain(signal_var, length_scale, noise_var):
  """f32[3] unconstrained values whose :func:`constrain` gives the three hyper-parameters."""
  values = jnp.stack([jnp.asarray(v, jnp.float32) for v in (signal_var, length_scale, noise_var)])
  return softplus_inverse(values - jnp.asarray(FLOORS, jnp.float32))


def yaw_chord(a, b):
  """Distance between headings ``a`` and ``b`` (rad) on the unit circle: ``2·|sin((a − b)/2)|``.

  Periodic in either argument with period 2π, symmetric, and ``|wrap(a − b)|`` up to a relative
  error of ``wrap(a − b)² / 24`` (see the module docstring for why not the wrapped difference).
  """
  return 2.0 * jnp.abs(jnp.sin(0.5 * (a - b)))


def sq_distances(xa, xb, wrap_yaw: bool = True):
  """Squared distances f32[N, M] between poses xa f32[N, 3] and xb f32[M, 3] (x, y, ψ).

  ``wrap_yaw=False``: the plain Euclidean distance over the three coordinates.
  """
  dx = xa[:, None, 0] - xb[None, :, 0]
  dy = xa[:, None, 1] - xb[None, :, 1]
  if wrap_yaw:
    dpsi = yaw_chord(xa[:, None, 2], xb[None, :, 2])
  else:
    dpsi = xa[:, None, 2] - xb[None, :, 2]
  return dx * dx + dy * dy + dpsi * dpsi


def matern32(sq_dist, signal_var, length_scale):
  """Matérn-3/2 of squared distances (R&W Eq 4.17); differentiable at distance 0."""
  positive = sq_dist > 0
  r = jnp.where(positive, jnp.sqrt(jnp.where(positive, sq_dist, 1.0)), 0.0)
  scaled = SQRT3 * r / length_scale
  return signal_var * (1.0 + scaled) * jnp.exp(-scaled)


def _train_factor(raw, x, mask, wrap_yaw):
  """Cholesky factor of the masked training covariance K + σ_n² I (see the module docstring)."""
  signal_var, length_scale, noise_var = constrain(raw)
  both = mask[:, None] & mask[None, :]
  k = jnp.where(both, matern32(sq_distances(x, x, wrap_yaw), signal_var, length_scale), 0.0)
  diagonal = jnp.where(mask, noise_var + JITTER * signal_var, 1.0)
  return linalg.cholesky(k + jnp.diag(diagonal))


def _solve(chol, b):
  """``(L Lᵀ)⁻¹ b`` for a lower-triangular ``L``."""
  z = linalg.solve_triangular(chol, b, lower=True)
  return linalg.solve_triangular(chol.T, z, lower=False)


def neg_log_marginal_likelihood(raw, x, y, mask, wrap_yaw: bool = True):
  """−log p(y | X, θ) of a zero-mean GP (R&W Eq 2.30) over the training points where ``mask``.

  Args:
    raw: f32[3] unconstrained hyper-parameters (:func:`constrain`).
    x: f32[N, 3] training poses; y: f32[N] targets; mask: bool[N] which points exist.
    wrap_yaw: compare headings on the circle (:func:`yaw_chord`); False: Euclidean in ψ.
  """
  y = jnp.where(mask, y, 0.0)
  chol = _train_factor(raw, x, mask, wrap_yaw)
  z = linalg.solve_triangular(chol, y, lower=True)
  n = jnp.sum(mask).astype(jnp.float32)
  return (0.5 * jnp.dot(z, z) + jnp.sum(jnp.log(jnp.diagonal(chol))) +
          0.5 * n * math.log(2 * math.pi))


def posterior(raw, x, y, mask, x_test, wrap_yaw: bool = True):
  """Posterior mean and variance of the latent function at ``x_test`` f32[M, 3] (R&W Eq 2.25-26).

  The variance is the latent function's (no observation noise), clipped at 0.

  Returns:
    (mean f32[M], var f32[M]).
  """
  signal_var, length_scale, _ = constrain(raw)
  y = jnp.where(mask, y, 0.0)
  chol = _train_factor(raw, x, mask, wrap_yaw)
  k_star = jnp.where(mask[None, :],
                     matern32(sq_distances(x_test, x, wrap_yaw), signal_var, length_scale), 0.0)
  mean = k_star @ _solve(chol, y)
  v = linalg.solve_triangular(chol, k_star.T, lower=True)
  var = jnp.maximum(signal_var - jnp.sum(v * v, axis=0), 0.0)
  return mean, var


def normalise(y, mask):
  """``(y − mean) / std`` over the masked entries (0 elsewhere), with the mean and std.

  A std of 0 (all targets equal, or one target) is replaced by 1.
  """
  n = jnp.maximum(jnp.sum(mask), 1).astype(jnp.float32)
  mean = jnp.sum(jnp.where(mask, y, 0.0)) / n
  centred = jnp.where(mask, y - mean, 0.0)
  std = jnp.sqrt(jnp.sum(centred * centred) / n)
  std = jnp.where(std > 0, std, 1.0)
  return centred / std, mean, std


def loss_and_grad(raw, x, y, mask, wrap_yaw: bool = True):
  """:func:`neg_log_marginal_likelihood` and its gradient with respect to ``raw``.

  The gradient in closed form (R&W Eq 5.9): ``∂/∂θ = ½ tr((K⁻¹ − ααᵀ) ∂K/∂θ)``, ``α = K⁻¹y``,
  with ``∂k/∂σ_f² = k/σ_f²``, ``∂k/∂ℓ = σ_f² s² e^{−s} / ℓ`` (``s = √3 r/ℓ``), ``∂K/∂σ_n² = I``,
  times the softplus' derivative. Autodiff through the Cholesky factorisation gives the same
  numbers but multiplies the compile time of a planning round.
  """
  signal_var, length_scale, noise_var = constrain(raw)
  y = jnp.where(mask, y, 0.0)
  both = mask[:, None] & mask[None, :]
  sq = sq_distances(x, x, wrap_yaw)
  positive = sq > 0
  s = SQRT3 * jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0) / length_scale
  shape = jnp.where(both, (1.0 + s) * jnp.exp(-s), 0.0)  # k / σ_f²
  diagonal = jnp.where(mask, noise_var + JITTER * signal_var, 1.0)
  chol = linalg.cholesky(signal_var * shape + jnp.diag(diagonal))
  z = linalg.solve_triangular(chol, y, lower=True)
  n = jnp.sum(mask).astype(jnp.float32)
  loss = (0.5 * jnp.dot(z, z) + jnp.sum(jnp.log(jnp.diagonal(chol))) +
          0.5 * n * math.log(2 * math.pi))

  alpha = linalg.solve_triangular(chol.T, z, lower=False)
  k_inv = _solve(chol, jnp.eye(y.shape[0], dtype=jnp.float32))
  w = k_inv - alpha[:, None] * alpha[None, :]
  valid = mask.astype(jnp.float32)
  d_signal = jnp.sum(w * shape) + JITTER * jnp.sum(jnp.diagonal(w) * valid)
  d_length = jnp.sum(w * jnp.where(both, signal_var * s * s * jnp.exp(-s) / length_scale, 0.0))
  d_noise = jnp.sum(jnp.diagonal(w) * valid)
  grad = 0.5 * jnp.stack([d_signal, d_length, d_noise]) * jax.nn.sigmoid(raw)
  return loss, grad


def fit(raw0, x, y, mask, steps: int = 100, learning_rate=0.05, wrap_yaw: bool = True):
  """Hyper-parameters by maximum marginal likelihood: ``steps`` Adam steps from ``raw0``.

  Warm start: pass the previous fit as ``raw0``. ``learning_rate`` may be traced.

  Returns:
    (raw f32[3], loss f32: the negative log marginal likelihood at the returned values).
  """
  optimiser = optax.adam(learning_rate)

  def step(carry, _):
    raw, state = carry
    _, grad = loss_and_grad(raw, x, y, mask, wrap_yaw)
    # A NaN gradient (a factorisation that failed) leaves the values where they are.
    grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
    updates, state = optimiser.update(grad, state, raw)
    return (optax.apply_updates(raw, updates), state), None

  raw0 = jnp.asarray(raw0, jnp.float32)
  (raw, _), _ = jax.lax.scan(step, (raw0, optimiser.init(raw0)), None, length=steps)
  return raw, neg_log_marginal_likelihood(raw, x, y, mask, wrap_yaw)


def ucb_beta(n_candidates, t, delta):
  """GP-UCB's ``β_t = 2 ln(|D| t² π² / (6δ))`` (Srinivas et al. 2010, Theorem 1), |D| >= 1."""
  n = jnp.maximum(jnp.asarray(n_candidates, jnp.float32), 1.0)
  t = jnp.asarray(t, jnp.float32)
  return 2.0 * jnp.log(n * t * t * math.pi**2 / (6.0 * delta))


def ucb(mean, var, beta):
  """The GP-UCB acquisition ``μ + √β·σ``."""
  return mean + jnp.sqrt(jnp.maximum(beta, 0.0) * var)
