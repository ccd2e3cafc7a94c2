"""How a keyframe's scan is drawn into the belief (jaxplore.slam.model.keyframe_counts and
keyframe_observation) and matched against it (end_points): each beam's end cell and the cells it
passes, against a NumPy traversal that sorts every grid-line crossing of the beam; the per-beam
vote of a scan; the map drawn at the true poses of a world with diagonal walls and door jambs,
cell for cell; end points moved into their surface along its normal; and the front end's match
of a scan from its true pose against that map."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import mapping, sensor
from jaxplore.config import SimConfig, make_params
from jaxplore.slam import model
from tests.conftest import EAGER_AND_JIT

RES = 0.2


def reference_counts(pose, ranges, offsets, origin, res, shape):
  """Per-cell (hits, passes) of beams from ``pose`` in float64, by sorting each beam's crossings
  of the grid lines x = i and y = j (cells): the cell between two successive crossings is the
  one its midpoint lies in. A beam that hit (range > 0) ends at the crossing nearest to its
  range, in the cell beyond it, and passes the cells before; one that hit nothing passes the
  cells before its range. Beams passing within 1e-2 cells of a grid corner (where the engine
  lists the cell beside the corner), or whose range is
  within 1e-4 of equidistant from two crossings, are returned as ambiguous (float32 may order
  them either way)."""
  h, w = shape
  u0 = (pose[0] - origin[0]) / res
  v0 = (pose[1] - origin[1]) / res
  hits = np.zeros(shape, np.int64)
  passes = np.zeros(shape, np.int64)
  ambiguous = np.zeros(len(ranges), bool)
  for b, (reading, offset) in enumerate(zip(ranges, offsets)):
    angle = float(pose[2]) + float(offset)
    du, dv = math.cos(angle), math.sin(angle)
    r = abs(float(reading))
    reach = r + 3.0
    ts = []
    for a0, da in ((u0, du), (v0, dv)):
      if abs(da) < 1e-9:
        continue
      lines = np.arange(math.floor(a0 - reach) - 1, math.ceil(a0 + reach) + 2)
      t = (lines - a0) / da
      ts.append(t[(t >= 0) & (t <= reach)])
    crossings = np.sort(np.concatenate(ts))
    if np.any(np.diff(crossings) < 1e-2):
      ambiguous[b] = True
      continue
    if reading > 0:
      gaps = np.abs(crossings - r)
      k = int(np.argmin(gaps))
      if np.sum(gaps < gaps[k] + 1e-4) > 1:
        ambiguous[b] = True
        continue
      t_end = crossings[k]
      after = crossings[k + 1] if k + 1 < len(crossings) else t_end + 1e-3
      mid = 0.5 * (t_end + after)
      row, col = math.floor(v0 + mid * dv), math.floor(u0 + mid * du)
      if 0 <= row < h and 0 <= col < w:
        hits[row, col] += 1
    else:
      t_end = r
    bounds = np.concatenate([[0.0], crossings[crossings < t_end], [t_end]])
    for t0, t1 in zip(bounds[:-1], bounds[1:]):
      if t1 <= t0:
        continue
      mid = 0.5 * (t0 + t1)
      row, col = math.floor(v0 + mid * dv), math.floor(u0 + mid * du)
      if 0 <= row < h and 0 <= col < w:
        passes[row, col] += 1
  return hits, passes, ambiguous


@EAGER_AND_JIT
def test_counts_match_a_traversal_of_sorted_crossings(transform):
  shape = (48, 64)
  origin = np.array([-1.3, 0.7])
  offsets = np.asarray(sensor.beam_angles(jnp.float32(0.0), math.radians(190.0), 95))
  counts = transform(lambda pose, scan: model.keyframe_counts(
      pose, scan, jnp.asarray(offsets), jnp.asarray(origin, jnp.float32), RES, shape, 80))
  rng = np.random.default_rng(0)
  checked = 0
  for _ in range(4):
    pose = np.array([origin[0] + rng.uniform(0.5, 12.0), origin[1] + rng.uniform(0.5, 9.0),
                     rng.uniform(-math.pi, math.pi)], np.float32)
    # Ranges as a keyframe stores them (float16 cells; negative: no hit), some off the grid.
    ranges = (rng.uniform(0.3, 40.0, offsets.size)
              * np.where(rng.uniform(size=offsets.size) < 0.8, 1, -1)).astype(np.float16)
    _, _, ambiguous = reference_counts(pose.astype(np.float64), ranges.astype(np.float64),
                                       offsets.astype(np.float64), origin, RES, shape)
    ranges[ambiguous] = 0  # a beam of range 0 neither ends nor passes anywhere
    hits, passes, _ = reference_counts(pose.astype(np.float64), ranges.astype(np.float64),
                                       offsets.astype(np.float64), origin, RES, shape)
    got_hits, got_passes = counts(jnp.asarray(pose), jnp.asarray(ranges))
    np.testing.assert_array_equal(np.asarray(got_hits), hits)
    np.testing.assert_array_equal(np.asarray(got_passes), passes)
    checked += int((~ambiguous).sum())
  assert checked > 300 and hits.sum() > 0 and passes.sum() > 1000


def test_a_scan_weighs_its_beams_as_the_sensor_model_does():
  """Beams along one line: the first ends in a cell the others pass through. One more beam passed
  than the sensor model's l_occ / -l_free: free; one fewer: occupied; as many: no observation."""
  params = make_params(res=RES)
  shape = (10, 40)
  pose = jnp.array([0.5 * RES, 5.5 * RES, 0.0])  # the centre of cell (5, 0), facing +x
  end_row = 5

  def observed(n_through):
    # Range 9.6 cells: the crossing nearest is x = 10 (cell (5, 10)); the others reach 30.
    ranges = jnp.asarray([9.6] + [30.0] * n_through, jnp.float16)
    offsets = jnp.zeros(ranges.shape, jnp.float32)
    flat = model.keyframe_observation(pose, ranges, offsets, jnp.zeros(2), RES, shape, 40, params)
    return np.asarray(sensor.observation_grid(flat, shape))

  ratio = -float(params.l_occ) / float(params.l_free)  # 2: one hit outweighs two passes
  assert ratio == 2.0
  assert observed(1)[end_row, 10] == 2
  assert observed(2)[end_row, 10] == 0
  assert observed(3)[end_row, 10] == 1
  # The cells before are free, the cells past the end cell only for the longer beams.
  assert (observed(3)[end_row, :10] == 1).all() and (observed(3)[end_row, 11:30] == 1).all()
  assert (observed(0)[end_row, :10] == 1).all() and (observed(0)[end_row, 11:] == 0).all()
  assert observed(0)[end_row, 10] == 2


