"""The run specification: every setting of one batch of robots, with one set of defaults.

A :class:`RunSpec` is what a user asks for, before anything is loaded or sized: the world, the
planner, how many robots and their seeds, the sensor/robot preset and every override. The
command line (``jaxplore run``), TOML files, the rows of a sweep, ``jaxplore animate`` (from a
results folder's ``config.json``) and the benchmarks all build one, and
:func:`jaxplore.resolve.resolve` turns it into the device-side batch. Its field defaults are
the only defaults of these settings; ``None`` means "derived" (from the world, the preset or the
sensor range) where a field allows it.

Construction checks every value that needs no map or planner registry (types, ranges, seeds,
the start pose, parameter names), so a bad setting is refused before any compute; the rest
(planner weights, ranges that depend on the grid) is checked by the resolver.

Every setting is declared once (:mod:`jaxplore.settings`): the run's own (this class's
declared fields, :data:`RUN_SETTINGS`: flags of ``jaxplore run``, top-level TOML keys), traced
simulator parameters (:class:`jaxplore.config.Params`; sweeping them never
recompiles), static simulator settings (:data:`STATIC_PARAMS`: each value is a compiled program
of its own), a planner's traced weights and its static settings (:func:`kind_of`). A user names
any of them in ``params`` (``--set``, a TOML ``[set]`` table) without saying whose it is:
construction moves a run setting to its field and a planner's name to ``planner_params``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import types
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np

from jaxplore.config import (
  PARAM_FIELDS,
  PRESETS,
  SLAM_MODELS,
  STATIC_SETTINGS,
  STRATEGIES,
  ConfigError,
  SimConfig,
  retired_hint,
)
from jaxplore.settings import declared, setting

# The static simulator settings a user sets by name (each value is a compiled program of its
# own), as SimConfig declares them.
STATIC_PARAMS = tuple(STATIC_SETTINGS)
WORD_PARAMS = tuple(name for name, s in STATIC_SETTINGS.items() if s.choices)  # e.g. slam
# Word settings that also take an object (a sensor): name -> its type.
OBJECT_PARAMS = {name: s.objects for name, s in STATIC_SETTINGS.items() if s.objects is not None}
SIM_PARAMS = PARAM_FIELDS + tuple(n for n in STATIC_PARAMS if n not in PARAM_FIELDS)
SEED_LIMIT = 2**32  # a PRNG seed is a uint32: larger seeds would alias smaller ones
AXES = ("world", "planner", "robots", "seed", "robot_seeds")  # what a sweep varies row by row
_EMPTY: Mapping = types.MappingProxyType({})


def _is_int(value) -> bool:
  return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value) -> bool:
  return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
      value, (bool, np.bool_))


def number(value, what: str) -> float:
  """``value`` as a finite float, or :class:`ConfigError` naming ``what``."""
  if not _is_number(value):
    raise ConfigError(f"{what} must be a number, got {value!r}")
  value = float(value)
  if not math.isfinite(value):
    raise ConfigError(f"{what} must be finite, got {value!r}")
  return value


def seed_value(value, what: str = "seed") -> int:
  """A PRNG seed: an integer in [0, 2**32) (``PRNGKey`` takes a uint32; larger seeds alias)."""
  if not _is_int(value) or not 0 <= value < SEED_LIMIT:
    raise ConfigError(f"{what} must be an integer in [0, 2**32), got {value!r}")
  return int(value)


def parse_start(start) -> tuple[float, float, float] | None:
  """``"x,y"``, ``"x,y,theta"`` or a sequence of 2 or 3 numbers (metres, radians)."""
  if start is None:
    return None
  try:
    values = [float(v) for v in (start.split(",") if isinstance(start, str) else start)]
  except (TypeError, ValueError):
    values = []
  if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
    raise ConfigError(f"start must be 'x,y' or 'x,y,theta' in metres/radians, got {start!r}")
  return (values[0], values[1], values[2] if len(values) == 3 else 0.0)


def _value(value, what: str, text_allowed: bool = False):
  """A setting's value: a finite number, one number per robot (a tuple), or (``text_allowed``:
  a planner's table, whose settings then check it) a bool (a static switch) or a string (such
  as li2020's ``region``)."""
  if isinstance(value, (bool, np.bool_)):
    if not text_allowed:  # the simulator has no switch among its parameters: true is no length
      raise ConfigError(f"{what} must be a number, got {value!r}")
    return bool(value)
  if isinstance(value, str) and text_allowed:
    return value
  if isinstance(value, (str, bytes)):
    raise ConfigError(f"{what} must be a number, got {value!r}")
  if _is_number(value) or (isinstance(value, np.ndarray) and value.ndim == 0):
    return number(value.item() if isinstance(value, np.ndarray) else value, what)
  if hasattr(value, "__iter__"):
    value = list(value)
    if text_allowed and value and all(isinstance(v, str) for v in value):
      return tuple(value)  # one word per robot (a sweep's rows of a word-valued setting)
    values = tuple(number(v.item() if isinstance(v, np.generic) else v, what) for v in value)
    if not values:
      raise ConfigError(f"{what} has no values")
    return values
  raise ConfigError(f"{what} must be a number, got {value!r}")


