"""Trajectory and map accuracy (jaxplore.slam.accuracy) against evo 1.38 itself (evo_ape --align,
evo_rpe --delta_unit m), a plain NumPy reading of the definitions, and scipy.ndimage."""

import logging
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.ndimage
from conftest import EAGER_AND_JIT
from evo import main_ape as evo_main_ape
from evo import main_rpe as evo_main_rpe
from evo.core import geometry as evo_geometry
from evo.core import metrics as evo_metrics
from evo.core import sync as evo_sync

from jaxplore.slam import accuracy
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402

logging.getLogger("evo").setLevel(logging.ERROR)

CAP = 64  # keyframe capacity of every test (one compiled program per function and setting)
TRANSLATION = evo_metrics.PoseRelation.translation_part


# ---------------------------------------------------------------------------------------------
# Trajectories, evo and the NumPy reading


def smooth_run(seed, n, zero_steps=3):
  """(truth, estimate) f64[n, 3]: a smooth random drive (turn, then drive 0.2-0.45 m per
  keyframe, with ``zero_steps`` turns in place), and its dead-reckoned estimate from odometry
  with noise proportional to each increment (drift), started off the true pose."""
  rng = np.random.default_rng(seed)
  turn = np.convolve(rng.normal(0.0, 0.35, n + 8), np.ones(5) / 5, "same")[:n]
  step = rng.uniform(0.2, 0.45, n)
  step[rng.choice(np.arange(1, n), zero_steps, replace=False)] = 0.0
  truth = np.zeros((n, 3))
  est = np.zeros((n, 3))
  truth[0] = [rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-math.pi, math.pi)]
  est[0] = truth[0] + [0.05, -0.03, 0.02]
  bias = rng.normal(0.0, 0.02)
  for k in range(1, n):
    dd, dphi = step[k], turn[k]
    dd_e = dd * (1 + rng.normal(0.0, 0.05))
    dphi_e = dphi + bias * dd + rng.normal(0.0, 0.03) * abs(dphi)
    for pose, d, p in ((truth, dd, dphi), (est, dd_e, dphi_e)):
      heading = pose[k - 1, 2] + p
      pose[k] = [pose[k - 1, 0] + d * math.cos(heading), pose[k - 1, 1] + d * math.sin(heading),
                 math.atan2(math.sin(heading), math.cos(heading))]
  return truth, est


def lift(poses):
  """SE(2) poses as an evo PoseTrajectory3D (rotation about z, z = 0, one pose per second)."""
  poses = np.asarray(poses, np.float64)
  n = poses.shape[0]
  xyz = np.column_stack([poses[:, :2], np.zeros(n)])
  quat_wxyz = np.column_stack([np.cos(poses[:, 2] / 2), np.zeros(n), np.zeros(n),
                               np.sin(poses[:, 2] / 2)])
  return PoseTrajectory3D(xyz, quat_wxyz, np.arange(n, dtype=np.float64))


def evo_ape(truth, est, align):
  """``evo_ape tum truth est [--align]`` (translation_part, RMSE), as its main does it."""
  ref, traj = evo_sync.associate_trajectories(lift(truth), lift(est))
  result = evo_main_ape.ape(ref, traj, TRANSLATION, align=align)
  return result.stats["rmse"]


def evo_rpe(truth, est, delta, all_pairs=False, pairs_from_reference=False):
  """``evo_rpe tum truth est --delta δ --delta_unit m [--all_pairs] [--pairs_from_reference]``
  (translation_part, RMSE), and the id pairs it compared."""
  ref, traj = evo_sync.associate_trajectories(lift(truth), lift(est))
  source = ref if pairs_from_reference else traj
  pairs = evo_metrics.id_pairs_from_delta(source.poses_se3, delta, evo_metrics.Unit.meters, 0.1,
                                          all_pairs)
  # (evo_rpe then reduces both trajectories to the pairs' poses, for its plots)
  result = evo_main_rpe.rpe(ref, traj, TRANSLATION, delta=delta, delta_unit=evo_metrics.Unit.meters,
                            all_pairs=all_pairs, pairs_from_reference=pairs_from_reference)
  return result.stats["rmse"], pairs


def se2(pose):
  c, s = math.cos(pose[2]), math.sin(pose[2])
  return np.array([[c, -s, pose[0]], [s, c, pose[1]], [0.0, 0.0, 1.0]])


def numpy_ate(truth, est, align):
  """RMSE of position errors after the least-squares proper rotation + translation (Kabsch by
  SVD with the determinant correction), or none."""
  p, q = np.asarray(est, np.float64)[:, :2], np.asarray(truth, np.float64)[:, :2]
  if align:
    a, b = p - p.mean(0), q - q.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    rot = u @ np.diag([1.0, np.linalg.det(u @ vt)]) @ vt
    p = (rot @ a.T).T + q.mean(0)
  return math.sqrt(np.mean(np.sum((p - q) ** 2, axis=1)))


