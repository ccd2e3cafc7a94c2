"""Lidar traversal against a brute-force finely sampled reference, the diagonal-leak rule, and the
engine's early-stopping walk (measure, mark_observed) against the plain enumeration (trace)."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import EAGER_AND_JIT
from jaxplore import sensor

STEP = 1e-4  # cells between reference samples


def sampled_cells(u0, v0, angle, length):
  """Cells (row, col) -> number of samples, from points every STEP cells along the beam."""
  t = np.arange(0.0, length, STEP)
  u = u0 + t * math.cos(angle)
  v = v0 + t * math.sin(angle)
  rows, cols = np.floor(v).astype(int), np.floor(u).astype(int)
  cells, counts = np.unique(np.stack([rows, cols], 1), axis=0, return_counts=True)
  return {tuple(c): n for c, n in zip(cells.tolist(), counts)}


def first_occupied_distance(occupied, u0, v0, angle, r_max):
  t = np.arange(0.0, r_max, STEP)
  rows = np.floor(v0 + t * math.sin(angle)).astype(int)
  cols = np.floor(u0 + t * math.cos(angle)).astype(int)
  h, w = occupied.shape
  inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
  occ = ~inside | occupied[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)]
  idx = np.nonzero(occ)[0]
  return (t[idx[0]], (rows[idx[0]], cols[idx[0]])) if idx.size else (r_max, None)


@EAGER_AND_JIT
def test_beam_cells_match_fine_sampling_on_empty_grid(transform):
  rng = np.random.default_rng(0)
  n_cross = 25
  fn = transform(lambda u, v, a: sensor.beam_cells(u, v, a, n_cross))
  for _ in range(40):
    u0, v0 = rng.uniform(30, 40, size=2)
    angle = rng.uniform(-math.pi, math.pi)
    length = float(rng.uniform(3, 20))
    cells = fn(jnp.float32(u0), jnp.float32(v0), jnp.float32(angle))
    t = np.asarray(cells.t)
    ours = {(int(r), int(c)) for r, c, tt in zip(np.asarray(cells.rows), np.asarray(cells.cols), t)
            if tt < length}
    reference = sampled_cells(u0, v0, angle, length)
    # Cells the beam crosses for less than ~2e-3 cells are at float32 resolution: either answer.
    marginal = {c for c, n in reference.items() if n * STEP < 2e-3}
    assert ours - set(reference) <= marginal
    assert set(reference) - ours <= marginal


def _random_world(seed, h, w, density):
  """(rng, occupied bool[h, w] with the given fraction of walls, the framed truth)."""
  rng = np.random.default_rng(seed)
  occupied = rng.random((h, w)) < density
  return rng, occupied, sensor.frame_truth(jnp.asarray(occupied))


@EAGER_AND_JIT
def test_cast_range_and_hit_cell_match_reference_on_random_grids(transform):
  h, w = 30, 30
  rng, occupied, truth = _random_world(1, h, w, 0.08)
  free_cells = np.argwhere(~occupied)
  cast = transform(lambda u, v, a: sensor.cast(truth, occupied.shape, u, v, a, 12.0, 13)[0])
  close = 0
  total = 0
  for _ in range(12 if transform is jax.jit else 4):  # op-by-op runs are slow
    r, c = free_cells[rng.integers(len(free_cells))]
    u0, v0 = c + rng.uniform(0.05, 0.95), r + rng.uniform(0.05, 0.95)
    angles = rng.uniform(-math.pi, math.pi, size=16).astype(np.float32)
    scan = cast(jnp.float32(u0), jnp.float32(v0), jnp.asarray(angles))
    for k, angle in enumerate(angles):
      ref_t, ref_cell = first_occupied_distance(occupied, u0, v0, float(angle), 12.0)
      got = float(scan.ranges[k])
      # Never farther than the first occupied cell: no beam passes through an obstacle.
      assert got <= ref_t + 2 * STEP
      total += 1
      if abs(got - ref_t) < 2e-3:
        close += 1
        if ref_cell is not None and 0 <= ref_cell[0] < h and 0 <= ref_cell[1] < w:
          assert bool(scan.hit[k])
          assert (int(scan.hit_rows[k]), int(scan.hit_cols[k])) == ref_cell
  # Only beams grazing a corner (within CORNER_EPS) may stop earlier than the reference.
  assert close >= 0.97 * total


@EAGER_AND_JIT
def test_no_beam_passes_between_diagonally_touching_cells(transform):
  occupied = np.zeros((12, 12), bool)
  occupied[5, 5] = occupied[6, 6] = True  # they touch at the corner point (u, v) = (6, 6)
  truth = sensor.frame_truth(jnp.asarray(occupied))
  one = lambda u, v, a: sensor.cast(truth, occupied.shape, u, v, a[None], 10.0, 11)[0]
  cast = transform(jax.vmap(one))
  rng = np.random.default_rng(2)
  # From the free side (rows >= 6, cols <= 5) aim exactly at the shared corner.
  u0 = rng.uniform(1.0, 5.99, 30).astype(np.float32)
  v0 = rng.uniform(6.01, 10.0, 30).astype(np.float32)
  angle = np.arctan2(6.0 - v0, 6.0 - u0).astype(np.float32)
  scan = jax.tree.map(np.asarray, cast(jnp.asarray(u0), jnp.asarray(v0), jnp.asarray(angle)))
  corner_distance = np.hypot(6.0 - u0, 6.0 - v0)
  assert scan.hit.all()
  assert (scan.ranges[:, 0] <= corner_distance + 1e-3).all()
  cells = set(zip(scan.hit_rows[:, 0].tolist(), scan.hit_cols[:, 0].tolist()))
  assert cells <= {(5, 5), (6, 6)}


def test_exact_45_degree_beam_from_cell_centre():
  # The common exact-corner case: a robot at a cell centre and a beam at 45 degrees.
  occupied = np.zeros((10, 10), bool)
  occupied[4, 3] = occupied[3, 4] = True
  scan, _ = sensor.cast(sensor.frame_truth(jnp.asarray(occupied)), occupied.shape, jnp.float32(2.5), jnp.float32(2.5),
                        jnp.asarray([math.pi / 4], jnp.float32), 8.0, 9)
  assert bool(scan.hit[0])
  assert float(scan.ranges[0]) <= math.hypot(1.5, 1.5) + 1e-3


def test_beam_angles_cover_fov():
  a = np.asarray(sensor.beam_angles(jnp.float32(0.3), jnp.float32(math.radians(190)), 191))
  assert a.shape == (191,)
  np.testing.assert_allclose(a[0], 0.3 - math.radians(95), atol=1e-5)
  np.testing.assert_allclose(a[-1], 0.3 + math.radians(95), atol=1e-5)
  full = np.asarray(sensor.beam_angles(jnp.float32(0.0), jnp.float32(2 * math.pi), 360))
  np.testing.assert_allclose(np.diff(full), 2 * math.pi / 360, atol=1e-5)
  assert full[-1] - full[0] < 2 * math.pi - 1e-3  # the first ray is not repeated


def test_mark_observed_marks_traversed_cells_free_and_end_occupied():
  occupied = np.zeros((20, 20), bool)
  occupied[:, 15] = True
  u0, v0 = jnp.float32(5.5), jnp.float32(10.5)
  angles = jnp.asarray([0.0], jnp.float32)
  scan = sensor.measure(sensor.frame_truth(jnp.asarray(occupied)), occupied.shape, u0, v0, angles, 18.0, 19)
  end_rows, end_cols = sensor.end_cells(scan, u0, v0, jnp.bool_(True))
  observed = sensor.mark_observed(sensor.empty_observation((20, 20)), (20, 20), scan, u0, v0, end_rows,
                                  end_cols, 19)
  grid = np.asarray(sensor.observation_grid(observed, (20, 20)))
  assert {tuple(c) for c in np.argwhere(grid == 1)} == {(10, c) for c in range(5, 15)}
  assert {tuple(c) for c in np.argwhere(grid == 2)} == {(10, 15)}
  np.testing.assert_allclose(float(scan.ranges[0]), 15 - 5.5, atol=1e-5)
  inactive = sensor.mark_observed(sensor.empty_observation((20, 20)), (20, 20), scan, u0, v0, end_rows,
                                  end_cols, 19, active=jnp.bool_(False))
  assert not np.asarray(inactive[:-1]).any()



_ends_from_estimate = jax.jit(lambda truth, u, v, eu, ev, angles: sensor.end_cells(
    sensor.measure(truth, (24, 24), u, v, angles, 20.0, 21), eu, ev, jnp.bool_(False),
    true_origin=(u, v)))


def test_a_hit_seen_from_a_hair_off_estimate_lands_in_the_wall_not_in_front_of_it():
  # Ranges end exactly on a wall's face; integrated from an estimate a few mm off the true pose
  # (0.002 cells either way), each hit must still land in the wall (a free cell in front of it
  # marked occupied thickens the wall; in a doorway that closes the door). Oracle: the truth.
  occupied = np.zeros((24, 24), bool)
  occupied[:, 18] = occupied[3, :] = True
  truth = sensor.frame_truth(jnp.asarray(occupied))
  rng = np.random.default_rng(4)
  angles = jnp.asarray(np.linspace(-math.pi, math.pi, 181)[:-1], jnp.float32)
  for u0, v0 in ((10.5, 10.5), (17.3, 4.1), (12.0, 9.0)):
    for offset in rng.uniform(-2e-3, 2e-3, (6, 2)):
      rows, cols = _ends_from_estimate(truth, jnp.float32(u0), jnp.float32(v0),
                                       jnp.float32(u0 + offset[0]), jnp.float32(v0 + offset[1]),
                                       angles)
      scan = sensor.measure(truth, (24, 24), jnp.float32(u0), jnp.float32(v0), angles, 20.0, 21)
      hit = np.asarray(scan.hit)
      rows, cols = np.asarray(rows)[hit], np.asarray(cols)[hit]
      framed = np.pad(occupied, 1, constant_values=True)  # outside the map counts as occupied
      wall = framed[np.clip(rows + 1, 0, 25), np.clip(cols + 1, 0, 25)]
      assert wall.all(), (u0, v0, offset, rows[~wall], cols[~wall])


def test_hits_seen_from_a_shifted_estimate_move_with_it():
  # An estimate 3 cells right and 2 up of the truth, same heading: every hit cell moves by the
  # same (2, 3) cells, as the rigid motion of the whole scan would move it.
  occupied = np.zeros((24, 24), bool)
  occupied[:, 18] = occupied[3, :] = True
  truth = sensor.frame_truth(jnp.asarray(occupied))
  angles = jnp.asarray(np.linspace(-math.pi, math.pi, 91)[:-1], jnp.float32)
  rows, cols = _ends_from_estimate(truth, jnp.float32(9.3), jnp.float32(8.6), jnp.float32(12.3),
                                   jnp.float32(10.6), angles)
  scan = sensor.measure(truth, (24, 24), jnp.float32(9.3), jnp.float32(8.6), angles, 20.0, 21)
  hit = np.asarray(scan.hit)
  np.testing.assert_array_equal(np.asarray(rows)[hit], np.asarray(scan.hit_rows)[hit] + 2)
  np.testing.assert_array_equal(np.asarray(cols)[hit], np.asarray(scan.hit_cols)[hit] + 3)

def test_a_hit_never_marks_the_cell_the_robot_stands_in():
  # A robot touching a wall (0.05 cells from its face): an end cell that falls in the robot's own
  # cell is dropped, the cell stays observed free.
  occupied = np.zeros((20, 20), bool)
  occupied[:, 15] = True
  u0, v0 = jnp.float32(14.95), jnp.float32(10.5)
  scan = sensor.measure(sensor.frame_truth(jnp.asarray(occupied)), occupied.shape, u0, v0,
                        jnp.asarray([0.0], jnp.float32), 18.0, 19)
  rows, cols = jnp.asarray([10], jnp.int32), jnp.asarray([14], jnp.int32)  # as if it fell short
  observed = sensor.mark_observed(sensor.empty_observation((20, 20)), (20, 20), scan, u0, v0, rows,
                                  cols, 19)
  grid = np.asarray(sensor.observation_grid(observed, (20, 20)))
  assert grid[10, 14] == 1 and not (grid == 2).any()


# The reference enumeration is compiled: XLA contracts ``t0 + k * step`` into a fused multiply-add
# inside compiled code (the engine's loops always are), so op-by-op results can differ by an ulp.
_trace = jax.jit(sensor.trace, static_argnums=3)


def _first_hits_from_trace(occupied, u0, v0, angles, r_max, n_cross):
  """The definition: the first occupied entry of trace() by distance (argmin: lowest index on ties)."""
  cells = _trace(jnp.float32(u0), jnp.float32(v0), jnp.asarray(angles), n_cross)
  rows, cols, t = (np.asarray(a) for a in cells)
  framed = np.pad(occupied, 1, constant_values=True)
  h, w = occupied.shape
  occ = framed[np.clip(rows + 1, 0, h + 1), np.clip(cols + 1, 0, w + 1)]
  t_block = np.where(occ & (t <= r_max), t, np.inf)
  first = np.argmin(t_block, axis=1)
  beam = np.arange(len(angles))
  return t_block[beam, first], rows[beam, first], cols[beam, first], (rows, cols, t)


# Origins at cell centres and on grid lines, beams along the axes and the diagonals: the corner
# and tie cases of the closed form, plus random ones.
def _awkward_poses(rng, free_cells, count):
  for i in range(count):
    r, c = free_cells[rng.integers(len(free_cells))]
    du, dv = [(0.5, 0.5), (0.0, 0.5), (0.5, 0.0), (0.0, 0.0)][i % 4] if i < 8 else rng.uniform(0.01, 0.99, 2)
    base = rng.uniform(-math.pi, math.pi) if i % 3 else 0.0
    angles = base + np.concatenate([np.arange(8) * math.pi / 4, rng.uniform(-math.pi, math.pi, 40)])
    yield c + du, r + dv, angles.astype(np.float32)


def _pose_count(transform, count):
  """Op-by-op runs are slow: eager runs check the 8 corner-case poses, compiled runs all ``count``."""
  return count if transform is jax.jit else min(count, 8)


@EAGER_AND_JIT
def test_measure_equals_first_occupied_entry_of_trace(transform):
  h, w = 24, 31
  rng, occupied, truth = _random_world(5, h, w, 0.12)
  measure = transform(lambda u, v, a, r: sensor.measure(truth, (h, w), u, v, a, r, 30))
  ranges = (3.0, 7.5, 29.0)
  for i, (u0, v0, angles) in enumerate(_awkward_poses(rng, np.argwhere(~occupied),
                                                      _pose_count(transform, 14))):
    # Op-by-op runs take one range per pose in turn; compiled runs every range at every pose.
    for r_max in ranges if transform is jax.jit else ranges[i % 3:i % 3 + 1]:
      scan = measure(jnp.float32(u0), jnp.float32(v0), jnp.asarray(angles), jnp.float32(r_max))
      t_ref, rows_ref, cols_ref, _ = _first_hits_from_trace(occupied, u0, v0, angles, r_max, 30)
      np.testing.assert_array_equal(np.asarray(scan.true_ranges), np.minimum(t_ref, r_max))
      np.testing.assert_array_equal(np.asarray(scan.hit), np.isfinite(t_ref))
      np.testing.assert_array_equal(np.asarray(scan.hit_rows), rows_ref)
      np.testing.assert_array_equal(np.asarray(scan.hit_cols), cols_ref)


def test_measure_of_an_inactive_robot_hits_nothing():
  occupied = np.ones((8, 8), bool)
  occupied[3, 3] = False
  scan = sensor.measure(sensor.frame_truth(jnp.asarray(occupied)), (8, 8), jnp.float32(3.5), jnp.float32(3.5),
                        jnp.linspace(-3, 3, 40), 5.0, 6, active=jnp.bool_(False))
  assert not np.asarray(scan.hit).any()
  np.testing.assert_array_equal(np.asarray(scan.ranges), 5.0)


@EAGER_AND_JIT
@pytest.mark.parametrize("walk", ["whole range at once", "in blocks"])
def test_mark_observed_equals_the_cells_of_trace(transform, walk, monkeypatch):
  """Free = entered before the measured range and not the beam's end cell; end cells occupied."""
  if walk == "in blocks":  # the walk of long-range scans, forced on this short one
    monkeypatch.setattr(sensor, "MARK_WHOLE_RANGE", 0)
  h, w = 26, 21
  rng, occupied, truth = _random_world(6, h, w, 0.1)

  def observe(u, v, a, key, noise, offset, exact):
    scan = sensor.measure(truth, (h, w), u, v, a, 12.0, 13, key=key, noise_cells=noise)
    eu, ev = u + offset[0], v + offset[1]  # where the robot believes it is
    scan = scan._replace(angles=a + offset[2])
    end_rows, end_cols = sensor.end_cells(scan, eu, ev, exact)
    observed = sensor.mark_observed(sensor.empty_observation((h, w)), (h, w), scan, eu, ev, end_rows,
                                    end_cols, 13)
    return scan, end_rows, end_cols, sensor.observation_grid(observed, (h, w))

  observe = transform(observe)
  for i, (u0, v0, angles) in enumerate(_awkward_poses(rng, np.argwhere(~occupied), _pose_count(transform, 12))):
    exact = i % 3 == 0  # the scan integrated from the pose it was cast from, without noise
    noise = 0.0 if exact else 0.6 * (i % 2)
    offset = np.zeros(3, np.float32) if exact else rng.normal(0, [0.6, 0.6, 0.05]).astype(np.float32)
    scan, end_rows, end_cols, grid = observe(jnp.float32(u0), jnp.float32(v0), jnp.asarray(angles),
                                              jax.random.PRNGKey(i), noise, jnp.asarray(offset),
                                              jnp.bool_(exact))
    cells = _trace(jnp.float32(u0) + offset[0], jnp.float32(v0) + offset[1], jnp.asarray(angles) + offset[2], 13)
    rows, cols, t = (np.asarray(a) for a in cells)
    end_rows, end_cols, hit = (np.asarray(a) for a in (end_rows, end_cols, scan.hit))
    is_end = (rows == end_rows[:, None]) & (cols == end_cols[:, None]) & hit[:, None]
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    free = (t < np.asarray(scan.ranges)[:, None]) & ~is_end & inside
    expected = np.zeros((h, w), np.int8)
    expected[rows[free], cols[free]] = 1
    own = (end_rows == np.floor(v0 + offset[1])) & (end_cols == np.floor(u0 + offset[0]))
    ends_inside = hit & (end_rows >= 0) & (end_rows < h) & (end_cols >= 0) & (end_cols < w) & ~own
    expected[end_rows[ends_inside], end_cols[ends_inside]] = 2
    np.testing.assert_array_equal(np.asarray(grid), expected)