def test_nothing_is_drawn_when_inactive():
  params = make_params(res=RES)
  ranges = jnp.full((20,), 7.3, jnp.float16)
  offsets = jnp.linspace(-1.0, 1.0, 20)
  flat = model.keyframe_observation(jnp.array([1.0, 1.0, 0.3]), ranges, offsets, jnp.zeros(2), RES,
                                    (16, 24), 40, params, active=jnp.bool_(False))
  assert not np.asarray(flat).any()


def diagonal_world():
  """A room and a diagonal corridor with staircase walls a cell thick, entered through a door in
  a straight wall (jambs): cells the beams enter near a corner."""
  h, w = 40, 44
  occ = np.zeros((h, w), bool)
  occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
  occ[14, :] = True  # the room's top wall (rows 1-13 below it) ...
  occ[14, 6:10] = False  # ... with a door four cells wide
  for k in range(22):  # a corridor up and to the right from the door, 4 cells across
    occ[15 + k, 5 + k] = True
    occ[15 + k, 10 + k] = True
  return occ


@pytest.mark.parametrize("heading", [0.3, 1.1, 2.4])
def test_the_map_drawn_at_the_true_poses_is_the_truth_cell_for_cell(heading):
  """Scans cast in a world of diagonal walls and door jambs, drawn from the poses they were cast
  from: every cell drawn occupied is a wall of the truth, every cell drawn free is free in it.
  (An end point pushed half a cell along its beam left a jamb's or a staircase's cell through its
  side and drew the free cell beside it.)"""
  occ = diagonal_world()
  shape = occ.shape
  params = make_params(res=RES, r_max=15.0, fov=math.radians(190.0))
  offsets = model.beam_offsets(params, 190)
  framed = sensor.frame_truth(jnp.asarray(occ))
  poses = [(8.5, 7.5, heading), (4.2, 10.1, heading + 1.0), (8.3, 12.9, heading - 0.7),
           (10.6, 17.2, 0.8), (15.5, 21.4, 3.9), (20.3, 26.6, 0.6)]
  drawn = np.zeros(shape, np.int8)
  pushed_off_the_wall = 0
  for col, row, theta in poses:
    pose = jnp.array([col * RES, row * RES, theta], jnp.float32)
    assert not occ[int(row), int(col)]
    scan = sensor.measure(framed, shape, jnp.float32(col), jnp.float32(row), pose[2] + offsets,
                          75.0, 76)
    stored = model.stored_scan(scan)
    flat = model.keyframe_observation(pose, stored, offsets, jnp.zeros(2), RES, shape, 76, params)
    grid = np.asarray(sensor.observation_grid(flat, shape))
    assert (grid == 2).sum() >= 5
    np.testing.assert_array_equal(occ[grid == 2], True)
    np.testing.assert_array_equal(occ[grid == 1], False)
    drawn = np.maximum(drawn, grid)
    # The scenes exercise what the rule is for: the end point pushed half a cell further along
    # the beam lands on a free cell for some of the beams.
    r = np.abs(np.asarray(stored, np.float32)) + model.END_PUSH_CELLS
    angles = np.asarray(pose[2] + offsets)
    hit = np.asarray(scan.hit)
    rows = np.floor(row + r * np.sin(angles)).astype(int)[hit]
    cols = np.floor(col + r * np.cos(angles)).astype(int)[hit]
    pushed_off_the_wall += int((~occ[rows, cols]).sum())
  assert pushed_off_the_wall > 0
  assert (drawn == 2).sum() > 60


