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

Two forms of the same traversal:

* :func:`trace` / :func:`beam_cells` list every entry of every beam (``[n, K]`` arrays): the plain
  definition, used by tests and tools.
* :func:`measure` (the first occupied cell of each beam) and :func:`mark_observed` (the cells a
  scan saw free or occupied) are what the engine runs, one robot at a time. They walk the
  crossings in blocks of a few crossings per axis for groups of neighbouring beams and stop
  as soon as the group is done: indoors most beams end within a few metres, so most of the
  ``[n, K]`` entries are never computed. A short-range scan is marked in one block for all
  beams instead (the loop would cost more than the entries it saves). Both evaluate the float
  expressions of :func:`beam_cells` (:func:`_crossings`), so they find bit-identical cells and
  distances.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

CORNER_EPS = 1e-3  # cells; a grid line crossed this close to another counts as a corner
# Beams walked in lockstep (the vector width) and crossings per axis per loop iteration. A group
# walks as far as its longest beam; an iteration has a fixed cost of about a microsecond on
# XLA:CPU. The best trade-offs on the 2-core CPU, the whole step timed: 32 x 8 to find the hits;
# 64 x 8 to mark the cells seen, and for ranges up to MARK_WHOLE_RANGE crossings every beam at
# once to its full range (faster for a short scan, slower for a long one). The numbers:
# experiments/results/bench_engine.md, "Marking a scan's cells".
MEASURE_GROUP, MEASURE_BLOCK = 32, 8
MARK_GROUP, MARK_BLOCK = 64, 8
MARK_WHOLE_RANGE = 48
OBS_TILE = 16  # observations are stored in OBS_TILE x OBS_TILE tiles (see empty_observation)
PROMISE_IN_BOUNDS = jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS


class Beams(NamedTuple):
  """Per-beam constants of the closed-form traversal from one origin (leaves f32[n] or scalars).

  The k-th vertical crossing (k = 0, 1, ...) is at distance ``t0_u + k * step_u`` and enters
  column ``floor(u0) + sign_u * (k + 1)``; horizontal crossings likewise with ``v``.

  Attributes:
    du, dv: the unit direction (cos, sin of the beam angle).
    t0_u, step_u, sign_u: first vertical crossing distance, spacing, column step (±1).
    t0_v, step_v, sign_v: the same for horizontal crossings (row step).
  """

  du: jax.Array
  dv: jax.Array
  t0_u: jax.Array
  step_u: jax.Array
  sign_u: jax.Array
  t0_v: jax.Array
  step_v: jax.Array
  sign_v: jax.Array


def directions(angles):
  """(cos, sin) of beam angles: the unit direction of each beam (u along columns, v along rows)."""
  return jnp.cos(angles), jnp.sin(angles)


def beams(u0, v0, angles, dirs=None) -> Beams:
  """The :class:`Beams` of beams from (u0, v0) (cell units) at absolute ``angles`` (rad).

  ``dirs``: the beams' :func:`directions` if already computed (``angles`` is then unused).
  """
  du, dv = directions(angles) if dirs is None else dirs

  def progression(a0, da):
    # Distances to the successive grid lines a = integer crossed while moving along a.
    ca0 = jnp.floor(a0)
    step = jnp.where(jnp.abs(da) < 1e-9, jnp.inf, 1.0 / jnp.maximum(jnp.abs(da), 1e-9))
    first = jnp.where(da >= 0, ca0 + 1.0 - a0, a0 - ca0)
    return first * step, step, jnp.where(da >= 0, 1.0, -1.0)

  return Beams(du, dv, *progression(u0, du), *progression(v0, dv))


def _crossings(b: Beams, u0, v0, k):
  """Entry distance and cell of the k-th vertical and horizontal crossing (``k`` f32).

  ``k`` broadcasts against the beams, which are aligned with its last axes.

  Returns:
    ``((t_x, row_x, col_x), (t_y, row_y, col_y))``; rows and columns i32.
  """
  b = jax.tree.map(lambda a: a.reshape((1,) * (jnp.ndim(k) - a.ndim) + a.shape), b)
  cu0, cv0 = jnp.floor(u0), jnp.floor(v0)
  t_x = b.t0_u + k * b.step_u  # vertical lines: the column changes
  t_y = b.t0_v + k * b.step_v  # horizontal lines: the row changes
  # the row the beam leaves (side cell at corners)
  row_x = jnp.floor(v0 + (t_x - CORNER_EPS) * b.dv)
  col_y = jnp.floor(u0 + (t_y + CORNER_EPS) * b.du)  # the column after the crossing
  # Exact small integers: the entered column (row) is formed in integer arithmetic.
  step = lambda sign: jnp.where(sign > 0, 1, -1) * (k.astype(jnp.int32) + 1)
  col_x = cu0.astype(jnp.int32) + step(b.sign_u)
  row_y = cv0.astype(jnp.int32) + step(b.sign_v)
  i32 = lambda a: a.astype(jnp.int32)
  return (t_x, i32(row_x), col_x), (t_y, row_y, i32(col_y))


