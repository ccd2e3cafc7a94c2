"""What a sweep asks for: worlds × planners × parameter settings × seeds, and the run settings
every row shares; from Python arguments or a TOML file, validated before any compute.

:class:`SweepSpec` is the identity of a sweep: a folder holds the same sweep when its schedule's
spec equals this one. It is JSON only at the file edge (:meth:`SweepSpec.to_json`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from collections.abc import Mapping

import numpy as np

from jaxplore.config import STATIC_SETTINGS, ConfigError
from jaxplore.runspec import (
  AXES,
  RUN_ONLY,
  SHARED,
  TOML_KEYS,
  WORD_PARAMS,
  RunSpec,
  kind_of,
  number,
  read_toml,
  seed_value,
  settings_from_toml,
)

DEFAULT_SEEDS = 8  # seeds per setting when none are given


@dataclasses.dataclass(frozen=True)
class RandomRange:
  """A random-search range: uniform in [low, high], or log-uniform with ``log``."""

  low: float
  high: float
  log: bool = False


@dataclasses.dataclass(frozen=True)
class WorldEntry:
  """A world of a sweep: a built-in name or map YAML path (``name``), or a GridMap given in
  Python, saved in the sweep folder (``grid`` its name, ``sha1`` of its cells, ``file``)."""

  name: str | None = None
  grid: str | None = None
  sha1: str | None = None
  file: str | None = None

  def to_json(self) -> dict:
    return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}

  @property
  def label(self) -> str:
    return self.name if self.name is not None else str(self.grid)


@dataclasses.dataclass(frozen=True)
class SweepSpec:
  """Everything a sweep asked for, resolved to plain values (no map loaded, nothing sized).

  Attributes:
    worlds, planners: the group axes. seeds: the seeds of every setting.
    grid: name -> values (every combination is a setting): numbers, or words for a planner's
      word-valued static setting (li2020's ``region``).
    random: name -> range; ``samples`` points drawn with ``random_seed`` (each combined with
      every grid combination).
    base: the run settings every row shares (its :data:`jaxplore.runspec.SHARED` fields).
  """

  worlds: tuple[WorldEntry, ...]
  planners: tuple[str, ...]
  seeds: tuple[int, ...]
  grid: Mapping[str, tuple[float | str, ...]]
  random: Mapping[str, RandomRange]
  samples: int | None
  random_seed: int
  base: RunSpec

  @property
  def names(self) -> list[str]:
    """Every swept name: the grid's, then the random search's."""
    return list(self.grid) + list(self.random)

  def to_json(self) -> dict:
    return {
        "worlds": [w.to_json() for w in self.worlds], "planners": list(self.planners),
        "seeds": list(self.seeds), "grid": {k: list(v) for k, v in self.grid.items()},
        "random": {k: dataclasses.asdict(v) for k, v in self.random.items()},
        "samples": self.samples, "random_seed": self.random_seed,
        "run": self.base.to_json(SHARED),
    }

  @classmethod
  def from_json(cls, data: dict) -> SweepSpec:
    """The spec of :meth:`to_json`'s dict (also the ``spec`` of older ``sweep_plan.json`` files,
    whose ``run`` lacks the newer settings: they take their defaults)."""
    return cls(worlds=tuple(WorldEntry(**w) for w in data["worlds"]),
               planners=tuple(data["planners"]), seeds=tuple(int(s) for s in data["seeds"]),
               grid={k: tuple(grid_value(x) for x in v) for k, v in data["grid"].items()},
               random={k: RandomRange(**v) for k, v in data["random"].items()},
               samples=data["samples"], random_seed=int(data["random_seed"]),
               base=RunSpec.from_json(data["run"]))


# --------------------------------------------------------------------------- values


def f32(value: float) -> float:
  """The value the engine will see (its parameters are float32), as a Python float."""
  return float(np.float32(value))


def grid_value(value) -> float | str:
  """A grid value as the schedule keeps it: a word as it is, a number as a float."""
  return value if isinstance(value, str) else float(value)


def is_word_axis(values) -> bool:
  """Whether a grid axis holds words (a planner's word-valued setting) rather than numbers."""
  return bool(values) and all(isinstance(v, str) for v in values)


def normalise_grid(grid) -> dict[str, tuple[float | str, ...]]:
  """``{name: (values)}`` with every value a finite number, or every value a word (a single
  value counts as one); whether a word suits the name is :func:`make_spec`'s check."""
  if grid is None:
    return {}
  if not isinstance(grid, Mapping):
    raise ConfigError(f"grid must map parameter names to lists of values, got {grid!r}")
  out = {}
  for name, values in grid.items():
    if isinstance(values, (int, float, np.integer, np.floating)) and not isinstance(values, bool):
      values = [values]
    if isinstance(values, str):
      values = [values]
    if isinstance(values, bytes) or not hasattr(values, "__iter__"):
      raise ConfigError(f"grid {name!r} must be a list of numbers, got {values!r}")
    values = list(values)
    if not values:
      raise ConfigError(f"sweep grid for {name!r} is empty")
    if any(isinstance(v, str) for v in values):
      if not is_word_axis(values):
        raise ConfigError(f"grid {name!r} mixes words and numbers: {values!r}")
      values = tuple(v.strip() for v in values)
      if len(set(values)) != len(values):
        raise ConfigError(f"grid {name!r} repeats a value: {list(values)}")
    else:
      values = tuple(number(v, f"grid value of {name!r}") for v in values)
      if len(set(values)) != len(values):
        raise ConfigError(f"grid {name!r} repeats a value: {list(values)}")
    out[str(name)] = values
  return out


def parse_random_spec(text: str) -> RandomRange:
  """``LOW:HIGH`` or ``LOW:HIGH:log`` (the CLI's ``--random NAME=LOW:HIGH[:log]``)."""
  parts = text.split(":")
  if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2].strip().lower() != "log"):
    raise ConfigError(f"--random takes NAME=LOW:HIGH or NAME=LOW:HIGH:log, got {text!r}")
  try:
    low, high = float(parts[0]), float(parts[1])
  except ValueError:
    raise ConfigError(f"--random {text!r}: LOW and HIGH must be numbers") from None
  return RandomRange(low, high, len(parts) == 3)


