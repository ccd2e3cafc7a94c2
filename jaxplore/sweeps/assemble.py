"""A sweep's final tables, ``config.json`` and figures, assembled from its chunks.

The tables are read back from the chunk files (or, without a folder, from memory) in the
schedule's order, so a resumed sweep gives the same bytes as an uninterrupted one.
"""

from __future__ import annotations

import platform
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from jaxplore import __version__, metrics, results
from jaxplore.config import ConfigError
from jaxplore.sweeps.execute import GroupRun
from jaxplore.sweeps.schedule import Schedule, chunk_paths


def figure_names(episodes: pd.DataFrame, names) -> list[str]:
  """What a setting is in the figure and table: world and planner when they vary, then the names."""
  keys = [c for c in ("world", "planner") if episodes[c].nunique() > 1]
  keys += [n for n in names]
  return keys or ["planner"]


def read_tables(schedule: Schedule, out: Path | None,
                tables: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
  """(episodes, curves) of every row, in the schedule's order."""
  parts_e, parts_c = [], []
  for chunk in schedule.chunks():
    if out is not None:
      paths = chunk_paths(out, chunk.index)
      if not paths["episodes"].exists():
        raise ConfigError(f"chunk {chunk.index} of {out} is missing (did a process of a "
                          f"multi-process sweep fail?); run jaxplore sweep --resume {out}")
      parts_e.append(pd.read_parquet(paths["episodes"]))
      parts_c.append(pd.read_parquet(paths["curves"]))
    else:
      parts_e.append(tables[chunk.index][0])
      parts_c.append(tables[chunk.index][1])
  return pd.concat(parts_e, ignore_index=True), pd.concat(parts_c, ignore_index=True)


def group_config(group_run: GroupRun) -> dict:
  """A group's resolved settings for ``config.json``: its world, rows, chunks, static config,
  and the values it did not sweep."""
  group, described = group_run.group, group_run.resolved.describe()
  swept = set(group.names)
  settings = described["planner_settings"]
  return {
      "world": described["world"], "planner": group.planner, "swept": list(group.names),
      "rows": [group.rows[0].row, group.rows[-1].row + 1],
      "chunk_size": group.chunk_size, "chunk_epochs": group.chunk_epochs,
      "sim_config": described["sim_config"],
      "fixed_params": {k: v for k, v in described["params"].items() if k not in swept},
      "fixed_planner_params": {k: v for k, v in described["planner_params"].items()
                               if k not in swept},
      "fixed_planner_settings": (None if settings is None
                                 else {k: v for k, v in settings.items() if k not in swept}),
  }


def describe(schedule: Schedule, group_runs: list[GroupRun], episodes: pd.DataFrame,
             n_processes: int) -> dict:
  """A sweep's ``config.json``: what it swept, its shared settings, every group, versions."""
  import jax
  spec = schedule.spec.to_json()
  return {
      "sweep": {"names": schedule.names, "grid": spec["grid"], "random": spec["random"],
                "samples": spec["samples"], "random_seed": spec["random_seed"],
                "seeds": spec["seeds"], "worlds": spec["worlds"], "planners": spec["planners"],
                "rows": schedule.rows, "chunks": schedule.n_chunks,
                "figure_names": figure_names(episodes, schedule.names)},
      "run": spec["run"],
      "groups": [group_config(g) for g in group_runs],
      "jaxplore_version": __version__, "jax_version": jax.__version__,
      "numpy_version": np.__version__,
      "python": platform.python_version(), "devices": [str(d) for d in jax.local_devices()],
      "processes": n_processes,
  }


def write_final(out: Path, schedule: Schedule, config: dict, timing: dict, episodes: pd.DataFrame,
                curves: pd.DataFrame):
  """The sweep folder's config.json, timing.json, tables, maps.npz (and memory.npz) of its first
  group, and figures."""
  from jaxplore import plot
  results.write_json(out / "config.json", config)
  results.write_json(out / "timing.json", timing)
  results.write_table(out / "episodes.parquet", episodes)
  results.write_table(out / "curves.parquet", curves)
  first = chunk_paths(out, schedule.groups[0].first_chunk)
  for kind, name in (("maps", "maps.npz"), ("memory", "memory.npz")):
    if first[kind].exists():
      results.atomic_write(out / name, lambda p, src=first[kind]: shutil.copyfile(src, p))
  plot.run_figures(out)  # map, curves and (config.json naming a sweep) sweep.png


def sweep_table(episodes: pd.DataFrame, names) -> str:
  """Mean ± std of the headline metrics per setting."""
  episodes = episodes.copy()
  for name in names:  # NaN (a weight the planner lacks) is a setting of its own, not dropped
    if episodes[name].isna().any():
      episodes[name] = episodes[name].astype(object).where(episodes[name].notna(), "-")
  table = metrics.summarise(episodes, names, ["E_r", "Std_E_r", "distance_m", "coverage", "time_s"])
  cols = list(names) + [c for c in table.columns if c.endswith("_mean") or c.endswith("_std")]
  return table[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}")


__all__ = ["describe", "figure_names", "group_config", "read_tables", "sweep_table", "write_final"]
