"""Correlative scan matching against a robot's own belief, as Karto / slam_toolbox do it.

Olson, "Real-Time Correlative Scan Matching" (ICRA 2009): the pose is searched exhaustively over a
3-D window (x, y, θ) around the prior, each candidate scored by looking the scan's end points up in
a rasterised, smeared likelihood table of the map, and the covariance is read off the scores of the
whole window rather than off a local linearisation. Karto (open_karto / slam_toolbox
``lib/karto_sdk/src/Mapper.cpp``, class ``ScanMatcher``) implements it as a coarse search then a
fine search around the coarse best, with an odometry penalty on every score; this module follows
Karto's code, function by function:

* :func:`smear` is Karto's ``CorrelationGrid`` (``CalculateKernel`` + ``SmearPoint``): every
  occupied cell spreads ``exp(-d² / 2σ²)`` over a square of ``radius_cells`` cells each side, the
  grid keeps the maximum.
* :func:`response` is ``GetResponse``: the mean of the field over the scan's end points.
* :func:`match` is ``MatchScan`` → ``CorrelateScan`` (coarse, then fine) with its penalties
  (``operator()``), the averaging of equally best poses, ``ComputePositionalCovariance`` (coarse)
  and ``ComputeAngularCovariance`` (fine).

Where this differs from Karto, and why (each also noted where it happens):

1. The field is built from a grid the caller gives (the robot's belief, a local crop), not from a
   buffer of previous scans (``AddScans``), and its values are floats in [0, 1], not Karto's
   integers 0-100 (``GridStates_Occupied`` = 100); an occupancy probability may be given instead of
   a bool, and then smears in proportion.
2. Sub-cell positions are read by bilinear interpolation of the field between cell centres. Karto
   rounds each point to its 1 cm correlation grid; our grids are 5-20 cm, where rounding would
   quantise every candidate to whole cells. The offsets of a window are then free (not whole
   cells): the extent of the search is a traced argument (a caller sizes it from the odometry
   covariance without recompiling) and the number of candidates per axis is static
   (:class:`Window`).
3. The fine search spans ± one coarse step in x, y and θ around the coarse best (Karto: ± half a
   coarse step), so a best lying between two coarse candidates is found on either side.
4. The fine search is penalised by the distance from the prior, as the coarse one is (Karto
   penalises it by the distance from the coarse best, its new search centre). The penalty is a
   model of the odometry, whose mean is the prior; centring it on the coarse best would pull the
   fine result toward a point of the coarse lattice.
5. The angular variance is taken about the best heading, both relative to the search centre.
   Karto's ``ComputeAngularCovariance`` subtracts the best heading *relative to* the centre from
   candidate headings that are absolute, so its variance grows with the robot's heading.
6. A scan point that is not valid (``valid`` False: no return) is left out of the mean; Karto
   divides by all readings, the invalid ones included (a scan with few returns scores lower).
7. Karto's ``use_response_expansion`` (retry with a wider angle window when nothing scores) is not
   done: shapes are static; the caller can widen ``half_angle`` and call again.
8. Equal best scores are grouped within :data:`TIE_TOLERANCE` (Karto's ``DoubleEqual``: 1e-6 in
   double precision): scores here are float32 sums of a few hundred terms.

Accuracy on a grid: the field peaks at the centres of occupied cells, while a lidar on a grid
returns the point where a beam enters its first occupied cell, half a cell short of the centre
along a wall's normal. Bilinear in between, each such point scores linearly over that half cell,
so a wall seen from one side pulls the pose up to half a cell toward itself, and walls seen from
both sides leave a plateau of ± half a cell around the truth on which the penalty picks the end
nearest the prior (the tests: <= 0.55 cell from such scans, <= 0.15 cell from end points moved
half a cell further along their beams, which a caller may do). A wall several cells thick is
flat across its thickness.

Conventions (:mod:`jaxplore.world`): cells are (row, col), row 0 holds the lowest y; ``origin``
f32[2] is the metres (x, y) of the lower-left corner of cell (0, 0), so cell (i, j)'s centre is at
``origin + (j + 0.5, i + 0.5) * res``. Poses are f32[3] (x m, y m, θ rad); scan points are
f32[B, 2] end points in the robot frame, metres. Every function is pure with static shapes
(``jit``- and ``vmap``-able); no LAPACK call (see :mod:`jaxplore.linalg`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplore.motion import wrap_angle

PROMISE_IN_BOUNDS = jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS

# Constants hard-coded in Karto's Mapper.cpp / Math.h (slam_toolbox lib/karto_sdk).
MAX_VARIANCE = 500.0  # m², the positional variance of a match that scored nothing
DISTANCE_PENALTY_GAIN = 0.2
ANGLE_PENALTY_GAIN = 0.2
KT_TOLERANCE = 1e-6  # a best response below this counts as no response
RESPONSE_BAND = 0.1  # the covariances weigh the candidates scoring within this of the best
MIN_VARIANCE_FACTOR = 0.1  # positional variance >= this * (coarse step)²
TIE_TOLERANCE = 1e-5  # scores this close to the best are "equally best" (Karto: 1e-6, doubles)


class KartoDefaults(NamedTuple):
  """slam_toolbox's default scan-matcher parameters (the values of its YAML, unconverted).

  Source: SteveMacenski/slam_toolbox, ``config/mapper_params_online_async.yaml`` (ROS 2 layout,
  ``slam_toolbox: ros__parameters:``; the ROS 1 file has the same values). Units as in the YAML
  (Karto's own built-in defaults in ``Mapper::InitializeParameters`` differ, e.g. a 0.03 m smear
  and a 0.3 m distance penalty); note that Karto's setters
  ``setParamDistanceVariancePenalty`` / ``setParamAngleVariancePenalty`` (``Mapper.cpp``) *square*
  the two ``*_variance_penalty`` values before use: they are standard deviations (m, rad), and
  :class:`Penalties` takes them so. ``fine_search_angle_offset`` is, despite its name, the
  *step* of the fine angle search (``CorrelateScan``'s ``searchAngleResolution``); the fine
  angle window is ± half ``coarse_angle_resolution``.
  """

  resolution: float = 0.05  # m, map cell size
  correlation_search_space_dimension: float = 0.5  # m, side of the sequential search square
  correlation_search_space_resolution: float = 0.01  # m, Karto's correlation grid cell
  correlation_search_space_smear_deviation: float = 0.1  # m, σ of the smear kernel
  loop_search_space_dimension: float = 8.0  # m
  loop_search_space_resolution: float = 0.05  # m
  loop_search_space_smear_deviation: float = 0.03  # m
  distance_variance_penalty: float = 0.5  # m (squared by Karto's setter)
  angle_variance_penalty: float = 1.0  # rad (squared by Karto's setter)
  fine_search_angle_offset: float = 0.00349  # rad, the fine angle step
  coarse_search_angle_offset: float = 0.349  # rad, half-width of the coarse angle window
  coarse_angle_resolution: float = 0.0349  # rad, the coarse angle step
  minimum_angle_penalty: float = 0.9
  minimum_distance_penalty: float = 0.5
  use_response_expansion: bool = True  # not implemented here (module docstring, 7)
  link_match_minimum_response_fine: float = 0.1  # a sequential match links above this
  link_scan_maximum_distance: float = 1.5  # m
  loop_search_maximum_distance: float = 3.0  # m
  loop_match_minimum_chain_size: int = 10
  # Squared by Karto's setter, then compared with the coarse x and y variances (TryCloseLoop).
  loop_match_maximum_variance_coarse: float = 3.0
  loop_match_minimum_response_coarse: float = 0.35
  loop_match_minimum_response_fine: float = 0.45


# Source: SteveMacenski/slam_toolbox, config/mapper_params_online_async.yaml (scan matcher,
# correlation and loop-closure parameters); constants above: lib/karto_sdk/src/Mapper.cpp.
KARTO_DEFAULTS = KartoDefaults()


class Window(NamedTuple):
  """The static shape of a search: ``2 * xy_steps + 1`` candidates along x and along y (each),
  ``2 * angle_steps + 1`` headings, evenly spaced over the (traced) half-widths."""

  xy_steps: int
  angle_steps: int


class Penalties(NamedTuple):
  """Karto's odometry penalty (``ScanMatcher::operator()``), traced scalars.

  A candidate offset from the prior by ``d`` metres and ``Δθ`` radians scores
  ``response * max(1 - 0.2 d² / distance_deviation², minimum_distance)
  * max(1 - 0.2 Δθ² / angle_deviation², minimum_angle)``.

  Attributes:
    distance_deviation: m, slam_toolbox's ``distance_variance_penalty`` (Karto squares it).
    angle_deviation: rad, ``angle_variance_penalty`` (squared likewise).
    minimum_distance: floor of the distance factor, ``minimum_distance_penalty``.
    minimum_angle: floor of the angle factor, ``minimum_angle_penalty``.
  """

  distance_deviation: jax.Array | float
  angle_deviation: jax.Array | float
  minimum_distance: jax.Array | float
  minimum_angle: jax.Array | float


def karto_penalties(defaults: KartoDefaults = KARTO_DEFAULTS) -> Penalties:
  """The :class:`Penalties` of slam_toolbox's defaults."""
  return Penalties(defaults.distance_variance_penalty, defaults.angle_variance_penalty,
                   defaults.minimum_distance_penalty, defaults.minimum_angle_penalty)


# Floors of 1 make both factors 1: Karto's ``doPenalize = false``, which its loop-closure and
# near-chain matches use (``TryCloseLoop``, ``LinkNearChains``); sequential matches penalise.
NO_PENALTIES = Penalties(1.0, 1.0, 1.0, 1.0)


class Match(NamedTuple):
  """The result of :func:`match`.

  Attributes:
    pose: f32[3] the best pose (the mean of the equally best fine candidates).
    response: f32 its penalised response in [0, 1] (Karto's return value, compared with
      ``link_match_minimum_response_fine`` / ``loop_match_minimum_response_fine``).
    cov: f32[3, 3] Karto's covariance: the x-y block from the coarse search
      (``ComputePositionalCovariance``), the θθ entry from the fine one
      (``ComputeAngularCovariance``), no x-θ or y-θ correlation.
    coarse_pose: f32[3] the best pose of the coarse search.
    coarse_response: f32 its penalised response (``loop_match_minimum_response_coarse``).
  """

  pose: jax.Array
  response: jax.Array
  cov: jax.Array
  coarse_pose: jax.Array
  coarse_response: jax.Array


def smear_radius(sigma: float, res: float) -> int:
  """Karto's kernel half-size ``round(2σ / res)`` cells (``GetHalfKernelSize``; host side).

  Karto accepts ``0.5 res <= σ <= 10 res`` only (``CalculateKernel``)."""
  return int(round(2.0 * sigma / res))


def smear(occupied, res: float, sigma, radius_cells: int):
  """Karto's smeared correlation grid of an occupancy grid (``CorrelationGrid::SmearPoint``).

  ``field[i, j] = max over (a, b) in [-r, r]² of occupied[i + a, j + b] * exp(-d² / 2σ²)`` with
  ``d = res * hypot(a, b)`` the distance between the cell centres and ``r = radius_cells``: a
  square kernel, as Karto's (corners included). An occupied cell holds 1; outside the grid counts
  as free. Karto stores ``round(100 * kernel)`` in bytes; here floats.

  The kernel is a product ``k(a) k(b)`` of non-negative factors, so the maximum separates:
  ``max_a k(a) max_b k(b) occupied[i + a, j + b]`` is exact and costs ``2 (2r + 1)`` shifts of the
  grid, not ``(2r + 1)²``.

  Args:
    occupied: bool[h, w], or f32[h, w] occupancy probabilities (each cell then spreads its own
      value times the kernel).
    res: m, cell size.
    sigma: m, the smear deviation (traced).
    radius_cells: static kernel half-size in cells (Karto: :func:`smear_radius`).
  Returns:
    f32[h, w] the field, in [0, 1].
  """
  grid = jnp.asarray(occupied).astype(jnp.float32)
  r = int(radius_cells)
  if r <= 0:
    return grid
  h, w = grid.shape
  shifts = jnp.arange(-r, r + 1, dtype=jnp.float32) * res
  kernel = jnp.exp(-0.5 * (shifts / sigma) ** 2)  # f32[2r + 1]
  padded = jnp.pad(grid, ((0, 0), (r, r)))
  along_cols = jnp.max(jnp.stack([kernel[k] * padded[:, k:k + w] for k in range(2 * r + 1)]), 0)
  padded = jnp.pad(along_cols, ((r, r), (0, 0)))
  return jnp.max(jnp.stack([kernel[k] * padded[k:k + h, :] for k in range(2 * r + 1)]), 0)


def _bilinear(field, rows, cols):
  """The field at continuous (row, col) cell coordinates (cell centres at integers), bilinear
  between centres, zero outside the grid (the taps beyond its edge read 0)."""
  h, w = field.shape
  flat = jnp.pad(field, 1).ravel()
  stride = w + 2
  r0, c0 = jnp.floor(rows), jnp.floor(cols)
  fr, fc = rows - r0, cols - c0
  inside = (r0 >= -1) & (r0 <= h - 1) & (c0 >= -1) & (c0 <= w - 1)
  top_left = (jnp.clip(r0.astype(jnp.int32) + 1, 0, h) * stride
              + jnp.clip(c0.astype(jnp.int32) + 1, 0, w))

  def tap(offset):
    return flat.at[top_left + offset].get(mode=PROMISE_IN_BOUNDS)

  value = ((1 - fr) * ((1 - fc) * tap(0) + fc * tap(1))
           + fr * ((1 - fc) * tap(stride) + fc * tap(stride + 1)))
  return jnp.where(inside, value, 0.0)


def _point_weights(valid):
  """f32[B] weights of a mean over the valid points (all 0 when none is)."""
  valid = valid.astype(jnp.float32)
  return valid / jnp.maximum(jnp.sum(valid), 1.0)


def _rotated_cells(origin, res, points, centre, headings):
  """Continuous (row, col) cell coordinates, f32[A, B] each, of the scan points at the position
  ``centre[:2]`` under each heading of f32[A]."""
  c, s = jnp.cos(headings)[:, None], jnp.sin(headings)[:, None]
  px, py = points[None, :, 0], points[None, :, 1]
  cols = (centre[0] + c * px - s * py - origin[0]) / res - 0.5
  rows = (centre[1] + s * px + c * py - origin[1]) / res - 0.5
  return rows, cols


def response(field, origin, res, points, valid, pose):
  """Karto's ``GetResponse``: the mean of the field over the valid scan end points at ``pose``.

  Args:
    field: f32[h, w] from :func:`smear`.
    origin: f32[2] metres of the lower-left corner of cell (0, 0); res: m, cell size.
    points: f32[B, 2] end points in the robot frame, m; valid: bool[B].
    pose: f32[3] (x, y, θ).
  Returns:
    f32 in [0, 1]; points outside the field count 0, no valid point gives 0. Sub-cell positions
    are interpolated bilinearly (Karto rounds to its grid; module docstring, 2); the mean is over
    the valid points (Karto: over all readings; module docstring, 6).
  """
  rows, cols = _rotated_cells(origin, res, points, pose, pose[2][None])
  return jnp.sum(_bilinear(field, rows[0], cols[0]) * _point_weights(valid))


def _offsets(steps: int, half):
  """f32[2 steps + 1] offsets evenly spaced over [-half, half] (just 0 for 0 steps), and the
  spacing (``half`` itself for 0 steps)."""
  step = half / max(steps, 1)
  return jnp.arange(-steps, steps + 1, dtype=jnp.float32) * step, step


def _responses(field, origin, res, points, weights, centre, dxy, dth):
  """Unpenalised responses f32[A, N, N] (heading, y, x) of the candidates
  ``centre + (dxy[ix], dxy[iy], dth[a])``: the points are rotated once per heading, the
  translations added to their cell coordinates, all candidates looked up at once. That holds
  the ``A N² B`` looked-up values (4 bytes each: 1 MB a robot for an 11³ window of 180 beams)
  and was measured faster than one heading at a time (``lax.map``;
  ``experiments/results/bench_slam_parts_cpu.md``)."""
  rows, cols = _rotated_cells(origin, res, points, centre, centre[2] + dth)
  d = dxy / res
  values = _bilinear(field, rows[:, None, None, :] + d[None, :, None, None],
                     cols[:, None, None, :] + d[None, None, :, None])
  return jnp.sum(values * weights[None, None, None, :], -1)


def _penalised(raw, prior, centre, dxy, dth, penalties: Penalties):
  """Karto's penalty (``ScanMatcher::operator()``) on responses f32[A, N, N], by each
  candidate's distance from the *prior* (module docstring, 4)."""
  ex = centre[0] - prior[0] + dxy
  ey = centre[1] - prior[1] + dxy
  eth = wrap_angle(centre[2] - prior[2] + dth)
  d2 = ey[:, None] ** 2 + ex[None, :] ** 2
  distance = jnp.maximum(1.0 - DISTANCE_PENALTY_GAIN * d2 / penalties.distance_deviation ** 2,
                         penalties.minimum_distance)
  angle = jnp.maximum(1.0 - ANGLE_PENALTY_GAIN * eth ** 2 / penalties.angle_deviation ** 2,
                      penalties.minimum_angle)
  return raw * angle[:, None, None] * distance[None, :, :]


def _best(scores, centre, dxy, dth):
  """``CorrelateScan``'s choice: the mean pose of the candidates scoring (within
  :data:`TIE_TOLERANCE` of) the best, headings averaged on the circle. Returns (pose f32[3],
  best score f32)."""
  best = jnp.max(scores)
  ties = (scores >= best - TIE_TOLERANCE).astype(jnp.float32)
  count = jnp.sum(ties)
  by_heading, by_y, by_x = jnp.sum(ties, (1, 2)), jnp.sum(ties, (0, 2)), jnp.sum(ties, (0, 1))
  headings = centre[2] + dth
  theta = jnp.arctan2(jnp.sum(by_heading * jnp.sin(headings)),
                      jnp.sum(by_heading * jnp.cos(headings)))
  pose = jnp.stack([centre[0] + jnp.sum(by_x * dxy) / count,
                    centre[1] + jnp.sum(by_y * dxy) / count, wrap_angle(theta)])
  return pose, best


def _positional_covariance(scores, best, mean, centre, dxy, step, angle_step):
  """``ComputePositionalCovariance``: the x-y covariance of the coarse window about the best
  pose, each position weighted by its best score over the headings, among the positions scoring
  at least ``best - 0.1``; variances floored at ``0.1 step²``, all scaled by ``1 / best``. A match
  that scored nothing gets :data:`MAX_VARIANCE` and θθ ``4 (angle step)²``. Returns f32[3, 3]."""
  per_cell = jnp.max(scores, 0)  # f32[N (y), N (x)]
  weights = jnp.where(per_cell >= best - RESPONSE_BAND, per_cell, 0.0)
  norm = jnp.sum(weights)
  ex = (centre[0] + dxy - mean[0])[None, :]
  ey = (centre[1] + dxy - mean[1])[:, None]
  safe = jnp.maximum(norm, KT_TOLERANCE)
  floor = MIN_VARIANCE_FACTOR * step ** 2
  vxx = jnp.maximum(jnp.sum(weights * ex ** 2) / safe, floor)
  vyy = jnp.maximum(jnp.sum(weights * ey ** 2) / safe, floor)
  vxy = jnp.sum(weights * ex * ey) / safe
  multiplier = 1.0 / jnp.maximum(best, KT_TOLERANCE)
  vxx, vxy, vyy = vxx * multiplier, vxy * multiplier, vyy * multiplier
  # Karto: a variance that came out exactly 0 (a zero-width window) becomes MAX_VARIANCE.
  vxx = jnp.where(vxx == 0.0, MAX_VARIANCE, vxx)
  vyy = jnp.where(vyy == 0.0, MAX_VARIANCE, vyy)
  scored = best >= KT_TOLERANCE
  vxx = jnp.where(scored, vxx, MAX_VARIANCE)
  vyy = jnp.where(scored, vyy, MAX_VARIANCE)
  vxy = jnp.where(scored, vxy, 0.0)
  vtt = 4.0 * angle_step ** 2
  zero = jnp.zeros_like(vxx)
  return jnp.stack([jnp.stack([vxx, vxy, zero]), jnp.stack([vxy, vyy, zero]),
                    jnp.stack([zero, zero, vtt])])


def _angular_variance(profile, best, best_theta, centre, dth, angle_step):
  """``ComputeAngularCovariance``: the variance of the headings about the best one, weighted by
  the unpenalised responses ``profile`` f32[A] at the best position, among those at least
  ``best - 0.1``; ``angle_step²`` when that comes out below 1e-6, ``1000 angle_step²`` when
  nothing qualifies. Headings are taken relative to the centre on both sides (module
  docstring, 5)."""
  weights = jnp.where(profile >= best - RESPONSE_BAND, profile, 0.0)
  norm = jnp.sum(weights)
  offsets = wrap_angle(dth - wrap_angle(best_theta - centre[2]))
  accumulated = jnp.sum(weights * offsets ** 2) / jnp.maximum(norm, KT_TOLERANCE)
  accumulated = jnp.where(accumulated < KT_TOLERANCE, angle_step ** 2, accumulated)
  return jnp.where(norm > KT_TOLERANCE, accumulated, 1000.0 * angle_step ** 2)


def match(field, origin, res, points, valid, prior, half_xy, half_angle, coarse: Window,
          fine: Window | None, penalties: Penalties) -> Match:
  """Karto's ``MatchScan``: a coarse search over the window, then a fine one around its best.

  Coarse: the ``(2n + 1)² (2m + 1)`` candidates ``prior + (i, j) * half_xy / n`` in x, y
  (``i, j = -n..n``, ``n = coarse.xy_steps``) and ``prior θ + k * half_angle / m``
  (``m = coarse.angle_steps``), each scored by :func:`response` times the penalty
  (:class:`Penalties`); the best pose is the mean of the equally best candidates; the x-y
  covariance comes from this window (``ComputePositionalCovariance``). Fine: the same around the
  coarse best over ± one coarse step in x, y and θ (``fine`` sets the counts; module docstring,
  3), penalised by the distance from the prior (4); the θθ variance comes from its headings at the
  best position (``ComputeAngularCovariance``). ``fine=None`` stops after the coarse search
  (Karto's ``doRefineMatch = false``, its loop-closure coarse check): θθ is then
  ``4 (coarse angle step)²``. A match scoring nothing (best response < 1e-6, e.g. no valid point)
  returns the prior with :data:`MAX_VARIANCE` in x and y.

  For scale, slam_toolbox's defaults search ± 0.25 m in 0.02 m steps (26 positions per axis,
  an even count: the prior itself is not a candidate) and ± 0.349 rad in 0.0349 rad steps
  (``angle_steps`` = 10), then ± 0.01 m in 0.01 m steps and ± 0.01745 rad in 0.00349 rad steps.

  Args:
    field: f32[h, w] :func:`smear` of the grid matched against (a crop is fine).
    origin: f32[2] metres of the lower-left corner of the field's cell (0, 0); res: m.
    points: f32[B, 2] scan end points in the robot frame, m; valid: bool[B].
    prior: f32[3] the odometry pose, centre of the coarse search and of the penalty.
    half_xy: m, half-width of the coarse window in x and in y (traced).
    half_angle: rad, half-width of the coarse window in θ (traced).
    coarse, fine: static :class:`Window` shapes.
    penalties: :class:`Penalties` (:func:`karto_penalties`, or :data:`NO_PENALTIES`).
  Returns:
    :class:`Match`.
  """
  weights = _point_weights(valid)
  half_xy = jnp.asarray(half_xy, jnp.float32)
  half_angle = jnp.asarray(half_angle, jnp.float32)
  dxy, step = _offsets(coarse.xy_steps, half_xy)
  dth, angle_step = _offsets(coarse.angle_steps, half_angle)
  raw = _responses(field, origin, res, points, weights, prior, dxy, dth)
  scores = _penalised(raw, prior, prior, dxy, dth, penalties)
  coarse_pose, coarse_best = _best(scores, prior, dxy, dth)
  cov = _positional_covariance(scores, coarse_best, coarse_pose, prior, dxy, step, angle_step)
  scored = coarse_best >= KT_TOLERANCE
  coarse_pose = jnp.where(scored, coarse_pose, prior)
  if fine is None:
    return Match(coarse_pose, jnp.minimum(coarse_best, 1.0), cov, coarse_pose,
                 jnp.minimum(coarse_best, 1.0))
  fxy, _ = _offsets(fine.xy_steps, step)
  fth, fine_angle_step = _offsets(fine.angle_steps, angle_step)
  raw = _responses(field, origin, res, points, weights, coarse_pose, fxy, fth)
  scores = _penalised(raw, prior, coarse_pose, fxy, fth, penalties)
  pose, best = _best(scores, coarse_pose, fxy, fth)
  pose = jnp.where(scored, pose, prior)
  # The headings' responses at the best position (Karto: at its grid cell), unpenalised.
  rows, cols = _rotated_cells(origin, res, points, pose, coarse_pose[2] + fth)
  profile = jnp.sum(_bilinear(field, rows, cols) * weights[None, :], -1)
  vtt = _angular_variance(profile, best, pose[2], coarse_pose, fth, fine_angle_step)
  cov = cov.at[2, 2].set(jnp.where(scored, vtt, cov[2, 2]))
  return Match(pose, jnp.minimum(best, 1.0), cov, coarse_pose, jnp.minimum(coarse_best, 1.0))


__all__ = ["KARTO_DEFAULTS", "KartoDefaults", "Match", "NO_PENALTIES", "Penalties", "Window",
           "karto_penalties", "match", "response", "smear", "smear_radius"]