def normalise_random(random) -> dict[str, RandomRange]:
  """Ranges from :class:`RandomRange`, ``{"low", "high", "log"}`` dicts,
  ``(low, high[, "log"|bool])`` or ``"LOW:HIGH[:log]"``, checked."""
  if random is None:
    return {}
  if not isinstance(random, Mapping):
    raise ConfigError(f"random must map parameter names to ranges, got {random!r}")
  out = {}
  for name, spec in random.items():
    if isinstance(spec, RandomRange):
      spec = dataclasses.asdict(spec)
    elif isinstance(spec, str):
      spec = dataclasses.asdict(parse_random_spec(spec))
    elif isinstance(spec, (tuple, list)):
      if len(spec) not in (2, 3):
        raise ConfigError(f"random {name!r}: give (low, high) or (low, high, 'log'), got {spec!r}")
      spec = {"low": spec[0], "high": spec[1], "log": len(spec) == 3 and spec[2] in ("log", True)}
    if not isinstance(spec, Mapping):
      raise ConfigError(f"random {name!r} must be {{low=, high=, log=}}, got {spec!r}")
    unknown = set(spec) - {"low", "high", "log"}
    if unknown:
      raise ConfigError(f"random {name!r}: unknown key(s) {sorted(unknown)}; valid: low, high, log")
    if "low" not in spec or "high" not in spec:
      raise ConfigError(f"random {name!r} needs both low and high")
    low = number(spec["low"], f"random {name!r} low")
    high = number(spec["high"], f"random {name!r} high")
    log = spec.get("log", False)
    if not isinstance(log, bool):
      raise ConfigError(f"random {name!r}: log must be true or false, got {log!r}")
    if not low < high:
      raise ConfigError(f"random {name!r}: low {low} is not below high {high}" + (
          " (one value: give it as a fixed setting or a grid of one)" if low == high else ""))
    if log and low <= 0:
      raise ConfigError(f"random {name!r}: a log range needs low > 0, got {low}")
    out[str(name)] = RandomRange(low, high, log)
  return out


def random_samples(random: Mapping[str, RandomRange], samples: int,
                   seed: int) -> list[tuple[float, ...]]:
  """``samples`` points drawn uniformly (log-uniformly where ``log``) in the ranges of
  ``random``."""
  rng = np.random.default_rng(int(seed))
  columns = []
  for spec in random.values():
    if spec.log:
      columns.append(np.exp(rng.uniform(math.log(spec.low), math.log(spec.high), samples)))
    else:
      columns.append(rng.uniform(spec.low, spec.high, samples))
  return [tuple(f32(c[i]) for c in columns) for i in range(samples)]


