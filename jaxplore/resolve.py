"""The resolver: a :class:`jaxplore.runspec.RunSpec` in, the device-side batch out.

:func:`resolve` is the one place where settings become the things the engine runs on: the truth
map, the static :class:`jaxplore.config.SimConfig` (sized from the largest range and radius of
the whole batch), the traced :class:`jaxplore.config.Params` (scalars, or one value per robot),
the device-side :class:`jaxplore.sim.World` and the start pose; every value is validated first,
so a bad setting is refused before any compute. :meth:`Resolved.batch` then gives the batched
parameters, PRNG keys and starts of all robots or of some of them: a sweep resolves a whole group
of rows once and runs it chunk by chunk, ``jaxplore animate`` replays a few robots of a run.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import memory, posegraph, sim
from jaxplore.config import (
  PARAM_FIELDS,
  STATIC_SETTINGS,
  ConfigError,
  Params,
  SimConfig,
  config_for,
  make_params,
  validate_params,
)
from jaxplore.maps import GridMap, load_world
from jaxplore.planners import PlannerSpec, get_planner
from jaxplore.runspec import STATIC_PARAMS, RunSpec


class Batch(NamedTuple):
  """What the engine's reset and advance take for a batch of B robots.

  Attributes:
    params: :class:`Params` with every leaf f32[B]. keys: the robots' PRNG keys, [B, 2].
    starts: f32[B, 3] start poses, or None to sample them from the keys.
  """

  params: Params
  keys: jax.Array
  starts: jax.Array | None


@dataclasses.dataclass(frozen=True, eq=False)
class Resolved:
  """A run specification resolved and validated (host side; only the World is on the device).

  Attributes:
    spec: the specification it came from (with the world as given).
    grid: the truth map.
    config: the static config of the whole batch.
    params: the traced parameters, each leaf a scalar or one value per robot (the planner's
      static settings are in ``config.planner_settings``).
    world: the device-side truth, reachable area and start area.
    start: the (x, y, θ) start pose of every robot, or None.
  """

  spec: RunSpec
  grid: GridMap
  config: SimConfig
  params: Params
  world: sim.World
  start: tuple[float, float, float] | None

  @property
  def robots(self) -> int:
    return self.spec.robots

  def keys(self, robots: Sequence[int] | None = None) -> jax.Array:
    """The PRNG keys of ``robots`` (indices into the batch; default all): ``PRNGKey(s)`` of each
    robot seed, or the keys split from ``PRNGKey(seed)``."""
    spec = self.spec
    if spec.robot_seeds is None:
      keys = jax.random.split(jax.random.PRNGKey(spec.seed), spec.robots)
      return keys if robots is None else keys[jnp.asarray(list(robots))]
    seeds = spec.robot_seeds if robots is None else [spec.robot_seeds[r] for r in robots]
    return jax.vmap(jax.random.PRNGKey)(jnp.asarray(seeds, jnp.uint32))

  def batch(self, robots: Sequence[int] | None = None) -> Batch:
    """The device-side inputs of ``robots`` (indices into the batch, repeats allowed; default
    all of them in order)."""
    if robots is None:
      params = sim.broadcast_params(self.params, self.robots)
      n = self.robots
    else:
      index = np.asarray(list(robots), np.int64)
      n = len(index)
      pick = lambda leaf: (leaf if np.ndim(leaf) == 0 else np.asarray(leaf, np.float32)[index])
      params = sim.broadcast_params(jax.tree.map(pick, self.params), n)
    starts = (None if self.start is None
              else jnp.tile(jnp.asarray(self.start, jnp.float32), (n, 1)))
    return Batch(params, self.keys(robots), starts)

  def describe(self) -> dict:
    """The resolved settings in JSON form: the world, the static config, the traced parameters
    and the planner's weights and settings (what ``config.json`` records)."""
    grid = self.grid
    return {
        "world": {"name": grid.name, "shape": list(grid.shape), "res": grid.res,
                  "origin": list(grid.origin), "free_m2": grid.free_area,
                  "reachable_m2": float(self.world.n_reachable) * grid.res**2},
        "sim_config": sim.config_record(self.config),
        "params": {k: to_json_number(v) for k, v in dataclasses.asdict(self.params).items()
                   if k != "planner"},
        "planner_params": {k: to_json_number(v) for k, v in self.params.planner.items()},
        "planner_settings": sim.config_record(self.config)["planner_settings"],
    }


