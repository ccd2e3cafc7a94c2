"""Results: the tables of a batch, and the files of a results folder (written and read).

Every file is written atomically (write, flush to disk, rename over the target), so a reader, or
a sweep resumed after ``kill -9``, sees the old file or the whole new one, never a torn one.

A results folder of ``jaxplore run --out`` holds ``config.json``, ``timing.json``,
``episodes.parquet`` (one row per robot), ``curves.parquet`` (one row per robot and step),
``maps.npz`` (the truth and the final belief of the first robots), ``memory.npz`` (the first
robots' planner memory, when the planner keeps one) and figures; a sweep folder holds the same
tables and files for all its rows, plus its schedule and chunk files.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from jaxplore import metrics, sim
from jaxplore.config import ConfigError, SimConfig
from jaxplore.errors import OutputError, check_writable
from jaxplore.maps import GridMap

SHOWN_ROBOTS = 4  # robots whose final belief (and planner memory) a results folder keeps
RESULT_FILES = ("config.json", "episodes.parquet", "curves.parquet")
SWEEP_MARKERS = ("sweep_schedule.json", "sweep_plan.json", "chunks")  # what makes a sweep folder


# --------------------------------------------------------------------------- tables


def tables(config: SimConfig, grid: GridMap, world: sim.World, state, records,
           rate_interval: float) -> tuple[pd.DataFrame, pd.DataFrame]:
  """(episodes, curves) DataFrames of a batch from its final state and records [T, B].

  ``curves`` has one row per robot and step up to the robot's done step; ``episodes`` one row per
  robot: its termination reason, the episode metrics of :func:`jaxplore.metrics.episode_row`,
  its idle steps, the map quality of its final belief and, with pose graphs, their connectivity
  (:func:`jaxplore.metrics.map_and_graph_row`).
  """
  robots = state.done.shape[0]
  n_reach = float(world.n_reachable)
  if records is None:
    curves = pd.DataFrame(columns=["robot", "step"])
  else:
    done = records.done
    ever = done.any(axis=0)
    last = np.where(ever, done.argmax(axis=0), done.shape[0] - 1)
    steps = np.arange(done.shape[0])
    keep = steps[:, None] <= last[None, :]
    t_idx, r_idx = np.nonzero(keep)
    order = np.lexsort((t_idx, r_idx))
    t_idx, r_idx = t_idx[order], r_idx[order]
    curves = pd.DataFrame({"robot": r_idx.astype(np.int32), "step": (t_idx + 1).astype(np.int32)})
    for name in ("time", "distance", "entropy", "coverage", "det_cov", "pose_error", "x", "y",
                 "graph_nodes", "graph_edges", "dopt_mean", "loop_closures", "false_closures",
                 "near_links", "revoked"):
      if getattr(records, name) is not None:  # the pose graph's columns only with a graph
        curves[name] = getattr(records, name)[t_idx, r_idx].astype(np.float64)
  initial = float(config.height * config.width * math.log(2.0))
  rows = []
  groups = dict(tuple(curves.groupby("robot"))) if len(curves) else {}
  for b in range(robots):
    curve = groups.get(b)
    row = {"robot": b, "reason": sim.REASONS[int(state.reason[b])]}
    if curve is not None and len(curve):
      row.update(metrics.episode_row(curve, initial, grid.res, n_reach, rate_interval))
    row["idle_steps"] = int(state.idle_steps[b])
    row["collisions"] = int(state.collisions[b])
    graph = None if state.graph is None else jax.tree.map(lambda x, b=b: x[b], state.graph)
    row.update(metrics.map_and_graph_row(
        state.logodds[b], grid.occupied, graph,
        None if curve is None or "dopt_mean" not in curve else curve.dopt_mean.to_numpy()))
    rows.append(row)
  return pd.DataFrame(rows), curves


# A robot whose keyframes are this far off the truth (RMS, after alignment) has a map that no
# longer matches the world: walls drawn metres off, frontiers where there are none.
LOST_TRACK_ATE_M = 1.0


def summary_table(episodes: pd.DataFrame) -> str:
  """A short text table: reasons, and mean ± std of the headline metrics, and a warning when the
  pose graph's loop list filled up or a robot's SLAM lost track (ATE over
  :data:`LOST_TRACK_ATE_M`)."""
  lines = []
  reasons = episodes["reason"].value_counts().to_dict()
  lines.append("termination: " + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())))
  for col, unit in (("time_s", "s"), ("distance_m", "m"), ("coverage", ""), ("coverage_m2", "m²"),
                    ("entropy_reduction", "nats"), ("E_r", "nats/m"), ("Std_E_r", "nats/m"),
                    ("t90_s", "s"), ("t99_s", "s"),
                    # with the scan_matching SLAM model only
                    ("ate_m", "m"), ("loop_closures", ""), ("false_closures", ""),
                    ("near_links", ""), ("revoked", "")):
    if col in episodes:
      v = episodes[col].astype(float)
      lines.append(f"  {col:<18} {v.mean():12.4g} ± {v.std():<10.4g} {unit}  "
                   f"(min {v.min():.4g}, max {v.max():.4g})")
  dropped = episodes["loops_dropped"] if "loops_dropped" in episodes else pd.Series(dtype=float)
  if (dropped > 0).any():
    lines.append(f"warning: the pose graph's loop list filled up for {int((dropped > 0).sum())} of "
                 f"{len(dropped)} robots: {dropped.mean():.4g} loop closures dropped a robot on "
                 f"average (max {int(dropped.max())}), never added to the graph (a larger "
                 f"--graph-loops keeps them)")
  ate = episodes["ate_m"].astype(float) if "ate_m" in episodes else pd.Series(dtype=float)
  lost = ate > LOST_TRACK_ATE_M
  if lost.any():
    lines.append(f"warning: the SLAM lost track on {int(lost.sum())} of {len(ate)} robots (ATE "
                 f"above {LOST_TRACK_ATE_M:g} m, worst {ate.max():.3g} m): their maps no longer "
                 f"match the world, so their coverage and distance say little of the planner "
                 f"(docs/slam.md: cells coarser than 0.2 m, false loop closures on repeated "
                 f"layouts)")
  return "\n".join(lines)


# --------------------------------------------------------------------------- writing


def atomic_write(path: Path, write) -> Path:
  """``write(tmp)``, flush it to disk, then rename over ``path``: a reader sees the old file or
  the whole new one, never a torn one."""
  path = Path(path)
  tmp = path.with_name(path.name + ".tmp")
  write(tmp)
  with open(tmp, "rb+") as f:
    os.fsync(f.fileno())
  os.replace(tmp, path)
  return path


def write_json(path: Path, obj) -> Path:
  return atomic_write(path, lambda p: p.write_text(json.dumps(obj, indent=2)))


def write_table(path: Path, frame: pd.DataFrame) -> Path:
  return atomic_write(path, lambda p: frame.to_parquet(p, index=False))


def write_npz(path: Path, **arrays) -> Path:
  def write(tmp):
    with open(tmp, "wb") as f:
      np.savez_compressed(f, **arrays)
  return atomic_write(path, write)


def write_maps(path: Path, grid: GridMap, logodds, shown: int = SHOWN_ROBOTS) -> Path:
  """``maps.npz``: the truth (``occupied``, ``res``, ``origin``) and the final log-odds belief of
  the first ``shown`` robots (f16[R, H, W])."""
  return write_npz(path, occupied=grid.occupied, res=grid.res, origin=np.asarray(grid.origin),
                   logodds=np.asarray(logodds[:shown]).astype(np.float16))


def memory_arrays(memory, shown: int = SHOWN_ROBOTS) -> dict[str, np.ndarray]:
  """The first ``shown`` robots' slices of every leaf of a batched memory pytree, named by its
  path in the tree (``"graph.nodes"``); empty for an empty tree (or None)."""
  if memory is None:
    return {}
  arrays = {}
  for path, leaf in jax.tree_util.tree_flatten_with_path(memory)[0]:
    parts = []
    for key in path:
      for attr in ("key", "name", "idx"):
        if hasattr(key, attr):
          parts.append(str(getattr(key, attr)))
          break
    arrays[".".join(parts) or "memory"] = np.asarray(leaf)[:shown]
  return arrays


def write_memory(path: Path, memory, shown: int = SHOWN_ROBOTS) -> Path | None:
  """``memory.npz`` with :func:`memory_arrays` of a batched planner memory; nothing (None) for a
  planner without memory."""
  arrays = memory_arrays(memory, shown)
  return write_npz(path, **arrays) if arrays else None


def write_world(path: Path, grid: GridMap) -> Path:
  """A truth map to an ``.npz`` that :func:`read_world` reads back (a sweep's GridMap worlds)."""
  path.parent.mkdir(parents=True, exist_ok=True)
  return write_npz(path, occupied=grid.occupied, res=grid.res, origin=np.asarray(grid.origin),
                   name=grid.name)


def read_world(path: Path) -> GridMap:
  with np.load(path) as f:
    return GridMap(f["occupied"], float(f["res"]), tuple(f["origin"].tolist()), str(f["name"]))


def read_maps_truth(path: Path, name: str = "map") -> GridMap:
  """The truth map stored in a ``maps.npz``."""
  with np.load(path) as stored:
    return GridMap(stored["occupied"], float(stored["res"]),
                   tuple(np.asarray(stored["origin"]).tolist()), name)


def is_sweep_folder(folder: Path) -> bool:
  return any((Path(folder) / marker).exists() for marker in SWEEP_MARKERS)


def check_run_out(out) -> Path | None:
  """``jaxplore run --out``: refused before any compute unless it is a new or empty folder, or
  the results folder of an earlier ``jaxplore run`` (whose files are replaced)."""
  if out is None:
    return None
  out = Path(out)
  if out.exists() and not out.is_dir():
    raise ConfigError(f"--out {str(out)!r} is a file, not a folder; choose another --out")
  check_writable(out, "--out")
  if out.is_dir():
    if is_sweep_folder(out):
      raise ConfigError(f"--out {str(out)!r} holds a sweep (jaxplore sweep --out); a run would mix "
                        f"its files into the sweep's; choose another --out")
    entries = [p for p in out.iterdir() if not p.name.endswith(".tmp")]
    if entries and not _is_run_folder(out):
      raise ConfigError(f"--out {str(out)!r} is not empty and holds no jaxplore run results; "
                        f"choose another --out")
  return out


def _is_run_folder(folder: Path) -> bool:
  try:
    config = json.loads((folder / "config.json").read_text())
  except (OSError, ValueError):
    return False
  return isinstance(config, dict) and "sim_config" in config and "sweep" not in config


def write_run(out: Path, config: dict, timing: dict, episodes: pd.DataFrame, curves: pd.DataFrame,
              grid: GridMap, state) -> Path:
  """Writes a run's results folder: config.json, timing.json, the tables, maps.npz, memory.npz
  (when the planner keeps a memory) and the figures."""
  from jaxplore import plot
  out = Path(out)

  def memory():
    if write_memory(out / "memory.npz", getattr(state, "memory", None)) is None:
      (out / "memory.npz").unlink(missing_ok=True)  # left by an earlier run with another planner

  steps = (("the folder", lambda: out.mkdir(parents=True, exist_ok=True)),
           ("config.json", lambda: write_json(out / "config.json", config)),
           ("timing.json", lambda: write_json(out / "timing.json", timing)),
           ("episodes.parquet", lambda: write_table(out / "episodes.parquet", episodes)),
           ("curves.parquet", lambda: write_table(out / "curves.parquet", curves)),
           ("maps.npz", lambda: write_maps(out / "maps.npz", grid, state.logodds)),
           ("memory.npz", memory), ("the figures", lambda: plot.run_figures(out)))
  for k, (name, write) in enumerate(steps):
    try:
      write()
    except OSError as err:
      done = ", ".join(n for n, _ in steps[1:k]) or "nothing"
      raise OutputError(f"could not write {name} in {str(out)!r} ({err.strerror or err}): "
                        f"written: {done}; missing: {', '.join(n for n, _ in steps[k:])}") from None
  return out


# --------------------------------------------------------------------------- reading


@dataclasses.dataclass
class Folder:
  """A finished results folder of ``jaxplore run`` or ``jaxplore sweep``."""

  path: Path
  config: dict
  episodes: pd.DataFrame
  curves: pd.DataFrame

  @property
  def is_sweep(self) -> bool:
    return is_sweep_folder(self.path)


def load_folder(folder) -> Folder:
  """Reads a results folder's config and tables.

  Raises:
    ConfigError: the folder, or one of its files, is missing or unreadable.
  """
  folder = Path(folder)
  if not folder.is_dir():
    raise ConfigError(f"run directory {str(folder)!r} does not exist")
  missing = [n for n in RESULT_FILES if not (folder / n).is_file()]
  if missing:
    raise ConfigError(f"{str(folder)!r} is not a finished results folder of `jaxplore run --out` "
                      f"or `jaxplore sweep --out`: {', '.join(missing)} missing")
  try:
    config = json.loads((folder / "config.json").read_text())
  except ValueError as err:
    raise ConfigError(f"{folder / 'config.json'} is not valid JSON ({err})") from None
  return Folder(folder, config, pd.read_parquet(folder / "episodes.parquet"),
                pd.read_parquet(folder / "curves.parquet"))


__all__ = ["Folder", "atomic_write", "check_run_out", "is_sweep_folder", "load_folder",
           "memory_arrays", "read_maps_truth", "read_world", "summary_table", "tables",
           "write_json", "write_maps", "write_memory", "write_npz", "write_run", "write_table",
           "write_world"]
