"""Lidar: exact grid traversal of every beam, in closed form.

A beam from ``p0`` (in cell units: ``u`` = column coordinate, ``v`` = row coordinate) along a unit
direction ``d`` enters a new cell exactly when it crosses a vertical (``u`` integer) or horizontal
(``v`` integer) grid line. The distances of the successive vertical crossings form an arithmetic
progression, and so do the horizontal ones; the row (or column) the beam is in at a crossing is
read off the line equation. So the cells a beam visits (Amanatides–Woo) are computed for all
crossings at once, with no sequential loop: ``2 * n_cross + 1`` entries per beam, each with its
entry distance ``t`` (entries are not sorted by ``t``; nothing here needs them to be).

Corners: when a beam passes within ``CORNER_EPS`` cells of a grid corner, the vertical crossing
lists the cell beside the corner on the beam's old row and the horizontal crossing lists the cell
diagonally across. A beam aimed between two diagonally touching occupied cells therefore always
meets one of them (the listed side cell): no beam slips through a diagonal wall.

Distances are in cells throughout this module; multiply by ``res`` for metres. The truth grid is
passed *framed* (a 1-cell occupied border, :func:`frame_truth`), so every beam stops inside the
frame and no lookup before a hit can fall outside the array.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

CORNER_EPS = 1e-3  # cells; a grid line crossed this close to another counts as a corner


class BeamCells(NamedTuple):
  """The cells one beam enters (K = 2 * n_cross + 1 entries; entry 0 = the start cell).

  Attributes:
    rows, cols: i32[K] cell each entry enters (may lie outside the grid past the map border).
    t: f32[K] distance (cells) from the origin at which the cell is entered; inf if never.
  """

  rows: jax.Array
  cols: jax.Array
  t: jax.Array


def beam_cells(u0, v0, angle, n_cross: int) -> BeamCells:
  """Cells visited by one beam from (u0, v0) (cell units) at ``angle`` (rad, from the +u axis).

  Args:
    u0, v0: f32 scalars, origin in cell units (column, row coordinates).
    angle: f32 scalar, absolute beam angle.
    n_cross: static number of grid-line crossings per axis (>= range in cells + 1).
  """
  du, dv = jnp.cos(angle), jnp.sin(angle)
  k = jnp.arange(n_cross, dtype=jnp.float32)
  cu0, cv0 = jnp.floor(u0), jnp.floor(v0)

  def progression(a0, ca0, da):
    # Distances to the successive grid lines a = integer crossed while moving along a.
    step = jnp.where(jnp.abs(da) < 1e-9, jnp.inf, 1.0 / jnp.maximum(jnp.abs(da), 1e-9))
    first = jnp.where(da >= 0, ca0 + 1.0 - a0, a0 - ca0)
    t = first * step + k * step
    entered = ca0 + jnp.where(da >= 0, 1.0, -1.0) * (k + 1.0)
    return t, entered

  t_x, col_x = progression(u0, cu0, du)  # vertical lines: the column changes
  t_y, row_y = progression(v0, cv0, dv)  # horizontal lines: the row changes
  row_x = jnp.floor(v0 + (t_x - CORNER_EPS) * dv)  # the row the beam leaves (side cell at corners)
  col_y = jnp.floor(u0 + (t_y + CORNER_EPS) * du)  # the column after the crossing

  as_int = lambda *a: jnp.concatenate(a).astype(jnp.int32)
  return BeamCells(rows=as_int(cv0[None], row_x, row_y), cols=as_int(cu0[None], col_x, col_y),
                   t=jnp.concatenate([jnp.zeros((1,), jnp.float32), t_x, t_y]))


def trace(u0, v0, angles, n_cross: int) -> BeamCells:
  """:func:`beam_cells` for every angle (leaves [n, K])."""
  return jax.vmap(lambda a: beam_cells(u0, v0, a, n_cross))(angles)


def frame_truth(occupied):
  """The truth grid with a 1-cell occupied border, flattened: bool[(H + 2) * (W + 2)]."""
  return jnp.pad(occupied, 1, constant_values=True).ravel()


def _framed_index(rows, cols, shape):
  h, w = shape
  flat = (rows + 1) * (w + 2) + (cols + 1)
  # Past the border only entries after a hit can land here; their value is never used.
  return jnp.clip(flat, 0, (h + 2) * (w + 2) - 1)


class Scan(NamedTuple):
  """One lidar scan against the ground truth.

  Attributes:
    angles: f32[n] absolute beam angles (rad).
    ranges: f32[n] measured range in cells (``r_max`` for a beam that hit nothing), noise included.
    hit: bool[n] beam ended on an obstacle before ``r_max``.
    hit_rows, hit_cols: i32[n] the occupied cell that stopped the beam (valid where ``hit``).
    true_ranges: f32[n] noise-free range, cells.
  """

  angles: jax.Array
  ranges: jax.Array
  hit: jax.Array
  hit_rows: jax.Array
  hit_cols: jax.Array
  true_ranges: jax.Array


def beam_angles(theta, fov, n_beams: int):
  """Absolute angles of ``n_beams`` rays spread evenly over ``fov`` centred on ``theta``.

  A full circle (fov = 2π) does not repeat its first ray at the end.
  """
  full = fov >= 2 * jnp.pi - 1e-6
  denom = jnp.where(full, n_beams, jnp.maximum(n_beams - 1, 1))
  step = fov / denom
  start = jnp.where(full, -jnp.pi, -0.5 * fov)
  offsets = start + step * jnp.arange(n_beams, dtype=jnp.float32)
  if n_beams == 1:
    offsets = jnp.zeros((1,), jnp.float32)
  return theta + offsets


def cast(truth_framed, shape, u0, v0, angles, r_max_cells, n_cross: int, key=None, noise_cells=0.0):
  """Casts every beam against the truth grid.

  Args:
    truth_framed: bool[(H + 2) * (W + 2)] from :func:`frame_truth` (outside counts as occupied).
    shape: static (H, W) of the unframed grid.
    u0, v0: origin in cell units.
    angles: f32[n] absolute beam angles.
    r_max_cells: max range in cells (traced).
    n_cross: static crossings per axis, >= ceil(r_max_cells) + 1.
    key: PRNG key for range noise (None: no noise).
    noise_cells: std of Gaussian range noise in cells.

  Returns:
    ``(scan, cells)``: the :class:`Scan` and the :class:`BeamCells` of every beam (leaves [n, K]),
    which :func:`observe` reuses when the robot knows its true pose.
  """
  cells = trace(u0, v0, angles, n_cross)
  occupied = truth_framed[_framed_index(cells.rows, cells.cols, shape)]
  t_block = jnp.where(occupied & (cells.t <= r_max_cells), cells.t, jnp.inf)
  first = jnp.argmin(t_block, axis=1)
  t_hit = jnp.take_along_axis(t_block, first[:, None], axis=1)[:, 0]
  hit = jnp.isfinite(t_hit)
  hit_rows = jnp.take_along_axis(cells.rows, first[:, None], axis=1)[:, 0]
  hit_cols = jnp.take_along_axis(cells.cols, first[:, None], axis=1)[:, 0]
  true_ranges = jnp.minimum(t_hit, r_max_cells)
  ranges = true_ranges
  if key is not None:
    noise = noise_cells * jax.random.normal(key, true_ranges.shape)
    ranges = jnp.where(hit, jnp.clip(true_ranges + noise, 0.0, r_max_cells), true_ranges)
  return Scan(angles, ranges, hit, hit_rows, hit_cols, true_ranges), cells


class Observation(NamedTuple):
  """What a scan says about the belief, as cells of a window (duplicates allowed).

  Attributes:
    index: i32[n * K + n] flat indices ``row * window_w + col`` into the window; entries to drop
      hold ``window_h * window_w``.
    value: i8[n * K + n] 1 = seen free, 2 = seen occupied.
    end_rows, end_cols: i32[n] global cell of each beam's end (valid where ``hit``).
    hit: bool[n] the beam ended on an obstacle.
  """

  index: jax.Array
  value: jax.Array
  end_rows: jax.Array
  end_cols: jax.Array
  hit: jax.Array


def observe(scan: Scan, cells: BeamCells, u0, v0, shape, exact_hits, window_origin, window_shape) -> Observation:
  """Turns a scan into free/occupied cells of a belief window.

  ``cells`` are the beams traced from ``(u0, v0)``, where the robot *believes* it is (the
  estimated pose; the same cells :func:`cast` returned when the estimate is the truth). Cells a
  beam enters before its measured range are free; the cell at the measured end is occupied. When
  ``exact_hits`` (a traced bool: no range noise and the estimate equals the truth) the occupied
  cell is the exact truth cell that stopped the beam (it may be a corner side cell).

  Args:
    shape: static (H, W) of the belief grid; cells outside it are dropped.
    window_origin: i32 (row, col) of the window's first cell; window_shape: static (h, w).
  """
  h, w = shape
  wh, ww = window_shape
  end_u = u0 + (scan.ranges + CORNER_EPS) * jnp.cos(scan.angles)
  end_v = v0 + (scan.ranges + CORNER_EPS) * jnp.sin(scan.angles)
  end_rows = jnp.where(exact_hits, scan.hit_rows, jnp.floor(end_v).astype(jnp.int32))
  end_cols = jnp.where(exact_hits, scan.hit_cols, jnp.floor(end_u).astype(jnp.int32))
  is_end = (cells.rows == end_rows[:, None]) & (cells.cols == end_cols[:, None]) & scan.hit[:, None]
  free = (cells.t < scan.ranges[:, None]) & ~is_end

  def local(rows, cols, keep):
    r, c = rows - window_origin[0], cols - window_origin[1]
    keep = keep & (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    keep = keep & (r >= 0) & (r < wh) & (c >= 0) & (c < ww)
    return jnp.where(keep, r * ww + c, wh * ww)

  index = jnp.concatenate([local(cells.rows, cells.cols, free).ravel(),
                           local(end_rows, end_cols, scan.hit)])
  value = jnp.concatenate([jnp.ones(free.size, jnp.int8), jnp.full(end_rows.shape, 2, jnp.int8)])
  return Observation(index, value, end_rows, end_cols, scan.hit)


def observation_grid(obs: Observation, window_shape):
  """int8 window grid: 0 unobserved, 1 seen free, 2 seen occupied (occupied wins)."""
  wh, ww = window_shape
  grid = jnp.zeros((wh * ww,), jnp.int8).at[obs.index].max(obs.value, mode="drop")
  return grid.reshape(wh, ww)