def test_range_noise_changes_ranges_only_for_hits():
  occupied = np.zeros((20, 20), bool)
  occupied[:, 15] = True
  angles = jnp.asarray([0.0, math.pi], jnp.float32)
  scan, _ = sensor.cast(sensor.frame_truth(jnp.asarray(occupied)), occupied.shape, jnp.float32(5.5), jnp.float32(10.5), angles, 4.0, 5,
                        key=jax.random.PRNGKey(0), noise_cells=0.5)
  assert not bool(scan.hit[0]) and float(scan.ranges[0]) == pytest.approx(4.0)  # max range: no noise
  occupied[:, 2] = True
  scan, _ = sensor.cast(sensor.frame_truth(jnp.asarray(occupied)), occupied.shape, jnp.float32(5.5), jnp.float32(10.5), angles, 18.0, 19,
                        key=jax.random.PRNGKey(0), noise_cells=0.5)
  assert bool(scan.hit[1])
  assert float(scan.ranges[1]) != pytest.approx(float(scan.true_ranges[1]))



SIZE = 40


@functools.partial(jax.jit, static_argnums=7)
def _observe_from_estimate(truth, u, v, eu, ev, angles, est_angles, carried):
  """The observation grid of a scan cast from (u, v) and integrated from the estimate (eu, ev):
  its free cells carried from the true beams (``carried``, the engine's way) or re-traced from
  the estimate."""
  shape = (SIZE, SIZE)
  scan = sensor.measure(truth, shape, u, v, angles, 30.0, 31)._replace(angles=est_angles)
  true_dirs = sensor.directions(angles)
  rows, cols = sensor.end_cells(scan, eu, ev, jnp.bool_(False), true_origin=(u, v),
                                true_dirs=true_dirs)
  frame = dict(true_origin=(u, v), true_dirs=true_dirs) if carried else {}
  observed = sensor.mark_observed(sensor.empty_observation(shape), shape, scan, eu, ev, rows, cols, 31,
                                  **frame)
  return sensor.observation_grid(observed, shape)