def seeds_of(seeds) -> tuple[int, ...]:
  """``range(seeds)`` for a count, or the given list of distinct seeds in [0, 2**32)."""
  if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
    if seeds < 1:
      raise ConfigError(f"seeds must be a positive number of seeds or a list of seeds, "
                        f"got {seeds!r}")
    return tuple(range(int(seeds)))
  if isinstance(seeds, (list, tuple)) and seeds:
    out = tuple(seed_value(s, "a seed") for s in seeds)
    if len(set(out)) != len(out):
      raise ConfigError(f"seeds repeat: {list(out)}")
    return out
  raise ConfigError(f"seeds must be a positive number of seeds or a list of seeds, got {seeds!r}")


def _as_list(value) -> list:
  return list(value) if isinstance(value, (list, tuple)) else [value]


def world_entry(world, index: int, grids: dict) -> WorldEntry:
  """The entry of a world; a GridMap is kept in ``grids`` under its file name (saved with the
  sweep's folder)."""
  from jaxplore.maps import GridMap
  if isinstance(world, GridMap):
    digest = hashlib.sha1(np.packbits(world.occupied).tobytes()
                          + repr((world.shape, world.res, world.origin)).encode()).hexdigest()
    entry = WorldEntry(grid=world.name, sha1=digest, file=f"worlds/{index}_{world.name}.npz")
    grids[entry.file] = world
    return entry
  if not isinstance(world, (str, os.PathLike)):
    raise ConfigError(f"a world must be a name, a map YAML path or a GridMap, got {world!r}")
  world = str(world)
  from jaxplore.maps.worlds import WORLDS
  if world not in WORLDS and os.path.exists(world):
    world = os.path.abspath(world)
  return WorldEntry(name=world)


def make_spec(grid=None, random=None, samples=None, random_seed=None, seeds=None, worlds=None,
              planners=None, base: RunSpec | None = None, grids: dict | None = None) -> SweepSpec:
  """What the user asked for, checked (no map loaded): every swept and fixed name must mean
  something to one of the planners, every value be a number."""
  from jaxplore.planners import get_planner
  grids = {} if grids is None else grids
  base = RunSpec() if base is None else base
  grid = normalise_grid(grid)
  random = normalise_random(random)
  both = set(grid) & set(random)
  if both:
    raise ConfigError(f"parameter(s) {sorted(both)} are both in the grid and in the random search")
  if random and (samples is None or isinstance(samples, bool)
                 or not isinstance(samples, (int, np.integer)) or samples < 1):
    raise ConfigError(f"a random search needs samples = a positive integer, got {samples!r}")
  if samples is not None and not random:
    raise ConfigError("samples is given but no parameter has a random range "
                      "(--random NAME=LOW:HIGH)")
  planners = [str(p) for p in _as_list(RunSpec.planner if planners is None else planners)]
  if not planners:
    raise ConfigError("a sweep needs at least one planner")
  if len(set(planners)) != len(planners):
    raise ConfigError(f"planners repeat: {planners}")
  specs = {p: get_planner(p) for p in planners}
  for name in list(grid) + list(random):
    if not any(kind_of(name, s) for s in specs.values()):
      weights = sorted({w for s in specs.values() for w in s.defaults})
      raise ConfigError(f"cannot sweep {name!r}: not a simulator parameter nor a weight of "
                        f"planner {' or '.join(repr(p) for p in planners)} "
                        f"({', '.join(weights) or 'none'})")
  for name, values in grid.items():
    if name in WORD_PARAMS:
      for value in values:
        STATIC_SETTINGS[name].check(value, f"grid value of {name!r}")
    elif is_word_axis(values) and not any(kind_of(name, s) == "setting"
                                          for s in specs.values()):
      raise ConfigError(f"grid value of {name!r} must be a number, got {list(values)} (words "
                        f"are for a word-valued setting, such as slam or li2020's region)")
  for what, values in (("params", base.params), ("planner_params", base.planner_params)):
    for name, value in values.items():
      if isinstance(value, tuple):
        raise ConfigError(f"{what}[{name!r}] must be one number for every row of a sweep "
                          f"(sweep it with grid or random), got {list(value)}")
  for name in base.planner_params:
    if not any(kind_of(name, s) in ("weight", "setting") for s in specs.values()):
      raise ConfigError(f"no planner of the sweep ({', '.join(planners)}) has a weight {name!r}")
  worlds = _as_list(RunSpec.world if worlds is None else worlds)
  if not worlds:
    raise ConfigError("a sweep needs at least one world")
  named = [str(w) for w in worlds if isinstance(w, (str, os.PathLike))]
  if len(set(named)) != len(named):
    raise ConfigError(f"worlds repeat: {named}")
  return SweepSpec(
      worlds=tuple(world_entry(w, i, grids) for i, w in enumerate(worlds)),
      planners=tuple(planners), seeds=seeds_of(DEFAULT_SEEDS if seeds is None else seeds),
      grid=grid, random=random, samples=None if not random else int(samples),
      random_seed=seed_value(random_seed or 0, "random_seed"), base=base)


