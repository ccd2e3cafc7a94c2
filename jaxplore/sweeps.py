"""Sweeps: worlds × planners × parameter settings × seeds, in chunks that survive interruption.

A sweep is resolved into a *plan* before any compute: every row (one robot-episode: a world, a
planner, the values of the swept parameters, a seed), grouped by (world, planner) because those
fix the shapes and the compiled program. Each group runs as batches of ``chunk_size`` rows: the
same shapes for every chunk (the last one is padded by repeating its last row, and the padding is
dropped), so one group compiles once. A parameter that fixes a shape exactly (``r_e``, the
radius of ``li2020``'s gain kernel) splits a group by its values. With ``out``, the plan is written first
(``sweep_plan.json``) and every finished chunk atomically (write, fsync, rename) to
``chunks/chunk_NNNNN.parquet`` (+ ``.curves.parquet``); ``sweep(resume=DIR)`` (``jaxplore sweep
--resume DIR``) reads the plan, skips finished chunks, computes the rest and assembles the final
``episodes.parquet``, ``curves.parquet``, ``config.json`` and figures from the chunk files, so an
interrupted-and-resumed sweep gives the same table as an uninterrupted one.

Robots are independent under ``vmap`` and robot ``s``'s PRNG key is ``PRNGKey(s)``, so a row's
result does not depend on which chunk it lands in, nor on how a chunk is sharded over devices
(``tests/test_sweep.py`` checks both bit for bit).

Memory guard: before allocating, :func:`jaxplore.runner.estimate_bytes` of a chunk is compared
with 80 % of :func:`jaxplore.runner.available_bytes`; a chunk that does not fit is made smaller
(and says so), and a sweep in which one robot does not fit is refused with the numbers.

Several hosts: with ``distributed=True`` (``--distributed``) ``jax.distributed.initialize()`` is
called and process ``i`` of ``n`` runs the chunks ``k`` with ``k % n == i`` on its own devices,
writing into the same ``out`` (a filesystem shared by every host); process 0 assembles the tables
after a barrier. Not tested on more than one host.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import itertools
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jaxplore import __version__
from jaxplore.config import PARAM_FIELDS, ConfigError

PLAN_FILE = "sweep_plan.json"
PLAN_FORMAT = "jaxplore-sweep-plan"
PLAN_VERSION = 1
MAX_AUTO_CHUNK = 256
MEMORY_FRACTION = 0.8
DEFAULTS = dict(world="building", planner="li2020", seeds=8, preset="li2020")
# Parameters that fix a static shape exactly (not just a bound): r_e sets the radius of li2020's
# gain kernel (SimConfig.gain_radius_cells). Rows with different values run as separate groups.
SHAPE_PARAMS = ("r_e",)
RUN_KEYS = ("preset", "res", "start", "max_steps", "replan_every", "params", "planner_params",
            "pose_noise", "path_capacity", "chunk_epochs", "rate_interval")


@dataclasses.dataclass
class SweepResult:
  """What a sweep produced (also written to ``out`` when given).

  Attributes:
    episodes: one row per robot-episode: ``world``, ``planner``, ``seed``, one column per swept
      parameter (NaN where a planner has no such weight), ``robot`` (the row's index in the
      sweep), then the episode metrics of :func:`jaxplore.run`.
    curves: one row per robot-episode and step (``robot`` joins with ``episodes``).
    config: the resolved plan, per-group settings and versions (what ``config.json`` holds).
    timing: this session's compile and run seconds, compile count, chunks run and skipped.
    out: the results folder, if any.
  """

  episodes: pd.DataFrame
  curves: pd.DataFrame
  config: dict
  timing: dict
  out: Path | None = None


# --------------------------------------------------------------------------- compile counting

_COMPILE_EVENTS: list[tuple[str, float]] = []
_LISTENING = False


def _listen_to_compiles():
  """Counts XLA backend compiles through JAX's monitoring hook (installed once per process)."""
  global _LISTENING
  if _LISTENING:
    return
  import jax.monitoring
  from jax._src import dispatch

  def on_event(event, duration, **kwargs):
    if event == dispatch.BACKEND_COMPILE_EVENT:
      _COMPILE_EVENTS.append((str(kwargs.get("fun_name", "?")), float(duration)))

  jax.monitoring.register_event_duration_secs_listener(on_event)
  _LISTENING = True


@contextlib.contextmanager
def _count_compiles(tally: dict):
  """Adds the XLA compiles (count and seconds) that happen inside the block to ``tally``."""
  _listen_to_compiles()
  first = len(_COMPILE_EVENTS)
  try:
    yield
  finally:
    events = _COMPILE_EVENTS[first:]
    tally["count"] = tally.get("count", 0) + len(events)
    tally["seconds"] = tally.get("seconds", 0.0) + sum(d for _, d in events)


# --------------------------------------------------------------------------- settings


def _number(value, what) -> float:
  if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
    raise ConfigError(f"{what} must be a number, got {value!r}")
  value = float(value)
  if not math.isfinite(value):
    raise ConfigError(f"{what} must be finite, got {value!r}")
  return value


def _f32(value: float) -> float:
  """The value the engine will see (its parameters are float32), as a Python float."""
  return float(np.float32(value))


def normalise_grid(grid) -> dict[str, list[float]]:
  """``{name: [values]}`` with every value a finite number (a single number counts as one value)."""
  if grid is None:
    return {}
  if not isinstance(grid, dict):
    raise ConfigError(f"grid must map parameter names to lists of values, got {grid!r}")
  out = {}
  for name, values in grid.items():
    if isinstance(values, (int, float, np.integer, np.floating)) and not isinstance(values, bool):
      values = [values]
    if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
      raise ConfigError(f"grid {name!r} must be a list of numbers, got {values!r}")
    values = [_number(v, f"grid value of {name!r}") for v in values]
    if not values:
      raise ConfigError(f"sweep grid for {name!r} is empty")
    out[str(name)] = values
  return out


def parse_random_spec(text: str) -> dict:
  """``LOW:HIGH`` or ``LOW:HIGH:log`` (the CLI's ``--random NAME=LOW:HIGH[:log]``) as a dict."""
  parts = text.split(":")
  if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2].strip().lower() != "log"):
    raise ConfigError(f"--random takes NAME=LOW:HIGH or NAME=LOW:HIGH:log, got {text!r}")
  try:
    low, high = float(parts[0]), float(parts[1])
  except ValueError:
    raise ConfigError(f"--random {text!r}: LOW and HIGH must be numbers") from None
  return {"low": low, "high": high, "log": len(parts) == 3}


