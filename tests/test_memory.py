"""The memory guard: its model against peaks measured on a GPU (lockstep), and the check of a
compiled program's own numbers."""

import jax
import jax.numpy as jnp
import pytest

from jaxplore import memory
from jaxplore.config import ConfigError, SimConfig
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



def _program(donate: bool):
  """``x -> 2 x + 1`` on 1,000 float32, its input donated or not."""
  return jax.jit(lambda x: 2.0 * x + 1.0, donate_argnums=0 if donate else ()).lower(
      jnp.zeros(1000)).compile()


def test_compiled_bytes_count_the_output_unless_it_reuses_the_input():
  assert memory.compiled_bytes(_program(False)) >= 1000 * 4  # a new output buffer
  assert memory.compiled_bytes(_program(True)) == 0  # written in place of the donated input


def test_a_compiled_program_that_does_not_fit_is_refused_with_the_numbers(monkeypatch):
  compiled = _program(False)
  need = memory.compiled_bytes(compiled)
  config = SimConfig(height=30, width=40, res=0.1)
  monkeypatch.setattr(memory, "available_bytes", lambda: int(need / memory.MEMORY_FRACTION) + 8)
  memory.check_compiled(compiled, config, robots=4)  # fits
  with pytest.raises(ConfigError, match=r"4 robots on a 30x40 grid .*GiB.*fewer robots"):
    memory.check_compiled(compiled, config, robots=4, n_dev=2)  # two host devices: twice
  monkeypatch.setattr(memory, "available_bytes", lambda: int(need / memory.MEMORY_FRACTION) - 8)
  with pytest.raises(ConfigError, match="allocates"):
    memory.check_compiled(compiled, config, robots=4)
