"""``jaxplore.run``: one batch of robots on one world, from settings to tables, files and figures.

A :class:`jaxplore.runspec.RunSpec` (or its fields as keyword arguments) is resolved and
validated before any compute (:func:`jaxplore.resolve.resolve`), checked against the memory
guard, then run by the host loop shared with sweeps (:mod:`jaxplore.driver`: compile once,
advance in chunks with a progress bar, stop when every robot is done, shard over local devices);
the tables and the results folder come from :mod:`jaxplore.results`.
"""

from __future__ import annotations

import dataclasses
import platform
import time
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from jaxplore import __version__, driver, interrupts, memory, results, sim
from jaxplore.maps import GridMap
from jaxplore.resolve import build_params, default_max_steps, resolve
from jaxplore.runspec import RunSpec


@dataclasses.dataclass
class RunResult:
  """What a run produced (also written to ``out`` when given).

  Attributes:
    episodes: one row per robot: episode metrics and termination reason.
    curves: one row per robot and step until the robot finished.
    config: the resolved settings (what ``config.json`` holds).
    timing: compile and run wall-clock seconds.
    grid: the truth map. state: the final engine state (NumPy leaves, batch first).
    out: the results folder, if any.
  """

  episodes: pd.DataFrame
  curves: pd.DataFrame
  config: dict
  timing: dict
  grid: GridMap
  state: sim.State
  out: Path | None = None