def to_json_number(leaf):
  """A parameter leaf as JSON: a float, or a list of floats (one per robot)."""
  arr = np.asarray(leaf, np.float64)
  return float(arr) if arr.ndim == 0 else arr.tolist()


def config_difference(recorded: dict | None, config: SimConfig) -> str | None:
  """Where a recorded static config (``config.json``'s or a sweep schedule's ``sim_config``)
  differs from ``config``, as ``field: A there, B now``; None when they agree (the execution
  strategy aside: a run recorded on a GPU replays on a CPU). Records of older
  versions are read as :func:`jaxplore.sim.config_from_dict` reads them; lengths in metres agree
  to a relative 1e-9 (an older record kept R_e in cells)."""
  if recorded is None:
    return None
  then = sim.config_record(sim.config_from_dict(recorded))
  now = sim.config_record(config)
  for name, value in now.items():
    if name == "strategy":
      continue  # how the batch ran, not what it computed; each backend has its own default
    old = then.get(name)
    if isinstance(value, float) and isinstance(old, (int, float)):
      same = math.isclose(old, value, rel_tol=1e-9)
    else:
      same = old == value
    if not same:
      return f"{name}: {old!r} there, {value!r} now"
  return None


def default_max_steps(grid: GridMap, params: Params) -> int:
  """A step budget generous for frontier exploration of the reachable area: the longer of about
  three sweeps of the free area with a swath of twice the (capped) sensor range, and 1.5 times
  the length of the map's wall faces (a frontier explorer's path follows the walls it maps: on
  cluttered maps the walls, not the area, set its length), plus turning time. With one value
  per robot, the budget of the slowest, shortest-sighted robot (one budget per batch).

  Measured with nearest frontier (4 robots, the li2020 preset): willow at 0.2 m (966 m² free,
  2,062 m of wall faces) needed 7,900-8,300 steps (830-885 m) against 3,416 from the area
  alone; office's path is ~0.4 of its 824 m of walls, as willow's is."""
  step_m = float(np.min(np.asarray(params.v_max, np.float64) * np.asarray(params.dt, np.float64)))
  swath = 2.0 * min(float(np.min(np.asarray(params.r_max))), 3.0)
  occupied = grid.occupied
  faces = (np.count_nonzero(occupied[1:] != occupied[:-1]) +
           np.count_nonzero(occupied[:, 1:] != occupied[:, :-1])) * grid.res
  return int(max(3.0 * grid.free_area / swath, 1.5 * faces) / step_m) + 1000


def _one_value(name: str, value):
  """A static setting's value: per-robot values must all be equal (one compiled program)."""
  if isinstance(value, tuple):
    if len(set(value)) > 1:
      raise ConfigError(f"{name} fixes the compiled program, so a batch takes one value of it, "
                        f"got {sorted(set(value))} (a sweep runs each value as a group of its own)")
    return value[0]
  return value


def split_planner_params(planner: str | PlannerSpec, planner_params) -> tuple[dict, dict]:
  """(traced weights, static settings) of ``planner_params`` for ``planner``: every name must be
  one or the other. Per-robot weights become float32 arrays; a static setting takes one value."""
  spec = get_planner(planner)
  planner = spec.name
  try:
    weights, settings = spec.split_overrides(planner_params)
  except ConfigError as err:
    simulator = sorted(set(planner_params or {}) & set(PARAM_FIELDS))
    if not simulator:
      raise
    raise ConfigError(f"{err}. {', '.join(simulator)}: the simulator's, so params (the flags "
                      f"--set NAME=VALUE or --NAME VALUE)") from None
  for name, value in weights.items():
    if any(isinstance(v, (str, bytes)) for v in (value if isinstance(value, tuple) else (value,))):
      raise ConfigError(f"planner {planner!r}: weight {name} must be a number, got {value!r}")
  weights = {k: np.asarray(v, np.float32) if isinstance(v, tuple) else v
             for k, v in weights.items()}
  settings = {k: _one_value(k, v) for k, v in settings.items()}
  for name, value in settings.items():
    default = getattr(spec.settings, name)
    if (isinstance(default, int) and not isinstance(default, bool) and isinstance(value, float)
        and not value.is_integer()):
      raise ConfigError(f"planner {planner!r}: setting {name} must be an integer, got {value!r}")
  return weights, settings