def _mapping(values, what: str, text_allowed: bool = False, words=()) -> Mapping:
  """``values`` checked name by name (:func:`_value`); ``words``: names that take a word even
  where ``text_allowed`` is off (the simulator's word-valued settings, such as ``slam``)."""
  if values is None:
    return _EMPTY
  if not isinstance(values, Mapping):
    raise ConfigError(f"{what} must map names to numbers, got {values!r}")
  return types.MappingProxyType({
      str(k): v if isinstance(v, OBJECT_PARAMS.get(str(k), ())) else
      _value(v, f"{what}[{k!r}]", text_allowed or (str(k) in words and not
                                                   isinstance(v, (bool, np.bool_))))
      for k, v in values.items()})


def route_settings(params: Mapping | None, planner_params: Mapping | None,
                   planners) -> tuple[dict, dict]:
  """(params, planner_params) with each name in the table it belongs to: a user names a setting
  without saying whose it is, so a weight or setting of one of ``planners`` (names) may come in
  ``params`` (``--set``) and a simulator parameter in ``planner_params``. A name given to both
  tables is refused; an unknown planner is left to be refused where it is looked up."""
  from jaxplore.planners import PlannerSpec, get_planner
  params, planner_params = dict(params or {}), dict(planner_params or {})
  one = isinstance(planners, (str, PlannerSpec))
  try:
    specs = [get_planner(p) for p in ([planners] if one else planners)]
  except ConfigError:
    return params, planner_params
  theirs = [n for n in params if any(kind_of(str(n), s) in ("weight", "setting") for s in specs)]
  ours = [n for n in planner_params if n in SIM_PARAMS]
  for name in theirs + ours:
    if name in params and name in planner_params:
      raise ConfigError(f"{name} is given twice (as a simulator parameter and a planner "
                        f"parameter); give it once")
  planner_params.update({n: params.pop(n) for n in theirs})
  params.update({n: planner_params.pop(n) for n in ours})
  return params, planner_params


def _refuse_unknown_params(params: Mapping, planner) -> None:
  """Refuses names in ``params`` that are no simulator parameter (a planner's were moved to
  ``planner_params`` before), listing the valid names."""
  unknown = sorted(set(map(str, params)) - set(SIM_PARAMS))
  if not unknown:
    return
  message = f"{retired_hint(unknown)}unknown parameter(s) {unknown}; valid: {', '.join(SIM_PARAMS)}"
  from jaxplore.planners import get_planner
  try:
    spec = get_planner(planner)
  except ConfigError:
    raise ConfigError(message) from None
  settings = planner_settings_of(spec)
  theirs = sorted(spec.defaults) + sorted(
      f.name for f in (dataclasses.fields(settings) if settings is not None else ()))
  from jaxplore.planners import planner_names
  owners = {name: [other for other in planner_names()
                   if kind_of(name, get_planner(other)) in ("weight", "setting")]
            for name in unknown}
  whose = "; ".join(f"{name}: planner {', '.join(found)}'s"
                    for name, found in owners.items() if found)
  raise ConfigError(f"{message}; of planner {spec.name!r}: {', '.join(theirs) or 'none'} "
                    f"(jaxplore settings --planner {spec.name} lists them with their ranges)"
                    + (f"; {whose}" if whose else ""))


