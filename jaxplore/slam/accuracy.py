"""Trajectory and map accuracy of a robot's SLAM against the truth: absolute trajectory error
(ATE), relative pose error per metre (RPE) and misplaced walls.

The trajectory metrics are evo's (Grupp 2017, https://github.com/MichaelGrupp/evo, 1.38), read
for SE(2) poses lifted to SE(3) (rotation about z, z = 0) with ``pose_relation=translation_part``
and the RMSE statistic:

* ATE is ``evo_ape --align``: the estimated positions are moved onto the true ones by the
  least-squares rigid motion (Umeyama 1991 without scale; Horn 1987), then
  ``sqrt(mean_i |p̂_i − p_i|²)``; or ``evo_ape`` without ``--align``.
* RPE is ``evo_rpe --delta δ --delta_unit m``: for the pose pairs (i, j) evo selects, the error
  ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` of the true ``Q`` and estimated ``P`` poses, whose translation
  norm is ``|R(−θ̂_i)(p̂_j − p̂_i) − R(−θ_i)(p_j − p_i)|``; its RMSE, divided by δ (m/m).

Trajectories are a robot's keyframes at fixed capacity N: ``f32[N, 3]`` (x m, y m, θ rad) with a
``bool[N]`` validity mask that is a prefix (the rows past it are padding and change nothing: they
may hold anything, NaN included). Every function is pure, of fixed shapes, ``vmap``- and
``jit``-able. No LAPACK call (batched LAPACK under ``vmap`` blocks multi-device CPU runs, see
:mod:`jaxplore.linalg`): the 2-D alignment is closed form.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplore import mapping, motion


class Alignment(NamedTuple):
  """The rigid motion ``p ↦ R(angle) p + translation`` of the plane."""

  angle: jax.Array  # rad
  translation: jax.Array  # f32[2], m


class Pairs(NamedTuple):
  """Pose pairs of the RPE, one candidate per row; ``pairs = [(first[k], second[k]) for k if
  valid[k]]`` in row order is evo's list of id pairs in its order."""

  first: jax.Array  # i32[N]
  second: jax.Array  # i32[N]
  valid: jax.Array  # bool[N]


def _masked(a, valid):
  """``a`` with the rows past the valid prefix zeroed (padding may hold NaN)."""
  return jnp.where(valid[:, None], a, jnp.zeros_like(a))


def _rms(err, mask):
  """``sqrt(mean(err²))`` over ``mask``; NaN over an empty mask (no sample, no mean)."""
  count = jnp.sum(mask)
  total = jnp.sum(jnp.where(mask, err * err, 0.0))
  return jnp.where(count > 0, jnp.sqrt(total / jnp.maximum(count, 1)), jnp.nan)


def rigid_alignment(source_xy, target_xy, valid) -> Alignment:
  """The rigid motion minimising ``Σ_i |R s_i + t − d_i|²`` over the valid rows (Umeyama 1991
  Eq 39-41 without scale, in 2-D closed form).

  With the centred points ``a_i = s_i − s̄``, ``b_i = d_i − d̄``, the objective is maximised by
  ``θ = atan2(Σ a_x b_y − a_y b_x, Σ a_x b_x + a_y b_y)`` and ``t = d̄ − R(θ) s̄``. The rotation
  is proper (SE(2)). evo's 3-D Umeyama on planar points may instead return a mirror (a half turn
  about an in-plane axis, z ↦ −z) when the 2-D cross-covariance has a negative determinant
  (an estimate so wrong that its mirror image fits better); both agree otherwise. evo refuses
  collinear points (covariance rank < 2); here they are aligned (the rotation is unique unless
  the cross-covariance vanishes). With no spread (0 or 1 valid point, or all points at one
  place) θ = 0 and the translation matches the centroids (0 with no valid point).
  """
  w = valid.astype(source_xy.dtype)
  count = jnp.maximum(jnp.sum(w), 1.0)
  src, dst = _masked(source_xy, valid), _masked(target_xy, valid)
  mean_s = jnp.sum(src, axis=0) / count
  mean_d = jnp.sum(dst, axis=0) / count
  a = (src - mean_s[None, :]) * w[:, None]
  b = (dst - mean_d[None, :]) * w[:, None]
  cos_part = jnp.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
  sin_part = jnp.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
  angle = jnp.arctan2(sin_part, cos_part)
  return Alignment(angle, mean_d - motion.rotate(angle, mean_s))


def apply_alignment(alignment: Alignment, xy):
  """``R xy + t`` for points ``f32[..., 2]``."""
  shift = jnp.reshape(alignment.translation, (1,) * (jnp.ndim(xy) - 1) + (2,))
  return motion.rotate(alignment.angle, xy) + shift


