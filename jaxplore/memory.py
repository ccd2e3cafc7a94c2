"""The memory guard: a batch's estimated peak memory against what the machine has free.

``jaxplore run`` refuses a batch that would not fit; a sweep shrinks its chunks until one fits
(:func:`fit_chunk`) and refuses a sweep in which one robot does not.
"""

from __future__ import annotations

import os
import sys

from jaxplore.config import ConfigError, SimConfig

MEMORY_FRACTION = 0.8  # of the available memory a batch may use


def _largest_part(config: SimConfig) -> str:
  """What makes one robot's estimate large, naming the setting behind it."""
  cells = config.height * config.width
  parts = {
      f"the {config.height}x{config.width} grid at {config.res:g} m/cell (--res)":
          cells * (4 + 4 + 1 + 4 * 8),
      f"the per-step records of max_steps={config.max_steps}": config.max_steps * 10 * 4,
      f"the lidar buffers of {config.n_beams} beams of {config.max_range_cells} cells (r_max)":
          config.n_beams * (4 * config.max_range_cells + 2) * 4 * 6,
  }
  return max(parts, key=parts.get)


def estimate_bytes(config: SimConfig, robots: int) -> int:
  """Rough peak memory of a run: per-robot state and planning masks, records, lidar buffers.

  The ``per_robot`` strategy plans a few robots at a time (at most 64 robots' planning buffers
  are counted), ``lockstep`` the whole batch at once.
  """
  cells = config.height * config.width
  per_robot_state = cells * (4 + 4 + 1)  # log-odds, entropy map, blacklist
  per_robot_planning = cells * 4 * 8  # distances, predecessors, masks of one planning round
  records = config.max_steps * 10 * 4
  lidar = config.n_beams * (4 * config.max_range_cells + 2) * 4 * 6
  planning = robots if config.strategy == "lockstep" else min(robots, 64)
  return robots * (per_robot_state + records + lidar) + planning * per_robot_planning


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


__all__ = ["MEMORY_FRACTION", "available_bytes", "check_fits", "estimate_bytes", "fit_chunk"]