@dataclasses.dataclass(frozen=True)
class RunSpec:
  """Every setting of one batch of robots (frozen; the field defaults are *the* defaults).

  Attributes:
    world: a built-in world name (``jaxplore maps``), a map_server YAML path, or a GridMap.
    planner: a registered planner's name, or a planner object
      (:class:`jaxplore.planners.PlannerSpec`, registered or not).
    robots: batch size.
    seed: robot ``b``'s PRNG key is the ``b``-th of ``robots`` keys split from ``PRNGKey(seed)``.
    robot_seeds: or one seed per robot, robot ``b``'s key being ``PRNGKey(robot_seeds[b])`` (the
      same seed starts at the same pose in every setting: what a sweep uses).
    preset: sensor/robot preset (``jaxplore.config.PRESETS``), or None for the bare defaults.
    res: resample a loaded world to this resolution (m/cell; coarser only).
    start: (x, y, θ) start pose of every robot, or None to sample one per robot.
    max_steps: step budget per robot; None: from the world's free area, its walls' length and
      the robot's speed (:func:`jaxplore.resolve.default_max_steps`).
    replan_every: steps between planning rounds of a robot following a path; None: the preset's.
    path_capacity: waypoints a path may hold; None: the engine's default.
    plan_window: side in cells of the window a ``windowed`` planner plans on first (0: the whole
      grid always); None: sized from the sensor range.
    pose_noise: noisy odometry, scans integrated at the dead-reckoned estimate.
    slam: the SLAM model, ``"oracle"`` or ``"scan_matching"``
      (:attr:`jaxplore.config.SimConfig.slam`): the same as ``params["slam"]``, where
      construction puts it (this field is then None); unset: ``"oracle"``.
    pose_graph: keep each robot's SLAM pose graph and its metrics (:mod:`jaxplore.posegraph`);
      None: when the planner reads one (ahmed, ags).
    graph_loops: loop-closure capacity of the pose graph; None: the engine's default.
    params: simulator parameters (``--set``): a number for every robot, or a tuple with one
      number per robot.
    planner_params: the planner's weights and static settings (``--planner-set``), likewise.
    rate_interval: metres per interval of ``Std(E_r)``.
    chunk_epochs: planning rounds per compiled call (progress and early-stop granularity; the
      results do not depend on it); None: about 500 steps.
    strategy: how the batch is executed, ``"per_robot"`` or ``"lockstep"``
      (:data:`jaxplore.config.STRATEGIES`; the results do not depend on it); None or ``"auto"``:
      per_robot on a CPU, lockstep on a GPU or TPU (:func:`jaxplore.config.resolve_strategy`).
  """

  world: Any = "office"
  planner: Any = "nearest_frontier"
  robots: int = setting(16, "robots in the batch", owner="run", static=True, ge=1,
                       integer=True)
  seed: int = 0
  robot_seeds: tuple[int, ...] | None = None
  preset: str | None = setting("li2020", "the sensor and robot of a paper (r_max, fov, v_max, "
                               "w_max, beams); the planner's paper's where it brings one",
                               owner="run", static=True, choices=tuple(PRESETS),
                               unset="the bare defaults")
  res: float | None = setting(None, "resample a loaded world to this resolution (coarser only)",
                              owner="run", unit="m/cell", static=True, gt=0,
                              unset="the map's own")
  start: tuple[float, float, float] | None = None
  max_steps: int | None = setting(None, "step budget per robot", owner="run", static=True, ge=1,
                                  integer=True, unset="from the world's free area, its walls' "
                                  "length and the robot's speed")
  replan_every: int | None = setting(None, "motion steps between planning rounds of a robot "
                                     "on its path", owner="run", static=True, ge=1, integer=True,
                                     unset="the preset's")
  path_capacity: int | None = setting(None, "waypoints a path may hold (the robot's own cell "
                                      "first, then where it goes)", owner="run",
                                      static=True, ge=2, integer=True,
                                      unset=str(SimConfig.path_capacity))
  plan_window: int | None = setting(None, "side in cells of the window a windowed planner "
                                    "(nearest frontier, fd) plans on first (0: the whole grid)",
                                    owner="run", static=True, ge=0, integer=True,
                                    unset="sized from the sensor range")
  pose_noise: bool = setting(False, "noisy odometry, scans integrated at the dead-reckoned "
                             "estimate (on with slam = scan_matching)", owner="run",
                             static=True, boolean=True)
  slam: str | None = None
  pose_graph: bool | None = setting(None, "keep each robot's SLAM pose graph and its metrics",
                                    owner="run", static=True, boolean=True,
                                    unset="when the planner reads one (ahmed, ags) or with "
                                    "slam = scan_matching")
  graph_loops: int | None = setting(None, "loop-closure capacity of the pose graph",
                                    owner="run", static=True, ge=1, integer=True,
                                    unset=f"with slam = scan_matching: the closures and "
                                    f"near links the run's distance allows "
                                    f"(posegraph.loop_bound); else {SimConfig.graph_loops}")
  params: Mapping[str, Any] = dataclasses.field(default_factory=lambda: _EMPTY)
  planner_params: Mapping[str, Any] = dataclasses.field(default_factory=lambda: _EMPTY)
  rate_interval: float = setting(1.0, "metres per interval of Std(E_r)", owner="run", unit="m",
                                 host=True, gt=0)
  chunk_epochs: int | None = setting(None, "planning rounds per compiled call (progress and "
                                     "early-stop granularity; the results do not depend on it)",
                                     owner="run", host=True, ge=1, integer=True,
                                     unset="about 500 steps")
  strategy: str | None = setting(None, "how the batch is executed: per_robot (robots one or a "
                                 "few at a time through the irregular stages) or lockstep (one "
                                 "kernel per stage for the whole batch); the results do not "
                                 "depend on it", owner="run", static=True, choices=STRATEGIES,
                                 unset="auto: per_robot on a CPU, lockstep on a GPU or TPU")

  def __post_init__(self):
    put = lambda name, value: object.__setattr__(self, name, value)
    world = self.world
    if isinstance(world, os.PathLike):
      put("world", str(world))
    elif not isinstance(world, str) and type(world).__name__ != "GridMap":
      raise ConfigError(f"world must be a world name, a map YAML path or a GridMap, got {world!r}")
    from jaxplore.planners import PlannerSpec
    if not isinstance(self.planner, (str, PlannerSpec)):
      raise ConfigError(f"planner must be a planner name or a PlannerSpec, got {self.planner!r}")
    if isinstance(self.params, Mapping):  # a run setting named in --set / [set]
      for name in [n for n in self.params if n in RUN_SETTINGS]:
        value, mine = self.params[name], getattr(self, name)
        if mine != RUN_SETTINGS[name].default and mine != value:
          raise ConfigError(f"{name} is given twice, as {mine!r} and {value!r}")
        put(name, value)
        put("params", {k: v for k, v in self.params.items() if k != name})
    for name, declaration in RUN_SETTINGS.items():
      put(name, declaration.convert(getattr(self, name), name))
    put("seed", seed_value(self.seed))
    if self.robot_seeds is not None:
      if isinstance(self.robot_seeds, (str, bytes)) or not hasattr(self.robot_seeds, "__iter__"):
        raise ConfigError(f"robot_seeds must be a list of seeds, got {self.robot_seeds!r}")
      seeds = tuple(seed_value(s, "a robot seed") for s in self.robot_seeds)
      if len(seeds) != self.robots:
        raise ConfigError(f"robot_seeds has {len(seeds)} seeds for {self.robots} robots")
      put("robot_seeds", seeds)
    put("start", parse_start(self.start))
    if isinstance(self.params, Mapping) and isinstance(self.planner_params, Mapping):
      params, planner_params = route_settings(self.params, self.planner_params, self.planner)
      put("params", params)
      put("planner_params", planner_params)
    if isinstance(self.params, Mapping):  # names first: a planner's word is no number either
      _refuse_unknown_params(self.params, self.planner)
    params = _mapping(self.params, "params", words=WORD_PARAMS)
    for name in WORD_PARAMS:
      value = params.get(name)
      for word in (value if isinstance(value, tuple) else () if value is None else (value,)):
        STATIC_SETTINGS[name].check(word, name)
    if self.slam is not None:  # the flag --slam is the setting slam
      if self.slam not in SLAM_MODELS:
        raise ConfigError(f"slam must be one of {', '.join(SLAM_MODELS)}, got {self.slam!r}")
      if params.get("slam", self.slam) != self.slam:
        raise ConfigError(f"slam is given twice, as {self.slam!r} and {params['slam']!r}")
      params = types.MappingProxyType({**params, "slam": self.slam})
      put("slam", None)
    put("params", params)
    put("planner_params", _mapping(self.planner_params, "planner_params", text_allowed=True))
    for what, values in (("parameter", params), ("planner parameter", self.planner_params)):
      for name, value in values.items():
        if isinstance(value, tuple) and len(value) != self.robots:
          raise ConfigError(f"{what} {name} has {len(value)} values for {self.robots} robots")

  @classmethod
  def create(cls, **settings) -> RunSpec:
    """A spec from keyword settings, where None means "the default" (what the CLI passes);
    ``robot_seeds`` without ``robots`` gives one robot per seed; without a ``preset``, a
    planner that brings its paper's preset (``PlannerSpec.preset``) runs with it, and without
    a ``slam`` (here or in ``params``), with its paper's SLAM model (``PlannerSpec.slam``)."""
    unknown = sorted(set(settings) - set(FIELDS))
    if unknown:
      raise ConfigError(f"unknown setting(s) {unknown}; valid: {', '.join(FIELDS)}")
    settings = {k: v for k, v in settings.items() if v is not None}
    from jaxplore.planners.base import planner_brings
    if "preset" not in settings:
      preset = planner_brings(settings.get("planner", cls.planner), "preset")
      if preset is not None:
        settings["preset"] = preset
    if "slam" not in settings and "slam" not in (settings.get("params") or {}):
      slam = planner_brings(settings.get("planner", cls.planner), "slam")
      if slam is not None:
        settings["slam"] = slam
    seeds: Any = settings.get("robot_seeds")  # any value; sized ones are counted below
    if "robots" not in settings and hasattr(seeds, "__len__") and not isinstance(seeds, str):
      settings["robots"] = len(seeds)  # one robot per seed
    return cls(**settings)

  def to_json(self, fields=None) -> dict:
    """The JSON form (``config.json``, a sweep's schedule); a GridMap world is named, not stored."""
    out = {}
    for name in fields or FIELDS:
      value = getattr(self, name)
      if name == "world" and not isinstance(value, str):
        value = {"grid": value.name}
      elif name == "planner" and not isinstance(value, str):
        value = value.name  # a PlannerSpec: results name it
      elif isinstance(value, Mapping):  # an object (a sensor) is recorded by its name
        value = {k: list(v) if isinstance(v, tuple) else
                 cast(Any, v).name if isinstance(v, tuple(OBJECT_PARAMS.values())) else v
                 for k, v in value.items()}
      elif isinstance(value, tuple):
        value = list(value)
      out[name] = value
    return out

  @property
  def planner_name(self) -> str:
    """The planner's name (results and labels record it)."""
    return self.planner if isinstance(self.planner, str) else self.planner.name

  @classmethod
  def from_json(cls, data: dict, **replace) -> RunSpec:
    """The spec of :meth:`to_json`'s dict (missing fields take their defaults); ``replace``
    overrides fields (e.g. the world, when the JSON names a GridMap)."""
    unknown = sorted(set(data) - set(FIELDS))
    if unknown:
      raise ConfigError(f"unknown run setting(s) {unknown}; valid: {', '.join(FIELDS)}")
    return cls(**{**data, **replace})


