"""The planner contract shared by every paper's planner, and the registry.

A planner plans for ONE robot (the engine batches it with ``vmap``) and sees the belief, never
the truth. The engine knows no paper: a planner declares what it needs when it registers (its
traced weights, its static settings and how the run sizes them, a per-robot memory, whether it
commits to a goal, a per-step hook) and the engine provides exactly that.

Two signatures:

- stateless: ``plan(ctx, view, robot, params, key) -> Plan``;
- with memory (``init_memory`` given): ``plan(ctx, view, robot, params, key, memory) ->
  (Plan, memory)``, ``init_memory(ctx, params) -> memory`` (a pytree of fixed shapes for one
  robot, kept in ``State.memory`` and written back only for robots that planned).

``ctx`` is a :class:`PlannerContext` (static: the grid the planner sees, its resolution, the
path capacity, solver bounds, the planner's own settings); ``params`` holds the traced numbers
(sensor, robot, ``params.planner[name]`` weights).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

import chex
import jax.numpy as jnp

from jaxplore import pytrees
from jaxplore.errors import ConfigError
from jaxplore.graph.dijkstra import STRATEGY_BATCHING, ShortestPaths, shortest_paths
from jaxplore.settings import Setting, declared


@dataclasses.dataclass(frozen=True)
class PlannerContext:
  """Static facts a planner may use (hashable, part of the compiled program's cache key).

  Attributes:
    height, width: the grid the planner sees (a window's, when the engine plans on one).
    res: metres per cell.
    path_capacity: waypoints a :class:`Plan` holds.
    dijkstra_max_sweeps: bound on cone-sweep rounds of the shortest-path solver.
    dijkstra_tiles_after_rounds: the solver's ``tiles_after_rounds`` (0 = never).
    max_inflation_cells: bound of the robot radius in cells.
    max_steps: the episode's step budget (for capacity checks before compute).
    settings: the planner's static settings (its registered frozen dataclass, resolved), or None.
    strategy: the engine's execution strategy (``SimConfig.strategy``, ``"per_robot"`` or
      ``"lockstep"``): a planner may shape its kernels by it, never its results.
  """

  height: int
  width: int
  res: float
  path_capacity: int = 256
  dijkstra_max_sweeps: int = 512
  dijkstra_tiles_after_rounds: int = 0
  max_inflation_cells: int = 3
  max_steps: int = 2000
  settings: Any = None
  strategy: str = "per_robot"

  def shortest_paths(self, node_cost, source) -> ShortestPaths:
    """:func:`jaxplore.graph.shortest_paths` from ``source`` with the run's solver bounds, batched
    under ``vmap`` as the execution strategy wants (:data:`jaxplore.graph.STRATEGY_BATCHING`)."""
    chunk, method = STRATEGY_BATCHING[self.strategy]
    return shortest_paths(node_cost, source, max_sweeps=self.dijkstra_max_sweeps,
                          tiles_after_rounds=self.dijkstra_tiles_after_rounds,
                          vmap_chunk=chunk, vmap_method=method)


@pytrees.dataclass(frozen=True)
class BeliefView:
  """What a planner may look at (one robot).

  Attributes:
    logodds: f32[H, W] occupancy belief.
    free, occupied, unknown: bool[H, W] belief classes.
    inflated: bool[H, W] cells within the robot radius of a believed-occupied cell.
    traversable: bool[H, W] free cells clear of occupied cells by the robot radius.
    frontier: bool[H, W] free cells next to unknown ones (see :func:`mapping.frontier`).
    blacklist: bool[H, W] goals the engine found unresolvable for this robot.
    pose_graph: the robot's SLAM pose graph (:class:`jaxplore.posegraph.PoseGraph`); None unless
      the planner registered ``needs_pose_graph``.
  """

  logodds: chex.Array
  free: chex.Array
  occupied: chex.Array
  unknown: chex.Array
  inflated: chex.Array
  traversable: chex.Array
  frontier: chex.Array
  blacklist: chex.Array
  pose_graph: Any = None

  if TYPE_CHECKING:  # chex.dataclass adds it at runtime
    def replace(self, **changes: Any) -> BeliefView: ...


@pytrees.dataclass(frozen=True)
class RobotView:
  """The robot as it believes itself to be: estimated pose (m, rad), its cell, covariance Σ,
  and where it stands in cell units (the fraction of its cell included), or None where the
  caller did not say."""

  pose: chex.Array  # f32[3]
  cell: chex.Array  # i32[2] (row, col)
  cov: chex.Array  # f32[3, 3]
  position: Any = None  # f32[2] (row, col) in cells: ``cell`` is its floor


@pytrees.dataclass(frozen=True)
class Plan:
  """A planner's answer for one robot.

  Attributes:
    waypoints: i32[L, 2] cells (row, col) from the robot's cell on; only ``length`` are valid.
    length: i32, number of valid waypoints (0 = no plan).
    goal: i32[2], the cell the plan is for (for bookkeeping: blacklist, figures).
    look_at: i32[2], a cell to face once the last waypoint is reached (e.g. the unknown cell
      behind a frontier), so narrow field-of-view sensors see what the goal was chosen for.
    valid: bool, a candidate was found.
    gain: f32, the planner's utility of the chosen candidate (planner-defined units).
    cost: f32, path cost of the chosen candidate (m, weighted by the planner's edge weights).
    n_candidates: i32, how many candidates the planner scored.
  """

  waypoints: chex.Array
  length: chex.Array
  goal: chex.Array
  look_at: chex.Array
  valid: chex.Array
  gain: chex.Array
  cost: chex.Array
  n_candidates: chex.Array

  if TYPE_CHECKING:  # chex.dataclass adds it at runtime
    def replace(self, **changes: Any) -> Plan: ...


PlanFn = Callable[..., Plan]


@dataclasses.dataclass(frozen=True)
class PlannerSpec:
  """A planner: its function, its settings and what it asks of the engine.

  A static, hashable value (equal specs share a compiled program): the engine is handed this
  object (``SimConfig.planner``), never a name to look up; a changed static setting is a new
  spec (:meth:`with_settings`). Build one with :func:`planner`; :func:`register` lists it under
  its name for the command line.

  Attributes:
    name: the planner's name (command line ``--planner``; results record it).
    plan: the plan function (see the module docstring for its two signatures).
    defaults: traced weights, name -> default value (``params.planner[name]``; sweeping them
      never recompiles).
    weights: their declarations (:class:`jaxplore.settings.Setting`, name -> declaration), where
      the planner registered a weights dataclass: each weight's help and range, checked before
      compute.
    summary: one line for listings.
    settings: the planner's static settings, a frozen dataclass instance (``ctx.settings``; a
      change recompiles; they may fix shapes), or None. A registered spec holds their defaults.
    validate: optional host-side check before compute,
      ``validate(weights: dict[str, np.ndarray], params, ctx) -> None``, raising ``ConfigError``.
    size_settings: ``size_settings(settings, given, config, params, preset) -> settings`` for a
      planner whose static settings the run sizes (a loop bound from the largest value of a
      traced weight, a radius from the sensor): called by :func:`jaxplore.config.config_for`
      with the sized :class:`~jaxplore.config.SimConfig`, the traced ``params`` (one value per
      robot or a scalar), the preset's name (or None) and ``given``, the names of the settings
      the user gave (to be left as they are). It refuses a bad value with ``ConfigError``.
    needs_pose_graph: the planner reads the robot's SLAM pose graph (``view.pose_graph``); the
      engine keeps one for such planners (for the others only when asked, for its metrics).
    init_memory: ``init_memory(ctx, params) -> memory`` for a planner with per-robot memory.
    commits: the robot drives to its chosen goal before the planner decides again (it replans
      only when its path is done or blocked, never every ``replan_every`` steps).
    step_hook: ``step_hook(ctx, params, memory, robot, logodds, moved) -> memory``, run after
      each scan a running robot integrates into its belief ``logodds`` (its first at reset,
      with ``moved`` true, then one every motion step; ``robot.position`` is set), for memories
      that follow the belief or grow while the robot moves; planners without one pay nothing.
      On a CPU the engine runs it for one robot after the other, their memories updated in
      place (:func:`jaxplore.mapping.per_robot`).
    blacklist_on_arrival: the engine blacklists a goal once the robot has reached the end of
      the path to it (Ahmed's FD), so it is never chosen again.
    windowed: the planner picks the candidate with the smallest path cost over unit node costs
      (``Plan.cost`` in metres, each step costing at least its length), so a plan made on a
      window around the robot can be certified as the whole grid's
      (:mod:`jaxplore.planners.window`).
    preset: the sensor/robot preset of the planner's paper (:data:`jaxplore.config.PRESETS`),
      used when a run names none; None: the project's default.
    slam: the SLAM model of the planner's paper (:data:`jaxplore.config.SLAM_MODELS`), used
      when a run names none: ``"scan_matching"`` for the active-SLAM planners, whose authors ran
      a graph SLAM (Karto, slam_toolbox) and whose choices change how well the robot knows
      where it is; None: the project's default (:attr:`jaxplore.config.SimConfig.slam`).
    memory_graph: ``memory_graph(arrays, res, origin) -> graph`` for a planner whose memory
      holds a graph worth drawing over the map (the REG family's exploration graph): ``arrays``
      one robot's memory leaves by their path in the tree (:func:`jaxplore.results.
      memory_arrays`' names), the graph an object with ``nodes`` f32[N, 2] (world m), ``edges``
      i32[E, 2], ``lsr`` (rays per node, or None), ``open`` (bool per ray, or None), ``current``
      and ``overflow``. ``jaxplore plot`` and ``jaxplore animate`` draw it.
  """

  name: str
  plan: PlanFn
  defaults: dict = dataclasses.field(default_factory=dict)
  weights: dict = dataclasses.field(default_factory=dict)
  summary: str = ""
  settings: Any = None
  validate: Callable | None = None
  size_settings: Callable | None = None
  needs_pose_graph: bool = False
  init_memory: Callable | None = None
  commits: bool = False
  step_hook: Callable | None = None
  blacklist_on_arrival: bool = False
  windowed: bool = False
  preset: str | None = None
  memory_graph: Callable | None = None
  slam: str | None = None

  def _key(self) -> tuple:
    return (self.name, self.plan, tuple(sorted(self.defaults.items())), self.settings,
            self.validate, self.size_settings, self.needs_pose_graph, self.init_memory,
            self.commits, self.step_hook, self.blacklist_on_arrival, self.windowed, self.preset,
            self.memory_graph, self.slam)

  def __eq__(self, other) -> bool:
    return isinstance(other, PlannerSpec) and self._key() == other._key()

  def __hash__(self) -> int:
    return hash(self._key())

  def __repr__(self) -> str:
    return f"PlannerSpec({self.name!r}, settings={self.settings!r})"

  def with_settings(self, settings=None, /, **overrides) -> PlannerSpec:
    """This planner with other static settings: a settings instance of its type, or overrides
    by name (converted and range-checked as :meth:`resolve_settings` does)."""
    if settings is not None:
      if self.settings is None or not isinstance(settings, type(self.settings)):
        expected = ("no settings" if self.settings is None else
                    f"a {type(self.settings).__module__}.{type(self.settings).__qualname__}")
        raise ConfigError(f"planner {self.name!r}: settings must be {expected}, "
                          f"got {type(settings).__qualname__}")
      check_settings(self.name, settings)
      base = dataclasses.replace(self, settings=settings)
      return base.with_settings(**overrides) if overrides else base
    if not overrides:
      return self
    return dataclasses.replace(self, settings=self.resolve_settings(overrides))

  def changed_settings(self) -> frozenset[str]:
    """The names of the static settings whose value is not their field's default (a user's,
    where the settings were built with them)."""
    if self.settings is None:
      return frozenset()
    return frozenset(f.name for f in dataclasses.fields(self.settings)
                     if f.default is not dataclasses.MISSING
                     and getattr(self.settings, f.name) != f.default)

  @property
  def has_memory(self) -> bool:
    return self.init_memory is not None

  def initial_memory(self, ctx: PlannerContext, params):
    """The memory of one robot at reset (an empty tuple for a planner without memory)."""
    # has_memory: init_memory is not None
    return cast(Callable, self.init_memory)(ctx, params) if self.has_memory else ()

  def propose(self, ctx: PlannerContext, view, robot, params, key, memory):
    """One call of the plan function under either signature: returns (Plan, memory)."""
    if self.has_memory:
      return self.plan(ctx, view, robot, params, key, memory)
    return self.plan(ctx, view, robot, params, key), memory

  def resolve_settings(self, overrides: dict | None = None):
    """The static settings with ``overrides`` (name -> value) applied, each converted to the
    type of its default; a name that is no setting is a ``ConfigError``."""
    overrides = dict(overrides or {})
    if not overrides:
      return self.settings
    fields = {f.name: f for f in dataclasses.fields(self.settings)} if self.settings else {}
    unknown = set(overrides) - set(fields)
    if unknown:
      raise ConfigError(f"planner {self.name!r} has no setting(s) {sorted(unknown)}; "
                        f"it has: {', '.join(sorted(fields)) or 'none'}")
    converted = {}
    for name, value in overrides.items():
      kind = type(getattr(self.settings, name))
      try:
        converted[name] = kind(value) if kind is not bool else _as_bool(value)
      except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"planner {self.name!r}: setting {name} must be a {kind.__name__}, "
                          f"got {value!r}") from None
      # A count or size fixes a shape: a fraction would be cut silently, a negative one fail
      # inside the compiler; a length must be a number.
      if kind is int and (_as_number(value) != converted[name] or converted[name] < 0):
        raise ConfigError(f"planner {self.name!r}: setting {name} must be a whole number >= 0, "
                          f"got {value!r}")
      if kind is float and not math.isfinite(converted[name]):
        raise ConfigError(f"planner {self.name!r}: setting {name} must be finite, got {value!r}")
    resolved = dataclasses.replace(self.settings, **converted)
    check_settings(self.name, resolved)
    return resolved

  def check_weights(self, weights: dict) -> None:
    """Refuses a weight (a scalar or one value per robot) outside its declared range, naming
    it; undeclared weights need only be finite."""
    for name, value in weights.items():
      declaration = self.weights.get(name)
      if declaration is not None:
        declaration.check(value, f"planner {self.name!r}: weight {name}")

  def declared_settings(self) -> list[Setting]:
    """The planner's traced weights and static settings as :class:`jaxplore.settings.Setting`
    declarations (listings, documentation): a settings field declared with
    :func:`jaxplore.settings.setting` brings its help and range, the others their default."""
    owner = f"planner {self.name}"
    out = [dataclasses.replace(self.weights[k], owner=owner) if k in self.weights else
           Setting(default=float(v), help="", owner=owner, name=k)
           for k, v in self.defaults.items()]
    if self.settings is not None:
      declared_fields = declared(type(self.settings))
      for field in dataclasses.fields(self.settings):
        default = getattr(self.settings, field.name)
        found = declared_fields.get(field.name)
        out.append(dataclasses.replace(found, default=default, owner=owner, static=True)
                   if found is not None else
                   Setting(default=default, help="", owner=owner, static=True, name=field.name))
    return out

  def split_overrides(self, overrides: dict | None):
    """Splits user overrides (``--planner-set``) into (traced weights, static settings)."""
    overrides = dict(overrides or {})
    names = {f.name for f in dataclasses.fields(self.settings)} if self.settings else set()
    static = {k: v for k, v in overrides.items() if k in names}
    traced = {k: v for k, v in overrides.items() if k not in names}
    unknown = set(traced) - set(self.defaults)
    if unknown:
      raise ConfigError(f"planner {self.name!r} has no parameter(s) {sorted(unknown)}; it has: "
                        f"{', '.join(sorted(set(self.defaults) | names)) or 'none'}")
    return traced, static


def check_settings(planner: str, settings) -> None:
  """Refuses a static setting of ``planner`` outside its declared range (the
  :func:`jaxplore.settings.setting` fields of its settings dataclass), naming it."""
  for name, declaration in declared(type(settings)).items():
    declaration.check(getattr(settings, name), f"planner {planner!r}: setting {name}")


def _as_bool(value) -> bool:
  if isinstance(value, str):
    if value.lower() in ("1", "true", "yes", "on"):
      return True
    if value.lower() in ("0", "false", "no", "off"):
      return False
    raise ValueError(value)
  return bool(value)


def _as_number(value) -> float:
  """``value`` as a float (a text such as "4" too), or NaN."""
  try:
    return float(value)
  except (TypeError, ValueError):
    return math.nan


_REGISTRY: dict[str, PlannerSpec] = {}


def planner(name: str, plan: PlanFn, defaults=None, summary: str = "", *, settings=None,
            validate: Callable | None = None, size_settings: Callable | None = None,
            needs_pose_graph: bool = False, init_memory: Callable | None = None,
            commits: bool = False, step_hook: Callable | None = None,
            blacklist_on_arrival: bool = False, windowed: bool = False,
            preset: str | None = None, memory_graph: Callable | None = None,
            slam: str | None = None) -> PlannerSpec:
  """A planner object for the engine (see :class:`PlannerSpec` for each argument), not
  registered: pass it as ``SimConfig.planner`` or ``jaxplore.run(planner=...)`` directly, or
  list it under its name with :func:`register`.

  ``defaults``: the traced weights, a dict name -> default, or a dataclass whose fields declare
  them (:func:`jaxplore.settings.setting`: default, help, range; the range is checked before
  compute). ``settings``: the static settings, a frozen dataclass instance; its fields may be
  declared the same way."""
  if settings is not None and not (dataclasses.is_dataclass(settings) and
                                   cast(Any, settings).__dataclass_params__.frozen):
    raise TypeError(f"planner {name!r}: settings must be a frozen dataclass instance")
  weights = {}
  if isinstance(defaults, type) and dataclasses.is_dataclass(defaults):
    weights = declared(defaults)
    if len(weights) != len(dataclasses.fields(defaults)):
      raise TypeError(f"planner {name!r}: every field of its weights dataclass must be declared "
                      f"with jaxplore.settings.setting")
    defaults = {k: w.default for k, w in weights.items()}
  if settings is not None:
    check_settings(name, settings)
  return PlannerSpec(
      name=name, plan=plan, defaults=dict(defaults or {}), weights=weights, summary=summary,
      settings=settings, validate=validate, size_settings=size_settings,
      needs_pose_graph=needs_pose_graph, init_memory=init_memory, commits=commits,
      step_hook=step_hook, blacklist_on_arrival=blacklist_on_arrival, windowed=windowed,
      preset=preset, memory_graph=memory_graph, slam=slam)


def register(spec: PlannerSpec | str, *args, **kwargs):
  """Lists a planner under its name (the command line's ``--planner``, TOML files, sweeps).

  ``register(spec)`` registers a :class:`PlannerSpec` (built with :func:`planner`) and returns
  it. ``@register(name, defaults, summary, **options)`` is the decorator form for a plan
  function (the arguments of :func:`planner`); it returns the function unchanged."""
  if isinstance(spec, PlannerSpec):
    if args or kwargs:
      raise TypeError("register(spec) takes no other arguments")
    _REGISTRY[spec.name] = spec
    return spec
  name = spec

  def wrap(fn):
    register(planner(name, fn, *args, **kwargs))
    return fn

  return wrap


# Planners from outside the package: os.pathsep-separated .py files or module names, imported
# (once) before the registry is first read; ``jaxplore --plugin FILE`` adds to it.
PLUGINS_ENV = "JAXPLORE_PLUGINS"
# Installed packages offer planners under this entry-point group (the module is imported).
ENTRY_POINT_GROUP = "jaxplore.planners"
_loaded_plugins: set[str] = set()
_entry_points: list[tuple] = []


def load_plugins() -> None:
  """Imports the planners of :data:`PLUGINS_ENV` and of the :data:`ENTRY_POINT_GROUP` entry
  points not imported yet; their ``@register`` lines add them to the registry. A file or module
  that cannot be imported is a :class:`ConfigError` naming it."""
  import importlib
  import importlib.metadata
  import importlib.util
  import os
  import sys
  from pathlib import Path
  sources = [s for s in os.environ.get(PLUGINS_ENV, "").split(os.pathsep) if s.strip()]
  if not _entry_points:  # read once per process: the installed packages do not change
    _entry_points.append(tuple(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)))
  entry_points = _entry_points[0]
  sources += [f"entry point {ep.name}={ep.value}" for ep in entry_points]
  for source in sources:
    if source in _loaded_plugins:
      continue
    _loaded_plugins.add(source)
    try:
      if source.startswith("entry point "):
        next(ep for ep in entry_points if source.endswith(f"{ep.name}={ep.value}")).load()
      elif source.endswith(".py"):
        path = Path(source).expanduser().resolve()
        if not path.is_file():
          raise FileNotFoundError(f"no file {str(path)!r}")
        name = f"jaxplore_plugin_{path.stem}"
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None  # a .py file has a source loader
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
      else:
        importlib.import_module(source)
    except ConfigError:
      raise
    except Exception as err:  # whatever the user's code raises: name the plugin, not a traceback
      raise ConfigError(f"planner plugin {source!r} could not be loaded: "
                        f"{type(err).__name__}: {err}") from err


def planner_brings(name, what: str) -> str | None:
  """What a planner brings for a run that names none: its paper's ``"preset"``
  (:attr:`PlannerSpec.preset`) or ``"slam"`` model (:attr:`PlannerSpec.slam`); None for a
  planner that brings none, or an unknown name (refused later, where the planner is looked up)."""
  if isinstance(name, PlannerSpec):
    return getattr(name, what)
  load_plugins()
  spec = _REGISTRY.get(name) if isinstance(name, str) else None
  return None if spec is None else getattr(spec, what)


def unregister(name: str) -> None:
  """Removes a planner from the registry (tests that register their own planners)."""
  _REGISTRY.pop(name, None)


def get_planner(name: str | PlannerSpec) -> PlannerSpec:
  """The planner registered under ``name`` (a :class:`PlannerSpec` is returned as it is)."""
  if isinstance(name, PlannerSpec):
    return name
  if not isinstance(name, str):
    raise ConfigError(f"planner must be a planner name or a PlannerSpec, got {name!r}")
  if name not in _REGISTRY:
    load_plugins()
  if name not in _REGISTRY:
    raise ConfigError(f"unknown planner {name!r}; valid planners: {', '.join(sorted(_REGISTRY))}")
  return _REGISTRY[name]


def planner_names() -> list[str]:
  load_plugins()
  return sorted(_REGISTRY)


def no_plan(capacity: int, robot: RobotView) -> Plan:
  """An invalid plan that keeps the robot where it is."""
  return Plan(waypoints=jnp.broadcast_to(robot.cell, (capacity, 2)).astype(jnp.int32),
              length=jnp.int32(0), goal=robot.cell, look_at=robot.cell, valid=jnp.bool_(False),
              gain=jnp.float32(0), cost=jnp.float32(jnp.inf), n_candidates=jnp.int32(0))
