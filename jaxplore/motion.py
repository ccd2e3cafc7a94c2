"""Robot kinematics, odometry noise, pose-covariance propagation and relocalisation.

Li et al. 2020 §"Correction of candidate paths": poses compound with ``⊕`` (Eq 9); the Jacobians
of the compounding are ``J1`` and ``J2`` (Eq 11–12); odometry noise is ``V_n`` (Eq 16); the
dead-reckoning covariance follows ``Σ_n = J1 Σ_{n−1} J1ᵀ + J2 V_n J2ᵀ`` (Eq 17). Added here: the
scale factors σ_d, σ_φ of the odometry noise and a relocalisation (Kalman) update.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplore import linalg


def wrap_angle(a):
  """Angle in (−π, π]."""
  return jnp.arctan2(jnp.sin(a), jnp.cos(a))


def rotate(angle, xy):
  """``R(angle) xy`` for ``xy: f32[..., 2]`` and an ``angle`` broadcasting with ``xy[..., 0]``."""
  c, s = jnp.cos(angle), jnp.sin(angle)
  return jnp.stack([c * xy[..., 0] - s * xy[..., 1], s * xy[..., 0] + c * xy[..., 1]], axis=-1)


def compound(pose_ij, x_jk):
  """Pose compounding ``X_ik = X_ij ⊕ X_jk`` (Li Eq 9); ``x_jk`` is expressed in frame j."""
  x, y, phi = pose_ij[0], pose_ij[1], pose_ij[2]
  c, s = jnp.cos(phi), jnp.sin(phi)
  return jnp.stack([x + c * x_jk[0] - s * x_jk[1], y + s * x_jk[0] + c * x_jk[1],
                    wrap_angle(phi + x_jk[2])])


def between(pose_a, pose_b):
  """``a⁻¹ ⊕ b``: pose ``b`` in ``a``'s frame, the inverse of :func:`compound` (GTSAM's
  ``Pose2::between``)."""
  c, s = jnp.cos(pose_a[2]), jnp.sin(pose_a[2])
  dx, dy = pose_b[0] - pose_a[0], pose_b[1] - pose_a[1]
  return jnp.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(pose_b[2] - pose_a[2])])


def compounding_jacobians(pose_ij, pose_ik):
  """``J1⊕`` (Eq 12) and ``J2⊕`` (the right block of Eq 11) of ``X_ik = X_ij ⊕ X_jk``."""
  c, s = jnp.cos(pose_ij[2]), jnp.sin(pose_ij[2])
  one, zero = jnp.ones_like(c), jnp.zeros_like(c)
  j1 = jnp.array([[one, zero, pose_ij[1] - pose_ik[1]],
                  [zero, one, pose_ik[0] - pose_ij[0]],
                  [zero, zero, one]])
  j2 = jnp.array([[c, -s, zero], [s, c, zero], [zero, zero, one]])
  return j1, j2


def odometry_covariance(delta_d, delta_phi, sigma_d, sigma_phi):
  """``V_n = diag((σ_d δd)², (σ_d δd)², (σ_φ δφ)²)`` (Li Eq 16 with scale factors σ_d, σ_φ)."""
  sd = (sigma_d * delta_d) ** 2
  return jnp.diag(jnp.stack([sd, sd, (sigma_phi * delta_phi) ** 2]))


def propagate_covariance(cov, pose_ij, pose_ik, v_n):
  """Li Eq 17: ``Σ_n = J1 Σ_{n−1} J1ᵀ + J2 V_n J2ᵀ``."""
  j1, j2 = compounding_jacobians(pose_ij, pose_ik)
  return j1 @ cov @ j1.T + j2 @ v_n @ j2.T


def increment(delta_d, delta_phi):
  """The odometry increment (in the frame before the move) of "turn by δφ, then drive δd"."""
  return jnp.stack([delta_d * jnp.cos(delta_phi), delta_d * jnp.sin(delta_phi), delta_phi])


class Drive(NamedTuple):
  """One control step toward a target point."""

  pose: jax.Array  # f32[3] new true pose
  delta_d: jax.Array  # distance driven, m
  delta_phi: jax.Array  # heading change, rad
  arrived: jax.Array  # bool, the target point was reached
  aligned: jax.Array  # bool, the heading points at the target after this step


def drive_toward(pose, target_xy, v_max, w_max, dt, translate=True) -> Drive:
  """Turns toward ``target_xy`` by at most ``w_max·dt``; once aligned, drives up to ``v_max·dt``.

  The robot drives only in a step where its turn completes (it never drives while misaligned),
  and it stops at the target rather than overshooting. With ``translate=False`` it only turns
  (used to face a look-at point).
  """
  d = target_xy - pose[:2]
  dist = jnp.sqrt(jnp.sum(d * d))
  desired = jnp.where(dist > 1e-6, jnp.arctan2(d[1], d[0]), pose[2])
  err = wrap_angle(desired - pose[2])
  turn = jnp.clip(err, -w_max * dt, w_max * dt)
  aligned = jnp.abs(err - turn) < 1e-4
  step = jnp.where(aligned & translate, jnp.minimum(v_max * dt, dist), 0.0)
  heading = wrap_angle(pose[2] + turn)
  new_xy = pose[:2] + step * jnp.stack([jnp.cos(heading), jnp.sin(heading)])
  arrived = translate & (dist - step < 1e-5)
  return Drive(jnp.concatenate([new_xy, heading[None]]), step, turn, arrived, aligned)


def relocalise(pose_est, cov, pose_true, meas_cov):
  """Kalman update with a direct pose measurement of covariance R.

  ``Σ ← (Σ⁻¹ + R⁻¹)⁻¹`` and the estimate moves toward the truth by the gain ``K = Σ(Σ + R)⁻¹``.
  """
  gain = cov @ linalg.inv(cov + meas_cov)
  innovation = pose_true - pose_est
  innovation = innovation.at[2].set(wrap_angle(innovation[2]))
  new_est = pose_est + gain @ innovation
  new_est = new_est.at[2].set(wrap_angle(new_est[2]))
  new_cov = (jnp.eye(3) - gain) @ cov
  return new_est, 0.5 * (new_cov + new_cov.T)
