"""The sequential NumPy/SciPy reference of ``experiments/bench_engine.py`` does the engine's job.

Same lidar cells as ``jaxplore.sensor``, the same first scan, and similar coverage after 60 steps
from the same starts (paths may differ where equal-cost predecessors are broken differently).
"""

import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import sensor, sim
from jaxplore.config import PARAM_FIELDS, config_for, make_params
from jaxplore.maps.grid import GridMap

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import reference_numpy  # noqa: E402

STEPS = 60
STARTS = ((1.0, 1.0, 0.3), (2.0, 3.0, -1.0), (4.5, 2.0, 2.0), (1.5, 2.5, 0.0))


def two_rooms() -> GridMap:
  """A walled 4 x 6 m box split in two rooms joined by a 1 m door."""
  occupied = np.zeros((40, 60), bool)
  occupied[[0, -1], :] = occupied[:, [0, -1]] = True
  occupied[1:39, 29:31] = True
  occupied[15:25, 29:31] = False
  return GridMap(occupied, 0.1, (0.0, 0.0), "two_rooms")


@pytest.fixture(scope="module")
def both_runs():
  grid = two_rooms()
  params = make_params("li2020", res=grid.res, r_max=1.0)
  config = config_for(grid.shape, grid.res, params, max_steps=STEPS, replan_every=6)
  world = sim.make_world(grid, float(params.r_robot), STARTS[0][:2])
  keys = jax.random.split(jax.random.PRNGKey(0), len(STARTS))
  # The engine runs tests/test_sim.py's program for these rooms (its rooms_run config: a lidar
  # buffer for 3 m, a 300-step budget, as many robots), loaded from the suite's compilation
  # cache instead of compiled again (~20 s): the range is a traced parameter, and no step before
  # the budget depends on it, so its first STEPS steps are this config's.
  shared = config_for(grid.shape, grid.res, make_params("li2020", res=grid.res, r_max=3.0),
                      max_steps=300, replan_every=6)
  _, records = sim.rollout(shared, world, sim.broadcast_params(params, len(STARTS)), keys,
                           jnp.asarray(STARTS, jnp.float32))
  params_dict = {name: float(getattr(params, name)) for name in PARAM_FIELDS}
  references = [reference_numpy.run_reference(grid, params_dict, config, start, STEPS) for start in STARTS]
  return np.asarray(records.coverage)[:STEPS], references


def test_reference_runs_the_same_number_of_steps(both_runs):
  _, references = both_runs
  for result in references:
    assert result["steps"] == STEPS and result["reason"] == "timeout"
    assert result["distance"] > 0.5 and np.isfinite(result["det_cov"])


def test_first_steps_see_the_same_cells(both_runs):
  coverage, references = both_runs
  for i, result in enumerate(references):
    np.testing.assert_allclose(result["coverage_curve"][0], coverage[0, i], atol=1e-5)


def test_reference_reaches_similar_coverage(both_runs):
  coverage, references = both_runs
  final_reference = np.array([r["coverage"] for r in references])
  assert np.all(final_reference > 1.5 * coverage[0]), "the reference robots did not explore"
  np.testing.assert_allclose(final_reference, coverage[-1], atol=0.1)


def test_scan_matches_the_engine_lidar():
  rng = np.random.default_rng(1)
  grid = two_rooms()
  occupied = grid.occupied
  free = np.argwhere(~occupied)
  r_max, n_cross = 45.0, 46
  truth = sensor.frame_truth(jnp.asarray(occupied))
  cast = jax.jit(lambda u, v, a: sensor.cast(truth, occupied.shape, u, v, a, r_max, n_cross))
  for _ in range(10):
    row, col = free[rng.integers(len(free))]
    u0, v0 = (float(np.float32(c + rng.uniform())) for c in (col, row))
    angles = reference_numpy.beam_angles(float(rng.uniform(-math.pi, math.pi)), 2 * math.pi, 360)
    scan, cells = cast(jnp.float32(u0), jnp.float32(v0), jnp.asarray(angles, jnp.float32))
    rows, cols, t = (np.asarray(a) for a in (cells.rows, cells.cols, cells.t))
    hit, hit_rows, hit_cols = (np.asarray(a) for a in (scan.hit, scan.hit_rows, scan.hit_cols))
    end = (rows == hit_rows[:, None]) & (cols == hit_cols[:, None]) & hit[:, None]
    engine_free = (t < np.asarray(scan.ranges)[:, None]) & ~end
    reference = reference_numpy.scan(occupied, u0, v0, angles, r_max, n_cross)
    engine_cells = set(zip(rows[engine_free], cols[engine_free]))
    assert engine_cells == set(zip(reference.free_rows, reference.free_cols))
    assert set(zip(hit_rows[hit], hit_cols[hit])) == set(
        zip(reference.hit_rows[reference.hit], reference.hit_cols[reference.hit]))
    np.testing.assert_allclose(reference.ranges, np.asarray(scan.ranges), atol=1e-3)