def normalise_random(random) -> dict[str, dict]:
  """``{name: {"low", "high", "log"}}`` from dicts, ``(low, high[, "log"|bool])`` or ``"LOW:HIGH[:log]"``."""
  if random is None:
    return {}
  if not isinstance(random, dict):
    raise ConfigError(f"random must map parameter names to ranges, got {random!r}")
  out = {}
  for name, spec in random.items():
    if isinstance(spec, str):
      spec = parse_random_spec(spec)
    elif isinstance(spec, (tuple, list)):
      if len(spec) not in (2, 3):
        raise ConfigError(f"random {name!r}: give (low, high) or (low, high, 'log'), got {spec!r}")
      spec = {"low": spec[0], "high": spec[1], "log": len(spec) == 3 and spec[2] in ("log", True)}
    if not isinstance(spec, dict):
      raise ConfigError(f"random {name!r} must be {{low=, high=, log=}}, got {spec!r}")
    unknown = set(spec) - {"low", "high", "log"}
    if unknown:
      raise ConfigError(f"random {name!r}: unknown key(s) {sorted(unknown)}; valid: low, high, log")
    if "low" not in spec or "high" not in spec:
      raise ConfigError(f"random {name!r} needs both low and high")
    low = _number(spec["low"], f"random {name!r} low")
    high = _number(spec["high"], f"random {name!r} high")
    log = spec.get("log", False)
    if not isinstance(log, bool):
      raise ConfigError(f"random {name!r}: log must be true or false, got {log!r}")
    if not low <= high:
      raise ConfigError(f"random {name!r}: low {low} is above high {high}")
    if log and low <= 0:
      raise ConfigError(f"random {name!r}: a log range needs low > 0, got {low}")
    out[str(name)] = {"low": low, "high": high, "log": log}
  return out


def random_samples(random: dict, samples: int, seed: int) -> list[tuple[float, ...]]:
  """``samples`` points drawn uniformly (log-uniformly where ``log``) in the ranges of ``random``."""
  rng = np.random.default_rng(int(seed))
  columns = []
  for spec in random.values():
    if spec["log"]:
      columns.append(np.exp(rng.uniform(math.log(spec["low"]), math.log(spec["high"]), samples)))
    else:
      columns.append(rng.uniform(spec["low"], spec["high"], samples))
  return [tuple(_f32(c[i]) for c in columns) for i in range(samples)]


def _seeds(seeds) -> list[int]:
  if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
    if seeds < 1:
      raise ConfigError(f"seeds must be a positive number of seeds or a list of seeds, got {seeds!r}")
    return list(range(int(seeds)))
  if isinstance(seeds, (list, tuple)) and seeds:
    out = []
    for s in seeds:
      if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 0 <= s < 2**32:
        raise ConfigError(f"a seed must be an integer in [0, 2**32), got {s!r}")
      out.append(int(s))
    if len(set(out)) != len(out):
      raise ConfigError(f"seeds repeat: {out}")
    return out
  raise ConfigError(f"seeds must be a positive number of seeds or a list of seeds, got {seeds!r}")


def _as_list(value) -> list:
  return list(value) if isinstance(value, (list, tuple)) else [value]


# --------------------------------------------------------------------------- TOML

TOML_KEYS = {
    "world": "a world name or map YAML path (or a list of them)",
    "worlds": "a list of worlds",
    "planner": "a planner name (or a list of them)",
    "planners": "a list of planners",
    "preset": "sensor/robot preset",
    "seeds": "number of seeds, or a list of seeds",
    "res": "planning resolution, m/cell",
    "start": "x,y[,theta] start of every robot",
    "max_steps": "step budget per episode",
    "replan_every": "motion steps between planning rounds",
    "pose_noise": "noisy odometry (true/false)",
    "path_capacity": "waypoints a plan may hold",
    "rate_interval": "metres per interval of Std(E_r)",
    "chunk_epochs": "planning rounds per compiled call",
    "chunk_size": "robot-episodes per chunk",
    "out": "results folder",
    "devices": "local devices to shard a chunk over",
    "grid": "[grid] table: name = [values]",
    "random": "[random] table: name = {low=, high=, log=}, samples = N, seed = S",
    "set": "[set] table: fixed simulator parameters",
    "planner_set": "[planner_set] table: fixed planner weights",
}


def load_config(path) -> dict:
  """Reads a sweep TOML file into keyword arguments of :func:`sweep` (validated key by key).

  Keys mirror the command line (see ``TOML_KEYS``); relative ``out`` paths are relative to the
  current directory, like ``--out``.
  """
  if sys.version_info >= (3, 11):
    import tomllib
  else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib
  path = Path(path)
  try:
    data = tomllib.loads(path.read_text())
  except FileNotFoundError:
    raise ConfigError(f"sweep config {str(path)!r} not found") from None
  except tomllib.TOMLDecodeError as err:
    raise ConfigError(f"{path}: not valid TOML: {err}") from None
  where = str(path)
  for key in data:
    if key not in TOML_KEYS:
      hint = (" (samples and seed of a random search go in the [random] table)"
              if key in ("samples", "seed", "random_seed") else "")
      raise ConfigError(f"{where}: unknown key {key!r}{hint}; valid keys: {', '.join(TOML_KEYS)}")
  if "world" in data and "worlds" in data:
    raise ConfigError(f"{where}: give either world or worlds, not both")
  if "planner" in data and "planners" in data:
    raise ConfigError(f"{where}: give either planner or planners, not both")

  def typed(key, kinds, what):
    value = data[key]
    if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
      raise ConfigError(f"{where}: {key} must be {what}, got {value!r}")
    return value

  def names(key):
    value = data[key]
    if isinstance(value, str):
      return value
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
      return value
    raise ConfigError(f"{where}: {key} must be a name or a list of names, got {value!r}")

  def table(key):
    value = data[key]
    if not isinstance(value, dict):
      raise ConfigError(f"{where}: {key} must be a table ([{key}]), got {value!r}")
    return value

  kwargs: dict = {}
  for key, target in (("world", "world"), ("worlds", "world"), ("planner", "planner"),
                      ("planners", "planner")):
    if key in data:
      kwargs[target] = names(key)
  if "preset" in data:
    kwargs["preset"] = typed("preset", str, "a preset name")
  if "seeds" in data:
    kwargs["seeds"] = typed("seeds", (int, list), "an integer or a list of integers")
  for key in ("res", "rate_interval"):
    if key in data:
      kwargs[key] = _number(typed(key, (int, float), "a number"), f"{where}: {key}")
  for key in ("max_steps", "replan_every", "path_capacity", "chunk_epochs", "chunk_size", "devices"):
    if key in data:
      value = typed(key, int, "a positive integer")
      if value < 1:
        raise ConfigError(f"{where}: {key} must be a positive integer, got {value!r}")
      kwargs[key] = value
  if "pose_noise" in data:
    kwargs["pose_noise"] = typed("pose_noise", bool, "true or false")
  if "start" in data:
    kwargs["start"] = typed("start", (str, list), "'x,y[,theta]' or [x, y, theta]")
  if "out" in data:
    kwargs["out"] = typed("out", str, "a folder path")
  if "grid" in data:
    kwargs["grid"] = normalise_grid(table("grid"))
  for key, target in (("set", "params"), ("planner_set", "planner_params")):
    if key in data:
      kwargs[target] = {name: _number(v, f"{where}: [{key}] {name}") for name, v in table(key).items()}
  if "random" in data:
    spec = dict(table("random"))
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


