"""The memory guard: a batch's estimated peak memory against what the machine has free.

``jaxplore run`` refuses a batch that would not fit; a sweep shrinks its chunks until one fits
(:func:`fit_chunk`) and refuses a sweep in which one robot does not.
"""

from __future__ import annotations

import functools
import math
import os
import sys

from jaxplore.config import ConfigError, SimConfig

MEMORY_FRACTION = 0.8  # of the available memory a batch may use


def _largest_part(config: SimConfig) -> str:
  """What makes one robot's estimate large, naming the setting behind it."""
  cells = config.height * config.width
  parts = {
      f"the planner's memory ({config.planner.name}'s settings)":
          PLANNER_MEMORY_COPIES * planner_memory_bytes(config),
      f"the pose graph of {config.graph_nodes} keyframes (max_steps, kf_dist, kf_rot) and their "
      f"scans of {config.n_beams} beams": PLANNER_MEMORY_COPIES * graph_bytes(config),
      f"the {config.height}x{config.width} grid at {config.res:g} m/cell (--res)":
          cells * (GRID_BYTES_PER_CELL + ROBOT_BYTES_PER_CELL),
      f"the per-step records of max_steps={config.max_steps}": config.max_steps * 10 * 4,
      f"the {config.sensor.name}'s buffers of {config.n_beams} beams of "
      f"{config.max_range_cells} cells (r_max)":
          config.sensor.buffer_bytes(config.n_beams, config.max_range_cells),
  }
  return max(parts, key=parts.__getitem__)


# The model's constants, fitted to the peak RSS of `jaxplore run` on this project's CPU
# (experiments/bench_memory.py, nearest frontier, 2000^2 and 4000^2 cells, 1 and 4 robots, less
# the peak of the same run on 64^2): one robot costs ~150 bytes per cell, each further robot
# ~13-22, so most of it is per batch, not per robot.
FIXED_BYTES = 128 << 20  # what a big grid adds whatever its size (the intercept of the fit)
GRID_BYTES_PER_CELL = 130  # the world (host and device), one robot's planning temporaries, and
# the tables' per-robot map quality (float64 SSIM filters), one robot at a time
ROBOT_BYTES_PER_CELL = 20  # a robot's belief and blacklist, and their host copies (a planner's
# memory, li2020's entropy map among them, is counted from its shapes: planner_memory_bytes)
# Lockstep (an accelerator): a robot's maps and the whole batch's per-stage temporaries, per cell
# of the grid and robot; no lidar term (the scan's buffers are the batch's, kernel by kernel).
# Fitted to the device's peak memory on one H200 (experiments/results/bench_accelerator_gpu.md):
# 19 (office), 18.5 (Explore-Bench room) and 25 (lab, li2020 with its entropy map) bytes per
# cell and robot between batch sizes; 32 leaves a margin.
LOCKSTEP_BYTES_PER_CELL = 32
# ... and per cell and robot of one planning chunk (jaxplore.planning.lockstep_plan_chunk): the
# planner's temporaries (li2020's visible-gain masks: ~0.13 GiB for a chunk of 64 on lab).
LOCKSTEP_PLANNING_BYTES_PER_CELL = 128


def _tree_bytes(shapes) -> int:
  """Bytes of a pytree of arrays or shapes (``jax.eval_shape``'s)."""
  import jax
  return sum(math.prod(leaf.shape) * leaf.dtype.itemsize for leaf in jax.tree.leaves(shapes))


@functools.lru_cache(maxsize=64)
def planner_memory_bytes(config: SimConfig) -> int:
  """Bytes of one robot's planner memory (``PlannerSpec.init_memory``), from its shapes alone
  (``jax.eval_shape``: nothing is computed or allocated); 0 for a planner without memory."""
  import jax

  from jaxplore.config import make_params
  from jaxplore.robot import planner_context
  spec = config.planner
  if not spec.has_memory:
    return 0
  params = make_params(res=config.res, planner=dict(spec.defaults))
  shapes = jax.eval_shape(lambda p: spec.initial_memory(planner_context(config), p), params)
  return _tree_bytes(shapes)


