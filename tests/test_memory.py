"""The memory guard's model against peaks measured on a GPU (lockstep)."""

import pytest

from jaxplore import memory
from jaxplore.resolve import resolve
from jaxplore.runspec import RunSpec

# Peak device memory measured on one H200 (experiments/results/bench_accelerator_gpu.md, 96 or
# 32 timed steps after reset): (world, planner, robots, max_steps, GiB).
MEASURED = [("office", "nearest_frontier", 4096, 224, 2.3),
            ("office", "nearest_frontier", 16384, 224, 8.5),
            ("lab", "li2020", 256, 96, 0.4)]


@pytest.mark.parametrize("world, planner, robots, max_steps, peak_gib", MEASURED)
def test_the_lockstep_estimate_covers_the_measured_peak_without_tripling_it(
    world, planner, robots, max_steps, peak_gib):
  config = resolve(RunSpec(world=world, planner=planner, robots=robots, preset="li2020",
                           max_steps=max_steps, strategy="lockstep")).config
  estimate_gib = memory.estimate_bytes(config, robots) / 2**30
  assert peak_gib <= estimate_gib <= 3 * peak_gib + 0.5, estimate_gib
