"""Sweeps: worlds × planners × parameter settings × seeds, in chunks that survive interruption.

A sweep is resolved into a *schedule* before any compute (:mod:`jaxplore.sweeps.schedule`):
every row (one robot-episode: a world, a planner, the values of the swept names, a seed),
grouped by compiled program and cut into chunks of equal shape, so one group compiles once.
With ``out``, the schedule is written first (``sweep_schedule.json``) and every finished chunk
atomically (write, fsync, rename) to ``chunks/chunk_NNNNN.parquet`` (+ ``.curves.parquet``);
``sweep(resume=DIR)`` (``jaxplore sweep --resume DIR``) reads the schedule, skips finished
chunks, computes the rest and assembles the final ``episodes.parquet``, ``curves.parquet``,
``config.json`` and figures from the chunk files, so an interrupted-and-resumed sweep gives the
same table as an uninterrupted one.

Robots are independent under ``vmap`` and robot ``s``'s PRNG key is ``PRNGKey(s)``, so a row's
result does not depend on which chunk it lands in, nor on how a chunk is sharded over devices
(``tests/test_sweep.py`` checks both bit for bit).

Memory guard: before allocating, the estimated memory of a chunk (:mod:`jaxplore.memory`) is
compared with 80 % of the available memory; a chunk that does not fit is made smaller (and says
so), and a sweep in which one robot does not fit is refused with the numbers.

Modules: :mod:`~jaxplore.sweeps.settings` (what is asked, TOML files),
:mod:`~jaxplore.sweeps.schedule` (rows, groups, chunks, the schedule file),
:mod:`~jaxplore.sweeps.execute` (running chunks, on one host or several),
:mod:`~jaxplore.sweeps.assemble` (final tables, config and figures).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import sys
from pathlib import Path

import pandas as pd

from jaxplore import driver, interrupts, results
from jaxplore.config import ConfigError
from jaxplore.errors import check_writable
from jaxplore.memory import MEMORY_FRACTION, fit_chunk
from jaxplore.runspec import SHARED, RunSpec, merge_settings, route_settings
from jaxplore.sweeps import assemble, execute
from jaxplore.sweeps import schedule as schedules
from jaxplore.sweeps.assemble import sweep_table
from jaxplore.sweeps.schedule import LEGACY_FILE, SCHEDULE_FILE, first_difference, read_schedule
from jaxplore.sweeps.settings import SweepSpec, load_config, make_spec, parse_random_spec

RUN_KEYS = SHARED  # the run settings a sweep's rows share (sweep(**run_kwargs))


@dataclasses.dataclass
class SweepResult:
  """What a sweep produced (also written to ``out`` when given).

  Attributes:
    episodes: one row per robot-episode: ``world``, ``planner``, ``seed``, one column per swept
      parameter (NaN where a planner has no such weight), ``robot`` (the row's index in the
      sweep), then the episode metrics of :func:`jaxplore.run`.
    curves: one row per robot-episode and step (``robot`` joins with ``episodes``).
    config: the resolved schedule, per-group settings and versions (what ``config.json`` holds).
    timing: this session's compile and run seconds, compile count, chunks run and skipped.
    out: the results folder, if any.
  """

  episodes: pd.DataFrame
  curves: pd.DataFrame
  config: dict
  timing: dict
  out: Path | None = None


@interrupts.deferred()
def _planners_bring(planner, what: str):
  """What the sweep's planners all bring (``planner_brings``: their paper's ``"preset"`` or
  ``"slam"`` model), or None: a sweep that compares planners of different papers runs them all
  on the project's default."""
  from jaxplore.planners.base import planner_brings
  if planner is None:
    return None
  found = {planner_brings(name, what)
           for name in ([planner] if isinstance(planner, str) else planner)}
  return found.pop() if len(found) == 1 else None


_planners_preset = functools.partial(_planners_bring, what="preset")
_planners_slam = functools.partial(_planners_bring, what="slam")


