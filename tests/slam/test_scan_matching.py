"""Correlative scan matching (Karto's ScanMatcher) against SciPy and a brute-force NumPy search.

Oracles: the smeared field against ``scipy.ndimage`` (a grey dilation by the log-kernel, and the
Euclidean distance transform); bilinear look-ups against ``scipy.ndimage.map_coordinates``; the
search against a plain float64 loop over the same candidates that follows Karto's
``CorrelateScan`` / ``ComputePositionalCovariance`` / ``ComputeAngularCovariance`` step by step.
Scans are cast in NumPy on small hand-made grids (60 x 60 cells of 0.1 m).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from conftest import EAGER_AND_JIT
from jaxplore.slam import scan_matching as sm

RES = 0.1
SIGMA = 0.1
RADIUS = sm.smear_radius(SIGMA, RES)
ORIGIN = np.array([-0.4, 0.3])
COARSE, FINE = sm.Window(4, 4), sm.Window(2, 2)
HALF_XY, HALF_ANGLE = 0.3, 0.16
N_BEAMS = 90


def room():
  """A walled 6 m x 6 m room (x -0.4 to 5.6 m, y 0.3 to 6.3 m) with three inner blocks (no
  symmetry): x 2.6-2.9 m by y 2.3-2.8 m, x 0.6-2.1 m by y 4.3-4.5 m, x 4.1-4.3 m by y 3.8-6.3 m."""
  occ = np.zeros((60, 60), bool)
  occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
  occ[20:25, 30:33] = True
  occ[40:42, 10:25] = True
  occ[35:60, 45:47] = True
  return occ


def corner():
  """Two perpendicular walls one cell thick (row 5 and column 5, as a belief marks the cells its
  beams hit), nothing else. A thicker wall would be flat across its thickness."""
  occ = np.zeros((60, 60), bool)
  occ[5, 5:] = True
  occ[5:, 5] = True
  return occ


def corridor():
  """Two parallel walls along x (rows 20 and 40), open at both ends."""
  occ = np.zeros((60, 60), bool)
  occ[20, :] = True
  occ[40, :] = True
  return occ


def cast(occ, pose, n=N_BEAMS, max_range=3.0, depth=0.0):
  """End points (robot frame) of ``n`` beams over 360° from ``pose`` on ``occ`` (origin ORIGIN):
  where each beam enters its first occupied cell, moved ``depth`` metres further along it;
  beams meeting nothing within ``max_range`` are invalid."""
  h, w = occ.shape
  assert not occ[int((pose[1] - ORIGIN[1]) // RES), int((pose[0] - ORIGIN[0]) // RES)]
  rel = np.linspace(-np.pi, np.pi, n, endpoint=False) + 0.013
  ang = pose[2] + rel
  t = np.arange(1, int(max_range / (RES / 100)) + 1) * (RES / 100)
  x = pose[0] + np.cos(ang)[:, None] * t
  y = pose[1] + np.sin(ang)[:, None] * t
  i = np.floor((y - ORIGIN[1]) / RES).astype(int)
  j = np.floor((x - ORIGIN[0]) / RES).astype(int)
  inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
  hit = np.zeros(inside.shape, bool)
  hit[inside] = occ[i[inside], j[inside]]
  valid = hit.any(1)
  r = t[np.argmax(hit, 1)] - RES / 200 + depth
  points = np.stack([r * np.cos(rel), r * np.sin(rel)], 1)
  return points.astype(np.float32), valid


# ------------------------------------------------------------------------------------- oracles


def np_field_at(field, xy):
  """The field at world points xy[..., 2]: bilinear between cell centres, zero outside."""
  rows = (xy[..., 1] - ORIGIN[1]) / RES - 0.5
  cols = (xy[..., 0] - ORIGIN[0]) / RES - 0.5
  out = ndimage.map_coordinates(np.asarray(field, np.float64), [rows.ravel(), cols.ravel()],
                                order=1, mode="grid-constant", cval=0.0)
  return out.reshape(rows.shape)


def np_response(field, points, valid, pose):
  c, s = math.cos(pose[2]), math.sin(pose[2])
  p = np.asarray(points, np.float64)
  xy = np.stack([pose[0] + c * p[:, 0] - s * p[:, 1], pose[1] + s * p[:, 0] + c * p[:, 1]], 1)
  values = np_field_at(field, xy)
  return float(values[valid].mean()) if valid.any() else 0.0


def wrap(a):
  return math.atan2(math.sin(a), math.cos(a))


def np_penalty(pose, prior, pen):
  d2 = (pose[0] - prior[0]) ** 2 + (pose[1] - prior[1]) ** 2
  dth = wrap(pose[2] - prior[2])
  distance = max(1.0 - 0.2 * d2 / pen.distance_deviation ** 2, pen.minimum_distance)
  angle = max(1.0 - 0.2 * dth ** 2 / pen.angle_deviation ** 2, pen.minimum_angle)
  return distance * angle


def np_correlate(field, points, valid, prior, centre, half_xy, half_angle, n_xy, n_angle, pen):
  """One ``CorrelateScan`` by brute force: every candidate scored one at a time."""
  step, angle_step = half_xy / max(n_xy, 1), half_angle / max(n_angle, 1)
  candidates = []  # (ix, iy, k, pose, score)
  for k in range(-n_angle, n_angle + 1):
    for iy in range(-n_xy, n_xy + 1):
      for ix in range(-n_xy, n_xy + 1):
        pose = (centre[0] + ix * step, centre[1] + iy * step, centre[2] + k * angle_step)
        score = np_response(field, points, valid, pose) * np_penalty(pose, prior, pen)
        candidates.append((ix, iy, k, pose, score))
  best = max(c[4] for c in candidates)
  ties = [c[3] for c in candidates if c[4] >= best - sm.TIE_TOLERANCE]
  mean = (sum(p[0] for p in ties) / len(ties), sum(p[1] for p in ties) / len(ties),
          math.atan2(sum(math.sin(p[2]) for p in ties), sum(math.cos(p[2]) for p in ties)))
  return candidates, best, mean, step, angle_step


def np_positional_cov(candidates, best, mean, step, angle_step):
  if best < 1e-6:
    return np.diag([500.0, 500.0, 4 * angle_step ** 2])
  per_cell = {}  # (ix, iy) -> (pose, best score over the headings)
  for ix, iy, _, pose, score in candidates:
    per_cell[(ix, iy)] = (pose, max(score, per_cell.get((ix, iy), (None, -1.0))[1]))
  norm = sxx = sxy = syy = 0.0
  for pose, score in per_cell.values():
    if score >= best - 0.1:
      dx, dy = pose[0] - mean[0], pose[1] - mean[1]
      norm += score
      sxx += score * dx * dx
      sxy += score * dx * dy
      syy += score * dy * dy
  vxx = max(sxx / norm, 0.1 * step ** 2) / best
  vyy = max(syy / norm, 0.1 * step ** 2) / best
  return np.array([[vxx, sxy / norm / best, 0], [sxy / norm / best, vyy, 0],
                   [0, 0, 4 * angle_step ** 2]])


def np_match(field, points, valid, prior, half_xy, half_angle, coarse, fine, pen):
  cands, best_c, mean_c, step, angle_step = np_correlate(
      field, points, valid, prior, prior, half_xy, half_angle, coarse.xy_steps,
      coarse.angle_steps, pen)
  cov = np_positional_cov(cands, best_c, mean_c, step, angle_step)
  if fine is None:
    return mean_c, best_c, cov, mean_c, best_c
  _, best_f, mean_f, _, fine_step = np_correlate(
      field, points, valid, prior, mean_c, step, angle_step, fine.xy_steps, fine.angle_steps, pen)
  norm = acc = 0.0
  for k in range(-fine.angle_steps, fine.angle_steps + 1):
    heading = mean_c[2] + k * fine_step
    r = np_response(field, points, valid, (mean_f[0], mean_f[1], heading))
    if r >= best_f - 0.1:
      norm += r
      acc += r * wrap(heading - mean_f[2]) ** 2
  vtt = (acc / norm if acc / norm >= 1e-6 else fine_step ** 2) if norm > 1e-6 else (
      1000 * fine_step ** 2)
  cov[2, 2] = vtt
  return mean_f, best_f, cov, mean_c, best_c


def field_of(occ):
  return sm.smear(jnp.asarray(occ), RES, SIGMA, RADIUS)


@functools.lru_cache(maxsize=None)
def jitted_match(coarse, fine):
  """One compiled program per pair of windows (the extents and penalties are traced)."""
  return jax.jit(functools.partial(sm.match, coarse=coarse, fine=fine))


def run_match(transform, field, points, valid, prior, pen, coarse=COARSE, fine=FINE,
              half_xy=HALF_XY, half_angle=HALF_ANGLE):
  fn = (jitted_match(coarse, fine) if transform is jax.jit
        else transform(functools.partial(sm.match, coarse=coarse, fine=fine)))
  return fn(field, jnp.asarray(ORIGIN, jnp.float32), RES, jnp.asarray(points), jnp.asarray(valid),
            jnp.asarray(prior, jnp.float32), half_xy, half_angle, penalties=pen)


def angle_diff(a, b):
  return abs(wrap(float(a) - float(b)))


# --------------------------------------------------------------------------------------- smear


@EAGER_AND_JIT
@pytest.mark.parametrize("sigma,radius", [(0.1, 2), (0.15, 3), (0.07, 1)])
def test_smear_matches_scipy_grey_dilation(transform, sigma, radius):
  rng = np.random.default_rng(3)
  occ = rng.random((23, 31)) < 0.04
  prob = np.where(rng.random((23, 31)) < 0.1, rng.random((23, 31)), 0.0).astype(np.float32)
  a = np.arange(-radius, radius + 1) * RES
  log_kernel = -(a[:, None] ** 2 + a[None, :] ** 2) / (2 * sigma ** 2)
  smear = transform(functools.partial(sm.smear, res=RES, radius_cells=radius))
  for grid in (occ, prob):
    log_grid = np.log(np.maximum(grid.astype(np.float64), 1e-30))
    expected = np.exp(ndimage.grey_dilation(log_grid, structure=log_kernel, mode="constant",
                                            cval=-1e30))
    got = np.asarray(smear(jnp.asarray(grid), sigma=sigma))
    np.testing.assert_allclose(got, expected, atol=2e-6)


def test_smear_matches_distance_transform():
  occ = room()
  field = np.asarray(field_of(occ))
  d = ndimage.distance_transform_edt(~occ)  # cells, to the nearest occupied centre
  near = d <= RADIUS  # the nearest occupied cell lies in the square kernel
  np.testing.assert_allclose(field[near], np.exp(-(d[near] * RES) ** 2 / (2 * SIGMA ** 2)),
                             atol=2e-6)
  assert np.all(field[d > RADIUS * math.sqrt(2)] == 0.0)
  assert np.all(field[occ] == 1.0)


def test_smear_radius_is_kartos_half_kernel():
  assert sm.smear_radius(0.1, 0.05) == 4  # slam_toolbox's defaults: round(2 σ / res)
  assert sm.smear_radius(0.03, 0.01) == 6
  assert sm.smear_radius(SIGMA, RES) == 2


# ------------------------------------------------------------------------------------ response


@EAGER_AND_JIT
def test_response_matches_map_coordinates(transform):
  rng = np.random.default_rng(5)
  field = rng.random((40, 50)).astype(np.float32)
  points = rng.uniform(-3.5, 3.5, (120, 2)).astype(np.float32)  # some fall off the field
  valid = rng.random(120) < 0.8
  resp = transform(functools.partial(sm.response, res=RES))
  for pose in ([1.7, 2.2, 0.4], [0.3, 3.9, -2.8], [4.4, 0.1, 3.1]):
    got = resp(jnp.asarray(field), jnp.asarray(ORIGIN, jnp.float32), points=jnp.asarray(points),
               valid=jnp.asarray(valid), pose=jnp.asarray(pose, jnp.float32))
    assert abs(float(got) - np_response(field, points, valid, pose)) < 1e-5
  none = resp(jnp.asarray(field), jnp.asarray(ORIGIN, jnp.float32), points=jnp.asarray(points),
              valid=jnp.zeros(120, bool), pose=jnp.zeros(3))
  assert float(none) == 0.0
  far = resp(jnp.asarray(field), jnp.asarray(ORIGIN, jnp.float32), points=jnp.asarray(points),
             valid=jnp.asarray(valid), pose=jnp.asarray([50.0, 50.0, 0.0]))
  assert float(far) == 0.0


# ------------------------------------------------------------------------- search vs brute force


@EAGER_AND_JIT
@pytest.mark.parametrize("penalised", [True, False], ids=["karto-penalties", "no-penalties"])
def test_match_equals_brute_force(transform, penalised):
  occ = room()
  field = field_of(occ)
  pen = sm.karto_penalties() if penalised else sm.NO_PENALTIES
  rng = np.random.default_rng(11)
  for true in ([2.23, 2.41, 0.37], [1.52, 4.18, -2.2]):
    points, valid = cast(occ, np.array(true))
    prior = np.array(true) + rng.uniform(-1, 1, 3) * [0.2, 0.2, 0.1]
    got = run_match(transform, field, points, valid, prior, pen)
    pose, best, cov, coarse_pose, coarse_best = np_match(
        np.asarray(field), points, valid, prior, HALF_XY, HALF_ANGLE, COARSE, FINE, pen)
    np.testing.assert_allclose(np.asarray(got.coarse_pose[:2]), coarse_pose[:2], atol=2e-5)
    assert angle_diff(got.coarse_pose[2], coarse_pose[2]) < 2e-5
    assert abs(float(got.coarse_response) - coarse_best) < 2e-5
    np.testing.assert_allclose(np.asarray(got.pose[:2]), pose[:2], atol=2e-5)
    assert angle_diff(got.pose[2], pose[2]) < 2e-5
    assert abs(float(got.response) - best) < 2e-5
    np.testing.assert_allclose(np.asarray(got.cov), cov, rtol=2e-3, atol=1e-8)


def test_coarse_only_equals_brute_force():
  occ = room()
  field = field_of(occ)
  true = np.array([3.61, 1.27, 1.1])
  points, valid = cast(occ, true)
  prior = true + [0.12, -0.17, 0.07]
  pen = sm.karto_penalties()
  got = run_match(jax.jit, field, points, valid, prior, pen, fine=None)
  pose, best, cov, _, _ = np_match(np.asarray(field), points, valid, prior, HALF_XY, HALF_ANGLE,
                                   COARSE, None, pen)
  np.testing.assert_allclose(np.asarray(got.pose[:2]), pose[:2], atol=2e-5)
  assert angle_diff(got.pose[2], pose[2]) < 2e-5
  assert abs(float(got.response) - best) < 2e-5
  np.testing.assert_allclose(np.asarray(got.cov), cov, rtol=2e-3, atol=1e-8)
  assert float(got.cov[2, 2]) == pytest.approx(4 * (HALF_ANGLE / COARSE.angle_steps) ** 2)


# ------------------------------------------------------------------------- geometry of the scene


def test_corner_is_well_constrained_on_both_axes():
  occ = corner()
  true = np.array([1.37, 1.58, 0.6])
  points, valid = cast(occ, true, depth=RES / 2)
  got = run_match(jax.jit, field_of(occ), points, valid, true + [0.15, -0.12, 0.05],
                  sm.karto_penalties())
  cov = np.asarray(got.cov)
  # Both axes tight: a tenth of the spread of a flat response over the window ((2 x 0.3 m)² / 12),
  # neither much looser than the other; and the pose found to within a quarter cell.
  flat = (2 * HALF_XY) ** 2 / 12
  assert max(cov[0, 0], cov[1, 1]) < 0.1 * flat
  assert max(cov[0, 0], cov[1, 1]) < 2 * min(cov[0, 0], cov[1, 1])
  assert np.all(np.abs(np.asarray(got.pose[:2]) - true[:2]) < 0.25 * RES)


def test_corridor_is_uncertain_along_and_recovers_across():
  occ = corridor()
  true = np.array([2.6, 3.37, 0.0])  # the walls' cells span y 2.3-2.4 and 4.3-4.4 m
  points, valid = cast(occ, true, max_range=2.2, depth=RES / 2)
  ends = np.asarray(points)[valid]
  assert np.all((np.abs(ends[:, 1] + true[1] - 2.35) < 0.1) | (np.abs(ends[:, 1] + true[1] - 4.35)
                                                             < 0.1))  # end points on the walls
  prior = true + [0.0, 0.17, 0.0]  # off across the corridor
  got = run_match(jax.jit, field_of(occ), points, valid, prior, sm.karto_penalties())
  cov = np.asarray(got.cov)
  assert cov[0, 0] > 20 * cov[1, 1]  # x (along) much more uncertain than y (across)
  assert cov[0, 0] > 0.5 * (2 * HALF_XY) ** 2 / 12  # along: near a flat response's spread
  assert abs(float(got.pose[1]) - true[1]) < 0.25 * RES
  assert abs(float(got.pose[0]) - true[0]) < 0.25 * RES  # along: held by the penalty (prior x)


@pytest.mark.parametrize("true", [(1.8, 1.6, 0.37), (3.3, 3.4, -1.0)])
def test_recovers_known_displacement(true):
  """Scans taken at ``true``, searched from ``true + offset`` (inside the window), with the
  engine's windows: coarse 5 steps a side, fine 3 (0.02 m and 0.01 rad fine steps)."""
  occ = room()
  field = field_of(occ)
  true = np.array(true)
  coarse, fine, half_angle = sm.Window(5, 5), sm.Window(3, 3), 0.15
  fine_angle_step = half_angle / coarse.angle_steps / fine.angle_steps
  # End points at the depth of the occupied cells' centres, where the field peaks; then where
  # the beams enter the walls (as a lidar on this grid returns them): there the bilinear field is
  # flat within half a cell of the truth between walls seen from both sides, and the penalty
  # picks the end of that plateau nearest the prior.
  for depth, tolerance in ((RES / 2, 0.15 * RES), (0.0, 0.55 * RES)):
    points, valid = cast(occ, true, depth=depth)
    for offset in ((0.21, -0.14, 0.09), (-0.26, 0.05, -0.12), (0.13, 0.22, -0.07)):
      got = run_match(jax.jit, field, points, valid, true + offset, sm.karto_penalties(),
                      coarse=coarse, fine=fine, half_angle=half_angle)
      assert np.all(np.abs(np.asarray(got.pose[:2]) - true[:2]) < tolerance), (depth, offset)
      assert angle_diff(got.pose[2], true[2]) < 1.01 * fine_angle_step, (depth, offset)