RUN_SETTINGS = declared(RunSpec)  # the run's own settings (owner "run")
FIELDS = tuple(f.name for f in dataclasses.fields(RunSpec))
SHARED = tuple(name for name in FIELDS if name not in AXES)  # what every row of a sweep shares


def planner_settings_of(planner_spec):
  """A registered planner's static settings (a frozen dataclass instance), or None."""
  return getattr(planner_spec, "settings", None)


def kind_of(name: str, planner_spec) -> str | None:
  """What a parameter name sets for a planner: ``"param"`` (traced simulator parameter),
  ``"static"`` (static simulator setting), ``"weight"`` (the planner's traced weight),
  ``"setting"`` (the planner's static setting), or None (nothing)."""
  if name in STATIC_PARAMS:
    return "static"
  if name in PARAM_FIELDS:
    return "param"
  if name in planner_spec.defaults:
    return "weight"
  settings = planner_settings_of(planner_spec)
  if settings is not None and name in {f.name for f in dataclasses.fields(settings)}:
    return "setting"
  return None


def is_static(name: str, planner_spec) -> bool:
  """Whether a value of ``name`` fixes the compiled program (rows with different values of it
  cannot share a batch)."""
  return kind_of(name, planner_spec) in ("static", "setting")


# --------------------------------------------------------------------------- TOML