def numpy_pairs(poses, delta, tol, all_pairs):
  """evo's filters.filter_pairs_by_path, read plainly."""
  xy = np.asarray(poses, np.float64)[:, :2]
  steps = [float(np.linalg.norm(xy[k] - xy[k - 1])) for k in range(1, len(xy))]
  if all_pairs:
    cum = np.concatenate([[0.0], np.cumsum(steps)])
    pairs = []
    for i in range(len(xy) - 1):
      errs = [abs(cum[j] - cum[i] - delta) for j in range(i + 1, len(xy))]
      best = min(range(len(errs)), key=lambda k: (errs[k], k))
      if errs[best] <= tol:
        pairs.append((i, i + 1 + best))
    return pairs
  ids, path = [0], 0.0
  for k, step in enumerate(steps, start=1):
    path += step
    if path >= delta:
      ids.append(k)
      path = 0.0
  return list(zip(ids, ids[1:]))


def numpy_rpe(truth, est, delta, all_pairs=False, pairs_from_reference=False):
  """RMSE over the pairs of ``|trans((Q_i⁻¹ Q_j)⁻¹ P_i⁻¹ P_j)|`` in SE(2) matrices, per metre."""
  pairs = numpy_pairs(truth if pairs_from_reference else est, delta, 0.1 * delta, all_pairs)
  errs = []
  for i, j in pairs:
    q_rel = np.linalg.inv(se2(truth[i])) @ se2(truth[j])
    p_rel = np.linalg.inv(se2(est[i])) @ se2(est[j])
    errs.append(np.linalg.norm((np.linalg.inv(q_rel) @ p_rel)[:2, 2]))
  return math.sqrt(np.mean(np.square(errs))) / delta, pairs


def padded(poses, n, fill=np.nan):
  """``poses`` (its first n rows) in CAP rows, padding filled with ``fill``, f32."""
  out = np.full((CAP, 3), fill, np.float32)
  out[:n] = poses[:n]
  return jnp.asarray(out)


def prefix(n):
  return jnp.arange(CAP) < n


def pair_list(pairs: accuracy.Pairs):
  mask = np.asarray(pairs.valid)
  return list(zip(np.asarray(pairs.first)[mask].tolist(), np.asarray(pairs.second)[mask].tolist()))


RUNS = [(0, 64), (1, 50), (2, 37), (3, 64)]


# ---------------------------------------------------------------------------------------------
# ATE


@EAGER_AND_JIT
@pytest.mark.parametrize("align", [True, False], ids=["align", "no_align"])
def test_ate_matches_evo_ape_and_numpy(transform, align):
  ate = transform(lambda e, t, v: accuracy.absolute_trajectory_error(e, t, v, align=align))
  for seed, n in RUNS:
    truth, est = smooth_run(seed, n)
    got = float(ate(padded(est, n), padded(truth, n), prefix(n)))
    want = evo_ape(truth, est, align)
    assert want > 0.02  # the drift is visible
    assert got == pytest.approx(want, abs=1e-4), (seed, n)
    assert got == pytest.approx(numpy_ate(truth, est, align), abs=1e-4)
  if align:  # alignment can only lower the error
    assert got <= float(accuracy.absolute_trajectory_error(
        padded(est, n), padded(truth, n), prefix(n), align=False))


@EAGER_AND_JIT
def test_alignment_recovers_a_rigid_motion_exactly(transform):
  truth, _ = smooth_run(7, CAP)
  angle, shift = 2.4, np.array([3.0, -1.5])
  c, s = math.cos(angle), math.sin(angle)
  moved = truth.copy()
  moved[:, :2] = truth[:, :2] @ np.array([[c, -s], [s, c]]).T + shift
  moved[:, 2] = truth[:, 2] + angle
  est, tru, valid = padded(moved, CAP), padded(truth, CAP), prefix(CAP)
  fit = transform(accuracy.rigid_alignment)(est[:, :2], tru[:, :2], valid)
  # est = R truth + shift, so the alignment est -> truth is R⁻¹, −R⁻¹ shift.
  assert float(fit.angle) == pytest.approx(-angle, abs=1e-5)
  back = np.array([[c, s], [-s, c]]) @ -shift
  np.testing.assert_allclose(np.asarray(fit.translation), back, atol=1e-4)
  assert float(transform(accuracy.absolute_trajectory_error)(est, tru, valid)) < 1e-5
  assert evo_ape(truth, moved, True) < 1e-9
  # RPE is blind to a rigid motion of the whole estimate.
  assert float(transform(accuracy.relative_pose_error)(est, tru, valid)) < 1e-5