def test_no_valid_point_returns_the_prior_with_max_variance():
  occ = room()
  points, _ = cast(occ, np.array([2.0, 2.0, 0.0]))
  prior = np.array([2.1, 1.9, 0.3])
  got = run_match(jax.jit, field_of(occ), points, np.zeros(N_BEAMS, bool), prior,
                  sm.karto_penalties())
  np.testing.assert_allclose(np.asarray(got.pose), prior, atol=1e-6)
  assert float(got.response) == 0.0
  assert float(got.cov[0, 0]) == sm.MAX_VARIANCE and float(got.cov[1, 1]) == sm.MAX_VARIANCE


# ------------------------------------------------------------------------------------- batching


def test_vmap_equals_one_at_a_time():
  occ = room()
  truths = np.array([[2.23, 2.41, 0.37], [1.52, 4.18, -2.2], [3.61, 1.27, 1.1]])
  scans = [cast(occ, t) for t in truths]
  points = np.stack([s[0] for s in scans])
  valid = np.stack([s[1] for s in scans])
  priors = truths + [[0.1, -0.2, 0.05], [-0.15, 0.0, -0.1], [0.2, 0.2, 0.0]]
  fields = jnp.stack([field_of(occ), field_of(np.roll(occ, 1, 0)), field_of(occ)])
  halves = jnp.asarray([0.3, 0.25, 0.35], jnp.float32)
  origin = jnp.asarray(ORIGIN, jnp.float32)
  pen = sm.karto_penalties()
  one = functools.partial(sm.match, coarse=COARSE, fine=FINE, penalties=pen)
  batched = jax.jit(jax.vmap(lambda f, p, v, q, hx: one(f, origin, RES, p, v, q, hx, HALF_ANGLE)))
  got = batched(fields, jnp.asarray(points), jnp.asarray(valid), jnp.asarray(priors, jnp.float32),
                halves)
  single = jax.jit(lambda f, p, v, q, hx: one(f, origin, RES, p, v, q, hx, HALF_ANGLE))
  for b in range(3):
    ref = single(fields[b], jnp.asarray(points[b]), jnp.asarray(valid[b]),
                 jnp.asarray(priors[b], jnp.float32), halves[b])
    for name in sm.Match._fields:
      np.testing.assert_allclose(np.asarray(getattr(got, name)[b]), np.asarray(getattr(ref, name)),
                                 rtol=1e-5, atol=1e-6, err_msg=name)


# ------------------------------------------------------------------------------------- defaults


def test_karto_defaults_are_slam_toolboxs():
  d = sm.KARTO_DEFAULTS
  assert d.correlation_search_space_smear_deviation == 0.1
  assert d.loop_search_space_smear_deviation == 0.03
  assert (d.distance_variance_penalty, d.angle_variance_penalty) == (0.5, 1.0)
  assert (d.minimum_distance_penalty, d.minimum_angle_penalty) == (0.5, 0.9)
  assert (d.coarse_angle_resolution, d.coarse_search_angle_offset) == (0.0349, 0.349)
  assert d.fine_search_angle_offset == 0.00349
  assert d.link_match_minimum_response_fine == 0.1
  assert (d.loop_match_minimum_response_coarse, d.loop_match_minimum_response_fine) == (0.35, 0.45)
  assert sm.karto_penalties() == sm.Penalties(0.5, 1.0, 0.5, 0.9)
