"""Lidar: exact grid traversal of every beam, in closed form.

A beam from ``p0`` (in cell units: ``u`` = column coordinate, ``v`` = row coordinate) along a unit
direction ``d`` enters a new cell exactly when it crosses a vertical (``u`` integer) or horizontal
(``v`` integer) grid line. The ``i``-th vertical crossing happens at a distance known in closed
form, and so does the row the beam is in at that moment; likewise for horizontal crossings. So the
cells a beam visits (Amanatides–Woo) are computed for all crossings at once, with no sequential
loop: ``2 * n_cross + 1`` entries per beam, each with its entry distance ``t``.

Corners: when a beam passes (within ``CORNER_EPS`` cells) through a grid corner it touches both
cells beside the corner; both are checked for occupancy ("side" cells), so a beam never slips
between two diagonally touching occupied cells. Only the cells a beam really enters are marked
free.

Distances are in cells throughout this module; multiply by ``res`` for metres.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

CORNER_EPS = 1e-3  # cells; a grid line crossed this close to another counts as a corner


class BeamCells(NamedTuple):
  """The cells one beam enters, in order of crossing type (not sorted by distance).

  Attributes:
    rows, cols: i32[K] cell each entry enters (K = 2 * n_cross + 1; entry 0 = the start cell).
    side_rows, side_cols: i32[K] the other cell touched when the entry is at a corner (else the
      same cell as rows/cols).
    t: f32[K] distance (cells) from the origin at which the cell is entered; inf if never.
  """

  rows: jax.Array
  cols: jax.Array
  side_rows: jax.Array
  side_cols: jax.Array
  t: jax.Array


def beam_cells(u0, v0, angle, n_cross: int) -> BeamCells:
  """Cells visited by one beam from (u0, v0) (cell units) at ``angle`` (rad, from the +u axis).

  Args:
    u0, v0: f32 scalars, origin in cell units (column, row coordinates).
    angle: f32 scalar, absolute beam angle.
    n_cross: static number of grid-line crossings per axis to enumerate (>= range in cells + 1).
  """
  du, dv = jnp.cos(angle), jnp.sin(angle)
  k = jnp.arange(1, n_cross + 1, dtype=jnp.float32)
  cu0, cv0 = jnp.floor(u0), jnp.floor(v0)

  def axis_crossings(a0, ca0, da, b0, db):
    # Crossings of grid lines a = integer, as the beam advances along axis a.
    sa = jnp.where(da >= 0, 1.0, -1.0)
    entered = ca0 + k * sa  # index along axis a of the cell entered
    boundary = entered + jnp.where(da >= 0, 0.0, 1.0)
    safe_da = jnp.where(jnp.abs(da) < 1e-12, 1e-12, da)
    t = jnp.where(jnp.abs(da) < 1e-12, jnp.inf, (boundary - a0) / safe_da)
    t_lo = jnp.maximum(t - CORNER_EPS, 0.0)
    other_after = jnp.floor(b0 + (t + CORNER_EPS) * db)
    other_before = jnp.floor(b0 + t_lo * db)
    return entered, other_after, other_before, t

  # Vertical lines (u integer): the column changes, the row is read off v(t).
  col_x, row_x_after, row_x_before, t_x = axis_crossings(u0, cu0, du, v0, dv)
  # Horizontal lines (v integer): the row changes, the column is read off u(t).
  row_y, col_y_after, col_y_before, t_y = axis_crossings(v0, cv0, dv, u0, du)

  zero = jnp.zeros((1,), jnp.float32)
  rows = jnp.concatenate([cv0[None], row_x_after, row_y])
  cols = jnp.concatenate([cu0[None], col_x, col_y_after])
  side_rows = jnp.concatenate([cv0[None], row_x_before, row_y])
  side_cols = jnp.concatenate([cu0[None], col_x, col_y_before])
  t = jnp.concatenate([zero, t_x, t_y])
  as_int = lambda a: a.astype(jnp.int32)
  return BeamCells(as_int(rows), as_int(cols), as_int(side_rows), as_int(side_cols), t)


def _occupied_at(occupied, rows, cols):
  """Truth lookup where everything outside the grid is occupied."""
  h, w = occupied.shape
  inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
  value = occupied[jnp.clip(rows, 0, h - 1), jnp.clip(cols, 0, w - 1)]
  return value | ~inside


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


def cast(occupied, u0, v0, angles, r_max_cells, n_cross: int, key=None, noise_cells=0.0):
  """Casts every beam against the truth grid.

  Args:
    occupied: bool[H, W] ground truth (outside counts as occupied).
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

  def one(angle):
    cells = beam_cells(u0, v0, angle, n_cross)
    occ_after = _occupied_at(occupied, cells.rows, cells.cols)
    occ_side = _occupied_at(occupied, cells.side_rows, cells.side_cols)
    blocked = (occ_after | occ_side) & (cells.t <= r_max_cells)
    t_block = jnp.where(blocked, cells.t, jnp.inf)
    first = jnp.argmin(t_block)
    t_hit = t_block[first]
    hit = jnp.isfinite(t_hit)
    use_after = occ_after[first]
    hit_row = jnp.where(use_after, cells.rows[first], cells.side_rows[first])
    hit_col = jnp.where(use_after, cells.cols[first], cells.side_cols[first])
    return (jnp.minimum(t_hit, r_max_cells), hit, hit_row, hit_col), cells

  (true_ranges, hit, hit_rows, hit_cols), cells = jax.vmap(one)(angles)
  ranges = true_ranges
  if key is not None:
    noise = noise_cells * jax.random.normal(key, true_ranges.shape)
    ranges = jnp.where(hit, jnp.clip(true_ranges + noise, 0.0, r_max_cells), true_ranges)
  return Scan(angles, ranges, hit, hit_rows, hit_cols, true_ranges), cells