# --------------------------------------------------------------------------- the plan


def _world_entry(world, index: int, out: Path | None, grids: dict) -> dict:
  """A JSON description of a world; a GridMap is kept in ``grids`` (and saved under ``out``)."""
  from jaxplore.maps import GridMap
  if isinstance(world, GridMap):
    digest = hashlib.sha1(np.packbits(world.occupied).tobytes()
                          + repr((world.shape, world.res, world.origin)).encode()).hexdigest()
    entry = {"grid": world.name, "sha1": digest, "file": f"worlds/{index}_{world.name}.npz"}
    grids[entry["file"]] = world
    return entry
  if not isinstance(world, (str, os.PathLike)):
    raise ConfigError(f"a world must be a name, a map YAML path or a GridMap, got {world!r}")
  world = str(world)
  from jaxplore.maps.worlds import WORLDS
  if world not in WORLDS and os.path.exists(world):
    world = os.path.abspath(world)
  return {"name": world}


def _load_world(entry: dict, res, out: Path | None, grids: dict):
  from jaxplore.maps import GridMap, load_world
  if "name" in entry:
    return load_world(entry["name"], res=res)
  if entry["file"] in grids:
    return grids[entry["file"]]
  if out is None:
    raise ConfigError(f"world {entry['grid']!r} was given as a GridMap and is not saved anywhere")
  path = out / entry["file"]
  if not path.exists():
    raise ConfigError(f"cannot resume: the world file {path} of the plan is missing")
  with np.load(path) as f:
    grid = GridMap(f["occupied"], float(f["res"]), tuple(f["origin"].tolist()), str(f["name"]))
  grids[entry["file"]] = grid
  return grid


def _save_world(grid, path: Path):
  path.parent.mkdir(parents=True, exist_ok=True)

  def write(tmp):
    with open(tmp, "wb") as f:
      np.savez_compressed(f, occupied=grid.occupied, res=grid.res, origin=np.asarray(grid.origin),
                          name=grid.name)
  _atomic_write(path, write)


def _run_settings(run_kwargs: dict) -> dict:
  """The run keyword arguments in JSON form (numbers as floats), defaults filled in."""
  from jaxplore.runner import parse_start
  run = {k: run_kwargs.get(k) for k in RUN_KEYS}
  run["preset"] = DEFAULTS["preset"] if run["preset"] is None else run["preset"]
  run["rate_interval"] = 1.0 if run["rate_interval"] is None else _number(run["rate_interval"],
                                                                          "rate_interval")
  run["pose_noise"] = bool(run["pose_noise"])
  for key in ("params", "planner_params"):
    values = run[key] or {}
    if not isinstance(values, dict):
      raise ConfigError(f"{key} must map names to numbers, got {values!r}")
    run[key] = {str(k): _number(v, f"{key}[{k!r}]") for k, v in values.items()}
  unknown = set(run["params"]) - set(PARAM_FIELDS)
  if unknown:
    raise ConfigError(f"unknown parameter(s) {sorted(unknown)}; valid: {', '.join(PARAM_FIELDS)}")
  start = parse_start(run["start"])
  run["start"] = None if start is None else list(start)
  if run["res"] is not None:
    run["res"] = _number(run["res"], "res")
  for key in ("max_steps", "replan_every", "path_capacity", "chunk_epochs"):
    value = run[key]
    if value is not None:
      if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{key} must be a positive integer, got {value!r}")
      run[key] = int(value)
  return run


def _jsonable(obj):
  return json.loads(json.dumps(obj))


def make_spec(grid, random, samples, random_seed, seeds, worlds, planners, run_kwargs, out, grids):
  """What the user asked for, resolved to JSON (the part of a plan that identifies a sweep)."""
  from jaxplore.planners import get_planner
  grid = normalise_grid(grid)
  random = normalise_random(random)
  both = set(grid) & set(random)
  if both:
    raise ConfigError(f"parameter(s) {sorted(both)} are both in the grid and in the random search")
  if random and (samples is None or isinstance(samples, bool) or not isinstance(samples, (int, np.integer))
                 or samples < 1):
    raise ConfigError(f"a random search needs samples = a positive integer, got {samples!r}")
  if samples is not None and not random:
    raise ConfigError("samples is given but no parameter has a random range (--random NAME=LOW:HIGH)")
  planners = [str(p) for p in _as_list(planners)]
  if not planners:
    raise ConfigError("a sweep needs at least one planner")
  specs = {p: get_planner(p) for p in planners}
  for name in list(grid) + list(random):
    if name not in PARAM_FIELDS and not any(name in s.defaults for s in specs.values()):
      weights = sorted({w for s in specs.values() for w in s.defaults})
      raise ConfigError(f"cannot sweep {name!r}: not a simulator parameter nor a weight of planner "
                        f"{' or '.join(repr(p) for p in planners)} ({', '.join(weights) or 'none'})")
  run = _run_settings(run_kwargs)
  for name in run["planner_params"]:
    if not any(name in s.defaults for s in specs.values()):
      raise ConfigError(f"no planner of the sweep ({', '.join(planners)}) has a weight {name!r}")
  worlds = _as_list(worlds)
  if not worlds:
    raise ConfigError("a sweep needs at least one world")
  if len(set(planners)) != len(planners):
    raise ConfigError(f"planners repeat: {planners}")
  return _jsonable({
      "worlds": [_world_entry(w, i, out, grids) for i, w in enumerate(worlds)],
      "planners": planners, "seeds": _seeds(seeds), "grid": grid, "random": random,
      "samples": None if not random else int(samples), "random_seed": int(random_seed or 0),
      "run": run,
  })


