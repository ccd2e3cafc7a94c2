"""The GPU candidates of ``experiments/bench_lockstep_variants.py`` compute what the engine does
(a candidate that won on a GPU moves into the package with these checks)."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import EAGER_AND_JIT
from jaxplore import mapping
from test_mapping import _observation_case

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import bench_lockstep_variants as variants  # noqa: E402


@EAGER_AND_JIT
@pytest.mark.parametrize("shape", [(37, 50), (48, 64), (5, 7)], ids=str)
def test_whole_grid_belief_update_equals_the_tile_loop(transform, shape):
  params, logodds, _, tiles, reachable = _observation_case(shape, seed=1 + sum(shape))
  args = (jnp.asarray(logodds), 2, jnp.asarray(tiles), jnp.asarray(reachable), params)
  tiles_new, tiles_entropy, tiles_covered = transform(mapping.integrate_observation)(*args)
  grid_new, grid_entropy, grid_covered = transform(variants.integrate_observation_whole_grid)(*args)
  np.testing.assert_array_equal(np.asarray(grid_new), np.asarray(tiles_new))
  assert int(grid_covered) == int(tiles_covered)
  np.testing.assert_allclose(float(grid_entropy), float(tiles_entropy), rtol=1e-5, atol=1e-4)


def test_whole_grid_belief_update_batches_like_the_engine():
  """Under vmap (the lockstep strategy: one robot's grid per batch row)."""
  params, logodds, _, tiles, reachable = _observation_case((37, 50), seed=7)
  stack = jnp.asarray(logodds)[:, None]  # three robots, each its own [1, H, W] grid
  many = jnp.stack([jnp.asarray(tiles), jnp.zeros_like(tiles), jnp.asarray(tiles)[:, ::-1]])
  run = lambda fn: jax.jit(jax.vmap(lambda l, o: fn(l, 0, o, jnp.asarray(reachable), params)))(
      stack, many)
  expected, got = run(mapping.integrate_observation), run(variants.integrate_observation_whole_grid)
  np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(expected[0]))
  np.testing.assert_array_equal(np.asarray(got[2]), np.asarray(expected[2]))
  np.testing.assert_allclose(np.asarray(got[1]), np.asarray(expected[1]), rtol=1e-5, atol=1e-4)
  assert not np.array_equal(np.asarray(expected[0][0]), logodds[:1])  # the scan changed robot 0


def test_compare_tells_bit_for_bit_from_a_changed_leaf(tmp_path):
  state = {".logodds": np.arange(6, dtype=np.float32), ".entropy": np.float32([100.0, 200.0])}
  np.savez(tmp_path / "a.npz", **state)
  np.savez(tmp_path / "same.npz", **state)
  np.savez(tmp_path / "rounding.npz", **dict(state, **{".entropy": np.float32([100.0001, 200.0])}))
  np.savez(tmp_path / "entropy.npz", **dict(state, **{".entropy": np.float32([101.0, 200.0])}))
  np.savez(tmp_path / "logodds.npz", **dict(state, **{".logodds": np.float32([0, 1, 2, 3, 4, 5.5])}))
  verdict = lambda name: variants.compare(tmp_path / "a.npz", tmp_path / f"{name}.npz")
  assert verdict("same") == "bit for bit"
  assert verdict("rounding").startswith(".entropy within")
  assert "beyond" in verdict("entropy")
  assert ".logodds DIFFERS" in verdict("logodds")