# --------------------------------------------------------------------------- TOML

SWEEP_TOML_KEYS = tuple(k for k in TOML_KEYS if k not in RUN_ONLY)


def load_config(path) -> dict:
  """Reads a sweep TOML file into keyword arguments of :func:`jaxplore.sweeps.sweep`, validated
  key by key (``jaxplore.runspec.TOML_KEYS`` lists them); relative ``out`` paths are relative to
  the current directory, like ``--out``."""
  data, where = read_toml(path)
  kwargs = settings_from_toml({k: v for k, v in data.items() if k not in (
      "world", "worlds", "planner", "planners", "seeds", "chunk_size", "grid", "random")},
      where, SWEEP_TOML_KEYS)
  if "world" in data and "worlds" in data:
    raise ConfigError(f"{where}: give either world or worlds, not both")
  if "planner" in data and "planners" in data:
    raise ConfigError(f"{where}: give either planner or planners, not both")

  def names(key):
    value = data[key]
    if isinstance(value, str):
      return value
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
      return value
    raise ConfigError(f"{where}: {key} must be a name or a list of names, got {value!r}")

  for key, target in (("world", "world"), ("worlds", "world"), ("planner", "planner"),
                      ("planners", "planner")):
    if key in data:
      kwargs[target] = names(key)
  if "seeds" in data:
    value = data["seeds"]
    if isinstance(value, bool) or not isinstance(value, (int, list)):
      raise ConfigError(f"{where}: seeds must be an integer or a list of integers, got {value!r}")
    kwargs["seeds"] = value
  if "chunk_size" in data:
    value = data["chunk_size"]
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
      raise ConfigError(f"{where}: chunk_size must be a positive integer, got {value!r}")
    kwargs["chunk_size"] = value
  if "grid" in data:
    if not isinstance(data["grid"], dict):
      raise ConfigError(f"{where}: grid must be a table ([grid]), got {data['grid']!r}")
    kwargs["grid"] = normalise_grid(data["grid"])
  if "random" in data:
    if not isinstance(data["random"], dict):
      raise ConfigError(f"{where}: random must be a table ([random]), got {data['random']!r}")
    spec = dict(data["random"])
    samples = spec.pop("samples", None)
    seed = spec.pop("seed", 0)
    if samples is None:
      raise ConfigError(f"{where}: [random] needs samples = N")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
      raise ConfigError(f"{where}: [random] samples must be a positive integer, got {samples!r}")
    if isinstance(seed, bool) or not isinstance(seed, int):
      raise ConfigError(f"{where}: [random] seed must be an integer, got {seed!r}")
    for name, value in spec.items():
      if not isinstance(value, dict):
        raise ConfigError(f"{where}: [random] {name} must be {{low = ..., high = ..., log = ...}}, "
                          f"got {value!r}")
    kwargs["random"] = normalise_random(spec)
    kwargs["samples"] = samples
    kwargs["random_seed"] = seed
  return kwargs


__all__ = ["DEFAULT_SEEDS", "RandomRange", "SweepSpec", "WorldEntry", "f32", "load_config",
           "make_spec", "normalise_grid", "grid_value", "is_word_axis", "normalise_random",
           "parse_random_spec", "random_samples", "seeds_of", "world_entry", "SWEEP_TOML_KEYS",
           "AXES"]
