"""Kinematics and Li Eq 9-17 against a plain NumPy reading of the paper."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from conftest import EAGER_AND_JIT
from jaxplore import motion


def numpy_eq17(poses, cov0, sigma_d, sigma_phi):
  """Plain loop of Li Eq 12, 16, 17 over consecutive poses (each step: turn δφ, drive δd)."""
  cov = np.array(cov0, np.float64)
  out = [cov]
  for a, b in zip(poses[:-1], poses[1:]):
    dd = math.hypot(b[0] - a[0], b[1] - a[1])
    dphi = math.atan2(math.sin(b[2] - a[2]), math.cos(b[2] - a[2]))
    j1 = np.array([[1, 0, a[1] - b[1]], [0, 1, b[0] - a[0]], [0, 0, 1]])
    j2 = np.array([[math.cos(a[2]), -math.sin(a[2]), 0], [math.sin(a[2]), math.cos(a[2]), 0], [0, 0, 1]])
    v = np.diag([(sigma_d * dd) ** 2, (sigma_d * dd) ** 2, (sigma_phi * dphi) ** 2])
    cov = j1 @ cov @ j1.T + j2 @ v @ j2.T
    out.append(cov)
  return out


@EAGER_AND_JIT
def test_covariance_propagation_matches_numpy_loop(transform):
  rng = np.random.default_rng(0)
  pose = np.array([1.0, 2.0, 0.3])
  poses = [pose]
  for _ in range(30):
    dphi, dd = rng.uniform(-0.5, 0.5), rng.uniform(0.0, 0.2)
    pose = np.asarray(motion.compound(jnp.asarray(pose, jnp.float32), motion.increment(dd, dphi)), np.float64)
    poses.append(pose)
  sigma_d, sigma_phi = 0.7, 0.4
  ref = numpy_eq17(poses, np.eye(3) * 1e-3, sigma_d, sigma_phi)

  @transform
  def ours(a, b, cov):
    dd = jnp.hypot(b[0] - a[0], b[1] - a[1])
    dphi = motion.wrap_angle(b[2] - a[2])
    return motion.propagate_covariance(cov, a, b, motion.odometry_covariance(dd, dphi, sigma_d, sigma_phi))

  cov = jnp.eye(3, dtype=jnp.float32) * 1e-3
  for k, (a, b) in enumerate(zip(poses[:-1], poses[1:])):
    cov = ours(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32), cov)
    np.testing.assert_allclose(np.asarray(cov), ref[k + 1], rtol=2e-3, atol=1e-7)
  dets = [np.linalg.det(c) for c in ref]
  assert all(d2 >= d1 - 1e-15 for d1, d2 in zip(dets, dets[1:]))  # Eq 14: det never decreases


def test_compound_matches_rigid_transform():
  a = jnp.asarray([1.0, -2.0, 0.7])
  x = jnp.asarray([0.5, 0.2, -0.3])
  out = np.asarray(motion.compound(a, x))
  c, s = math.cos(0.7), math.sin(0.7)
  np.testing.assert_allclose(out, [1.0 + c * 0.5 - s * 0.2, -2.0 + s * 0.5 + c * 0.2, 0.4], atol=1e-6)


def test_relocalise_is_information_form_update():
  cov = jnp.asarray(np.diag([0.04, 0.09, 0.01]) + 0.005, jnp.float32)
  r = jnp.diag(jnp.asarray([0.01, 0.02, 0.003], jnp.float32))
  est, new_cov = motion.relocalise(jnp.zeros(3), cov, jnp.asarray([0.3, -0.2, 0.1]), r)
  ref = np.linalg.inv(np.linalg.inv(np.asarray(cov, np.float64)) + np.linalg.inv(np.asarray(r, np.float64)))
  np.testing.assert_allclose(np.asarray(new_cov), ref, rtol=1e-3, atol=1e-6)
  gain = np.asarray(cov, np.float64) @ np.linalg.inv(np.asarray(cov + r, np.float64))
  np.testing.assert_allclose(np.asarray(est), gain @ [0.3, -0.2, 0.1], atol=1e-5)


@EAGER_AND_JIT
def test_drive_turns_before_moving_and_stops_at_target(transform):
  drive = transform(motion.drive_toward)
  pose = jnp.asarray([0.0, 0.0, 0.0])
  out = drive(pose, jnp.asarray([0.0, 1.0]), 0.25, 0.5, 1.0, True)  # needs a 90° turn, 0.5 rad/step
  assert float(out.delta_d) == 0.0 and abs(float(out.delta_phi) - 0.5) < 1e-6
  pose = jnp.asarray([0.0, 0.0, math.pi / 2])
  out = drive(pose, jnp.asarray([0.0, 0.1]), 0.25, 0.5, 1.0, True)
  assert abs(float(out.delta_d) - 0.1) < 1e-6 and bool(out.arrived)
  np.testing.assert_allclose(np.asarray(out.pose[:2]), [0.0, 0.1], atol=1e-6)
  out = drive(pose, jnp.asarray([0.0, 5.0]), 0.25, 0.5, 1.0, True)
  assert abs(float(out.delta_d) - 0.25) < 1e-6 and not bool(out.arrived)


def test_jacobian_determinants_are_one():
  a = jnp.asarray([0.3, 0.4, 1.1])
  b = motion.compound(a, motion.increment(0.3, 0.2))
  j1, j2 = motion.compounding_jacobians(a, b)
  assert abs(float(jnp.linalg.det(j1)) - 1) < 1e-6 and abs(float(jnp.linalg.det(j2)) - 1) < 1e-6
  assert jax.numpy.isfinite(j1).all()


def test_between_inverts_compound_and_matches_the_matrix_form():
  rng = np.random.default_rng(3)
  for _ in range(5):
    a = jnp.asarray(rng.uniform([-5, -5, -3], [5, 5, 3]), jnp.float32)
    x = jnp.asarray(rng.uniform([-2, -2, -3], [2, 2, 3]), jnp.float32)
    np.testing.assert_allclose(motion.between(a, motion.compound(a, x)), x, atol=1e-5)
    # The same as the homogeneous matrices' T_a⁻¹ T_b.
    b = motion.compound(a, x)
    t = lambda p: np.array([[np.cos(p[2]), -np.sin(p[2]), p[0]], [np.sin(p[2]), np.cos(p[2]), p[1]],
                            [0, 0, 1]], np.float64)
    rel = np.linalg.inv(t(np.asarray(a, np.float64))) @ t(np.asarray(b, np.float64))
    np.testing.assert_allclose(motion.between(a, b)[:2], rel[:2, 2], atol=1e-5)