def sweep(grid=None, seeds=None, world=None, planner=None, out=None, quiet=False, *, random=None,
          samples=None, random_seed=None, worlds=None, planners=None, chunk_size=None, resume=None,
          config=None, progress=True, devices=None, distributed=False, **run_kwargs) -> SweepResult:
  """Runs every world × planner × setting × seed in chunks; returns (and writes) the tables.

  Args:
    grid: parameter name -> list of values; names are simulator parameters, or a planner's
      weights or static settings (e.g. ``{"alpha": [1.0, 1.5], "k1": [0, 0.2]}``). Every
      combination is a setting. A name that a planner does not have is not swept for that
      planner. Static names (``r_e``, a planner's settings) run each value as a compile group;
      a word-valued setting takes words (``{"region": ["visible", "disc"]}`` for li2020).
    seeds: seeds per setting (``range(seeds)``) or a list of seeds (default 8); seed ``s`` starts
      at the same pose in every setting (its key is ``PRNGKey(s)``).
    world: a world (name, map YAML path or GridMap) or a list of worlds (default: ``jaxplore
      run``'s).
    planner: a planner name or a list of them (default: ``jaxplore run``'s).
    out: results folder: the schedule, the chunks as they finish, then the final tables and
      figures.
    quiet: print no summary or per-setting table (warnings and the progress bar still show).
    random: random search: name -> ``{"low", "high", "log"}`` (or ``(low, high[, "log"])`` or
      ``"LOW:HIGH[:log]"``); ``samples`` points drawn with ``random_seed`` (combined with every
      grid combination).
    worlds, planners: aliases of ``world`` and ``planner`` for lists.
    chunk_size: robot-episodes per chunk (default: at most 256, as many as fit in memory).
    resume: a sweep folder to finish: everything comes from its schedule (no other setting).
    config: a TOML file (or the dict :func:`load_config` made of one) with the same keys as the
      command line (explicit arguments win).
    progress: a progress bar over robot-episodes with an ETA.
    devices: local devices to shard each chunk over (default: all).
    distributed: call ``jax.distributed.initialize()`` and split the chunks over processes.
    **run_kwargs: the run settings every row shares, :class:`jaxplore.runspec.RunSpec`'s fields
      other than world, planner, robots and seeds: ``preset``, ``res``, ``start``,
      ``max_steps``, ``replan_every``, ``path_capacity``, ``plan_window``, ``pose_noise``,
      ``params``, ``planner_params``, ``rate_interval``, ``chunk_epochs``.

  Returns:
    A :class:`SweepResult`.

  Raises:
    ConfigError: a bad setting (before any compute), a folder holding another sweep, a missing
      or corrupt schedule on resume, or a sweep in which one robot does not fit in memory.
  """
  unknown = set(run_kwargs) - set(RUN_KEYS)
  if unknown:
    raise ConfigError(f"sweep got unknown setting(s) {sorted(unknown)}; valid: "
                      f"{', '.join(RUN_KEYS)}")
  if world is not None and worlds is not None:
    raise ConfigError("give either world or worlds, not both")
  if planner is not None and planners is not None:
    raise ConfigError("give either planner or planners, not both")
  world = worlds if world is None else world
  planner = planners if planner is None else planner
  asked = dict(grid=grid, seeds=seeds, world=world, planner=planner, random=random, samples=samples,
               random_seed=random_seed, chunk_size=chunk_size, config=config, **run_kwargs)
  if resume is not None:
    given = sorted(k for k, v in asked.items() if v is not None)
    if given:
      raise ConfigError(f"--resume takes every setting from the sweep's schedule; do not give "
                        f"{', '.join(given)}")
    if out is not None and Path(out).resolve() != Path(resume).resolve():
      raise ConfigError(f"--resume {resume} writes into that folder; do not give --out {out}")
    out = Path(resume)
  explicit = dict(grid=grid, seeds=seeds, world=world, planner=planner, random=random,
                  samples=samples, random_seed=random_seed, chunk_size=chunk_size, devices=devices,
                  out=out, **run_kwargs)
  if config is not None:
    explicit = merge_settings(config if isinstance(config, dict) else load_config(config), explicit)
  out = None if explicit["out"] is None else Path(explicit["out"])
  if out is not None:
    check_writable(out, "--resume" if resume is not None else "--out")

  process, n_processes = execute.distributed() if distributed else (0, 1)
  if n_processes > 1 and out is None:
    raise ConfigError("a multi-process sweep needs --out on a filesystem every process can write")
  with contextlib.ExitStack() as held:
    n_dev = driver.local_devices(explicit["devices"])
    grids: dict = {}

    # Process 0 checks the folder and writes the schedule; the others (several hosts) read it
    # after a barrier, so that every process runs the same chunks even if their memory differs.
    made, resolved = None, None
    if resume is not None:
      if out.is_dir():
        held.enter_context(_folder_lock(out, process))
      made = read_schedule(out)
      # The first collective sets up the processes' communication, which waits only ~30 s for
      # all of them: hold it now, while they are in step, not after chunks of unequal length.
      execute.barrier("jaxplore-sweep-resume", n_processes)
    else:
      shared = {k: explicit.get(k) for k in RUN_KEYS}
      shared["preset"] = shared["preset"] or _planners_preset(explicit["planner"])
      swept = set(explicit["grid"] or {}) | set(explicit["random"] or {})
      if shared["slam"] is None and "slam" not in swept | set(shared["params"] or {}):
        shared["slam"] = _planners_slam(explicit["planner"])
      # a name in --set may be any of the sweep's planners' (the base spec names none of them)
      shared["params"], shared["planner_params"] = route_settings(
          shared["params"], shared["planner_params"], explicit["planner"] or RunSpec.planner)
      base = RunSpec.create(**shared)
      spec = make_spec(explicit["grid"], explicit["random"], explicit["samples"],
                       explicit["random_seed"], explicit["seeds"], explicit["world"],
                       explicit["planner"], base, grids)
      held.enter_context(_folder_lock(out, process))  # one sweep at a time in a folder
      if process == 0:
        made = _existing_schedule(out, spec, quiet)
        if made is None:
          made, resolved = schedules.make_schedule(spec, out, grids, explicit["chunk_size"], n_dev)
          if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            for path, gridmap in grids.items():
              results.write_world(out / path, gridmap)
            results.write_json(out / SCHEDULE_FILE, made.to_json())
      execute.barrier("jaxplore-sweep-schedule", n_processes)
      if process != 0:
        made = read_schedule(out)
        if made.spec.to_json() != spec.to_json():
          raise ConfigError(f"process {process} was given another sweep than process 0 "
                            f"({first_difference(made.spec.to_json(), spec.to_json())})")
    assert made is not None  # every branch above reads or makes the schedule
    if resolved is None:
      resolved = schedules.resolve_schedule(made, out, grids, n_dev)
    group_runs = [execute.GroupRun(g, r) for g, r in zip(made.groups, resolved)]
    tables, timing = execute.execute(made, group_runs, out, n_dev, progress, process, n_processes)
    execute.barrier("jaxplore-sweep-chunks", n_processes)

    # Assemble from the chunk files (or memory): the same bytes whether or not the sweep was
    # resumed.
    episodes, curves = assemble.read_tables(made, out, tables)
    described = assemble.describe(made, group_runs, episodes, n_processes)
    result = SweepResult(episodes, curves, described, timing, out)
    if out is not None and process == 0:
      assemble.write_final(out, made, described, timing, episodes, curves)
    if not quiet and len(episodes):
      print(results.summary_table(episodes))
      print(sweep_table(episodes, assemble.figure_names(episodes, made.names)))
    return result