def test_mirror_image_is_not_aligned_unlike_evo():
  """evo's 3-D Umeyama on planar points may mirror the estimate (a half turn about an in-plane
  axis); the SE(2) alignment here does not (documented in rigid_alignment)."""
  truth, _ = smooth_run(4, 40)
  mirrored = truth * np.array([1.0, -1.0, -1.0])
  got = float(accuracy.absolute_trajectory_error(padded(mirrored, 40), padded(truth, 40),
                                                 prefix(40)))
  assert evo_ape(truth, mirrored, True) < 1e-9
  assert got > 0.1
  assert got == pytest.approx(numpy_ate(truth, mirrored, True), abs=1e-4)


@EAGER_AND_JIT
def test_degenerate_trajectories(transform):
  ate = transform(accuracy.absolute_trajectory_error)
  ate_raw = transform(lambda e, t, v: accuracy.absolute_trajectory_error(e, t, v, align=False))
  rpe = transform(accuracy.relative_pose_error)
  truth, est = smooth_run(5, CAP)
  e, t = padded(est, CAP), padded(truth, CAP)
  assert math.isnan(float(ate(e, t, prefix(0))))
  assert math.isnan(float(ate_raw(e, t, prefix(0))))
  assert float(ate(e, t, prefix(1))) == 0.0
  assert float(ate_raw(e, t, prefix(1))) == pytest.approx(math.hypot(0.05, 0.03), abs=1e-6)
  assert math.isnan(float(rpe(e, t, prefix(0))))
  assert math.isnan(float(rpe(e, t, prefix(1))))
  assert math.isnan(float(rpe(e, t, prefix(3))))  # under 1 m: no pair (evo raises)
  # Collinear keyframes: evo refuses to align them (covariance rank 1); here they align.
  line = np.column_stack([np.linspace(0, 5, 20), np.zeros(20), np.zeros(20)])
  bent = line + np.column_stack([np.zeros(20), 0.01 * np.arange(20) ** 1.5, np.zeros(20)])
  with pytest.raises(evo_geometry.GeometryException):
    evo_ape(bent, line, True)
  got = float(ate(padded(line, 20), padded(bent, 20), prefix(20)))
  assert got == pytest.approx(numpy_ate(bent, line, True), abs=1e-4)


# ---------------------------------------------------------------------------------------------
# RPE


@EAGER_AND_JIT
@pytest.mark.parametrize("all_pairs", [False, True], ids=["consecutive", "all_pairs"])
@pytest.mark.parametrize("from_reference", [False, True], ids=["est_path", "ref_path"])
def test_rpe_matches_evo_rpe_and_numpy(transform, all_pairs, from_reference):
  def run(est, truth, valid, delta):
    pairs = accuracy.rpe_pairs(truth if from_reference else est, valid, delta,
                               all_pairs=all_pairs)
    rpe = accuracy.relative_pose_error(est, truth, valid, delta, all_pairs=all_pairs,
                                       pairs_from_reference=from_reference)
    return pairs, rpe

  run = transform(run)
  for seed, n in RUNS:
    truth, est = smooth_run(seed, n)
    for delta in (1.0, 0.7, 2.5):
      pairs, got = run(padded(est, n), padded(truth, n), prefix(n), delta)
      want, evo_pairs = evo_rpe(truth, est, delta, all_pairs, from_reference)
      ref, ref_pairs = numpy_rpe(truth, est, delta, all_pairs, from_reference)
      assert pair_list(pairs) == [tuple(p) for p in evo_pairs] == ref_pairs, (seed, n, delta)
      assert float(got) == pytest.approx(want / delta, abs=1e-4), (seed, n, delta)
      assert float(got) == pytest.approx(ref, abs=1e-4)
      assert want > 0.005


def test_all_pairs_takes_the_first_of_tied_partners_in_float64():
  """Runs of zero-length steps tie partners exactly (np.argmin takes the first); in float64 the
  bisection reproduces evo's floating-point choices pair for pair, and its RMSE to 1e-12."""
  pairs_and_rpe = jax.jit(
      lambda e, t, v, delta, all_pairs: (
          accuracy.rpe_pairs(e, v, delta, all_pairs=all_pairs),
          accuracy.relative_pose_error(e, t, v, delta, all_pairs=all_pairs)),
      static_argnames="all_pairs")
  with jax.enable_x64(True):
    for seed, n in RUNS:
      truth, est = smooth_run(seed, n, zero_steps=12)
      for delta in (1.0, 0.45, 3.0):
        e = jnp.asarray(np.pad(est, ((0, CAP - n), (0, 0)), constant_values=np.nan))
        t = jnp.asarray(np.pad(truth, ((0, CAP - n), (0, 0)), constant_values=np.nan))
        valid = prefix(n)
        for all_pairs in (False, True):
          pairs, got = pairs_and_rpe(e, t, valid, delta, all_pairs=all_pairs)
          assert got.dtype == jnp.float64
          want, evo_pairs = evo_rpe(truth, est, delta, all_pairs)
          assert pair_list(pairs) == [tuple(p) for p in evo_pairs]
          assert float(got) == pytest.approx(want / delta, rel=1e-12, abs=1e-14)