@functools.lru_cache(maxsize=64)
def graph_bytes(config: SimConfig) -> int:
  """Bytes of one robot's SLAM pose graph (:func:`jaxplore.posegraph.init`: keyframes, edges
  and, with the ``scan_matching`` model, every keyframe's scan), from its shapes alone."""
  if not config.graph_nodes:
    return 0
  import jax
  import jax.numpy as jnp

  from jaxplore import posegraph
  beams = config.n_beams if config.slam == "scan_matching" else 0
  shapes = jax.eval_shape(lambda: posegraph.init(jnp.zeros(3), config.graph_nodes,
                                                 config.graph_loops, beams=beams))
  return _tree_bytes(shapes)


# A planner's memory (and a pose graph) is held three times: in the state, in the next state of
# the compiled loop, and in the host copy of the final state.
PLANNER_MEMORY_COPIES = 3


def estimate_bytes(config: SimConfig, robots: int) -> int:
  """Peak memory of a run: a per-batch part (the world, planning temporaries, the tables) and,
  per robot, its maps, per-step records and lidar buffers (with ``lockstep``, its maps and the
  batch's temporaries per cell, :data:`LOCKSTEP_BYTES_PER_CELL`, and one planning chunk's
  temporaries, :data:`LOCKSTEP_PLANNING_BYTES_PER_CELL`).

  Within 25 % of the measured peak RSS (less the runtime's own) on 1000^2 to 4000^2 cells with
  1 and 4 robots and on 8000^2 cells with 1 robot, on a CPU
  (``experiments/results/bench_memory.md``, where the constants were fitted). With lockstep,
  1.1-4x the peak device memory measured on one GPU, 2-2.5x from 1,024 robots on
  (``tests/test_memory.py``).
  """
  cells = config.height * config.width
  records = config.max_steps * 10 * 4
  if config.strategy == "lockstep":
    from jaxplore.planning import lockstep_plan_chunk
    planning = lockstep_plan_chunk(config, robots) * cells * LOCKSTEP_PLANNING_BYTES_PER_CELL
    per_robot = (cells * LOCKSTEP_BYTES_PER_CELL + records
                 + PLANNER_MEMORY_COPIES * (planner_memory_bytes(config) + graph_bytes(config)))
    return FIXED_BYTES + cells * GRID_BYTES_PER_CELL + planning + robots * per_robot
  lidar = config.sensor.buffer_bytes(config.n_beams, config.max_range_cells)
  per_robot = (cells * ROBOT_BYTES_PER_CELL + records + lidar
               + PLANNER_MEMORY_COPIES * (planner_memory_bytes(config) + graph_bytes(config)))
  return FIXED_BYTES + cells * GRID_BYTES_PER_CELL + robots * per_robot


def available_bytes() -> int:
  """Free memory for a batch: on a GPU or TPU, the free memory of the first local device (its
  limit less what is in use); on a CPU, the host's free RAM."""
  import jax
  if jax.default_backend() != "cpu":
    stats = jax.local_devices()[0].memory_stats() or {}
    if "bytes_limit" in stats:
      return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
  try:
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
  except (ValueError, OSError, AttributeError):
    return 8 << 30


def _gib(n: int) -> str:
  return f"{n / 2**30:.3g} GiB ({n} bytes)"


def check_fits(config: SimConfig, robots: int) -> None:
  """Raises :class:`ConfigError` with the numbers when ``robots`` robots would not fit."""
  need, have = estimate_bytes(config, robots), available_bytes()
  if need > MEMORY_FRACTION * have:
    raise ConfigError(f"{robots} robots on a {config.height}x{config.width} grid need about "
                      f"{need / 2**30:.1f} GiB, more than {MEMORY_FRACTION:.0%} of the "
                      f"{have / 2**30:.1f} GiB available, mostly for {_largest_part(config)}; "
                      f"use fewer robots or change that setting")