class Observation(NamedTuple):
  """What a scan says about the belief grid, as cell lists (duplicates allowed).

  Attributes:
    free_rows, free_cols: i32[n, K] cells seen free; masked entries point outside the grid.
    occ_rows, occ_cols: i32[n] end cells seen occupied; masked entries point outside the grid.
  """

  free_rows: jax.Array
  free_cols: jax.Array
  occ_rows: jax.Array
  occ_cols: jax.Array


def observe(scan: Scan, cells: BeamCells, u0, v0, shape, exact_hits) -> Observation:
  """Turns a scan into free/occupied cells of the belief.

  ``cells`` are the beams traced from ``(u0, v0)``, where the robot *believes* it is (the
  estimated pose; the same cells :func:`cast` returned when the estimate is the truth). Cells a
  beam enters before its measured range are free; the cell at the measured end is occupied. When
  ``exact_hits`` (a traced bool: no range noise and the estimate equals the truth) the occupied
  cell is the exact truth cell that stopped the beam (it may be a corner side cell).
  """
  h, w = shape
  outside = jnp.int32(max(h, w) + 1)

  def one(angle, rng, hit, hit_row, hit_col, cells):
    free = cells.t < rng
    end_u = u0 + (rng + CORNER_EPS) * jnp.cos(angle)
    end_v = v0 + (rng + CORNER_EPS) * jnp.sin(angle)
    end_row = jnp.where(exact_hits, hit_row, jnp.floor(end_v).astype(jnp.int32))
    end_col = jnp.where(exact_hits, hit_col, jnp.floor(end_u).astype(jnp.int32))
    is_end = (cells.rows == end_row) & (cells.cols == end_col) & hit
    free = free & ~is_end
    free_rows = jnp.where(free, cells.rows, outside)
    free_cols = jnp.where(free, cells.cols, outside)
    return free_rows, free_cols, jnp.where(hit, end_row, outside), jnp.where(hit, end_col, outside)

  return Observation(*jax.vmap(one)(scan.angles, scan.ranges, scan.hit, scan.hit_rows,
                                    scan.hit_cols, cells))


def trace(u0, v0, angles, n_cross: int) -> BeamCells:
  """:func:`beam_cells` for every angle (leaves [n, K])."""
  return jax.vmap(lambda a: beam_cells(u0, v0, a, n_cross))(angles)