def test_a_diagonal_wall_seen_from_a_hair_off_estimate_is_not_seen_free():
  # A staircase (diagonal) wall two cells thick, scanned from cell centres (where the engine's
  # robots stand) and integrated from estimates off by the few mm (0.005 cells, 1e-4 rad) the
  # relocalisation leaves. Re-traced from the estimate, beams that in truth passed a wall cell's
  # corner, or ended on the face of its neighbour, clip that cell by a hair, and some wall cells
  # are marked free (willow's diagonal walls were eaten away this way, and nearest frontier
  # chased the "frontiers" inside them). Carried from the true beams, none is. Oracle: the truth.
  occupied = np.zeros((SIZE, SIZE), bool)
  for i in range(SIZE - 1):
    occupied[i, i] = occupied[i, i + 1] = True
  truth = sensor.frame_truth(jnp.asarray(occupied))
  rng = np.random.default_rng(7)
  angles = np.linspace(-math.pi, math.pi, 1441)[:-1]
  walls_seen_free = {False: 0, True: 0}
  cells_seen_free = {False: 0, True: 0}
  for u0, v0 in ((8.5, 20.5), (12.5, 30.5), (3.5, 33.5), (25.5, 36.5)):
    for du, dv, dtheta in rng.uniform(-1, 1, (4, 3)) * [5e-3, 5e-3, 1e-4]:
      for carried in walls_seen_free:
        grid = np.asarray(_observe_from_estimate(
            truth, jnp.float32(u0), jnp.float32(v0), jnp.float32(u0 + du), jnp.float32(v0 + dv),
            jnp.asarray(angles, jnp.float32), jnp.asarray(angles + dtheta, jnp.float32), carried))
        walls_seen_free[carried] += int((occupied & (grid == 1)).sum())
        cells_seen_free[carried] += int((~occupied & (grid == 1)).sum())
  assert walls_seen_free[True] == 0
  assert walls_seen_free[False] > 0  # the clipping happens at these errors
  # Carrying loses no free space: the same free cells are seen.
  assert cells_seen_free[True] >= 0.99 * cells_seen_free[False]