def fit_chunk(config: SimConfig, requested: int, n_dev: int = 1, fixed: bool = False) -> int:
  """The largest chunk of at most ``requested`` robots whose estimated memory fits.

  Args:
    fixed: the chunk size is fixed by a written schedule: refuse instead of shrinking it.
  Raises:
    ConfigError: not even one robot fits (the message names bytes needed and available, the
      grid size and the robots), or a ``fixed`` chunk does not fit.
  """
  have = available_bytes()
  budget = int(MEMORY_FRACTION * have)
  one = estimate_bytes(config, 1)
  if one > budget:
    raise ConfigError(
        f"one robot on a {config.height}x{config.width} grid with max_steps={config.max_steps} "
        f"needs about {_gib(one)}, more than {MEMORY_FRACTION:.0%} of the {_gib(have)} available, "
        f"mostly for {_largest_part(config)}; change that setting")
  need = estimate_bytes(config, requested)
  if need <= budget:
    return requested
  if fixed:
    raise ConfigError(
        f"the schedule's chunks of {requested} robots on a {config.height}x{config.width} grid "
        f"need about {_gib(need)}, more than {MEMORY_FRACTION:.0%} of the {_gib(have)} available "
        f"now; free some memory and resume again")
  lo, hi = 1, requested  # estimate_bytes grows with robots: the largest lo that fits
  while lo < hi:
    mid = (lo + hi + 1) // 2
    if estimate_bytes(config, mid) <= budget:
      lo = mid
    else:
      hi = mid - 1
  chunk = lo - lo % n_dev if lo >= n_dev else lo
  print(f"jaxplore: a chunk of {requested} robots on a {config.height}x{config.width} grid needs "
        f"about {_gib(need)}, more than {MEMORY_FRACTION:.0%} of the {_gib(have)} available; "
        f"running chunks of {chunk} robots instead", file=sys.stderr)
  return chunk


def compiled_bytes(compiled) -> int | None:
  """What running ``compiled`` (a ``jax.stages.Compiled``) allocates on one device beyond its
  inputs, in XLA's own numbers: its outputs and temporaries, less the outputs that reuse input
  buffers. None where the backend does not say."""
  try:
    stats = compiled.memory_analysis()
  except (NotImplementedError, RuntimeError):
    return None
  if stats is None:
    return None
  return int(stats.output_size_in_bytes + stats.temp_size_in_bytes - stats.alias_size_in_bytes)


def check_compiled(compiled, config: SimConfig, robots: int, n_dev: int = 1) -> None:
  """Raises :class:`ConfigError` when the compiled chunk function would not fit beside the batch
  already in memory (call it after the reset and the compile, before the first chunk runs).

  The model of :func:`estimate_bytes` comes before any compute; this second check reads what
  XLA will allocate beyond the inputs (the batch, already in memory). It matters where the model
  is short: forcing ``lockstep`` on a CPU, li2020 on lab compiles to arguments, outputs and
  temporaries of 0.58 / 1.45 / 5.8 GiB at 256 / 1,024 / 4,096 robots against the model's 0.47 /
  1.14 / 4.2 (its per-cell constants were fitted to a GPU's peaks).
  """
  import jax
  need = compiled_bytes(compiled)
  if need is None:
    return
  if jax.default_backend() == "cpu":
    need *= n_dev  # host devices share the host's memory
  have = available_bytes()
  if need > MEMORY_FRACTION * have:
    raise ConfigError(
        f"{robots} robots on a {config.height}x{config.width} grid ({config.strategy} strategy) "
        f"compiled to a program that allocates {_gib(need)} beside the batch, more than "
        f"{MEMORY_FRACTION:.0%} of the {_gib(have)} available; use fewer robots (a sweep: "
        f"smaller chunks), or the other strategy")


__all__ = ["MEMORY_FRACTION", "available_bytes", "check_compiled", "check_fits",
           "compiled_bytes", "estimate_bytes", "fit_chunk", "planner_memory_bytes"]