def ape_errors(estimated, truth, valid, align: bool = True):
  """Per-pose ``|p̂_i − p_i|`` (m) of evo's APE (``translation_part``), after
  :func:`rigid_alignment` of the estimated positions onto the true ones when ``align``; 0 on
  padding rows."""
  est_xy = _masked(estimated[:, :2], valid)
  true_xy = _masked(truth[:, :2], valid)
  if align:
    est_xy = apply_alignment(rigid_alignment(est_xy, true_xy, valid), est_xy)
  d = est_xy - true_xy
  return jnp.where(valid, jnp.sqrt(jnp.sum(d * d, axis=-1)), 0.0)


def absolute_trajectory_error(estimated, truth, valid, align: bool = True):
  """ATE (m): the RMSE of :func:`ape_errors`, ``evo_ape --align`` (or plain ``evo_ape`` without
  ``align``) with ``pose_relation=translation_part``.

  Degenerate cases: NaN with no valid pose (no error to average); with one valid pose, 0 when
  aligned (a point aligns exactly; evo's Umeyama raises) and the pose's position error otherwise.
  """
  return _rms(ape_errors(estimated, truth, valid, align), valid)


def _path_step(carry, x):
  """One pose of :func:`_path_scan` (module level, so eager calls reuse its trace)."""
  total, path, last, delta = carry
  step, i, ok = x
  total = total + step
  path = path + step  # evo: current_path += |p_i − p_{i−1}|, reset when a pose is selected
  hit = ok & (path >= delta)
  carry = (total, jnp.where(hit, jnp.zeros_like(path), path), jnp.where(hit, i, last), delta)
  return carry, (total, hit, last)


def _path_scan(xy, valid, delta):
  """One sequential pass over the valid prefix (the order of evo's loop and of ``np.cumsum``):
  the accumulated path length ``cum: f[N]`` (``geometry.accumulated_distances``), and for each
  row i the consecutive-pairs rule of ``filters.filter_pairs_by_path``: whether i is selected
  (``hit``) and the previously selected row (``last``)."""
  d = xy[1:] - xy[:-1]
  steps = jnp.where(valid[1:], jnp.sqrt(jnp.sum(d * d, axis=-1)), 0.0)
  zero = jnp.zeros((), xy.dtype)
  index = jnp.arange(1, xy.shape[0], dtype=jnp.int32)
  init = (zero, zero, jnp.zeros((), jnp.int32), jnp.asarray(delta, xy.dtype))
  _, (cum, hit, last) = jax.lax.scan(_path_step, init, (steps, index, valid[1:]))
  return (jnp.concatenate([zero[None], cum]), jnp.concatenate([jnp.zeros((1,), bool), hit]),
          jnp.concatenate([jnp.zeros((1,), jnp.int32), last]))


def _excess(cum, j, delta):
  """evo's ``(c_j − c_i) − delta`` for every row i, at ``j: i32[N]`` (clipped to the array)."""
  return (cum[jnp.minimum(j, cum.shape[0] - 1)] - cum) - delta


def _bisect_step(_, state):
  """One bisection step of :func:`_first_at_least` (module level, so eager calls reuse it)."""
  lo, hi, cum, delta, level = state
  mid = (lo + hi) // 2
  active = lo < hi
  yes = _excess(cum, mid, delta) >= level
  return (jnp.where(active & ~yes, mid + 1, lo), jnp.where(active & yes, mid, hi), cum, delta,
          level)


def _first_at_least(cum, delta, level, lo, hi):
  """Per row i, the least ``j`` in ``[lo_i, hi_i)`` with ``(c_j − c_i) − delta ≥ level_i``
  (``hi_i`` if none), by bisection: the excess is non-decreasing in j."""
  iterations = max(1, cum.shape[0].bit_length())
  state = (lo, hi, cum, jnp.asarray(delta, cum.dtype), level)
  return jax.lax.fori_loop(0, iterations, _bisect_step, state)[0]