def _group_settings(spec: dict, planner: str, samples_drawn) -> tuple[list[str], list[tuple]]:
  """The swept names that apply to ``planner`` and its list of distinct settings (in order)."""
  from jaxplore.planners import get_planner
  weights = get_planner(planner).defaults
  applies = lambda n: n in PARAM_FIELDS or n in weights
  grid_names = [n for n in spec["grid"] if applies(n)]
  random_names = list(spec["random"])
  keep = [k for k, n in enumerate(random_names) if applies(n)]
  combos = list(itertools.product(*(spec["grid"][n] for n in grid_names)))
  points = list(dict.fromkeys(tuple(s[k] for k in keep) for s in samples_drawn)) or [()]
  settings = [c + p for c in combos for p in points]
  return grid_names + [random_names[k] for k in keep], settings


def _build_groups(spec: dict) -> list[dict]:
  """Groups of rows that share a compiled program: one per world and planner, split further by
  the values of ``SHAPE_PARAMS``. Rows are numbered across the whole sweep."""
  drawn = (random_samples(spec["random"], spec["samples"], spec["random_seed"])
           if spec["random"] else [()])
  groups, row = [], 0
  for w, world in enumerate(spec["worlds"]):
    for planner in spec["planners"]:
      names, settings = _group_settings(spec, planner, drawn)
      shape_at = [k for k, n in enumerate(names) if n in SHAPE_PARAMS]
      parts = {}  # shape values -> settings, in order of first appearance
      for values in settings:
        parts.setdefault(tuple(values[k] for k in shape_at), []).append(values)
      for part in parts.values():
        rows = []
        for values in part:
          for seed in spec["seeds"]:
            rows.append({"row": row, "seed": seed, "values": list(values)})
            row += 1
        groups.append({"world": w, "planner": planner, "names": names, "rows": rows})
  return groups


# --------------------------------------------------------------------------- resolution


@dataclasses.dataclass
class _Group:
  """A (world, planner) group resolved for compute."""

  plan: dict
  grid: object
  config: object
  world_dev: object
  start: tuple | None
  run: dict
  compiled: object = None


def _group_params(run: dict, planner: str, names, rows) -> tuple[dict, dict]:
  """params and planner_params of ``rows``: the fixed values, and one float32 array per swept name."""
  from jaxplore.planners import get_planner
  params, planner_params = dict(run["params"]), dict(run["planner_params"])
  weights = get_planner(planner).defaults
  planner_params = {k: v for k, v in planner_params.items() if k in weights}
  for k, name in enumerate(names):
    values = np.asarray([r["values"][k] for r in rows], np.float32)
    (params if name in PARAM_FIELDS else planner_params)[name] = values
  return params, planner_params


def _default_max_steps(grid, p) -> int:
  """:func:`jaxplore.runner.default_max_steps` for batched parameters: the budget of the slowest,
  shortest-sighted robot, so every row of a group gets the same budget."""
  step_m = float(np.min(np.asarray(p.v_max) * np.asarray(p.dt)))
  swath = 2.0 * min(float(np.min(np.asarray(p.r_max))), 3.0)
  return int(3.0 * grid.free_area / swath / step_m) + 1000


def _resolve_group(spec: dict, gplan: dict, out: Path | None, grids: dict) -> _Group:
  """Validates a group's every row (no compute) and fixes its static config from all its rows."""
  from jaxplore import runner, sim
  run = spec["run"]
  grid = _load_world(spec["worlds"][gplan["world"]], run["res"], out, grids)
  params, planner_params = _group_params(run, gplan["planner"], gplan["names"], gplan["rows"])
  max_steps = gplan.get("max_steps", run["max_steps"])
  if max_steps is None:
    p = runner.build_params(gplan["planner"], run["preset"], grid.res, params, planner_params)
    max_steps = _default_max_steps(grid, p)
  grid, config, p, start = runner.prepare(
      grid, gplan["planner"], len(gplan["rows"]), 0, run["preset"], None, run["start"], max_steps,
      run["replan_every"], params, planner_params, run["pose_noise"], run["path_capacity"])
  world_dev = sim.make_world(grid, float(np.max(np.asarray(p.r_robot))),
                             None if start is None else start[:2])
  return _Group(gplan, grid, config, world_dev, start, run)


def fit_chunk(config, requested: int, n_dev: int = 1, fixed: bool = False) -> int:
  """The largest chunk of at most ``requested`` robots whose estimated memory fits.

  Args:
    fixed: the chunk size is fixed by a written plan: refuse instead of shrinking it.
  Raises:
    ConfigError: not even one robot fits (the message names bytes needed and available, the
      grid size and the robots), or a ``fixed`` chunk does not fit.
  """
  from jaxplore import runner
  have = runner.available_bytes()
  budget = int(MEMORY_FRACTION * have)
  gib = lambda b: f"{b / 2**30:.3g} GiB ({b} bytes)"
  one = runner.estimate_bytes(config, 1)
  if one > budget:
    raise ConfigError(
        f"one robot on a {config.height}x{config.width} grid with max_steps={config.max_steps} needs "
        f"about {gib(one)}, more than {MEMORY_FRACTION:.0%} of the {gib(have)} available; use a "
        f"coarser --res or fewer --max-steps")
  need = runner.estimate_bytes(config, requested)
  if need <= budget:
    return requested
  if fixed:
    raise ConfigError(
        f"the plan's chunks of {requested} robots on a {config.height}x{config.width} grid need about "
        f"{gib(need)}, more than {MEMORY_FRACTION:.0%} of the {gib(have)} available now; free some "
        f"memory and resume again")
  lo, hi = 1, requested  # estimate_bytes grows with robots: the largest lo that fits
  while lo < hi:
    mid = (lo + hi + 1) // 2
    if runner.estimate_bytes(config, mid) <= budget:
      lo = mid
    else:
      hi = mid - 1
  chunk = lo - lo % n_dev if lo >= n_dev else lo
  print(f"jaxplore: a chunk of {requested} robots on a {config.height}x{config.width} grid needs about "
        f"{gib(need)}, more than {MEMORY_FRACTION:.0%} of the {gib(have)} available; "
        f"running chunks of {chunk} robots instead", file=sys.stderr)
  return chunk