def test_a_robot_beside_a_wall_whose_estimate_crosses_into_it_does_not_see_it_free():
  """A robot 2 mm from a wall cell's edge, its estimate 3 mm across it: the cell it stands in
  is carried from where it truly stands, so the wall cell stays unseen-free (before, the
  estimate's own cell was marked free at every scan: willow's walls beside the paths were freed
  this way)."""
  occupied = np.zeros((SIZE, SIZE), bool)
  occupied[:, 10] = True
  truth = sensor.frame_truth(jnp.asarray(occupied))
  angles = jnp.asarray(np.linspace(-math.pi, math.pi, 361)[:-1], jnp.float32)
  carried, retraced = (np.asarray(_observe_from_estimate(
      truth, jnp.float32(9.998), jnp.float32(20.5), jnp.float32(10.001), jnp.float32(20.5), angles,
      angles, carry)) for carry in (True, False))
  assert not (carried[:, 10] == 1).any() and carried[20, 9] == 1
  assert retraced[20, 10] == 1  # the estimate's own cell, the wall


@pytest.mark.parametrize("shift, dtheta", [((3, -2), 0.0), ((0, 0), math.pi / 2)])
def test_a_scan_integrated_from_a_moved_estimate_moves_with_it(shift, dtheta):
  """An estimate moved by whole cells, or turned by a right angle about the robot's cell centre,
  sees the true scan's observation moved the same way, free cells and hits alike (the rigid
  motion maps cell centres to cell centres). Oracle: the observation integrated at the true
  pose, moved with NumPy."""
  rng, occupied, truth = _random_world(13, SIZE, SIZE, 0.12)
  occupied = np.asarray(occupied)
  u0, v0 = 20.5, 19.5
  occupied[18:22, 18:23] = False  # room to stand
  truth = sensor.frame_truth(jnp.asarray(occupied))
  angles = jnp.asarray(np.linspace(-math.pi, math.pi, 721)[:-1], jnp.float32)
  exact = np.asarray(_observe_from_estimate(truth, jnp.float32(u0), jnp.float32(v0), jnp.float32(u0),
                                            jnp.float32(v0), angles, angles, True))
  du, dv = shift
  moved = np.asarray(_observe_from_estimate(
      truth, jnp.float32(u0), jnp.float32(v0), jnp.float32(u0 + du), jnp.float32(v0 + dv), angles,
      angles + jnp.float32(dtheta), True))
  rows, cols = np.indices(exact.shape).reshape(2, -1)
  if dtheta:  # (u, v) - origin turned by +90 degrees: (-(v - v0), u - u0)
    new_cols = np.floor(u0 - (rows + 0.5 - v0)).astype(int)
    new_rows = np.floor(v0 + (cols + 0.5 - u0)).astype(int)
  else:
    new_rows, new_cols = rows + dv, cols + du
  inside = (new_rows >= 0) & (new_rows < SIZE) & (new_cols >= 0) & (new_cols < SIZE)
  # Compared where the moved cell comes from inside the grid (beyond its edge the truth's frame
  # counts as walls, which the exact observation drops and the moved one may keep).
  got = moved[new_rows[inside], new_cols[inside]]
  want = exact[rows[inside], cols[inside]]
  assert (want == 1).sum() > 200 and (want == 2).sum() > 20
  np.testing.assert_array_equal(got, want)