def test_end_points_move_into_a_straight_wall_along_its_normal():
  """A wall along x = 1 m seen from the origin: every end point with a neighbour on the wall moves
  half a cell to x = 1 m + res / 2 and keeps its y (moved along their beams, the grazing ones
  would slide along the wall and stop short of that line); a lone return moves along its beam."""
  res = 0.1
  offsets = jnp.linspace(-1.1, 1.1, 61)
  ranges = (1.0 / res) / np.cos(np.asarray(offsets))
  stored = jnp.asarray(ranges, jnp.float16)
  r = np.abs(np.asarray(stored, np.float64)) * res  # what the keyframe kept
  points, hit = model.end_points(stored, offsets, res)
  points = np.asarray(points, np.float64)
  assert bool(hit.all())
  np.testing.assert_allclose(points[:, 0], 1.0 + 0.5 * res, atol=2e-3)
  np.testing.assert_allclose(points[:, 1], r * np.sin(np.asarray(offsets)), atol=1e-3)
  along_beam = (r + 0.5 * res) * np.cos(np.asarray(offsets))
  assert np.max(np.abs(along_beam - (1.0 + 0.5 * res))) > 0.02
  # One return among beams that hit nothing: no surface to take a normal from.
  lone = jnp.asarray(np.where(np.arange(61) == 30, 10.0, -150.0), jnp.float16)
  points, hit = model.end_points(lone, offsets, res)
  np.testing.assert_allclose(np.asarray(points[30]), [1.05, 0.0], atol=1e-6)
  assert int(hit.sum()) == 1
  # A beam that hit nothing ends at its range, unmoved.
  np.testing.assert_allclose(np.asarray(points[0]), 15.0 * np.array([np.cos(-1.1), np.sin(-1.1)]),
                             rtol=1e-3)