LOCK_FILE = ".jaxplore-sweep.lock"


@contextlib.contextmanager
def _folder_lock(out: Path | None, process: int):
  """Holds an exclusive ``fcntl.flock`` on ``out``'s lock file (process ``process`` of a sweep)
  for the block; refuses, before touching anything, a folder another sweep holds (two sweeps
  would delete each other's temporaries and write each other's chunks)."""
  if out is None:
    yield
    return
  if out.exists() and not out.is_dir():
    raise ConfigError(f"--out {str(out)!r} is a file, not a folder; choose another --out")
  import fcntl
  out.mkdir(parents=True, exist_ok=True)
  path = out / (LOCK_FILE if process == 0 else f"{LOCK_FILE}.{process}")
  with open(path, "a") as handle:
    try:
      fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
      raise ConfigError(f"{out} is in use by another jaxplore sweep running now (it holds "
                        f"{path.name}); wait for it to finish, or choose another --out") from None
    try:
      yield
    finally:
      fcntl.flock(handle, fcntl.LOCK_UN)


def _existing_schedule(out: Path | None, spec: SweepSpec, quiet: bool):
  """The schedule already in ``out`` if it is this sweep's; refuses a folder holding anything
  else."""
  if out is None:
    return None
  if out.exists() and not out.is_dir():
    raise ConfigError(f"--out {str(out)!r} is a file, not a folder; choose another --out")
  if schedules.schedule_path(out) is not None:
    existing = read_schedule(out, action="reuse")
    theirs, mine = existing.spec.to_json(), spec.to_json()
    if theirs != mine:
      raise ConfigError(f"{out} already holds a different sweep "
                        f"({first_difference(theirs, mine)}); finish it with "
                        f"`jaxplore sweep --resume {out}` or choose another --out")
    if not quiet:
      print(f"jaxplore: {out} holds this same sweep: finished chunks are kept", file=sys.stderr)
    return existing
  if out.exists() and any(not p.name.endswith(".tmp") and not p.name.startswith(LOCK_FILE)
                          for p in out.iterdir()):
    raise ConfigError(f"{out} is not empty and holds no sweep schedule; choose another --out "
                      f"(or --resume DIR for an interrupted sweep)")
  return None


__all__ = ["LEGACY_FILE", "LOCK_FILE", "MEMORY_FRACTION", "RUN_KEYS", "SCHEDULE_FILE",
           "SweepResult",
           "fit_chunk", "load_config", "make_spec", "parse_random_spec", "read_schedule", "sweep",
           "sweep_table"]
