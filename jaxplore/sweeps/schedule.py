"""A sweep's schedule: its rows, grouped by compiled program, cut into chunks of equal shape.

Every row is one robot-episode (a world, a planner, the values of the swept names, a seed),
numbered across the whole sweep. Rows are grouped by (world, planner), because those fix the
shapes and the compiled program, and further by the values of every swept static setting
(:func:`jaxplore.runspec.is_static`, e.g. ``r_e``). Each group runs as chunks of
``chunk_size`` rows: the same shapes for every chunk (the last one is padded by repeating its
last row, and the padding is dropped), so one group compiles once.

The schedule is made before any compute and written first (``sweep_schedule.json``), so an
interrupted sweep resumes from it; the records here are typed, JSON only at the file edge.
Folders written before the schedule had its name hold ``sweep_plan.json`` in the same layout,
which :func:`read_schedule` also reads.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path
from typing import cast

import numpy as np

from jaxplore import __version__, driver, memory, sim
from jaxplore.config import ConfigError
from jaxplore.maps import GridMap, load_world
from jaxplore.planners import get_planner
from jaxplore.resolve import Resolved, config_difference, resolve
from jaxplore.results import read_world
from jaxplore.runspec import RunSpec, is_static, kind_of
from jaxplore.sweeps.settings import SweepSpec, WorldEntry, grid_value, random_samples

SCHEDULE_FILE = "sweep_schedule.json"
SCHEDULE_FORMAT = "jaxplore-sweep-schedule"
LEGACY_FILE, LEGACY_FORMAT = "sweep_plan.json", "jaxplore-sweep-plan"  # before the rename
SCHEDULE_VERSION = 1
MAX_AUTO_CHUNK = 256
# On a GPU or TPU (the lockstep strategy) a chunk's time grows far less than its size: fill the
# device (the memory guard shrinks a chunk that does not fit).
MAX_AUTO_CHUNK_ACCELERATOR = 4096


@dataclasses.dataclass(frozen=True)
class Row:
  """One robot-episode: its number in the sweep, its seed, the values of its group's names."""

  row: int
  seed: int
  values: tuple[float | str, ...]