def split_params(params) -> tuple[dict, dict]:
  """(traced :class:`Params` overrides, static simulator settings) of ``params``: see
  :data:`jaxplore.runspec.STATIC_PARAMS`."""
  traced, static = {}, {}
  for name, value in (params or {}).items():
    if name in STATIC_PARAMS:
      static[name] = STATIC_SETTINGS[name].convert(_one_value(name, value), name)
    else:
      traced[name] = np.asarray(value, np.float32) if isinstance(value, tuple) else value
  return traced, static


def build_params(planner: str | PlannerSpec, preset, res: float, params=None,
                 planner_params=None) -> Params:
  """The traced :class:`Params` of a batch: the preset, the simulator parameters and the
  planner's default weights with the given ones (static names are left out: they go to the
  ``SimConfig``). Leaves are scalars, or arrays with one value per robot. No validation of
  values."""
  weights = dict(get_planner(planner).defaults)
  weights.update(split_planner_params(planner, planner_params or {})[0])
  return make_params(preset, res=res, planner=weights, **split_params(params)[0])


def load_grid(spec: RunSpec) -> GridMap:
  """The spec's truth map: a GridMap as given, else the world loaded (resampled to ``res``)."""
  return spec.world if isinstance(spec.world, GridMap) else load_world(spec.world, res=spec.res)


def resolve(spec: RunSpec) -> Resolved:
  """Loads, sizes and validates everything a batch needs; no compute on the robots.

  Raises:
    ConfigError, MapError: the first bad setting, naming it (unknown planner or preset, a
      planner name it does not have, a value out of range, a start inside or near a wall).
  """
  planner = get_planner(spec.planner)
  grid = load_grid(spec)
  params = build_params(planner, spec.preset, grid.res, dict(spec.params),
                        dict(spec.planner_params))
  given = split_planner_params(planner, spec.planner_params)[1]
  planner = planner.with_settings(**given)
  overrides = dict(planner=planner, pose_noise=spec.pose_noise, **split_params(spec.params)[1])
  slam = overrides.get("slam", SimConfig.slam)
  for name in ("replan_every", "path_capacity", "plan_window", "strategy"):
    if getattr(spec, name) is not None:
      overrides[name] = getattr(spec, name)
  cells = grid.shape[0] * grid.shape[1]
  if spec.path_capacity is not None and spec.path_capacity > cells:
    raise ConfigError(f"path_capacity {spec.path_capacity} is more waypoints than the "
                      f"{grid.shape[1]}x{grid.shape[0]} grid has cells ({cells}): a shortest "
                      f"path visits each cell at most once")
  max_steps = spec.max_steps if spec.max_steps is not None else default_max_steps(grid, params)
  if (spec.pose_graph or (spec.pose_graph is None and planner.needs_pose_graph)
      or slam == "scan_matching"):
    # Room for every keyframe the run can create (posegraph.keyframe_bound).
    overrides["graph_nodes"] = posegraph.keyframe_bound(max_steps, params.v_max, params.w_max,
                                                        params.dt, params.kf_dist, params.kf_rot)
    if spec.graph_loops is not None:
      overrides["graph_loops"] = spec.graph_loops
    elif slam == "scan_matching":  # closures and links spaced by distance driven: sized by it
      overrides["graph_loops"] = posegraph.loop_bound(max_steps, params,
                                                      overrides["graph_nodes"])
  config = config_for(grid.shape, grid.res, params, preset=spec.preset, max_steps=max_steps,
                      planner_given=given, **overrides)
  validate_params(params, config)
  planner.check_weights(params.planner)
  if planner.validate is not None:
    planner.validate({k: np.asarray(v) for k, v in params.planner.items()}, params,
                     sim.planner_context(config))
  # Before the world's host-side preparation (distance transforms, labels: tens of bytes per
  # cell), which a 20000 x 20000 map at its own resolution would take past the machine's memory.
  memory.fit_chunk(config, 1)  # refuses where not even one robot fits
  world = sim.make_world(grid, float(np.max(np.asarray(params.r_robot))),
                         None if spec.start is None else spec.start[:2])
  return Resolved(spec, grid, config, params, world, spec.start)


__all__ = ["Batch", "Resolved", "build_params", "config_difference", "default_max_steps",
           "load_grid", "resolve", "split_params", "split_planner_params", "to_json_number"]