@interrupts.deferred()
def run(spec: RunSpec | None = None, *, out=None, progress: bool = True, devices: int | None = None,
        quiet: bool = False, **settings) -> RunResult:
  """Runs a batch of robots exploring a world and returns (and writes) the results.

  Args:
    spec: the run specification; or give its fields as keyword ``settings`` (None = default),
      e.g. ``run(world="lab", planner="li2020", robots=32, params={"r_max": 10})``. Settings given
      with a spec replace its fields. See :class:`jaxplore.runspec.RunSpec` for every field:
      ``world``, ``planner``, ``robots``, ``seed``, ``robot_seeds``, ``preset``, ``res``,
      ``start``, ``max_steps``, ``replan_every``, ``path_capacity``, ``plan_window``,
      ``pose_noise``, ``params``, ``planner_params``, ``rate_interval``, ``chunk_epochs``,
      ``strategy``.
    out: results folder (created; checked before any compute); None writes nothing.
    progress: a progress bar over steps.
    devices: how many local devices to shard the batch over (default: all; at most one per robot;
      a batch that does not divide runs with copies of its last robot, their results dropped).
    quiet: print nothing: no summary, no progress bar.
  Raises:
    ConfigError, MapError: a bad setting, before any compute.
    KeyboardInterrupt: after Ctrl-C, once the results of the chunks finished before it are
      written (``out``) and summarised.
    jaxplore.driver.Stalled: a chunk made no progress (:class:`jaxplore.driver.Watchdog`), once
      the results of the chunks finished before it are written and summarised.
  """
  if spec is None:
    spec = RunSpec.create(**settings)
  elif settings:
    spec = dataclasses.replace(spec, **{k: v for k, v in settings.items() if v is not None})
  out = results.check_run_out(out)
  resolved = resolve(spec)
  config, world, grid = resolved.config, resolved.world, resolved.grid
  robots = spec.robots
  # Every device holds as many robots: a batch that does not divide is padded with copies of
  # its last robot, whose results are dropped (each robot's run is its own).
  n_dev = min(driver.local_devices(devices), robots)
  padded = -(-robots // n_dev) * n_dev
  memory.check_fits(config, padded)
  nothing = "interrupted before the first step; nothing was computed or written"
  interrupts.check(nothing)
  batch = resolved.batch(None if padded == robots else
                         list(range(robots)) + [robots - 1] * (padded - robots))
  chunk_epochs = driver.chunk_epochs_for(config, spec.chunk_epochs)

  bar = None
  if progress and not quiet:  # shown from the start: a compile can take a minute on a GPU
    from tqdm.auto import tqdm
    label = f"{spec.planner_name} x{robots} on {grid.name}"
    # smoothing=0: the rate is the mean since the start, the compile taken out below
    bar = tqdm(total=config.max_steps, unit="step", desc=f"{label} (compiling)", smoothing=0)

  def show(rec, done):
    bar.update(min(rec.done.shape[0], config.max_steps - bar.n))
    bar.set_postfix(done=f"{int(done[:robots].sum())}/{robots}",
                    coverage=f"{float(rec.coverage[-1, :robots].mean()):.3f}")

  try:
    t0 = time.perf_counter()
    try:
      state = driver.reset(config, world, batch)
    except KeyboardInterrupt as err:
      raise KeyboardInterrupt(f"{nothing} ({err})") from None
    t_reset = time.perf_counter() - t0
    interrupts.check(nothing)
    t0 = time.perf_counter()
    compiled = driver.compile_advance(config, chunk_epochs, n_dev, world, batch.params, state)
    t_compile = time.perf_counter() - t0
    memory.check_compiled(compiled, config, padded, n_dev)
    interrupts.check(nothing)
    if bar is not None:
      bar.start_t += t_reset + t_compile  # the rate and ETA count the steps' time only
      bar.set_description(label)
    rollout = driver.drive(compiled, world, batch.params, state, config.max_steps,
                           interruptible=True, on_chunk=None if bar is None else show)
  finally:
    if bar is not None:
      bar.close()

  if padded > robots:  # the copies' results go (records are [T, B])
    rollout = dataclasses.replace(
        rollout, state=jax.tree.map(lambda leaf: leaf[:robots], rollout.state),
        records=jax.tree.map(lambda leaf: leaf[:, :robots], rollout.records))
  episodes, curves = results.tables(config, grid, world, rollout.state, rollout.records,
                                    spec.rate_interval)
  episodes.insert(0, "planner", spec.planner_name)
  episodes.insert(0, "world", grid.name)
  episodes.insert(2, "seed", spec.seed if spec.robot_seeds is None else list(spec.robot_seeds))
  described = resolved.describe()
  resolved_config = {
      "jaxplore_version": __version__, "jax_version": jax.__version__,
      "numpy_version": np.__version__,
      "python": platform.python_version(), "devices": [str(d) for d in jax.devices()],
      "backend": jax.default_backend(), "device_kind": jax.local_devices()[0].device_kind,
      "sharded_over": n_dev, "seed": spec.seed,
      "robot_seeds": None if spec.robot_seeds is None else list(spec.robot_seeds),
      "robots": robots, "planner": spec.planner_name, "preset": spec.preset,
      "start": None if spec.start is None else list(spec.start),
      "interrupted": rollout.interrupted, "stalled": rollout.stalled, **described,
      "rate_interval_m": spec.rate_interval,
      "spec": spec.to_json(),
  }
  robot_steps = int(np.asarray(rollout.state.steps).sum())
  t_run = rollout.run_s
  timing = {"reset_s": t_reset, "compile_s": t_compile, "run_s": t_run,
            "sim_steps": rollout.steps, "robot_steps": robot_steps,
            "robot_steps_per_s": robot_steps / t_run if t_run > 0 else float("nan")}
  result = RunResult(episodes, curves, resolved_config, timing, grid, rollout.state)
  if out is not None:
    result.out = results.write_run(out, resolved_config, timing, episodes, curves, grid,
                                   rollout.state)
  if not quiet:
    print(results.summary_table(episodes))
  kept = f"; partial results kept{' in ' + str(out) if out else ''}"
  if rollout.stalled:
    raise driver.Stalled(rollout.stalled + kept)
  if rollout.interrupted:
    raise KeyboardInterrupt(f"interrupted{'; ' + rollout.dropped if rollout.dropped else ''}{kept}")
  return result


def prepare(world=None, planner=None, robots=None, seed=None, preset=None, res=None, start=None,
            max_steps=None, replan_every=None, params=None, planner_params=None, pose_noise=None,
            path_capacity=None, plan_window=None, strategy=None):
  """(grid, config, params, start) of a run: :func:`jaxplore.resolve.resolve` of these settings
  (None = :class:`RunSpec`'s default), for scripts that drive the engine themselves."""
  resolved = resolve(RunSpec.create(
      world=world, planner=planner, robots=robots, seed=seed, preset=preset, res=res, start=start,
      max_steps=max_steps, replan_every=replan_every, params=params, planner_params=planner_params,
      pose_noise=pose_noise, path_capacity=path_capacity, plan_window=plan_window,
      strategy=strategy))
  return resolved.grid, resolved.config, resolved.params, resolved.start


def sweep(*args, **kwargs):
  """A parameter sweep in chunks, resumable: see :func:`jaxplore.sweeps.sweep` (same arguments)."""
  from jaxplore import sweeps
  return sweeps.sweep(*args, **kwargs)


summary_table = results.summary_table

__all__ = ["RunResult", "build_params", "default_max_steps", "prepare", "run", "summary_table",
           "sweep"]