# Keys of a settings file, shared by `jaxplore run --config` and `jaxplore sweep --config`.
TOML_KEYS = {
    "world": "a world name or map YAML path (a list of them in a sweep)",
    "worlds": "a list of worlds (sweep)",
    "planner": "a planner name (a list of them in a sweep)",
    "planners": "a list of planners (sweep)",
    "seed": "PRNG seed of the batch (run)",
    "robot_seeds": "one PRNG seed per robot, instead of seed (run)",
    "seeds": "number of seeds, or a list of seeds (sweep)",
    "start": "x,y[,theta] start of every robot",
    "slam": "SLAM model: oracle or scan_matching",
    **{name: declaration.help for name, declaration in RUN_SETTINGS.items()},
    "chunk_size": "robot-episodes per chunk (sweep)",
    "out": "results folder",
    "devices": "local devices to shard over",
    "grid": "[grid] table: name = [values] (sweep)",
    "random": "[random] table: name = {low=, high=, log=}, samples = N, seed = S (sweep)",
    "set": "[set] table: any setting by name (jaxplore settings lists them)",
    "planner_set": "[planner_set] table: the same as [set] (kept for older files)",
}
RUN_ONLY = ("robots", "seed", "robot_seeds")
SWEEP_ONLY = ("worlds", "planners", "seeds", "chunk_size", "grid", "random")
RUN_TOML_KEYS = tuple(k for k in TOML_KEYS if k not in SWEEP_ONLY)