@dataclasses.dataclass(frozen=True)
class Group:
  """Rows that share one compiled program, and how they run.

  Attributes:
    world: index into the spec's worlds. planner: its name.
    names: the swept names that apply to this planner (the order of each row's values).
    rows: the group's rows, numbered across the sweep.
    chunk_size: rows per chunk (the memory guard may have made it smaller than asked).
    chunk_epochs: planning rounds per compiled call. max_steps: the group's step budget.
    sim_config: the static config the group resolved to (checked again on resume).
    first_chunk: the sweep-wide number of the group's first chunk.
  """

  world: int
  planner: str
  names: tuple[str, ...]
  rows: tuple[Row, ...]
  chunk_size: int = 0
  chunk_epochs: int = 0
  max_steps: int | None = None
  sim_config: dict | None = None
  first_chunk: int = 0

  @property
  def n_chunks(self) -> int:
    return -(-len(self.rows) // self.chunk_size)

  def chunks(self) -> list[Chunk]:
    size = self.chunk_size
    return [Chunk(self.first_chunk + k, self, start, self.rows[start:start + size])
            for k, start in enumerate(range(0, len(self.rows), size))]

  def to_json(self) -> dict:
    return {"world": self.world, "planner": self.planner, "names": list(self.names),
            "rows": [{"row": r.row, "seed": r.seed, "values": list(r.values)} for r in self.rows],
            "chunk_size": self.chunk_size, "chunk_epochs": self.chunk_epochs,
            "max_steps": self.max_steps, "sim_config": self.sim_config,
            "first_chunk": self.first_chunk, "n_chunks": self.n_chunks}

  @classmethod
  def from_json(cls, data: dict) -> Group:
    return cls(world=int(data["world"]), planner=str(data["planner"]), names=tuple(data["names"]),
               rows=tuple(Row(int(r["row"]), int(r["seed"]),
                              tuple(grid_value(v) for v in r["values"])) for r in data["rows"]),
               chunk_size=int(data["chunk_size"]), chunk_epochs=int(data["chunk_epochs"]),
               max_steps=data.get("max_steps"), sim_config=data.get("sim_config"),
               first_chunk=int(data["first_chunk"]))


@dataclasses.dataclass(frozen=True)
class Chunk:
  """The rows one compiled call batch runs: ``group.rows[start:start + len(rows)]``."""

  index: int
  group: Group
  start: int
  rows: tuple[Row, ...]

  def batch_rows(self) -> list[int]:
    """Indices into the group's rows of the chunk's batch: its rows, then its last row again
    up to ``chunk_size`` (the padding, whose results are dropped)."""
    own = list(range(self.start, self.start + len(self.rows)))
    return own + [own[-1]] * (self.group.chunk_size - len(own))


@dataclasses.dataclass(frozen=True)
class Schedule:
  """The whole sweep: what was asked (``spec``), its groups, and the versions that made it."""

  spec: SweepSpec
  groups: tuple[Group, ...]
  chunk_size_requested: int | None = None
  jaxplore_version: str = __version__
  jax_version: str = ""

  @property
  def names(self) -> list[str]:
    return self.spec.names

  @property
  def n_chunks(self) -> int:
    return sum(g.n_chunks for g in self.groups)

  @property
  def rows(self) -> int:
    return sum(len(g.rows) for g in self.groups)

  def chunks(self) -> list[Chunk]:
    return [c for g in self.groups for c in g.chunks()]

  def to_json(self) -> dict:
    return {"format": SCHEDULE_FORMAT, "version": SCHEDULE_VERSION,
            "jaxplore_version": self.jaxplore_version, "jax_version": self.jax_version,
            "spec": self.spec.to_json(), "names": self.names,
            "chunk_size_requested": self.chunk_size_requested, "n_chunks": self.n_chunks,
            "rows": self.rows, "groups": [g.to_json() for g in self.groups]}

  @classmethod
  def from_json(cls, data: dict) -> Schedule:
    return cls(spec=SweepSpec.from_json(data["spec"]),
               groups=tuple(Group.from_json(g) for g in data["groups"]),
               chunk_size_requested=data.get("chunk_size_requested"),
               jaxplore_version=str(data.get("jaxplore_version")),
               jax_version=str(data.get("jax_version")))


# --------------------------------------------------------------------------- grouping


def _settings_of(spec: SweepSpec, planner: str, drawn) -> tuple[list[str], list[tuple]]:
  """The swept names that apply to ``planner`` and its list of distinct settings (in order)."""
  planner_spec = get_planner(planner)
  applies = lambda n: kind_of(n, planner_spec) is not None
  grid_names = [n for n in spec.grid if applies(n)]
  random_names = list(spec.random)
  keep = [k for k, n in enumerate(random_names) if applies(n)]
  combos = list(itertools.product(*(spec.grid[n] for n in grid_names)))
  points = list(dict.fromkeys(tuple(s[k] for k in keep) for s in drawn)) or [()]
  settings = [c + p for c in combos for p in points]
  return grid_names + [random_names[k] for k in keep], settings


# Host memory a sweep holds per robot-episode before its first chunk (its rows, their settings,
# the schedule and its JSON): a 1e6-episode grid held ~4 GB and wrote a 405 MB schedule.
ROW_BYTES = 4096


def count_rows(spec: SweepSpec) -> int:
  """Robot-episodes of a sweep, counted without listing them (a grid's size is a product)."""
  total = 0
  for planner in spec.planners:
    planner_spec = get_planner(planner)
    applies = [n for n in spec.grid if kind_of(n, planner_spec) is not None]
    random_applies = any(kind_of(n, planner_spec) is not None for n in spec.random)
    # make_spec: samples is an int whenever spec.random is not empty
    total += (math.prod(len(spec.grid[n]) for n in applies)
              * (cast(int, spec.samples) if random_applies else 1) * len(spec.seeds))
  return total * len(spec.worlds)


def check_size(spec: SweepSpec) -> None:
  """Refuses, before listing them, a sweep whose episodes would not fit in host memory."""
  rows = count_rows(spec)
  if rows <= 10_000:  # 40 MB at most: never what stops a machine
    return
  have = memory.available_bytes()
  if rows * ROW_BYTES > memory.MEMORY_FRACTION * have:
    raise ConfigError(f"the sweep has {rows:.4g} robot-episodes; listing them takes about "
                      f"{rows * ROW_BYTES / 2**30:.3g} GiB, more than "
                      f"{memory.MEMORY_FRACTION:.0%} of the {have / 2**30:.3g} GiB available: "
                      f"sweep fewer values, seeds or samples, or split it into several sweeps")


def split_groups(spec: SweepSpec) -> list[Group]:
  """The groups of a sweep (rows numbered across it), before their chunks are sized: one per
  world and planner, split further by the values of every swept static setting."""
  check_size(spec)
  # make_spec: samples is an int whenever spec.random is not empty
  drawn = (random_samples(spec.random, cast(int, spec.samples), spec.random_seed)
           if spec.random else [()])
  groups, row = [], 0
  for w in range(len(spec.worlds)):
    for planner in spec.planners:
      names, settings = _settings_of(spec, planner, drawn)
      planner_spec = get_planner(planner)
      static_at = [k for k, n in enumerate(names) if is_static(n, planner_spec)]
      parts: dict[tuple, list] = {}  # static values -> settings, in order of first appearance
      for values in settings:
        parts.setdefault(tuple(values[k] for k in static_at), []).append(values)
      for part in parts.values():
        rows = []
        for values in part:
          for seed in spec.seeds:
            rows.append(Row(row, seed, tuple(values)))
            row += 1
        groups.append(Group(w, planner, tuple(names), tuple(rows)))
  return groups


def group_spec(spec: SweepSpec, group: Group, grid: GridMap) -> RunSpec:
  """The run specification of all of a group's rows: the shared settings, each swept name with
  one value per row, one seed per row (robot ``b`` of it is the group's row ``b``)."""
  planner = get_planner(group.planner)
  base = spec.base
  params = dict(base.params)
  planner_params = {k: v for k, v in base.planner_params.items()
                    if kind_of(k, planner) in ("weight", "setting")}
  for k, name in enumerate(group.names):
    values = tuple(r.values[k] for r in group.rows)
    (params if kind_of(name, planner) in ("param", "static") else planner_params)[name] = values
  max_steps = group.max_steps if group.max_steps is not None else base.max_steps
  return dataclasses.replace(base, world=grid, planner=group.planner, robots=len(group.rows),
                             seed=0, robot_seeds=tuple(r.seed for r in group.rows),
                             params=params, planner_params=planner_params, max_steps=max_steps)


def load_world_entry(entry: WorldEntry, res, out: Path | None, grids: dict) -> GridMap:
  """The truth map of a world entry: loaded by name, or the GridMap given (kept in ``grids``,
  else read back from the sweep folder)."""
  if entry.name is not None:
    return load_world(entry.name, res=res)
  if entry.file in grids:
    return grids[entry.file]
  if out is None:
    raise ConfigError(f"world {entry.grid!r} was given as a GridMap and is not saved anywhere")
  assert entry.file is not None  # an entry without a name is a saved GridMap: file is set
  path = out / entry.file
  if not path.exists():
    raise ConfigError(f"cannot resume: the world file {path} of the schedule is missing")
  grids[entry.file] = read_world(path)
  return grids[entry.file]


def resolve_group(spec: SweepSpec, group: Group, out: Path | None, grids: dict,
                  worlds: dict | None = None) -> Resolved:
  """A group resolved and validated (every row; no compute). ``worlds`` caches loaded maps by
  world index."""
  worlds = {} if worlds is None else worlds
  if group.world not in worlds:
    worlds[group.world] = load_world_entry(spec.worlds[group.world], spec.base.res, out, grids)
  return resolve(group_spec(spec, group, worlds[group.world]))


def _chunk_size_for(config, rows: int, requested, n_dev: int) -> int:
  whole = -(-rows // n_dev) * n_dev  # every row in one chunk, a multiple of the devices
  if requested is None:
    most = MAX_AUTO_CHUNK if config.strategy == "per_robot" else MAX_AUTO_CHUNK_ACCELERATOR
    wanted = min(most - most % n_dev or n_dev, whole)
  else:
    if isinstance(requested, bool) or not isinstance(requested, (int, np.integer)) or requested < 1:
      raise ConfigError(f"chunk_size must be a positive integer, got {requested!r}")
    wanted = min(int(requested), whole)
  return memory.fit_chunk(config, wanted, n_dev)


def make_schedule(spec: SweepSpec, out: Path | None, grids: dict, chunk_size,
                  n_dev: int) -> tuple[Schedule, list[Resolved]]:
  """The schedule of a new sweep, and its groups resolved (every row validated; chunk sizes from
  the memory guard; no compute)."""
  import jax
  worlds: dict = {}
  groups, resolved, first = [], [], 0
  for draft in split_groups(spec):
    r = resolve_group(spec, draft, out, grids, worlds)
    size = _chunk_size_for(r.config, len(draft.rows), chunk_size, n_dev)
    group = dataclasses.replace(
        draft, chunk_size=size,
        chunk_epochs=driver.chunk_epochs_for(r.config, spec.base.chunk_epochs),
        max_steps=r.config.max_steps, sim_config=jsonable(sim.config_record(r.config)),
        first_chunk=first)
    first += group.n_chunks
    groups.append(group)
    resolved.append(r)
  return Schedule(spec, tuple(groups), chunk_size, __version__, jax.__version__), resolved


def resolve_schedule(schedule: Schedule, out: Path | None, grids: dict,
                     n_dev: int) -> list[Resolved]:
  """The groups of a written schedule, checked to resolve as they did when it was made and to
  fit in memory with its chunk sizes."""
  worlds: dict = {}
  resolved = []
  for group in schedule.groups:
    r = resolve_group(schedule.spec, group, out, grids, worlds)
    difference = config_difference(group.sim_config, r.config)
    if difference is not None:
      raise ConfigError(
          f"cannot resume {out}: its schedule was made by jaxplore {schedule.jaxplore_version} and "
          f"resolves differently here ({difference}); finish it with that version or start a new "
          f"sweep")
    memory.fit_chunk(r.config, group.chunk_size, n_dev, fixed=True)
    resolved.append(r)
  return resolved


# --------------------------------------------------------------------------- files


def jsonable(obj):
  return json.loads(json.dumps(obj))


def chunk_paths(out: Path, k: int) -> dict[str, Path]:
  """The files of chunk ``k``: ``episodes`` (written last: it marks the chunk done), ``curves``,
  and for a group's first chunk ``maps`` and ``memory``."""
  stem = out / "chunks" / f"chunk_{k:05d}"
  return {kind: stem.with_name(stem.name + suffix) for kind, suffix in (
      ("episodes", ".parquet"), ("curves", ".curves.parquet"), ("maps", ".maps.npz"),
      ("memory", ".memory.npz"))}


def schedule_path(folder: Path) -> Path | None:
  """The schedule file of a sweep folder (or its older name), or None."""
  for name in (SCHEDULE_FILE, LEGACY_FILE):
    if (Path(folder) / name).exists():
      return Path(folder) / name
  return None


def read_schedule(folder: Path, action: str = "resume") -> Schedule:
  """The schedule written in a sweep folder (``sweep_schedule.json``, or an older folder's
  ``sweep_plan.json``).

  Raises:
    ConfigError: no folder, no schedule, or an unreadable one (naming what to do).
  """
  folder = Path(folder)
  if not folder.is_dir():
    raise ConfigError(f"cannot {action} {str(folder)!r}: no such folder")
  path = schedule_path(folder)
  if path is None:
    raise ConfigError(f"cannot {action} {str(folder)!r}: it holds no {SCHEDULE_FILE} (a sweep "
                      f"folder is made by jaxplore sweep --out DIR)")
  try:
    data = json.loads(path.read_text())
    expected = SCHEDULE_FORMAT if path.name == SCHEDULE_FILE else LEGACY_FORMAT
    if data.get("format") != expected:
      raise ValueError("not a jaxplore sweep schedule")
    if data.get("version") != SCHEDULE_VERSION:
      raise ValueError(f"schedule version {data.get('version')!r}, this jaxplore reads "
                       f"{SCHEDULE_VERSION}")
    schedule = Schedule.from_json(data)
  except (ValueError, KeyError, TypeError, AttributeError) as err:
    raise ConfigError(f"cannot {action} {str(folder)!r}: its {path.name} is corrupt ({err}); "
                      f"start the sweep again with another --out") from None
  return schedule


def first_difference(a, b, where="") -> str:
  """Where two JSON values first differ, as ``key.key: A there, B now``."""
  if isinstance(a, dict) and isinstance(b, dict):
    for key in list(a) + [k for k in b if k not in a]:
      if a.get(key) != b.get(key):
        return first_difference(a.get(key), b.get(key), f"{where}.{key}" if where else key)
  return f"{where or 'schedule'}: {a!r} there, {b!r} now"


__all__ = ["Chunk", "Group", "Row", "Schedule", "SCHEDULE_FILE", "LEGACY_FILE", "chunk_paths",
           "first_difference", "group_spec", "load_world_entry", "make_schedule", "read_schedule",
           "resolve_group", "resolve_schedule", "schedule_path", "split_groups"]