def _chunk_size_for(config, rows: int, requested, n_dev: int) -> int:
  whole = -(-rows // n_dev) * n_dev  # every row in one chunk, a multiple of the devices
  if requested is None:
    wanted = min(MAX_AUTO_CHUNK - MAX_AUTO_CHUNK % n_dev or n_dev, whole)
  else:
    if isinstance(requested, bool) or not isinstance(requested, (int, np.integer)) or requested < 1:
      raise ConfigError(f"chunk_size must be a positive integer, got {requested!r}")
    wanted = min(int(requested), whole)
  return fit_chunk(config, wanted, n_dev)


def _chunks_of(gplan: dict) -> list[tuple[int, list[dict]]]:
  rows, size = gplan["rows"], gplan["chunk_size"]
  return [(gplan["first_chunk"] + k, rows[i:i + size]) for k, i in enumerate(range(0, len(rows), size))]


# --------------------------------------------------------------------------- files


def _atomic_write(path: Path, write):
  """``write(tmp)``, flush it to disk, then rename over ``path``: a reader (or a resume after
  ``kill -9``) sees the old file or the whole new one, never a torn one."""
  tmp = path.with_name(path.name + ".tmp")
  write(tmp)
  with open(tmp, "rb+") as f:
    os.fsync(f.fileno())
  os.replace(tmp, path)


def _write_json(path: Path, obj):
  _atomic_write(path, lambda p: p.write_text(json.dumps(obj, indent=2)))


def _chunk_paths(out: Path, k: int) -> tuple[Path, Path, Path]:
  stem = out / "chunks" / f"chunk_{k:05d}"
  return (stem.with_name(stem.name + ".parquet"), stem.with_name(stem.name + ".curves.parquet"),
          stem.with_name(stem.name + ".maps.npz"))


def _read_plan(folder: Path) -> dict:
  path = folder / PLAN_FILE
  if not folder.is_dir():
    raise ConfigError(f"cannot resume {str(folder)!r}: no such folder")
  if not path.exists():
    raise ConfigError(f"cannot resume {str(folder)!r}: it holds no {PLAN_FILE} (a sweep folder "
                      f"is made by jaxplore sweep --out DIR)")
  try:
    plan = json.loads(path.read_text())
    if plan.get("format") != PLAN_FORMAT:
      raise ValueError("not a jaxplore sweep plan")
    if plan.get("version") != PLAN_VERSION:
      raise ValueError(f"plan version {plan.get('version')!r}, this jaxplore reads {PLAN_VERSION}")
    spec, groups = plan["spec"], plan["groups"]
    for key in ("worlds", "planners", "seeds", "grid", "random", "run"):
      spec[key]
    for g in groups:
      g["rows"], g["names"], g["chunk_size"], g["first_chunk"], g["planner"], g["world"]
  except (ValueError, KeyError, TypeError, AttributeError) as err:
    raise ConfigError(f"cannot resume {str(folder)!r}: its {PLAN_FILE} is corrupt ({err}); "
                      f"start the sweep again with another --out") from None
  return plan


def _first_difference(a, b, where="") -> str:
  if isinstance(a, dict) and isinstance(b, dict):
    for key in list(a) + [k for k in b if k not in a]:
      if a.get(key) != b.get(key):
        return _first_difference(a.get(key), b.get(key), f"{where}.{key}" if where else key)
  return f"{where or 'plan'}: {a!r} there, {b!r} now"


# --------------------------------------------------------------------------- running


def _run_chunk(group: _Group, rows: list[dict], n_dev: int, tally: dict, times: dict):
  """One chunk: reset, advance until every robot is done, (episodes, curves, state) of its rows."""
  import jax
  from jaxplore import runner, sim
  size, n = group.plan["chunk_size"], len(rows)
  padded = rows + [rows[-1]] * (size - n)
  run = group.run
  params, planner_params = _group_params(run, group.plan["planner"], group.plan["names"], padded)
  p = runner.build_params(group.plan["planner"], run["preset"], group.grid.res, params, planner_params)
  params_b = sim.broadcast_params(p, size)
  keys = runner.robot_keys([r["seed"] for r in padded])
  starts = (None if group.start is None
            else jax.numpy.tile(jax.numpy.asarray(group.start, jax.numpy.float32), (size, 1)))
  config = group.config
  t0 = time.perf_counter()
  state = sim.reset_batch(config, group.world_dev, params_b, keys, starts)
  jax.block_until_ready(state)
  times["reset_s"] += time.perf_counter() - t0
  if group.compiled is None:
    t0 = time.perf_counter()
    advance = runner._compiled_advance(config, group.plan["chunk_epochs"], n_dev)
    with _count_compiles(tally):
      group.compiled = advance.lower(group.world_dev, params_b, state).compile()
    times["compile_s"] += time.perf_counter() - t0
  t0 = time.perf_counter()
  records, steps_done = [], 0
  while steps_done < config.max_steps:
    state, rec = group.compiled(group.world_dev, params_b, state)
    rec = jax.tree.map(np.asarray, rec)
    records.append(rec)
    steps_done += rec.done.shape[0]
    if np.asarray(state.done).all():
      break
  records = jax.tree.map(lambda *xs: np.concatenate(xs, axis=0)[: config.max_steps], *records)
  state_np = jax.tree.map(np.asarray, state)
  times["run_s"] += time.perf_counter() - t0
  episodes, curves = runner.tables(config, group.grid, group.world_dev, p, state_np, records,
                                   run["rate_interval"])
  row_ids = np.asarray([r["row"] for r in padded], np.int64)
  episodes = episodes.iloc[:n].copy()
  curves = curves[curves.robot < n].copy()
  episodes["robot"] = row_ids[episodes.robot.to_numpy()]
  curves["robot"] = row_ids[curves.robot.to_numpy()]
  return episodes, curves.reset_index(drop=True), state_np


def _label_episodes(episodes: pd.DataFrame, group: _Group, rows: list[dict], all_names) -> pd.DataFrame:
  episodes.insert(0, "world", group.grid.name)
  episodes.insert(1, "planner", group.plan["planner"])
  episodes.insert(2, "seed", np.asarray([r["seed"] for r in rows], np.int64))
  names = group.plan["names"]
  for k, name in enumerate(all_names):
    if name in names:
      j = names.index(name)
      column = np.asarray([r["values"][j] for r in rows], np.float64)
    else:
      column = np.full(len(rows), np.nan)
    episodes.insert(3 + k, name, column)
  return episodes


def _distributed():
  """(process index, process count) after ``jax.distributed.initialize()`` from the environment.

  ``JAX_COORDINATOR_ADDRESS`` is read by JAX; ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` by
  jaxplore (on SLURM, Open MPI, Kubernetes and Cloud TPU JAX detects all three itself).
  """
  import jax
  if not jax.distributed.is_initialized():
    kwargs = {}
    if os.environ.get("JAX_NUM_PROCESSES"):
      kwargs["num_processes"] = int(os.environ["JAX_NUM_PROCESSES"])
    if os.environ.get("JAX_PROCESS_ID"):
      kwargs["process_id"] = int(os.environ["JAX_PROCESS_ID"])
    jax.distributed.initialize(**kwargs)
  return jax.process_index(), jax.process_count()


def _barrier(name: str, n_processes: int):
  if n_processes > 1:
    from jax.experimental import multihost_utils
    multihost_utils.sync_global_devices(name)


def sweep(grid=None, seeds=None, world=None, planner=None, out=None, quiet=False, *, random=None,
          samples=None, random_seed=None, worlds=None, planners=None, chunk_size=None, resume=None,
          config=None, progress=True, devices=None, distributed=False, **run_kwargs) -> SweepResult:
  """Runs every world × planner × setting × seed in chunks; returns (and writes) the tables.

  Args:
    grid: parameter name -> list of values; names are :class:`jaxplore.config.Params` fields or
      planner weights (e.g. ``{"alpha": [1.0, 1.5], "k1": [0, 0.2]}``). Every combination is a
      setting. A weight that a planner does not have is not swept for that planner.
    seeds: seeds per setting (``range(seeds)``) or a list of seeds (default 8); seed ``s`` starts
      at the same pose in every setting (its key is ``PRNGKey(s)``).
    world: a world (name, map YAML path or GridMap) or a list of worlds (default ``building``).
    planner: a planner name or a list of them (default ``li2020``).
    out: results folder: the plan, the chunks as they finish, then the final tables and figures.
    quiet: print no summary or per-setting table (warnings and the progress bar still show).
    random: random search: name -> ``{"low", "high", "log"}`` (or ``(low, high[, "log"])`` or
      ``"LOW:HIGH[:log]"``); ``samples`` points drawn with ``random_seed`` (combined with every
      grid combination).
    worlds, planners: aliases of ``world`` and ``planner`` for lists.
    chunk_size: robot-episodes per chunk (default: at most 256, as many as fit in memory).
    resume: a sweep folder to finish: everything comes from its plan (no other setting allowed).
    config: a TOML file with the same keys as the command line (explicit arguments win).
    progress: a progress bar over robot-episodes with an ETA.
    devices: local devices to shard each chunk over (default: all).
    distributed: call ``jax.distributed.initialize()`` and split the chunks over processes.
    **run_kwargs: :func:`jaxplore.run` settings shared by every row: ``preset``, ``res``,
      ``start``, ``max_steps``, ``replan_every``, ``params``, ``planner_params``, ``pose_noise``,
      ``path_capacity``, ``chunk_epochs``, ``rate_interval``.

  Returns:
    A :class:`SweepResult`.

  Raises:
    ConfigError: a bad setting (before any compute), a folder holding another sweep, a missing
      or corrupt plan on resume, or a sweep in which one robot does not fit in memory.
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
               random_seed=random_seed, chunk_size=chunk_size, config=config,
               **{k: v for k, v in run_kwargs.items()})
  if resume is not None:
    given = sorted(k for k, v in asked.items() if v is not None)
    if given:
      raise ConfigError(f"--resume takes every setting from the sweep's plan; do not give "
                        f"{', '.join(given)}")
    if out is not None and Path(out).resolve() != Path(resume).resolve():
      raise ConfigError(f"--resume {resume} writes into that folder; do not give --out {out}")
    out = Path(resume)
  if config is not None:
    # Explicit arguments win over the file; tables ([grid], [set], ...) merge name by name.
    from_file = load_config(config)
    explicit = dict(grid=grid, seeds=seeds, world=world, planner=planner, random=random,
                    samples=samples, random_seed=random_seed, chunk_size=chunk_size,
                    devices=devices, out=out)
    for key, value in from_file.items():
      if key in ("grid", "random", "params", "planner_params"):
        mine = explicit.get(key) if key in explicit else run_kwargs.get(key)
        merged = {**value, **(mine or {})}
        if key in explicit:
          explicit[key] = merged
        else:
          run_kwargs[key] = merged
      elif key in explicit:
        explicit[key] = value if explicit[key] is None else explicit[key]
      elif run_kwargs.get(key) is None:
        run_kwargs[key] = value
    grid, seeds, world, planner = (explicit[k] for k in ("grid", "seeds", "world", "planner"))
    random, samples, random_seed = (explicit[k] for k in ("random", "samples", "random_seed"))
    chunk_size, devices, out = explicit["chunk_size"], explicit["devices"], explicit["out"]
  out = None if out is None else Path(out)

  import jax
  process, n_processes = _distributed() if distributed else (0, 1)
  if n_processes > 1 and out is None:
    raise ConfigError("a multi-process sweep needs --out on a filesystem every process can write")
  n_local = len(jax.local_devices())
  n_dev = n_local if devices is None else max(1, min(int(devices), n_local))
  grids: dict = {}

  # Process 0 checks the folder and writes the plan; the others (several hosts) read it after a
  # barrier, so that every process runs the same chunks even if their memory differs.
  plan, groups = None, None
  if resume is not None:
    plan = _read_plan(out)
    # The first collective sets up the processes' communication, which waits only ~30 s for
    # all of them: hold it now, while they are in step, not after chunks of unequal length.
    _barrier("jaxplore-sweep-resume", n_processes)
  else:
    spec = make_spec(grid, random, samples, random_seed,
                     DEFAULTS["seeds"] if seeds is None else seeds,
                     DEFAULTS["world"] if world is None else world,
                     DEFAULTS["planner"] if planner is None else planner, run_kwargs, out, grids)
    if process == 0:
      plan = _existing_plan(out, spec, quiet)
      if plan is None:
        plan, groups = _new_plan(spec, out, grids, chunk_size, n_dev)
        if out is not None:
          out.mkdir(parents=True, exist_ok=True)
          for path, gridmap in grids.items():
            _save_world(gridmap, out / path)
          _write_json(out / PLAN_FILE, plan)
    _barrier("jaxplore-sweep-plan", n_processes)
    if process != 0:
      plan = _read_plan(out)
      if plan["spec"] != spec:
        raise ConfigError(f"process {process} was given another sweep than process 0 "
                          f"({_first_difference(plan['spec'], spec)})")
  if groups is None:
    groups = _planned_groups(plan, out, grids, n_dev)
  return _execute(plan, groups, out, n_dev, quiet, progress, process, n_processes)


def _existing_plan(out: Path | None, spec: dict, quiet: bool) -> dict | None:
  """The plan already in ``out`` if it is this sweep's; refuses a folder holding anything else."""
  if out is None:
    return None
  if (out / PLAN_FILE).exists():
    try:
      existing = json.loads((out / PLAN_FILE).read_text())
      same = existing.get("spec") == spec
    except (ValueError, AttributeError):
      raise ConfigError(f"{out} holds an unreadable {PLAN_FILE}; choose another --out") from None
    if not same:
      raise ConfigError(f"{out} already holds a different sweep "
                        f"({_first_difference(existing.get('spec'), spec)}); finish it with "
                        f"`jaxplore sweep --resume {out}` or choose another --out")
    if not quiet:
      print(f"jaxplore: {out} holds this same sweep: finished chunks are kept", file=sys.stderr)
    return _read_plan(out)
  if out.exists() and any(not p.name.endswith(".tmp") for p in out.iterdir()):
    raise ConfigError(f"{out} is not empty and holds no sweep plan; choose another --out "
                      f"(or --resume DIR for an interrupted sweep)")
  return None


def _new_plan(spec: dict, out, grids: dict, chunk_size, n_dev: int) -> tuple[dict, list[_Group]]:
  """Rows, groups, chunk sizes (memory guard) and static configs of a new sweep (no compute)."""
  import jax
  groups = [_resolve_group(spec, g, out, grids) for g in _build_groups(spec)]
  first = 0
  for group in groups:
    g = group.plan
    g["chunk_size"] = _chunk_size_for(group.config, len(g["rows"]), chunk_size, n_dev)
    g["chunk_epochs"] = spec["run"]["chunk_epochs"] or _default_chunk_epochs(group.config)
    g["max_steps"] = group.config.max_steps
    g["sim_config"] = _jsonable(dataclasses.asdict(group.config))
    g["first_chunk"] = first
    g["n_chunks"] = -(-len(g["rows"]) // g["chunk_size"])
    first += g["n_chunks"]
  plan = {"format": PLAN_FORMAT, "version": PLAN_VERSION, "jaxplore_version": __version__,
          "jax_version": jax.__version__, "spec": spec,
          "names": list(spec["grid"]) + list(spec["random"]), "chunk_size_requested": chunk_size,
          "n_chunks": first, "rows": sum(len(g.plan["rows"]) for g in groups),
          "groups": [g.plan for g in groups]}
  return plan, groups


def _planned_groups(plan: dict, out: Path, grids: dict, n_dev: int) -> list[_Group]:
  """The groups of a written plan, checked to resolve as they did when it was made."""
  groups = [_resolve_group(plan["spec"], g, out, grids) for g in plan["groups"]]
  for group in groups:
    recorded, now = group.plan.get("sim_config"), _jsonable(dataclasses.asdict(group.config))
    if recorded is not None and recorded != now:
      raise ConfigError(
          f"cannot resume {out}: its plan was made by jaxplore {plan.get('jaxplore_version')} and "
          f"resolves differently here ({_first_difference(recorded, now)}); finish it with that "
          f"version or start a new sweep")
    fit_chunk(group.config, group.plan["chunk_size"], n_dev, fixed=True)
  return groups


def _default_chunk_epochs(config) -> int:
  from jaxplore.runner import default_chunk_epochs
  return default_chunk_epochs(config)


def _execute(plan, groups, out, n_dev, quiet, progress, process, n_processes) -> SweepResult:
  all_names = plan["names"]
  if out is not None:
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    for stray in (out / "chunks").glob("chunk_*.tmp"):
      # A write cut short by an interruption; each process clears its own chunks' only, since
      # another process may be writing one of its own right now.
      if int(stray.name[len("chunk_"):].split(".")[0]) % n_processes == process:
        stray.unlink(missing_ok=True)
  work = []  # (group, chunk index, rows)
  done_rows = 0
  for group in groups:
    for k, rows in _chunks_of(group.plan):
      if out is not None and _chunk_paths(out, k)[0].exists():
        done_rows += len(rows)
      elif k % n_processes == process:
        work.append((group, k, rows))
  total_rows = plan["rows"]
  tally, times = {}, {"reset_s": 0.0, "compile_s": 0.0, "run_s": 0.0}
  memory: dict[int, tuple] = {}
  bar = None
  if progress:
    from tqdm.auto import tqdm
    # smoothing=0: the ETA comes from the mean rate since the start, compile time taken out below
    bar = tqdm(total=total_rows, initial=done_rows, unit="episode", desc="sweep",
               dynamic_ncols=True, smoothing=0)
  t_start = time.perf_counter()
  ran_rows, sharded_over = 0, 0
  try:
    for i, (group, k, rows) in enumerate(work):
      size = group.plan["chunk_size"]
      dev = math.gcd(n_dev, size)
      sharded_over = max(sharded_over, dev)
      compiling = group.compiled is None
      if compiling and bar is not None:
        bar.set_description(f"sweep (compiling {group.grid.name}, {group.plan['planner']})")
      before = times["compile_s"] + times["reset_s"]
      episodes, curves, state = _run_chunk(group, rows, dev, tally, times)
      if compiling and bar is not None:
        bar.start_t += times["compile_s"] + times["reset_s"] - before  # no compile in the ETA
        bar.set_description("sweep")
      episodes = _label_episodes(episodes, group, rows, all_names)
      first_of_group = k == group.plan["first_chunk"]
      if out is not None:
        ep_path, cu_path, maps_path = _chunk_paths(out, k)
        if first_of_group:
          _save_maps(maps_path, group.grid, state, len(rows))
        _atomic_write(cu_path, lambda p: curves.to_parquet(p, index=False))
        _atomic_write(ep_path, lambda p: episodes.to_parquet(p, index=False))  # marks the chunk done
      else:
        memory[k] = (episodes, curves)
      ran_rows += len(rows)
      if bar is not None:
        bar.update(len(rows))
        bar.set_postfix(chunk=f"{i + 1}/{len(work)}", compiles=tally.get("count", 0))
  except KeyboardInterrupt:
    if bar is not None:
      bar.close()
    where = f"; finished chunks are in {out}: jaxplore sweep --resume {out}" if out else ""
    raise KeyboardInterrupt(f"sweep interrupted{where}") from None
  if bar is not None:
    bar.close()
  wall = time.perf_counter() - t_start
  _barrier("jaxplore-sweep-chunks", n_processes)

  # Assemble from the chunk files (or memory): the same bytes whether or not the sweep was resumed.
  parts_e, parts_c = [], []
  for group in groups:
    for k, rows in _chunks_of(group.plan):
      if out is not None:
        ep_path, cu_path, maps_path = _chunk_paths(out, k)
        if not ep_path.exists():
          raise ConfigError(f"chunk {k} of {out} is missing (did a process of a multi-process sweep "
                            f"fail?); run jaxplore sweep --resume {out}")
        parts_e.append(pd.read_parquet(ep_path))
        parts_c.append(pd.read_parquet(cu_path))
      else:
        parts_e.append(memory[k][0])
        parts_c.append(memory[k][1])
  episodes = pd.concat(parts_e, ignore_index=True)
  curves = pd.concat(parts_c, ignore_index=True)
  import jax
  resolved = {
      "sweep": {"names": all_names, "grid": plan["spec"]["grid"], "random": plan["spec"]["random"],
                "samples": plan["spec"]["samples"], "random_seed": plan["spec"]["random_seed"],
                "seeds": plan["spec"]["seeds"], "worlds": plan["spec"]["worlds"],
                "planners": plan["spec"]["planners"], "rows": plan["rows"], "chunks": plan["n_chunks"],
                "figure_names": _figure_names(episodes, all_names)},
      "run": plan["spec"]["run"],
      "groups": [_group_config(g) for g in groups],
      "jaxplore_version": __version__, "jax_version": jax.__version__, "numpy_version": np.__version__,
      "python": platform.python_version(), "devices": [str(d) for d in jax.local_devices()],
      "processes": n_processes,
  }
  ran = sum(1 for _ in work)
  timing = {"compile_s": times["compile_s"], "compiles": tally.get("count", 0),
            "xla_compile_s": tally.get("seconds", 0.0), "reset_s": times["reset_s"],
            "run_s": times["run_s"], "wall_s": wall, "chunks": plan["n_chunks"],
            "chunks_run": ran, "chunks_skipped": plan["n_chunks"] - ran,
            "robot_episodes": total_rows, "robot_episodes_run": ran_rows,
            "sharded_over": sharded_over,
            "robot_episodes_per_hour": ran_rows / wall * 3600 if wall > 0 and ran_rows else float("nan")}
  result = SweepResult(episodes, curves, resolved, timing, out)
  if out is not None and process == 0:
    _write_final(result, out, groups, all_names)
  if not quiet and len(episodes):
    from jaxplore.runner import summary_table
    print(summary_table(episodes))
    print(sweep_table(episodes, _figure_names(episodes, all_names)))
  return result


def _group_config(group: _Group) -> dict:
  from jaxplore import runner
  run = group.run
  params, planner_params = _group_params(run, group.plan["planner"], [], [])
  p = runner.build_params(group.plan["planner"], run["preset"], group.grid.res, params, planner_params)
  to_float, swept = runner._to_float, set(group.plan["names"])
  return {
      "world": {"name": group.grid.name, "shape": list(group.grid.shape), "res": group.grid.res,
                "origin": list(group.grid.origin), "free_m2": group.grid.free_area,
                "reachable_m2": float(group.world_dev.n_reachable) * group.grid.res**2},
      "planner": group.plan["planner"], "swept": group.plan["names"],
      "rows": [group.plan["rows"][0]["row"], group.plan["rows"][-1]["row"] + 1],
      "chunk_size": group.plan["chunk_size"], "chunk_epochs": group.plan["chunk_epochs"],
      "sim_config": dataclasses.asdict(group.config),
      "fixed_params": {k: to_float(v) for k, v in dataclasses.asdict(p).items()
                       if k != "planner" and k not in swept},
      "fixed_planner_params": {k: to_float(v) for k, v in p.planner.items() if k not in swept},
  }


def _save_maps(path: Path, grid, state, n: int):
  shown = min(4, n)

  def write(tmp):
    with open(tmp, "wb") as f:
      np.savez_compressed(f, occupied=grid.occupied, res=grid.res, origin=np.asarray(grid.origin),
                          logodds=np.asarray(state.logodds[:shown]).astype(np.float16))
  _atomic_write(path, write)


def _figure_names(episodes: pd.DataFrame, names) -> list[str]:
  """What a setting is in the figure and table: world and planner when they vary, then the names."""
  keys = [c for c in ("world", "planner") if episodes[c].nunique() > 1]
  keys += [n for n in names]
  return keys or ["planner"]


def _write_final(result: SweepResult, out: Path, groups, names):
  from jaxplore import plot
  _write_json(out / "config.json", result.config)
  _write_json(out / "timing.json", result.timing)
  _atomic_write(out / "episodes.parquet", lambda p: result.episodes.to_parquet(p, index=False))
  _atomic_write(out / "curves.parquet", lambda p: result.curves.to_parquet(p, index=False))
  maps = _chunk_paths(out, groups[0].plan["first_chunk"])[2]
  _atomic_write(out / "maps.npz", lambda p: p.write_bytes(maps.read_bytes()))
  plot.run_figures(out)  # map, curves and (config.json naming a sweep) sweep.png


def sweep_table(episodes: pd.DataFrame, names) -> str:
  """Mean ± std of the headline metrics per setting."""
  from jaxplore import metrics
  episodes = episodes.copy()
  for name in names:  # NaN (a weight the planner lacks) is a setting of its own, not dropped
    if episodes[name].isna().any():
      episodes[name] = episodes[name].astype(object).where(episodes[name].notna(), "-")
  table = metrics.summarise(episodes, names, ["E_r", "Std_E_r", "distance_m", "coverage", "time_s"])
  cols = list(names) + [c for c in table.columns if c.endswith("_mean") or c.endswith("_std")]
  return table[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}")


__all__ = ["SweepResult", "sweep", "load_config", "fit_chunk", "parse_random_spec", "sweep_table",
           "PLAN_FILE"]
