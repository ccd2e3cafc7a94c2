"""Belief, entropy and neighbourhood kernels against closed forms, SciPy and plain NumPy loops."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from conftest import EAGER_AND_JIT
from jaxplore import mapping
from jaxplore.config import make_params


def test_entropy_closed_form():
  p = np.linspace(0.0, 1.0, 101)
  with np.errstate(divide="ignore", invalid="ignore"):
    expected = np.nan_to_num(-p * np.log(p)) + np.nan_to_num(-(1 - p) * np.log(1 - p))
  np.testing.assert_allclose(np.asarray(mapping.entropy_of_probability(p)), expected, atol=1e-6)
  assert float(mapping.entropy_of_probability(0.5)) == np.float32(math.log(2))


@EAGER_AND_JIT
def test_entropy_of_logodds_matches_probability_form(transform):
  l = np.linspace(-12, 12, 241).astype(np.float32)
  p = 1 / (1 + np.exp(-l.astype(np.float64)))
  expected = -p * np.log(p) - (1 - p) * np.log(1 - p)
  np.testing.assert_allclose(np.asarray(transform(mapping.entropy_of_logodds)(l)), expected, atol=2e-6)


@EAGER_AND_JIT
def test_neighbour_count_is_3x3_convolution(transform):
  rng = np.random.default_rng(0)
  mask = rng.random((17, 23)) < 0.4
  ours = np.asarray(transform(mapping.neighbour_count)(jnp.asarray(mask)))
  ref = ndimage.convolve(mask.astype(int), np.ones((3, 3), int), mode="constant", cval=0)
  np.testing.assert_array_equal(ours, ref)


@EAGER_AND_JIT
def test_inflate_matches_distance_transform(transform):
  rng = np.random.default_rng(1)
  mask = rng.random((30, 40)) < 0.03
  for radius in (0.0, 1.0, 1.5, 2.3, 3.0):
    ours = np.asarray(transform(lambda m, r: mapping.inflate(m, r, 3))(jnp.asarray(mask), jnp.float32(radius)))
    # distance from each cell centre to the nearest set cell centre (outside the grid: unset)
    ref = ndimage.distance_transform_edt(~mask) <= radius + 1e-6
    np.testing.assert_array_equal(ours, ref, err_msg=f"radius {radius}")


def test_frontier_matches_numpy_loop():
  rng = np.random.default_rng(2)
  for _ in range(5):
    state = rng.integers(0, 3, size=(15, 18))  # 0 free, 1 occupied, 2 unknown
    free, occ, unk = state == 0, state == 1, state == 2
    ours = np.asarray(mapping.frontier(jnp.asarray(free), jnp.asarray(unk), jnp.asarray(occ)))
    h, w = state.shape
    ref = np.zeros_like(free)
    occ_at = lambda r, c: not (0 <= r < h and 0 <= c < w) or occ[r, c]
    for r in range(h):
      for c in range(w):
        if not free[r, c]:
          continue
        for dr in (-1, 0, 1):
          for dc in (-1, 0, 1):
            rr, cc = r + dr, c + dc
            if (dr, dc) == (0, 0) or not (0 <= rr < h and 0 <= cc < w) or not unk[rr, cc]:
              continue
            if dr and dc and occ_at(r + dr, c) and occ_at(r, c + dc):
              continue  # sealed diagonal
            ref[r, c] = True
    np.testing.assert_array_equal(ours, ref)


def test_update_logodds_once_per_cell_and_clamped():
  p = make_params()
  l = jnp.zeros((3, 3), jnp.float32).at[0, 0].set(4.5)
  observed = jnp.asarray([[2, 1, 0], [0, 2, 1], [0, 0, 0]], jnp.int8)
  new = np.asarray(mapping.update_logodds(l, observed, p))
  assert new[0, 0] == float(p.l_max)  # 4.5 + 2 clamped to 5
  assert new[0, 1] == float(p.l_free) and new[1, 1] == float(p.l_occ) and new[2, 2] == 0.0


@EAGER_AND_JIT
def test_entropy_map_update_is_eq3_inside_radius_only(transform):
  rng = np.random.default_rng(3)
  h, w = 25, 30
  e = rng.uniform(0, math.log(2), (h, w)).astype(np.float32)
  l = rng.normal(0, 2, (h, w)).astype(np.float32)
  robot = np.array([12.3, 7.8], np.float32)
  radius, k = 5.5, 0.3
  ours = np.asarray(transform(lambda e_, l_, r_: mapping.update_entropy_map(e_, l_, r_, radius, k, 15))(
      jnp.asarray(e), jnp.asarray(l), jnp.asarray(robot)))
  ref = e.copy()
  p = 1 / (1 + np.exp(-l.astype(np.float64)))
  h_hat = -p * np.log(p) - (1 - p) * np.log(1 - p)
  for i in range(h):
    for j in range(w):
      if (i + 0.5 - robot[0]) ** 2 + (j + 0.5 - robot[1]) ** 2 <= radius**2:
        ref[i, j] = k * e[i, j] + (1 - k) * h_hat[i, j]
  np.testing.assert_allclose(ours, ref, atol=1e-5)


def _observation_case(shape, seed):
  """Random beliefs of 3 robots, one scan's observation as tiles (tiles not seen, seen free
  only, or mixed; cells at the clamp), and the reachable cells."""
  from jaxplore import sensor

  params = make_params("li2020")
  rng = np.random.default_rng(seed)
  h, w, t = shape[0], shape[1], sensor.OBS_TILE
  logodds = rng.uniform(float(params.l_min), float(params.l_max), (3, h, w)).astype(np.float32)
  logodds[:, rng.random((h, w)) < 0.3] = 0.0
  logodds[:, rng.random((h, w)) < 0.05] = np.float32(params.l_max)
  grid = rng.integers(0, 3, (h, w)).astype(np.int8)
  n_rows, n_cols = -(-h // t), -(-w // t)
  by_tile = lambda mask: np.kron(mask, np.ones((t, t), bool))[:h, :w]
  grid[by_tile(rng.random((n_rows, n_cols)) < 0.5) & (grid == 2)] = 1  # tiles seen free only
  hidden = rng.random((n_rows, n_cols)) < 0.4  # tiles not seen (the first one is)
  hidden.flat[0] = False
  grid[by_tile(hidden)] = 0
  padded = np.zeros((n_rows * t, n_cols * t), np.int8)
  padded[:h, :w] = grid
  tiles = padded.reshape(n_rows, t, n_cols, t).transpose(0, 2, 1, 3)
  reachable = rng.random((h, w)) < 0.7
  return params, logodds, grid, tiles, reachable


def _entropy64(logodds):
  p = 1.0 / (1.0 + np.exp(-logodds.astype(np.float64)))
  with np.errstate(divide="ignore", invalid="ignore"):
    return np.nan_to_num(-p * np.log(p)) + np.nan_to_num(-(1 - p) * np.log(1 - p))


@EAGER_AND_JIT
@pytest.mark.parametrize("whole_grid", [False, True], ids=["tile_loop", "whole_grid"])
@pytest.mark.parametrize("shape", [(37, 50), (32, 16), (5, 7)], ids=str)
def test_integrate_observation_is_the_inverse_sensor_model_on_one_robot(transform, shape,
                                                                        whole_grid):
  """The tile loop (per_robot) and the whole-grid update (lockstep) against the model written
  over the whole grid in NumPy: the other robots' grids untouched, each seen cell + l_free /
  l_occ once, clamped; the entropy and coverage changes of that robot's map."""
  params, logodds, grid, tiles, reachable = _observation_case(shape, seed=sum(shape))
  robot = 1
  integrate = functools.partial(mapping.integrate_observation, whole_grid=whole_grid)
  new, d_entropy, d_covered = transform(integrate)(
      jnp.asarray(logodds), robot, jnp.asarray(tiles), jnp.asarray(reachable), params)
  new = np.asarray(new)
  old = logodds[robot]
  delta = np.where(grid == 2, np.float32(params.l_occ), np.where(grid == 1, np.float32(params.l_free),
                                                                 np.float32(0.0)))
  expected = np.clip(old + delta, np.float32(params.l_min), np.float32(params.l_max))
  np.testing.assert_array_equal(new[robot], expected)
  np.testing.assert_array_equal(np.delete(new, robot, 0), np.delete(logodds, robot, 0))
  threshold = np.float32(mapping.logit(params.p_free))
  assert int(d_covered) == (int(np.sum(reachable & (expected < threshold)))
                            - int(np.sum(reachable & (old < threshold))))
  np.testing.assert_allclose(float(d_entropy), np.sum(_entropy64(expected) - _entropy64(old)),
                             rtol=1e-4, atol=1e-3)