def read_toml(path) -> tuple[dict, str]:
  """(the parsed table, the path as text) of a settings file; :class:`ConfigError` when it is
  missing, not a regular file, or not valid TOML."""
  if sys.version_info >= (3, 11):
    import tomllib
  else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib
  path = Path(path)
  try:
    text = path.read_text()
  except FileNotFoundError:
    raise ConfigError(f"settings file {str(path)!r} not found") from None
  except (IsADirectoryError, PermissionError, UnicodeDecodeError) as err:
    raise ConfigError(f"cannot read settings file {str(path)!r}: {err}") from None
  try:
    return tomllib.loads(text), str(path)
  except tomllib.TOMLDecodeError as err:
    raise ConfigError(f"{path}: not valid TOML: {err}") from None


def settings_from_toml(data: dict, where: str, allowed) -> dict:
  """Keyword settings of the keys of ``data`` that a run spec holds, typed and checked key by
  key (the table names of the file become ``params`` and ``planner_params``); ``out`` and
  ``devices`` too. Keys outside ``allowed`` are refused naming them."""
  for key in data:
    if key not in allowed:
      random_key = key in ("samples", "random_seed") or (key == "seed" and "seed" not in allowed)
      hint = (" (samples and seed of a random search go in the [random] table)"
              if random_key and "random" in allowed else "")
      raise ConfigError(f"{where}: unknown key {key!r}{hint}; valid keys: {', '.join(allowed)}")

  def typed(key, kinds, what):
    value = data[key]
    kinds = kinds if isinstance(kinds, tuple) else (kinds,)
    if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
      raise ConfigError(f"{where}: {key} must be {what}, got {value!r}")
    return value

  def table(key):
    value = data[key]
    if not isinstance(value, dict):
      raise ConfigError(f"{where}: {key} must be a table ([{key}]), got {value!r}")
    return value

  kwargs: dict = {}
  for key, declaration in RUN_SETTINGS.items():
    if key in data:
      kwargs[key] = declaration.convert(data[key], f"{where}: {key}")
  if "devices" in data:
    value = typed("devices", int, "a positive integer")
    if value < 1:
      raise ConfigError(f"{where}: devices must be a positive integer, got {value!r}")
    kwargs["devices"] = value
  if "seed" in data:
    kwargs["seed"] = seed_value(typed("seed", int, "an integer"), f"{where}: seed")
  if "robot_seeds" in data:
    kwargs["robot_seeds"] = [seed_value(s, f"{where}: a robot seed")
                             for s in typed("robot_seeds", list, "a list of seeds")]
  if "slam" in data:
    kwargs["slam"] = typed("slam", str, "oracle or scan_matching")
  if "start" in data:
    kwargs["start"] = typed("start", (str, list), "'x,y[,theta]' or [x, y, theta]")
  if "out" in data:
    kwargs["out"] = typed("out", str, "a folder path")
  for key, target in (("set", "params"), ("planner_set", "planner_params")):
    if key in data:  # a planner's names take words; a run spec checks them
      numeric = lambda name: name in SIM_PARAMS and name not in WORD_PARAMS
      kwargs[target] = {name: _value(v, f"{where}: [{key}] {name}", not numeric(name))
                        for name, v in table(key).items()}
  return kwargs


