"""Running a sweep's chunks, on this host or split over several.

Each chunk is reset, advanced until every robot is done (:func:`jaxplore.driver.drive`, the loop
of ``jaxplore run``) and turned into tables; a group compiles once, for its first chunk run
here. With a folder, every finished chunk is written at once (curves first, then the episodes
table, which marks the chunk done), so an interruption loses at most the chunks in flight.

Several hosts: with ``jax.distributed`` initialised, process ``i`` of ``n`` runs the chunks
``k`` with ``k % n == i`` on its own devices, writing into the same folder (a filesystem shared
by every host); the caller assembles the tables after :func:`barrier`. Tested with two
processes on one host (``tests/test_distributed.py``: the loopback address, one CPU device each).
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jaxplore import driver, interrupts, memory, results
from jaxplore.errors import ConfigError
from jaxplore.resolve import Resolved
from jaxplore.sweeps.schedule import Chunk, Group, Schedule, chunk_paths


@dataclasses.dataclass
class GroupRun:
  """A group of the schedule, resolved, and its compiled chunk function once compiled."""

  group: Group
  resolved: Resolved
  compiled: object = None


def run_chunk(group_run: GroupRun, chunk: Chunk, n_dev: int, tally: dict, times: dict):
  """One chunk: reset, advance until every robot is done, and (episodes, curves, state) of its
  rows (the padding dropped; ``robot`` numbers the rows across the sweep)."""
  group, resolved = group_run.group, group_run.resolved
  config, world = resolved.config, resolved.world
  batch = resolved.batch(chunk.batch_rows())
  t0 = time.perf_counter()
  state = driver.reset(config, world, batch)
  times["reset_s"] += time.perf_counter() - t0
  if group_run.compiled is None:
    t0 = time.perf_counter()
    with driver.count_compiles(tally):
      compiled = driver.compile_advance(config, group.chunk_epochs, n_dev, world, batch.params,
                                        state)
    times["compile_s"] += time.perf_counter() - t0
    memory.check_compiled(compiled, config, group.chunk_size, n_dev)
    group_run.compiled = compiled
  interrupts.check("interrupted while compiling")
  rollout = driver.drive(group_run.compiled, world, batch.params, state, config.max_steps)
  times["run_s"] += rollout.run_s
  episodes, curves = results.tables(config, resolved.grid, world, rollout.state, rollout.records,
                                    resolved.spec.rate_interval)
  n = len(chunk.rows)
  row_ids = np.asarray([r.row for r in chunk.rows] + [chunk.rows[-1].row] * (group.chunk_size - n),
                       np.int64)
  episodes = episodes.iloc[:n].copy()
  curves = curves[curves.robot < n].copy()
  episodes["robot"] = row_ids[episodes.robot.to_numpy()]
  curves["robot"] = row_ids[curves.robot.to_numpy()]
  return episodes, curves.reset_index(drop=True), rollout.state


def label_episodes(episodes: pd.DataFrame, group_run: GroupRun, chunk: Chunk,
                   all_names) -> pd.DataFrame:
  """The chunk's episodes with ``world``, ``planner``, ``seed`` and one column per swept name
  (NaN where the group's planner does not have it; a column of words holds strings)."""
  group = group_run.group
  episodes.insert(0, "world", group_run.resolved.grid.name)
  episodes.insert(1, "planner", group.planner)
  episodes.insert(2, "seed", np.asarray([r.seed for r in chunk.rows], np.int64))
  for k, name in enumerate(all_names):
    if name in group.names:
      j = group.names.index(name)
      values = [r.values[j] for r in chunk.rows]
      column = np.asarray(values, object if isinstance(values[0], str) else np.float64)
    else:
      column = np.full(len(chunk.rows), np.nan)
    episodes.insert(3 + k, name, column)
  return episodes


def is_done(out: Path, chunk: Chunk) -> bool:
  """Whether chunk's tables are in ``out``: both files there, readable Parquet, one episode per
  row of the chunk."""
  return chunk_damage(out, chunk) is None and chunk_paths(out, chunk.index)["episodes"].exists()


def chunk_damage(out: Path, chunk: Chunk) -> str | None:
  """What is wrong with a chunk's files (one missing, empty or not Parquet, a wrong row count),
  or None when they are whole or were never written (no episodes file: not done)."""
  import pyarrow.parquet as pq
  paths = chunk_paths(out, chunk.index)
  if not paths["episodes"].exists():
    return None
  for kind in ("episodes", "curves"):
    path = paths[kind]
    if not path.exists():
      return f"{path.name} is missing"
    try:
      rows = pq.read_metadata(path).num_rows
    except Exception as err:  # pyarrow's errors for a torn or empty file vary by version
      return f"{path.name} is unreadable ({type(err).__name__}: {err})"
    if kind == "episodes" and rows != len(chunk.rows):
      return f"{path.name} holds {rows} episodes, not {len(chunk.rows)}"
  return None


def execute(schedule: Schedule, group_runs: list[GroupRun], out: Path | None, n_dev: int,
            progress: bool, process: int = 0, n_processes: int = 1):
  """Runs this process's chunks that are not done yet.

  Returns:
    (tables, timing): ``tables`` maps the chunk number to its (episodes, curves) when there is
    no folder (else the chunk files hold them); ``timing`` this session's seconds and counts.
  Raises:
    KeyboardInterrupt: with the command that finishes the sweep (finished chunks are kept).
  """
  if out is not None:
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    for stray in (out / "chunks").glob("chunk_*.tmp"):
      # A write cut short by an interruption; each process clears its own chunks' only, since
      # another process may be writing one of its own right now.
      if int(stray.name[len("chunk_"):].split(".")[0]) % n_processes == process:
        stray.unlink(missing_ok=True)
  names = schedule.names
  work, done_rows = [], 0
  for group_run in group_runs:
    for chunk in group_run.group.chunks():
      damage = None if out is None else chunk_damage(out, chunk)
      if damage is not None and chunk.index % n_processes == process:
        print(f"jaxplore: chunk {chunk.index} of {out} is damaged ({damage}): computing it again",
              file=sys.stderr)
        assert out is not None  # damage is only found in a sweep folder
        for path in chunk_paths(out, chunk.index).values():
          path.unlink(missing_ok=True)
      if out is not None and is_done(out, chunk):
        done_rows += len(chunk.rows)
      elif chunk.index % n_processes == process:
        work.append((group_run, chunk))
  tally: dict[str, Any]
  tally, times = {}, {"reset_s": 0.0, "compile_s": 0.0, "run_s": 0.0}
  tables = {}
  bar = None
  if progress:
    from tqdm.auto import tqdm
    # smoothing=0: the ETA comes from the mean rate since the start, compile time taken out below
    bar = tqdm(total=schedule.rows, initial=done_rows, unit="episode", desc="sweep",
               dynamic_ncols=True, smoothing=0)
  t_start = time.perf_counter()
  ran_rows, sharded_over = 0, 0
  try:
    for i, (group_run, chunk) in enumerate(work):
      group = group_run.group
      dev = math.gcd(n_dev, group.chunk_size)
      sharded_over = max(sharded_over, dev)
      compiling = group_run.compiled is None
      if compiling and bar is not None:
        bar.set_description(f"sweep (compiling {group_run.resolved.grid.name}, {group.planner})")
      before = times["compile_s"] + times["reset_s"]
      episodes, curves, state = run_chunk(group_run, chunk, dev, tally, times)
      if compiling and bar is not None:
        bar.start_t += times["compile_s"] + times["reset_s"] - before  # no compile in the ETA
        bar.set_description("sweep")
      episodes = label_episodes(episodes, group_run, chunk, names)
      if out is not None:
        paths = chunk_paths(out, chunk.index)
        if chunk.index == group.first_chunk:
          results.write_maps(paths["maps"], group_run.resolved.grid,
                             state.logodds[:len(chunk.rows)])
          results.write_memory(paths["memory"], getattr(state, "memory", None),
                               min(results.SHOWN_ROBOTS, len(chunk.rows)))
        results.write_table(paths["curves"], curves)
        results.write_table(paths["episodes"], episodes)  # marks the chunk done
      else:
        tables[chunk.index] = (episodes, curves)
      ran_rows += len(chunk.rows)
      if bar is not None:
        bar.update(len(chunk.rows))
        bar.set_postfix(chunk=f"{i + 1}/{len(work)}", compiles=tally.get("count", 0))
      interrupts.check("interrupted")
  except KeyboardInterrupt:
    if bar is not None:
      bar.close()
    where = f"; finished chunks are in {out}: jaxplore sweep --resume {out}" if out else ""
    raise KeyboardInterrupt(f"sweep interrupted{where}") from None
  if bar is not None:
    bar.close()
  wall = time.perf_counter() - t_start
  timing = {"compile_s": times["compile_s"], "compiles": tally.get("count", 0),
            "xla_compile_s": tally.get("seconds", 0.0), "reset_s": times["reset_s"],
            "run_s": times["run_s"], "wall_s": wall, "chunks": schedule.n_chunks,
            "chunks_run": len(work), "chunks_skipped": schedule.n_chunks - len(work),
            "robot_episodes": schedule.rows, "robot_episodes_run": ran_rows,
            "sharded_over": sharded_over,
            "robot_episodes_per_hour": (ran_rows / wall * 3600 if wall > 0 and ran_rows
                                        else float("nan"))}
  return tables, timing


def distributed() -> tuple[int, int]:
  """(process index, process count) after ``jax.distributed.initialize()`` from the environment.

  ``JAX_COORDINATOR_ADDRESS`` is read by JAX; ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` by
  jaxplore (on SLURM, Open MPI, Kubernetes and Cloud TPU JAX detects all three itself).
  """
  import jax
  if not jax.distributed.is_initialized():
    kwargs: dict[str, Any] = {}
    if os.environ.get("JAX_NUM_PROCESSES"):
      kwargs["num_processes"] = int(os.environ["JAX_NUM_PROCESSES"])
    if os.environ.get("JAX_PROCESS_ID"):
      kwargs["process_id"] = int(os.environ["JAX_PROCESS_ID"])
    try:
      jax.distributed.initialize(**kwargs)
    except ValueError as err:  # no coordinator in the environment, nor a cluster JAX detects
      raise ConfigError(f"--distributed: {err} Set JAX_COORDINATOR_ADDRESS=host:port, "
                        "JAX_NUM_PROCESSES and JAX_PROCESS_ID in every process (SLURM, Open MPI, "
                        "Kubernetes and Cloud TPU set them for JAX), or run without "
                        "--distributed") from None
  return jax.process_index(), jax.process_count()


def barrier(name: str, n_processes: int):
  """Waits for every process of a multi-process sweep (nothing to wait for with one)."""
  if n_processes > 1:
    from jax.experimental import multihost_utils
    multihost_utils.sync_global_devices(name)


__all__ = ["GroupRun", "barrier", "distributed", "execute", "is_done", "label_episodes",
           "run_chunk"]