def test_the_whole_grid_update_batches_like_the_tile_loop():
  """Under vmap, as the lockstep strategy runs it (one robot's [1, H, W] grid per batch row, a
  row with nothing seen): the same beliefs and coverage as the tile loop's, bit for bit, and the
  same entropy change up to summation order."""
  params, logodds, _, tiles, reachable = _observation_case((37, 50), seed=7)
  stack = jnp.asarray(logodds)[:, None]
  many = jnp.stack([jnp.asarray(tiles), jnp.zeros_like(tiles), jnp.asarray(tiles)[:, ::-1]])
  run = lambda whole_grid: jax.jit(jax.vmap(lambda l, o: mapping.integrate_observation(
      l, 0, o, jnp.asarray(reachable), params, whole_grid=whole_grid)))(stack, many)
  tile_loop, whole_grid = run(False), run(True)
  np.testing.assert_array_equal(np.asarray(whole_grid[0]), np.asarray(tile_loop[0]))
  np.testing.assert_array_equal(np.asarray(whole_grid[2]), np.asarray(tile_loop[2]))
  np.testing.assert_allclose(np.asarray(whole_grid[1]), np.asarray(tile_loop[1]), rtol=1e-5,
                             atol=1e-4)
  assert not np.array_equal(np.asarray(tile_loop[0][0]), logodds[:1])  # the scan changed robot 0
  assert np.asarray(tile_loop[1])[1] == 0.0 and np.asarray(tile_loop[2])[1] == 0  # nothing seen