def _distance(t0, step, k):
  """Distance of crossing ``k`` (i32) of one progression, as :func:`_crossings` computes it."""
  return t0 + k.astype(jnp.float32) * step


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
  k = jnp.arange(n_cross, dtype=jnp.float32)
  (t_x, row_x, col_x), (t_y, row_y, col_y) = _crossings(beams(u0, v0, angle), u0, v0, k)
  start = lambda a: jnp.floor(a).astype(jnp.int32)[None]
  return BeamCells(rows=jnp.concatenate([start(v0), row_x, row_y]),
                   cols=jnp.concatenate([start(u0), col_x, col_y]),
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


def _inside(rows, cols, shape):
  return (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])


class Scan(NamedTuple):
  """One lidar scan against the ground truth.

  Attributes:
    angles: f32[n] absolute beam angles (rad).
    ranges: f32[n] measured range in cells (``r_max`` for a beam that hit nothing), noise included.
    hit: bool[n] beam ended on an obstacle before ``r_max``.
    hit_rows, hit_cols: i32[n] the occupied cell that stopped the beam (valid where ``hit``;
      the start cell elsewhere).
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


def _groups(a, group: int):
  """Splits a beam axis into [n_groups, group], padding with copies of the last beam."""
  return jnp.pad(a, (0, -a.shape[0] % group), mode="edge").reshape(-1, group)


def _for_each_group(n_groups, active, body, carry):
  """``body(g, carry)`` for every group, none when ``active`` is False."""
  return jax.lax.fori_loop(0, jnp.where(active, n_groups, 0), body, carry)


def measure(truth_framed, shape, u0, v0, angles, r_max_cells, n_cross: int, key=None,
            noise_cells=0.0, active=True, dirs=None) -> Scan:
  """Casts every beam against the truth grid (the first occupied cell of each beam).

  Equal to the first occupied entry of :func:`trace` by distance (ties: the start cell, then a
  vertical crossing, then a horizontal one), found without listing the entries past it: a
  group's walk stops once every beam of the group has a hit nearer than the next block (the k-th
  crossing of either axis is at least k cells away).

  Args:
    truth_framed: bool[(H + 2) * (W + 2)] from :func:`frame_truth` (outside counts as occupied).
    shape: static (H, W) of the unframed grid.
    u0, v0: origin in cell units.
    angles: f32[n] absolute beam angles.
    r_max_cells: max range in cells (traced).
    n_cross: static crossings per axis, >= ceil(r_max_cells) + 1.
    key: PRNG key for range noise (None: no noise).
    noise_cells: std of Gaussian range noise in cells.
    active: traced bool; when False nothing is cast (every beam reports no hit at ``r_max``).
    dirs: :func:`directions` of ``angles``, if the caller has them. XLA:CPU's cos and sin are slow
      and, computed here, get fused into (and re-evaluated by) each of their consumers; computed
      by the caller outside its loops (e.g. for a whole batch at once) they are evaluated once.
  """
  n = angles.shape[0]
  du, dv = directions(angles) if dirs is None else dirs
  none = jnp.int32(n_cross)  # "no occupied crossing found" on an axis
  start_row, start_col = jnp.floor(v0).astype(jnp.int32), jnp.floor(u0).astype(jnp.int32)
  start_occupied = truth_framed[_framed_index(start_row, start_col, shape)]
  grouped = tuple(_groups(a, MEASURE_GROUP) for a in (du, dv))
  # crossings on axis 0, beams on axis 1
  block = jnp.arange(MEASURE_BLOCK, dtype=jnp.int32)[:, None]

  def walk_group(g, found):
    b = beams(u0, v0, None, (grouped[0][g], grouped[1][g]))

    def hit_distances(kx, ky):
      t_x = jnp.where(kx < none, _distance(b.t0_u, b.step_u, kx), jnp.inf)
      t_y = jnp.where(ky < none, _distance(b.t0_v, b.step_v, ky), jnp.inf)
      return (jnp.where(t_x <= r_max_cells, t_x, jnp.inf),
              jnp.where(t_y <= r_max_cells, t_y, jnp.inf))

    def body(carry):
      k0, kx, ky = carry
      k = k0 + block
      (_, row_x, col_x), (_, row_y, col_y) = _crossings(b, u0, v0, k.astype(jnp.float32))
      # Crossings are increasingly far along each axis: the first occupied one is the nearest.
      occupied = lambda rows, cols: truth_framed.at[_framed_index(rows, cols, shape)].get(
          mode=PROMISE_IN_BOUNDS)
      kx = jnp.minimum(kx, jnp.min(jnp.where(occupied(row_x, col_x), k, none), axis=0))
      ky = jnp.minimum(ky, jnp.min(jnp.where(occupied(row_y, col_y), k, none), axis=0))
      return k0 + MEASURE_BLOCK, kx, ky

    def unfinished(carry):
      k0, kx, ky = carry
      # Crossing k is at least k cells away; ">=": a vertical crossing wins a tie.
      nearest = jnp.minimum(*hit_distances(kx, ky))
      return (k0 < n_cross) & (k0 <= r_max_cells) & ~start_occupied & jnp.any(nearest >= k0)

    missing = jnp.full((MEASURE_GROUP,), none)
    _, kx, ky = jax.lax.while_loop(unfinished, body, (jnp.int32(0), missing, missing))
    t_x, t_y = hit_distances(kx, ky)
    (_, row_x, col_x), _ = _crossings(b, u0, v0, kx.astype(jnp.float32))
    _, (_, row_y, col_y) = _crossings(b, u0, v0, ky.astype(jnp.float32))
    x_first = t_x <= t_y
    t, rows, cols = found
    return (t.at[g].set(jnp.minimum(t_x, t_y)), rows.at[g].set(jnp.where(x_first, row_x, row_y)),
            cols.at[g].set(jnp.where(x_first, col_x, col_y)))

  shape_g = grouped[0].shape
  nothing = (jnp.full(shape_g, jnp.inf), jnp.zeros(shape_g, jnp.int32),
             jnp.zeros(shape_g, jnp.int32))
  found = _for_each_group(shape_g[0], active, walk_group, nothing)
  t_hit, hit_rows, hit_cols = (a.ravel()[:n] for a in found)
  at_start = start_occupied & active
  t_hit = jnp.where(at_start, 0.0, t_hit)
  hit = jnp.isfinite(t_hit)
  on_start = at_start | ~hit
  hit_rows = jnp.where(on_start, start_row, hit_rows)
  hit_cols = jnp.where(on_start, start_col, hit_cols)
  true_ranges = jnp.minimum(t_hit, r_max_cells)
  ranges = true_ranges
  if key is not None:
    noise = noise_cells * jax.random.normal(key, true_ranges.shape)
    ranges = jnp.where(hit, jnp.clip(true_ranges + noise, 0.0, r_max_cells), true_ranges)
  return Scan(angles, ranges, hit, hit_rows, hit_cols, true_ranges)


def cast(truth_framed, shape, u0, v0, angles, r_max_cells, n_cross: int, key=None, noise_cells=0.0):
  """:func:`measure`, plus the :class:`BeamCells` of every beam (leaves [n, K]) from :func:`trace`.

  Returns:
    ``(scan, cells)``.
  """
  scan = measure(truth_framed, shape, u0, v0, angles, r_max_cells, n_cross, key, noise_cells)
  return scan, trace(u0, v0, angles, n_cross)


def _carried(offset_u, offset_v, true_dirs, origin, dirs, ahead=0.0):
  """Where a point at ``offset`` (cells) from a true beam's reference point lands when the scan
  is moved rigidly onto the beam (``dirs``) from ``origin``, ``ahead`` cells along it: its
  offset along and across the true beam, laid along and across the moved one."""
  tdu, tdv = true_dirs
  du, dv = dirs
  along = offset_u * tdu + offset_v * tdv
  across = offset_v * tdu - offset_u * tdv  # along (-dv, du)
  return (origin[0] + (ahead + along) * du - across * dv,
          origin[1] + (ahead + along) * dv + across * du)


def end_cells(scan: Scan, u0, v0, exact_hits, dirs=None, true_origin=None, true_dirs=None):
  """(rows, cols) i32[n]: the cell each beam's measured range ends in, seen from (u0, v0).

  ``exact_hits`` (traced bool: no range noise and (u0, v0) is the pose the scan was cast from)
  gives the exact truth cell that stopped the beam (it may be a corner side cell). Otherwise the
  truth's hit cell is carried into the frame of (u0, v0) and of the beams' ``dirs``: its centre's
  offset from the point where the true beam met it (along and across the beam) is added to the
  measured range along the measured beam. A range measured exactly to a wall's face thus ends
  inside that wall whatever the few-mm error of an estimated pose (the end point itself, on the
  face, fell in front of it about one time in two), range noise moves the hit along the beam, and
  a larger pose error moves it as a rigid motion of the scan would.

  Args:
    scan: the scan (``angles`` may be the estimated frame's; ``true_ranges`` and the hit cells
      are the truth's).
    u0, v0: where the scan is integrated from (the estimate), cells.
    dirs: :func:`directions` of ``scan.angles``, if the caller has them.
    true_origin, true_dirs: the pose and beam directions the scan was cast from (default: the
      same as ``(u0, v0)`` and ``dirs``).
  """
  du, dv = directions(scan.angles) if dirs is None else dirs
  tu, tv = (u0, v0) if true_origin is None else true_origin
  tdu, tdv = (du, dv) if true_dirs is None else true_dirs
  end_u, end_v = _carried(scan.hit_cols.astype(jnp.float32) + 0.5 - (tu + scan.true_ranges * tdu),
                          scan.hit_rows.astype(jnp.float32) + 0.5 - (tv + scan.true_ranges * tdv),
                          (tdu, tdv), (u0, v0), (du, dv), scan.ranges)
  rows = jnp.where(exact_hits, scan.hit_rows, jnp.floor(end_v).astype(jnp.int32))
  cols = jnp.where(exact_hits, scan.hit_cols, jnp.floor(end_u).astype(jnp.int32))
  return rows, cols


def _tile_counts(shape):
  return -(-shape[0] // OBS_TILE), -(-shape[1] // OBS_TILE)


def empty_observation(shape, dtype=jnp.int8):
  """int8[n_tiles * OBS_TILE**2 + 1] zeros: the observation layout of :func:`mark_observed`
  (``dtype``: another integer type for the buffer, ``SimConfig.observation_dtype``; int8 won:
  ``experiments/results/bench_lockstep_variants_gpu.md``, ``obs32``).

  Cell (row, col) of an (H, W) grid lives in tile ``(row // OBS_TILE, col // OBS_TILE)`` (tiles
  row-major, ``ceil(W / OBS_TILE)`` per row), at ``(row % OBS_TILE, col % OBS_TILE)`` inside it;
  the last element is a sink for dropped writes. Tiles let the belief update find and read only
  the parts of the grid a scan touched (:func:`observation_tiles`).
  """
  n_rows, n_cols = _tile_counts(shape)
  return jnp.zeros((n_rows * n_cols * OBS_TILE**2 + 1,), dtype)


def _observation_index(rows, cols, shape):
  t = OBS_TILE
  tile = (rows // t) * _tile_counts(shape)[1] + cols // t
  return tile * (t * t) + (rows % t) * t + cols % t


def observation_tiles(observed, shape):
  """The observation as int8[ceil(H / OBS_TILE), ceil(W / OBS_TILE), OBS_TILE, OBS_TILE] tiles."""
  return observed[:-1].reshape(*_tile_counts(shape), OBS_TILE, OBS_TILE)


def observation_grid(observed, shape):
  """The observation as an int8[H, W] grid: 0 unobserved, 1 seen free, 2 seen occupied."""
  return grid_of_tiles(observation_tiles(observed, shape), shape)


def grid_of_tiles(tiles, shape):
  """:func:`observation_tiles`' tiles laid out as the (H, W) grid again."""
  n_rows, n_cols = tiles.shape[:2]
  grid = tiles.transpose(0, 2, 1, 3).reshape(n_rows * OBS_TILE, n_cols * OBS_TILE)
  return grid[: shape[0], : shape[1]]


def mark_observed(observed, shape, scan: Scan, u0, v0, end_rows, end_cols, n_cross: int,
                  active=True, dirs=None, true_origin=None, true_dirs=None):
  """Writes what a scan says about the grid into ``observed``: 1 = seen free, 2 = seen occupied.

  Seen from (u0, v0) (where the robot *believes* it is) along ``scan.angles``: a cell a beam
  enters before its measured range is free, unless it is that beam's end cell; the end cell of a
  beam that hit is occupied (occupied wins over free). Cells outside the grid are dropped.

  Integrated from an estimated pose (``true_origin`` given), the free cells are those the true
  beam entered before the measured range, each carried into the estimate's frame as a rigid
  motion of the scan would carry it (its centre's offset from the true origin, along and across
  the true beam, laid along and across the estimate's beam), as :func:`end_cells` carries the
  hits. Re-traced from the estimate instead, a beam a few mm off clips the corner of a wall cell
  the true beam passed, or enters the face it ended on, and walls seen at grazing incidence are
  eaten away cell by cell (willow's diagonal walls were). An error of a cell or more leaves holes
  in the carried cells (two cells landing on one); the next scans fill them.

  Args:
    observed: int8 observation in the layout of :func:`empty_observation`.
    shape: static (H, W) of the grid.
    end_rows, end_cols: i32[n] from :func:`end_cells`.
    active: traced bool; when False nothing is written.
    dirs: :func:`directions` of ``scan.angles``, if the caller has them (see :func:`measure`).
    true_origin, true_dirs: the pose (cells) and beam directions the scan was cast from, when
      they are not (u0, v0) and ``dirs``.
  """
  du, dv = directions(scan.angles) if dirs is None else dirs
  sink = observed.shape[0] - 1
  start_row, start_col = jnp.floor(v0).astype(jnp.int32), jnp.floor(u0).astype(jnp.int32)
  # The cell the robot stands in is no obstacle it can see. Integrated from an estimated pose a
  # hair away from the true one, a beam that hits a wall the robot is touching can end a hair
  # short of it, in the robot's own cell; believed occupied, that cell would leave the robot
  # nowhere to plan from.
  own = (end_rows == start_row) & (end_cols == start_col)
  end_ok = scan.hit & _inside(end_rows, end_cols, shape) & ~own
  end_index = jnp.where(end_ok, _observation_index(end_rows, end_cols, shape), -1)

  carried = true_origin is not None
  tu, tv = true_origin if carried else (u0, v0)
  tdu, tdv = (du, dv) if true_dirs is None else true_dirs

  def free_index(rows, cols, t, ranges, end_index, beam_dirs=None):
    if carried and beam_dirs is not None:
      u, v = _carried(cols.astype(jnp.float32) + 0.5 - tu, rows.astype(jnp.float32) + 0.5 - tv,
                      beam_dirs[0], (u0, v0), beam_dirs[1])
      cols, rows = jnp.floor(u).astype(jnp.int32), jnp.floor(v).astype(jnp.int32)
    index = _observation_index(rows, cols, shape)
    free = (t < ranges) & _inside(rows, cols, shape) & (index != end_index)
    return jnp.where(free, index, sink)

  # The cell the robot stands in is free: carried too, from the cell it truly stands in (a robot
  # beside a wall, its estimate a hair across the cell edge, must not see the wall cell free).
  start_rows = jnp.broadcast_to(jnp.floor(tv).astype(jnp.int32), scan.ranges.shape)
  start_cols = jnp.broadcast_to(jnp.floor(tu).astype(jnp.int32), scan.ranges.shape)
  start = free_index(start_rows, start_cols, 0.0, jnp.where(active, scan.ranges, 0.0), end_index,
                     ((tdu, tdv), (du, dv)))
  observed = observed.at[start].set(1, mode=PROMISE_IN_BOUNDS)

  group, block_size = MARK_GROUP, MARK_BLOCK
  if n_cross <= MARK_WHOLE_RANGE:
    group, block_size = scan.ranges.shape[0], n_cross
  grouped = tuple(_groups(a, group) for a in (tdu, tdv, du, dv, scan.ranges, end_index))
  block = jnp.arange(block_size, dtype=jnp.int32)[:, None]

  def walk_group(g, observed):
    tdu, tdv, du, dv, ranges, end_index = (a[g] for a in grouped)
    # The walk follows the beams as cast (from the truth when the scan is carried).
    b = beams(tu, tv, None, (tdu, tdv))
    furthest = jnp.max(ranges)

    def body(carry):
      k0, observed = carry
      (t_x, row_x, col_x), (t_y, row_y, col_y) = _crossings(
          b, tu, tv, (k0 + block).astype(jnp.float32))
      beam_dirs = ((tdu[None], tdv[None]), (du[None], dv[None]))
      index = jnp.concatenate([
          free_index(row_x, col_x, t_x, ranges[None], end_index[None], beam_dirs),
          free_index(row_y, col_y, t_y, ranges[None], end_index[None], beam_dirs)])
      return k0 + block_size, observed.at[index.ravel()].set(1, mode=PROMISE_IN_BOUNDS)

    # Crossing k is at least k cells away: none past the longest range of the group is free.
    return jax.lax.while_loop(lambda c: (c[0] < n_cross) & (c[0] < furthest), body,
                              (jnp.int32(0), observed))[1]

  observed = _for_each_group(grouped[0].shape[0], active, walk_group, observed)
  ends = jnp.where(end_ok & active, end_index, sink)
  return observed.at[ends].set(2, mode=PROMISE_IN_BOUNDS)