def test_a_scan_matched_from_its_true_pose_against_the_map_drawn_at_the_true_poses_stays():
  """The front end's accuracy with nothing to correct: keyframes of the diagonal world drawn at
  their true poses, then scans from other true poses matched with the truth as the prior. The
  match keeps the truth, within a few millimetres and hundredths of a degree. (End points moved
  half a cell along their beams instead: centimetres and tenths of a degree; the scenes below
  show it.)"""
  occ = diagonal_world()
  h, w = occ.shape
  params = make_params(res=RES, r_max=15.0, fov=math.radians(190.0))
  config = SimConfig(height=h, width=w, res=RES, n_beams=190, max_range_cells=75, max_steps=10,
                     planner="nearest_frontier", max_inflation_cells=1, graph_nodes=16,
                     graph_loops=4, max_loop_cells=20, slam="scan_matching", pose_noise=True)
  offsets = model.beam_offsets(params, 190)
  framed = sensor.frame_truth(jnp.asarray(occ))
  stride = model.sizes(config).stride

  def scan_at(col, row, theta):
    scan = sensor.measure(framed, (h, w), jnp.float32(col), jnp.float32(row), theta + offsets,
                          75.0, 76)
    return model.stored_scan(scan)

  logodds = jnp.zeros((h, w), jnp.float32)
  for col, row, theta in [(8.5, 7.5, 0.3), (4.2, 10.1, 1.3), (8.3, 12.9, -0.4), (10.6, 17.2, 0.8),
                          (15.5, 21.4, 3.9), (20.3, 26.6, 0.6), (30.5, 5.5, 2.8)]:
    pose = jnp.array([col * RES, row * RES, theta], jnp.float32)
    flat = model.keyframe_observation(pose, scan_at(col, row, theta), offsets, jnp.zeros(2), RES,
                                      (h, w), 76, params)
    logodds = mapping.update_logodds(logodds, sensor.observation_grid(flat, (h, w)), params)
  cov = jnp.diag(jnp.array([0.02, 0.02, 0.01], jnp.float32) ** 2)
  register = jax.jit(lambda points, valid, prior: model.register(
      config, params, logodds, jnp.zeros(2), points, valid, prior, cov).pose)
  errors, along_beam = [], []
  for col, row, theta in [(6.7, 9.3, 0.9), (9.1, 11.2, -1.2), (12.4, 19.6, 0.7),
                          (18.2, 24.3, 2.2), (25.5, 6.5, 1.7), (7.5, 4.4, -0.3)]:
    truth = jnp.array([col * RES, row * RES, theta], jnp.float32)
    stored = scan_at(col, row, theta)
    points, valid = model.scan_points(stored, offsets, RES, stride)
    errors.append(np.asarray(register(points, valid, truth) - truth))
    r = (jnp.abs(stored.astype(jnp.float32)) + model.END_PUSH_CELLS) * RES
    beam = jnp.stack([r * jnp.cos(offsets), r * jnp.sin(offsets)], axis=-1)[::stride]
    along_beam.append(np.asarray(register(beam, valid, truth) - truth))
  errors, along_beam = np.array(errors), np.array(along_beam)
  xy = lambda e: np.hypot(e[:, 0], e[:, 1])
  assert np.max(xy(errors)) < 0.005 and np.max(np.abs(errors[:, 2])) < math.radians(0.05), errors
  assert np.max(xy(along_beam)) > 0.01 or np.max(np.abs(along_beam[:, 2])) > math.radians(0.1)