def merge_settings(from_file: dict, explicit: dict) -> dict:
  """Settings of a TOML file under explicit ones: an explicit value (not None) wins; tables
  (grid, random, params, planner_params) merge name by name, explicit names winning."""
  merged = dict(explicit)
  for key, value in from_file.items():
    mine = merged.get(key)
    if key in ("grid", "random", "params", "planner_params"):
      merged[key] = {**value, **(mine or {})}
    elif mine is None:
      merged[key] = value
  return merged


def load_run_config(path) -> dict:
  """Reads a run's TOML file (the keys of :data:`RUN_TOML_KEYS`) into keyword settings of
  :func:`jaxplore.run` (``out`` and ``devices`` included), validated key by key."""
  data, where = read_toml(path)
  kwargs = settings_from_toml({k: v for k, v in data.items() if k not in ("world", "planner")},
                              where, RUN_TOML_KEYS)
  for key in ("world", "planner"):
    if key in data:
      if not isinstance(data[key], str):
        raise ConfigError(f"{where}: {key} must be a name, got {data[key]!r}")
      kwargs[key] = data[key]
  return kwargs


__all__ = ["RunSpec", "FIELDS", "SHARED", "AXES", "STATIC_PARAMS", "SIM_PARAMS", "TOML_KEYS",
           "RUN_TOML_KEYS", "kind_of", "is_static", "load_run_config",
           "merge_settings", "number", "parse_start",
           "read_toml", "route_settings",
           "seed_value", "settings_from_toml", "planner_settings_of"]
