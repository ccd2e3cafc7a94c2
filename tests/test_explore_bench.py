"""The explore_bench preset on the six Explore-Bench blueprints (the full runs to completion are
in experiments/explore_bench.py; here: every blueprint runs and the preset means one cell per step)."""

import math

import numpy as np
import pytest

import jaxplore
from conftest import SHARED_MAPS, needs_shared_maps

BLUEPRINTS = SHARED_MAPS / "explore_bench"
NAMES = ("corner", "corridor", "loop", "loop_with_corridor", "room", "room_with_corner")


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
@needs_shared_maps
@pytest.mark.parametrize("name", NAMES)
def test_blueprint_runs_with_the_explore_bench_preset(name):
  start = "6,6,0" if name == "corner" else "8,8,0"
  result = jaxplore.run(world=str(BLUEPRINTS / f"{name}.yaml"), planner="nearest_frontier",
                        preset="explore_bench", robots=1, start=start, max_steps=30,
                        progress=False, quiet=True, devices=1)
  curve = result.curves
  assert result.config["sim_config"]["replan_every"] == 1
  assert result.config["params"]["r_max"] == pytest.approx(3.5)
  assert result.config["params"]["fov"] == pytest.approx(2 * math.pi)
  # one waypoint (orthogonal 0.1 m or diagonal 0.141 m) per moving step
  steps = np.diff(np.concatenate([[0.0], curve.distance.to_numpy()]))
  assert steps.max() <= math.sqrt(2) * 0.1 + 1e-5
  assert (steps > 0).mean() > 0.8
  assert curve.coverage.iloc[-1] > curve.coverage.iloc[0]