def rpe_pairs(poses, valid, delta, rel_delta_tol=0.1, all_pairs: bool = False) -> Pairs:
  """The pose pairs evo's ``metrics.id_pairs_from_delta(poses, delta, Unit.meters, rel_tol,
  all_pairs)`` selects, i.e. ``filters.filter_pairs_by_path(poses, delta, delta·rel_delta_tol,
  all_pairs)``, over the valid prefix (n poses) of ``poses: f32[N, 3]``.

  Consecutive pairs (default): pose 0 is selected; walking i = 1, …, n−1, the path length since
  the last selected pose accumulates ``|p_i − p_{i−1}|`` and pose i is selected (the
  accumulator reset to 0) once it reaches ``delta``; the pairs join successive selected poses.
  Row ``j`` holds the pair ending at j.

  All pairs: for each i < n − 1, with the accumulated path lengths ``c`` and
  ``f(j) = (c_j − c_i) − delta``, the partner is the first ``j`` in (i, n) minimising ``|f(j)|``
  (``np.argmin``), kept when ``|f(j)| ≤ delta·rel_delta_tol``. ``f`` is non-decreasing in j, so
  the candidates are the first j with ``f ≥ 0`` and the first j whose ``f`` equals that of the
  last j with ``f < 0``, each found by bisection. Row ``i`` holds the pair starting at i.
  """
  n_rows = poses.shape[0]
  xy = _masked(poses[:, :2], valid)
  cum, hit, last = _path_scan(xy, valid, delta)
  rows = jnp.arange(n_rows, dtype=jnp.int32)
  if not all_pairs:
    return Pairs(last, rows, hit)
  n = jnp.sum(valid).astype(jnp.int32)
  ends = jnp.broadcast_to(n, rows.shape)
  above = _first_at_least(cum, delta, jnp.zeros_like(cum), rows + 1, ends)  # first f ≥ 0
  below = above - 1  # the last j with f < 0 (a candidate only when it is past i)
  first_below = _first_at_least(cum, delta, _excess(cum, below, delta), rows + 1, below)
  err_below = jnp.abs(_excess(cum, first_below, delta))
  err_above = jnp.abs(_excess(cum, above, delta))
  take_below = (below > rows) & ((above >= n) | (err_below <= err_above))
  partner = jnp.where(take_below, first_below, above)
  err = jnp.where(take_below, err_below, err_above)
  keep = (rows + 1 < n) & (err <= delta * rel_delta_tol)
  return Pairs(rows, jnp.where(keep, partner, rows), keep)


def rpe_errors(estimated, truth, pairs: Pairs):
  """Per-pair translation norm (m) of evo's ``RPE.rpe_base`` error
  ``(Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)``: ``|R(−θ̂_i)(p̂_j − p̂_i) − R(−θ_i)(p_j − p_i)|``; 0 on rows that
  are not pairs."""
  i, j = pairs.first, pairs.second  # valid pairs index valid poses only
  rel_est = motion.rotate(-estimated[i, 2], estimated[j, :2] - estimated[i, :2])
  rel_true = motion.rotate(-truth[i, 2], truth[j, :2] - truth[i, :2])
  d = rel_est - rel_true
  return jnp.where(pairs.valid, jnp.sqrt(jnp.sum(d * d, axis=-1)), 0.0)


def relative_pose_error(estimated, truth, valid, delta=1.0, rel_delta_tol=0.1,
                        all_pairs: bool = False, pairs_from_reference: bool = False):
  """RPE per metre (m/m): the RMSE of :func:`rpe_errors` over the pairs of :func:`rpe_pairs`,
  divided by ``delta``; ``evo_rpe --delta δ --delta_unit m`` with
  ``pose_relation=translation_part`` (``--all_pairs``, ``--pairs_from_reference`` as the flags).

  As in evo, the pairs are selected on the path of the *estimated* trajectory unless
  ``pairs_from_reference`` (then on the true one). NaN when no pair is selected (evo raises).
  RPE needs no alignment: a rigid motion of the estimate leaves it unchanged.
  """
  poses = truth if pairs_from_reference else estimated
  pairs = rpe_pairs(poses, valid, delta, rel_delta_tol, all_pairs)
  return _rms(rpe_errors(estimated, truth, pairs), pairs.valid) / delta


def misplaced_walls(belief_occupied, truth_occupied):
  """The fraction of the cells the belief holds occupied that are more than one cell (Chebyshev
  distance) from every truth-occupied cell: walls the map puts where there are none. 0 when
  the belief holds no occupied cell (no wall, none misplaced). Swapping the arguments gives the
  converse (true walls with no believed wall within one cell, unobserved ones included).
  """
  framed = mapping.frame(truth_occupied, False)
  near = truth_occupied
  for di in (-1, 0, 1):
    for dj in (-1, 0, 1):
      if di or dj:
        near = near | mapping.shifted(framed, di, dj)
  count = jnp.sum(belief_occupied)
  misplaced = jnp.sum(belief_occupied & ~near)
  return jnp.where(count > 0, misplaced / jnp.maximum(count, 1), 0.0).astype(jnp.float32)