# ---------------------------------------------------------------------------------------------
# Padding, vmap, jit


def four_metrics(e, t, v):
  """ATE aligned and not, RPE per metre (δ = 1 m, consecutive; δ = 0.5 m, all pairs)."""
  return jnp.stack([accuracy.absolute_trajectory_error(e, t, v),
                    accuracy.absolute_trajectory_error(e, t, v, align=False),
                    accuracy.relative_pose_error(e, t, v),
                    accuracy.relative_pose_error(e, t, v, 0.5, all_pairs=True)])


four_metrics_jit = jax.jit(four_metrics)


@EAGER_AND_JIT
def test_padding_changes_nothing_and_vmap_equals_one_at_a_time(transform):
  one_robot = transform(four_metrics)
  batch_e, batch_t, batch_v, singles = [], [], [], []
  for (seed, n), fill in zip([(1, 50), (2, 37), (3, 50)], [np.nan, 1e6, 0.0]):
    truth, est = smooth_run(seed, n)
    e, t = padded(est, n, fill), padded(truth, n, -fill)
    one = np.asarray(one_robot(e, t, prefix(n)))
    # The same trajectory at its own length (no padding at all).
    exact = np.asarray(four_metrics_jit(jnp.asarray(est, jnp.float32),
                                        jnp.asarray(truth, jnp.float32), jnp.ones(n, bool)))
    np.testing.assert_allclose(one, exact, rtol=1e-5, atol=1e-7)
    assert np.all(np.isfinite(one))
    batch_e.append(e)
    batch_t.append(t)
    batch_v.append(prefix(n))
    singles.append(one)
  batched = transform(jax.vmap(four_metrics))(jnp.stack(batch_e), jnp.stack(batch_t),
                                              jnp.stack(batch_v))
  np.testing.assert_allclose(np.asarray(batched), np.stack(singles), rtol=1e-6, atol=1e-7)


# ---------------------------------------------------------------------------------------------
# Map error


def scipy_misplaced(belief, truth):
  """Fraction of believed walls at chessboard distance > 1 from every true wall (scipy)."""
  if not belief.any():
    return 0.0
  if not truth.any():
    return 1.0
  dist = scipy.ndimage.distance_transform_cdt(~truth, metric="chessboard")
  dilated = scipy.ndimage.binary_dilation(truth, structure=np.ones((3, 3), bool))
  assert np.array_equal(dist <= 1, dilated)
  return float(np.sum(belief & (dist > 1)) / np.sum(belief))


@EAGER_AND_JIT
def test_misplaced_walls_matches_scipy(transform):
  rng = np.random.default_rng(11)
  fn = transform(accuracy.misplaced_walls)
  cases = []
  for density_t, density_b in [(0.05, 0.1), (0.2, 0.05), (0.01, 0.3), (0.0, 0.1), (0.1, 0.0)]:
    truth = rng.random((23, 31)) < density_t
    belief = rng.random((23, 31)) < density_b
    cases.append((belief, truth))
  # A wall seen one cell off (kept), two cells off (misplaced), on the border.
  truth = np.zeros((23, 31), bool)
  truth[5, 3:20] = True
  truth[:, 0] = True
  belief = np.zeros((23, 31), bool)
  belief[6, 3:10] = True
  belief[7, 12:18] = True
  belief[:, 1] = True
  cases.append((belief, truth))
  for belief, truth in cases:
    got = fn(jnp.asarray(belief), jnp.asarray(truth))
    assert got.dtype == jnp.float32
    assert float(got) == pytest.approx(scipy_misplaced(belief, truth), abs=1e-6)
  assert float(fn(*map(jnp.asarray, cases[-1]))) == pytest.approx(6 / (7 + 6 + 23))
  batched = jax.vmap(accuracy.misplaced_walls)(jnp.asarray([c[0] for c in cases]),
                                               jnp.asarray([c[1] for c in cases]))
  np.testing.assert_allclose(np.asarray(batched), [scipy_misplaced(b, t) for b, t in cases],
                             atol=1e-6)
