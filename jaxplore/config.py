"""Static configuration (shapes, loop bounds) and traced parameters (everything a user sweeps).

A hashable :class:`SimConfig` fixes every shape and loop
bound and is a compile-time constant; a :class:`Params` pytree holds the numbers a study may sweep
(sensor, map model, motion, noise, planner weights). Changing a ``Params`` value never recompiles;
a sweep over 256 settings is one ``vmap``.

Presets carry the papers' sensors and robots: ``li2020``, ``godoy_open``, ``godoy_office``,
``toriz``, ``explore_bench``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import chex
import jax.numpy as jnp
import numpy as np

from jaxplore import posegraph
from jaxplore.errors import ConfigError, shown




# The SLAM models (SimConfig.slam; jaxplore.slam.model).
SLAM_MODELS = ("oracle", "scan_matching")
# Each SLAM model's default SimConfig.map_hole_cells: a SLAM map has holes of a few cells where
# walls drawn from keyframes a fraction of a cell apart leave evidence both ways (4 cells: 0.16
# m² at 0.2 m, below explore_lite's min_frontier_size of 0.75 m of frontier).
MAP_HOLE_CELLS = {"oracle": 0, "scan_matching": 4}

# How a batch of robots is executed (SimConfig.strategy).
STRATEGIES = ("auto", "per_robot", "lockstep")


def resolve_strategy(strategy: str = "auto", backend: str | None = None) -> str:
  """The execution strategy ``"auto"`` stands for on ``backend`` (default: JAX's default backend).

  On a CPU, ``"per_robot"``: XLA:CPU runs a loop body on one thread and a robot's maps fit in
  cache, so the irregular stages (lidar walk, belief update, shortest paths) are fastest one
  robot, or a chunk of 4, at a time, and robots that do not plan cost nothing. On a GPU or TPU,
  ``"lockstep"``: each stage is one kernel over the whole batch; a loop over robots would make
  every stage a chain of tiny kernels whose time grows with the batch.
  """
  if strategy != "auto":
    return strategy
  if backend is None:
    import jax
    backend = jax.default_backend()
  return "per_robot" if backend == "cpu" else "lockstep"


@dataclasses.dataclass(frozen=True)
class SimConfig:
  """Everything that fixes a shape or a loop bound. Hashable; a jit cache key.

  Attributes:
    height, width: grid shape in cells (from the world).
    res: metres per cell (from the world).
    n_beams: lidar rays per scan.
    max_range_cells: static bound of the lidar range in cells; ``Params.r_max`` may be anything
      up to ``max_range_cells * res``.
    path_capacity: waypoints a plan may hold.
    replan_every: a robot replans after this many motion steps even if its path is not done
      (it always replans when its path is done).
    max_steps: the step budget of an episode (``timeout`` after it).
    planner: registry name of the planner.
    pose_noise: corrupt odometry and dead-reckon the estimate; when False the estimate
      is the true pose (the covariance is still propagated for planning).
    max_inflation_cells: static bound of the robot radius in cells (``Params.r_robot``).
    max_update_radius_cells: static bound of the entropy-map update radius ``R_u = α·R_e`` in cells.
    r_e: Li et al.'s effective radius R_e in metres (Eq 5-6): the entropy map is updated within
      ``R_u = alpha * R_e`` of the robot (Eq 7), and li2020's information gain sweeps a disc of
      radius R_e along a path (Eq 20). Static: it fixes the shape of li2020's gain kernels.
    entropy_map: keep Li's entropy map I_e (Eq 1-3) in the state and update it every step even
      if the planner does not read it (it is always kept for one that does:
      ``PlannerSpec.needs_entropy_map``).
    planner_settings: the planner's static settings (its registered frozen dataclass, resolved;
      None for a planner without settings).
    dijkstra_max_sweeps: bound on cone-sweep rounds of the shortest-path kernel.
    dijkstra_tiles_after_rounds: the solver's ``tiles_after_rounds``
      (:func:`jaxplore.graph.shortest_paths`): rounds of whole-grid sweeps after which a plan not
      yet settled is finished tile by tile; 0 (the default) = never. The built-in worlds' plans
      settle in at most ~18 rounds, where the tiles do not pay, and they add ~0.6 s of compile
      time per solver in the program. The solver alone finishes 256 x 256 mazes of 3-cell
      corridors ~2.8x sooner with 16 (``experiments/bench_dijkstra.py``), but the engine, whose
      plans are mostly windowed, ran a 0.6 m-corridor maze at the same rate with it.
    plan_chunk: robots planned together with ``vmap`` (:func:`jaxplore.sim.plan_where_needed`).
    plan_window: side in cells of the square window around the robot that a ``windowed``
      planner (nearest frontier, FD) plans on first; the whole grid is planned only when the
      window cannot certify the answer. 0 = always the whole grid. :func:`config_for` picks it
      from the sensor range, capped at :data:`PLAN_REACH_M` (:func:`auto_plan_window`).
    graph_nodes: keyframe capacity of each robot's SLAM pose graph (:mod:`jaxplore.posegraph`);
      0 = no pose graph. A run that could create more keyframes is refused before compute.
    graph_loops: loop-closure capacity of the pose graph; closures found with the list full are
      counted (``loops_dropped``) and not added.
    max_loop_cells: static bound of the loop-closure radius ``Params.loop_radius`` in cells (it
      fixes the samples of a line-of-sight test).
    slam: the SLAM model (:data:`SLAM_MODELS`): ``"oracle"`` relocalises a robot by a
      measurement of its true pose when its scan ends on well-mapped walls; ``"scan_matching"``
      runs a graph SLAM (:mod:`jaxplore.slam.model`: scan matching against the robot's own
      belief, loop closures, pose-graph optimisation, the map rebuilt from the keyframes'
      scans). ``scan_matching`` turns ``pose_noise`` on (the odometry error is what it corrects)
      and needs ``graph_nodes`` > 0.
    slam_match_beams: scan points a match scores (every ``n_beams // slam_match_beams``-th beam).
    slam_smear: std (m) of the correlation field's Gaussian around each belief wall, front end
      (slam_toolbox's ``correlation_search_space_smear_deviation``).
    slam_search_m: largest half-width (m) of the front end's search (slam_toolbox's
      ``correlation_search_space_dimension`` / 2); the window is 3σ of the odometry since the
      last keyframe, within ``[res, slam_search_m]``.
    slam_steps: coarse candidates on each side of the prediction in x, y and θ.
    slam_fine_steps: fine candidates on each side of the coarse best (within one coarse step).
    loop_search_m: largest half-width (m) of a loop closure's search; the window is 3σ of the
      odometry since the last closure.
    loop_smear: the correlation field's std (m), loop closures.
    loop_steps: coarse candidates on each side in x and y, loop closures.
    loop_candidates: older keyframes whose scans make a loop closure's local map.
    slam_iterations: most Gauss-Newton / Levenberg-Marquardt iterations of an optimisation.
    map_hole_cells: unknown specks of at most this many cells enclosed by known ones are holes
      in the map, not unexplored space: no frontier borders them (:func:`jaxplore.planning.
      unexplored`). -1 (default): :data:`MAP_HOLE_CELLS` of the SLAM model (0, off, with the
      oracle, whose maps have none).
    strategy: how the batch is executed (:data:`STRATEGIES`): ``"per_robot"`` walks the robots
      one (or ``plan_chunk``) at a time through the irregular stages, ``"lockstep"`` runs each
      stage as one kernel over the whole batch; ``"auto"`` (the default) is resolved on
      construction by :func:`resolve_strategy` from the default JAX backend.
  """

  height: int
  width: int
  res: float
  n_beams: int = 360
  max_range_cells: int = 60
  path_capacity: int = 256
  replan_every: int = 8
  max_steps: int = 2000
  planner: str = "nearest_frontier"
  pose_noise: bool = False
  max_inflation_cells: int = 3
  max_update_radius_cells: int = 30
  r_e: float = 0.75
  entropy_map: bool = False
  planner_settings: Any = None
  dijkstra_max_sweeps: int = 512
  dijkstra_tiles_after_rounds: int = 0
  plan_chunk: int = 4
  plan_window: int = 0
  graph_nodes: int = 0
  graph_loops: int = 256
  max_loop_cells: int = 40
  slam: str = "oracle"
  slam_match_beams: int = 90
  slam_smear: float = 0.1
  slam_search_m: float = 0.25
  slam_steps: int = 5
  slam_fine_steps: int = 3
  loop_search_m: float = 2.0
  loop_smear: float = 0.1
  loop_steps: int = 10
  loop_candidates: int = 10
  slam_iterations: int = 10
  map_hole_cells: int = -1
  strategy: str = "auto"

  def __post_init__(self):
    if self.strategy not in STRATEGIES:
      raise ConfigError(f"strategy must be one of {', '.join(STRATEGIES)}, got {self.strategy!r}")
    object.__setattr__(self, "strategy", resolve_strategy(self.strategy))
    for name in ("height", "width", "n_beams", "max_range_cells", "path_capacity", "replan_every",
                 "max_steps", "dijkstra_max_sweeps", "plan_chunk", "max_update_radius_cells"):
      value = getattr(self, name)
      if not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be a positive integer, got {value!r}")
    if self.path_capacity < 2:
      raise ConfigError(f"path_capacity must be at least 2 (a path holds the robot's own cell "
                        f"first, then where it goes), got {self.path_capacity}")
    if self.max_inflation_cells < 0:
      raise ConfigError(f"max_inflation_cells must be >= 0, got {self.max_inflation_cells}")
    for name in ("graph_nodes", "graph_loops", "max_loop_cells", "dijkstra_tiles_after_rounds"):
      value = getattr(self, name)
      if not isinstance(value, (int, np.integer)) or value < 0:
        raise ConfigError(f"{name} must be a non-negative integer, got {value!r}")
    if not isinstance(self.plan_window, (int, np.integer)) or self.plan_window < 0:
      raise ConfigError(f"plan_window must be a non-negative integer, got {self.plan_window!r}")
    if not (math.isfinite(self.res) and self.res > 0):
      raise ConfigError(f"res must be a positive number of metres, got {self.res!r}")
    if not (isinstance(self.r_e, (int, float)) and math.isfinite(self.r_e) and self.r_e > 0):
      raise ConfigError(f"r_e must be a positive number of metres, got {self.r_e!r}")
    if self.slam not in SLAM_MODELS:
      raise ConfigError(f"slam must be one of {', '.join(SLAM_MODELS)}, got {self.slam!r}")
    for name in ("slam_match_beams", "slam_steps", "slam_fine_steps", "loop_steps",
                 "loop_candidates", "slam_iterations"):
      value = getattr(self, name)
      if not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be a positive integer, got {value!r}")
    for name in ("slam_smear", "slam_search_m", "loop_search_m", "loop_smear"):
      value = getattr(self, name)
      if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{name} must be a positive number of metres, got {value!r}")
    if not isinstance(self.map_hole_cells, (int, np.integer)) or self.map_hole_cells < -1:
      raise ConfigError(f"map_hole_cells must be a non-negative integer (or -1: the SLAM "
                        f"model's default), got {self.map_hole_cells!r}")
    if self.map_hole_cells == -1:
      object.__setattr__(self, "map_hole_cells", MAP_HOLE_CELLS[self.slam])
    if self.slam == "scan_matching":
      object.__setattr__(self, "pose_noise", True)
      if not self.graph_nodes:
        raise ConfigError("slam='scan_matching' keeps a pose graph: graph_nodes must be > 0 "
                          "(posegraph.keyframe_bound; jaxplore.resolve.resolve sets it)")

  @property
  def n_epochs(self) -> int:
    """Planning rounds needed to cover ``max_steps``."""
    return -(-self.max_steps // self.replan_every)


@chex.dataclass(frozen=True)
class Params:
  """Traced numbers of the simulator; every leaf is a float32 scalar (or batched under vmap).

  Units: metres, seconds, radians, log-odds. Planner weights live in ``planner`` (a dict of
  scalars, so every planner can add its own without the simulator knowing them).
  """

  # lidar
  r_max: Any = 15.0  # max range, m
  fov: Any = math.radians(190.0)  # field of view, rad
  range_noise: Any = 0.0  # std of Gaussian range noise, m
  # belief (inverse sensor model, log-odds)
  l_free: Any = -1.0
  l_occ: Any = 2.0
  l_min: Any = -5.0
  l_max: Any = 5.0
  p_free: Any = 0.35  # a cell with P(occ) below this is believed free
  p_occ: Any = 0.65  # and above this, occupied
  # entropy map (Li Eq 3, 5-7)
  entropy_k: Any = 0.5  # smoothing k of Eq 3
  alpha: Any = 1.5  # R_u = alpha * R_e (R_e is static: SimConfig.r_e)
  # robot
  v_max: Any = 0.25  # m/s
  w_max: Any = 1.0  # rad/s
  dt: Any = 0.4  # s
  r_robot: Any = 0.2  # m
  # localisation (Li Eq 16-17; relocalisation by a Kalman update)
  sigma_d: Any = 1.0  # Li's planning model V_n (Eq 16): std per metre driven, for Σ
  sigma_phi: Any = 1.0  # and per radian turned
  # The simulated odometry error with ``pose_noise`` (not Li's V_n, a 100 % std per metre):
  # zero-mean Gaussian increments of a wheeled robot whose SLAM front end keeps the error to a
  # few percent, corrected further by relocalisation.
  odom_noise_d: Any = 0.03  # std of the distance (and lateral) error per metre driven
  odom_noise_phi: Any = 0.03  # std of the heading error per radian turned
  sigma0: Any = 1e-4  # initial pose covariance, diag, m² and rad²
  reloc_min_hits: Any = 20.0  # beams that must end on well-mapped occupied cells
  reloc_entropy: Any = 0.3  # "well-mapped": cell entropy below this, nats
  reloc_var_xy: Any = 1e-3  # measurement covariance R, m²
  reloc_var_theta: Any = 1e-3  # rad²
  # SLAM pose graph (jaxplore.posegraph; Karto's settings in Ahmed et al.'s configuration)
  kf_dist: Any = 0.3  # a keyframe every kf_dist m of odometry ...
  kf_rot: Any = 0.3  # ... or kf_rot rad of turn
  scan_match_sigma: Any = 0.018  # std of a scan match (odometry-edge floor, loop closures): m, rad
  loop_radius: Any = 4.0  # a loop closes to a keyframe within this distance, m ...
  loop_min_age: Any = 15.0  # ... at least this many keyframes older ...
  loop_max_turn: Any = math.pi / 2  # ... whose heading differs by at most this, rad
  # The scan_matching SLAM model (jaxplore.slam.model). Karto's scan matcher settings, as
  # slam_toolbox's mapper_params_online_async.yaml sets them:
  slam_min_response: Any = 0.1  # link_match_minimum_response_fine: a weaker match is refused
  slam_distance_penalty: Any = 0.5  # distance_variance_penalty, m²
  slam_angle_penalty: Any = 1.0  # angle_variance_penalty, rad²
  slam_min_distance_penalty: Any = 0.5  # minimum_distance_penalty
  slam_min_angle_penalty: Any = 0.9  # minimum_angle_penalty
  slam_min_angle: Any = math.radians(2.0)  # the angular search's half-width, at least ...
  slam_max_angle: Any = 0.349  # ... and at most (coarse_search_angle_offset), rad
  loop_min_response: Any = 0.45  # loop_match_minimum_response_fine
  loop_max_variance: Any = 3.0  # loop_match_maximum_variance_coarse, m²
  # A closure's pose must lie within this Mahalanobis distance² of the estimate (chi-square,
  # 3 degrees of freedom, 99 %; not Karto's: its 8 m window has no such gate); a closure whose
  # own bound this far excludes the truth is counted false.
  loop_gate: Any = 11.34
  # episode
  # Fraction of reachable free area that counts as complete; above 1 coverage never ends an
  # episode, only the planner (a planner that returns home, Toriz & Sánchez) or the step budget.
  coverage_goal: Any = 0.99
  # planner weights (name -> scalar)
  planner: Any = dataclasses.field(default_factory=dict)


PARAM_FIELDS = tuple(f.name for f in dataclasses.fields(Params) if f.name != "planner")


@dataclasses.dataclass(frozen=True)
class Preset:
  """A paper's sensor and robot: parameter overrides and static sizes.

  Attributes:
    step_cells: when set, a motion step moves the robot this many cells (``v_max = step_cells *
      res``, ``dt = 1 s``), whatever the resolution: a grid simulator that moves one waypoint
      (orthogonal or diagonal, so √2 cells) per step. Otherwise ``dt = res / v_max``.
  """

  name: str
  description: str
  params: dict
  n_beams: int
  replan_every: int = 8
  step_cells: float | None = None


PRESETS: dict[str, Preset] = {
    "li2020": Preset(
        "li2020", "Li et al. 2020: 15 m, 190° lidar, 0.25 m/s",
        dict(r_max=15.0, fov=math.radians(190.0), v_max=0.25, w_max=1.0), n_beams=190),
    "godoy_open": Preset(
        "godoy_open", "Godoy-Calvo et al. 2023, open world: 5.5 m, 270° lidar",
        dict(r_max=5.5, fov=math.radians(270.0), v_max=0.5, w_max=1.5), n_beams=270),
    "godoy_office": Preset(
        "godoy_office", "Godoy-Calvo et al. 2023, office world: 5 m, 360° lidar",
        dict(r_max=5.0, fov=math.radians(360.0), v_max=0.5, w_max=1.5), n_beams=360),
    "toriz": Preset(
        "toriz", "Toriz & Sánchez: 4 m, 240° lidar at 0.36°",
        dict(r_max=4.0, fov=math.radians(240.0), v_max=0.3, w_max=1.0), n_beams=667),
    "explore_bench": Preset(
        "explore_bench",
        "Explore-Bench grid simulator: 3.5 m, 360°, one cell per step, replanning every step",
        dict(r_max=3.5, fov=math.radians(360.0), w_max=1e3, r_robot=0.1), n_beams=360,
        replan_every=1, step_cells=math.sqrt(2.0)),
}


def make_params(preset: str | None = None, *, res: float | None = None, planner: dict | None = None,
                **overrides) -> Params:
  """Builds a validated :class:`Params` from a preset plus overrides.

  ``dt`` defaults to ``res / v_max`` (one cell of travel per step) when ``res`` is given and ``dt``
  is not; a preset with ``step_cells`` moves that many cells per 1 s step instead.
  """
  values: dict[str, Any] = {}
  if preset is not None:
    if preset not in PRESETS:
      raise ConfigError(f"unknown preset {preset!r}; valid presets: {', '.join(sorted(PRESETS))}")
    values.update(PRESETS[preset].params)
  unknown = set(overrides) - set(PARAM_FIELDS)
  if unknown:
    raise ConfigError(f"unknown parameter(s) {sorted(unknown)}; valid: {', '.join(PARAM_FIELDS)}")
  values.update({k: v for k, v in overrides.items() if v is not None})
  if res is not None and "dt" not in overrides:
    step_cells = PRESETS[preset].step_cells if preset is not None else None
    if step_cells is not None:
      values["v_max"] = step_cells * res
      values["dt"] = 1.0
    else:
      values["dt"] = res / values.get("v_max", Params.v_max)
  params = Params(**{k: jnp.float32(v) for k, v in values.items()},
                  planner={k: jnp.float32(v) for k, v in (planner or {}).items()})
  return params


def _as_float(params: Params) -> dict[str, float]:
  return {k: float(np.asarray(getattr(params, k))) for k in PARAM_FIELDS}


def validate_params(params: Params, config: SimConfig) -> None:
  """Raises :class:`ConfigError` naming the first NaN or out-of-range value (host side, before compute).

  Works on scalar or batched leaves (every element is checked).
  """
  def check(name, arr, ok, what):
    arr = np.asarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
      raise ConfigError(f"parameter {name} is NaN or infinite: {shown(arr, ~np.isfinite(arr))}")
    if not np.all(ok(arr)):
      raise ConfigError(f"parameter {name} must be {what}, got {shown(arr, ~ok(arr))}")

  p = params
  positive = lambda a: a > 0
  check("r_max", p.r_max, positive, "> 0")
  max_r = config.max_range_cells * config.res
  check("r_max", p.r_max, lambda a: a <= max_r + 1e-6,
        f"<= max_range_cells * res = {max_r:.3g} m (raise SimConfig.max_range_cells)")
  check("fov", p.fov, lambda a: (a > 0) & (a <= 2 * math.pi + 1e-6), "in (0, 2π]")
  check("range_noise", p.range_noise, lambda a: a >= 0, ">= 0")
  check("l_free", p.l_free, lambda a: a < 0, "< 0 (log-odds of a free observation)")
  check("l_occ", p.l_occ, lambda a: a > 0, "> 0 (log-odds of an occupied observation)")
  check("l_min", p.l_min, lambda a: a < 0, "< 0")
  check("l_max", p.l_max, lambda a: a > 0, "> 0")
  check("p_free", p.p_free, lambda a: (a > 0) & (a < 0.5), "in (0, 0.5)")
  check("p_occ", p.p_occ, lambda a: (a > 0.5) & (a < 1), "in (0.5, 1)")
  check("entropy_k", p.entropy_k, lambda a: (a >= 0) & (a < 1), "in [0, 1)")
  check("alpha", p.alpha, positive, "> 0")
  check("v_max", p.v_max, positive, "> 0")
  check("w_max", p.w_max, positive, "> 0")
  check("dt", p.dt, positive, "> 0")
  # A step ends at its waypoint, a neighbouring cell (diagonal at most): a longer reach would
  # count time not driven.
  reach = np.asarray(p.v_max, np.float64) * np.asarray(p.dt, np.float64)
  longest = math.sqrt(2) * config.res * (1 + 1e-4)
  if np.any(reach > longest):
    raise ConfigError(f"v_max * dt = {shown(reach, reach > longest)} m per step, more than a "
                      f"cell's diagonal ({math.sqrt(2) * config.res:.3g} m): a step ends at the "
                      f"next waypoint, so the time would count travel that never happens; leave "
                      f"dt unset (it is res / v_max) or give dt <= res / v_max")
  half_turn = math.pi / (np.asarray(p.w_max, np.float64) * np.asarray(p.dt, np.float64))
  most = max(config.max_steps, 1000)
  if np.any(half_turn > most):
    raise ConfigError(f"w_max * dt = {shown(math.pi / half_turn)} rad per step: the robot would "
                      f"need {shown(np.ceil(half_turn))} steps to turn half a circle, more than "
                      f"its {config.max_steps} and 1000 (dt = res / v_max is {shown(p.dt)} s: "
                      f"is v_max = {shown(p.v_max)} m/s meant?)")
  max_ru = config.max_update_radius_cells * config.res
  check("alpha", np.asarray(p.alpha) * config.r_e, lambda a: a <= max_ru + 1e-6,
        f"such that alpha * r_e <= max_update_radius_cells * res = {max_ru:.3g} m")
  check("r_robot", p.r_robot, lambda a: a >= 0, ">= 0")
  max_rr = config.max_inflation_cells * config.res
  check("r_robot", p.r_robot, lambda a: a <= max_rr + 1e-6,
        f"<= max_inflation_cells * res = {max_rr:.3g} m (raise SimConfig.max_inflation_cells)")
  for name in ("sigma_d", "sigma_phi", "odom_noise_d", "odom_noise_phi", "reloc_min_hits",
               "reloc_entropy"):
    check(name, getattr(p, name), lambda a: a >= 0, ">= 0")
  for name in ("sigma0", "reloc_var_xy", "reloc_var_theta"):
    check(name, getattr(p, name), positive, "> 0")
  for name in ("kf_dist", "kf_rot", "scan_match_sigma", "loop_radius"):
    check(name, getattr(p, name), positive, "> 0")
  check("loop_min_age", p.loop_min_age, lambda a: a >= 1, ">= 1")
  check("loop_max_turn", p.loop_max_turn, lambda a: (a >= 0) & (a <= math.pi + 1e-6), "in [0, π]")
  if config.graph_nodes:
    max_r = config.max_loop_cells * config.res
    check("loop_radius", p.loop_radius, lambda a: a <= max_r + 1e-6,
          f"<= max_loop_cells * res = {max_r:.3g} m (raise SimConfig.max_loop_cells)")
    posegraph.check_capacity(config.graph_nodes, config.max_steps, p)
  for name in ("slam_min_response", "loop_min_response", "slam_min_distance_penalty",
               "slam_min_angle_penalty"):
    check(name, getattr(p, name), lambda a: (a >= 0) & (a <= 1), "in [0, 1]")
  for name in ("slam_distance_penalty", "slam_angle_penalty", "loop_max_variance", "loop_gate",
               "slam_min_angle"):
    check(name, getattr(p, name), positive, "> 0")
  check("slam_max_angle", p.slam_max_angle, lambda a: (a >= np.asarray(p.slam_min_angle))
        & (a <= math.pi), "in [slam_min_angle, π]")
  check("coverage_goal", p.coverage_goal, lambda a: a > 0, "> 0 (above 1: never complete by coverage)")
  for name, value in p.planner.items():
    check(f"planner.{name}", value, lambda a: np.ones_like(a, bool), "finite")


def window_margin(max_inflation_cells: int) -> int:
  """Cells along a window's inner edges whose belief masks may differ from the whole grid's
  (inflation, the escape zone and frontier tests look up to this far); planning avoids them."""
  return 2 * max_inflation_cells + 3


# Distance (m) around the robot a planning window is sized for. The nearest frontier is usually
# this close whatever the sensor range: frontiers also open at the edges of the field of view and
# behind nearby obstacles. Measured with nearest frontier, 32 robots, the li2020 preset (15 m
# lidar) over the first 600 steps (office 1200): a 96-cell window at 0.1 m could not certify
# 0.6 % of plans on `open`, 10.9 % on `lab`, 6.5 % on `office`, against 8.0 %, 25.0 %, 14.4 %
# with 64 cells; 128 cells certify 94-100 % but cost ~1.8x a 96-cell plan. Explore-Bench `room`
# (3.5 m lidar): 0.9 % over the first 600 steps, 17 % over whole episodes; `room_with_corner`
# with 88 cells (see auto_plan_window), 32 robots: 2.2 % over the first 200 steps, 13.5 % over
# whole episodes (96 cells: 1.2 %, 11.4 %).
PLAN_REACH_M = 3.5


def plan_reach_cells(max_range_cells: int, res: float) -> int:
  """Cells on each side of the robot a planning window is sized for: the sensor range, at most
  :data:`PLAN_REACH_M` metres."""
  return min(max_range_cells, max(1, math.ceil(PLAN_REACH_M / res - 1e-6)))


def auto_plan_window(height: int, width: int, reach_cells: int, max_inflation_cells: int) -> int:
  """A planning window that holds the nearest frontier in most plans: ``reach_cells``
  (:func:`plan_reach_cells`) on each side of the robot plus the margin and 4 cells, rounded up
  to 8 cells; 0 (off) when it would not have at most half the grid's cells.

  Rounding to 8 rather than 32 cells gives Explore-Bench (3.5 m at 0.1 m) 88 cells instead of
  96: the planning round costs less and the few more plans the window cannot certify cost less
  than that (interleaved A/B of 32 steps of 128 robots, steps 0-32 / 300-332: room_with_corner
  0.92 / 0.95x, corridor 0.93 / 0.99x, loop_with_corridor 0.89 / 0.90x; 80 cells were 1.06x on
  room_with_corner at steps 300-332, 72 cells 1.24x).
  """
  side = 8 * math.ceil((2 * reach_cells + 2 * window_margin(max_inflation_cells) + 8) / 8)
  return side if 2 * side * side <= height * width and side < min(height, width) else 0


def effective_radius(res: float, fov: float, n_beams: int, dpi_min: float | None = None) -> float:
  """Li et al.'s effective radius R_e (Eq 5-6), m: the largest distance D at which the scanner
  density ``S_dpi = 1 / (D·tan θ)`` stays above ``dpi_min``, i.e. ``1 / (dpi_min·tan θ)``.

  Args:
    res: metres per cell; ``dpi_min`` defaults to one beam per cell, ``1 / res``.
    fov, n_beams: the lidar's field of view (rad) and beam count; θ is the angle between two
      adjacent beams (:func:`jaxplore.sensor.beam_angles`' spacing).
    dpi_min: Eq 6's minimum density, beams per metre.
  """
  if n_beams < 2 or not fov > 0:
    raise ConfigError(f"R_e needs at least 2 beams over a positive field of view, got {n_beams}, {fov}")
  step = fov / n_beams if fov >= 2 * math.pi - 1e-6 else fov / (n_beams - 1)
  spacing = res if dpi_min is None else 1.0 / dpi_min
  if not spacing > 0:
    raise ConfigError(f"dpi_min must be > 0 beams per metre, got {dpi_min}")
  return spacing / math.tan(step)


# A length that sizes buffers (lidar range, robot radius, R_e, R_u, loop radius) may reach
# this far, or across the map's diagonal if that is longer: beyond the diagonal it reaches no
# more cells, only sizes buffers for cells that do not exist.
LENGTH_LIMIT_M = 100.0


def check_length(name: str, value, limit: float, sizes: str, length: str | None = None) -> None:
  """Raises :class:`ConfigError` naming parameter ``name`` when the ``length`` it gives (m; a
  scalar or one per robot; default: the parameter itself), which sizes ``sizes``, is NaN,
  infinite, negative or beyond ``limit`` metres."""
  arr = np.asarray(value, np.float64)
  if not np.all(np.isfinite(arr)):
    raise ConfigError(f"parameter {name} is NaN or infinite: {shown(arr, ~np.isfinite(arr))}")
  if np.any(arr < 0):
    raise ConfigError(f"parameter {name} must be >= 0, got {shown(arr, arr < 0)}")
  if np.any(arr > limit):
    raise ConfigError(f"parameter {name}: {length or name} = {float(arr.max()):.4g} m sizes "
                      f"{sizes}, and "
                      f"may be at most the map's diagonal or {LENGTH_LIMIT_M:g} m, whichever is "
                      f"longer ({limit:.4g} m here): beyond the map it reaches no more cells")


def config_for(world_shape: tuple[int, int], res: float, params: Params, *, preset: str | None = None,
               **overrides) -> SimConfig:
  """A :class:`SimConfig` sized for a world and the largest range/radius in ``params``.

  With a ``preset`` and no ``r_e`` among the overrides, R_e is derived from the lidar by Eq 5-6
  (:func:`effective_radius`, one beam per cell unless ``dpi_min`` is given; the widest ``fov``
  of ``params``), at most the lidar's range ``r_max``; without a preset it is ``SimConfig.r_e``'s default unless given.
  """
  dpi_min = overrides.pop("dpi_min", None)
  limit = max(math.hypot(*world_shape) * res, LENGTH_LIMIT_M)
  # Lengths that size buffers are checked before anything is sized from them.
  check_length("r_max", params.r_max, limit, "the lidar's buffers")
  r_max_all = np.asarray(params.r_max, np.float64)
  if np.any(r_max_all <= 0):  # checked here: R_e is derived from it below
    raise ConfigError(f"parameter r_max must be > 0, got {shown(r_max_all, r_max_all <= 0)}")
  check_length("r_robot", params.r_robot, limit, "the robot's inflation kernels")
  check_length("loop_radius", params.loop_radius, limit, "the loop-closure line-of-sight samples")
  check_length("alpha", params.alpha, math.inf, "")
  if preset is not None and "r_e" not in overrides:
    n_beams = int(overrides.get("n_beams", PRESETS[preset].n_beams))
    # A scan sees nothing beyond r_max, however dense its beams would be there (coarse grids).
    overrides["r_e"] = min(effective_radius(float(res), float(np.max(np.asarray(params.fov))),
                                            n_beams, dpi_min),
                           float(np.max(np.asarray(params.r_max))))
    check_length("r_e", overrides["r_e"], limit, "the gain kernels",
                 "R_e derived from fov, the beam count and dpi_min by Eq 5-6,")
  elif "r_e" in overrides:
    check_length("r_e", overrides["r_e"], limit, "the gain kernels (R_e)")
  r_max = float(np.max(np.asarray(params.r_max)))
  r_robot = float(np.max(np.asarray(params.r_robot)))
  r_u = float(np.max(np.asarray(params.alpha))) * float(overrides.get("r_e", SimConfig.r_e))
  check_length("alpha", r_u, limit, "the entropy-map update", "R_u = alpha * r_e")
  kwargs = dict(
      height=int(world_shape[0]), width=int(world_shape[1]), res=float(res),
      max_range_cells=max(1, math.ceil(r_max / res - 1e-6)),
      max_inflation_cells=max(0, math.ceil(r_robot / res - 1e-6)),
      max_update_radius_cells=max(1, math.ceil(r_u / res - 1e-6)),
      max_loop_cells=max(1, math.ceil(float(np.max(np.asarray(params.loop_radius))) / res - 1e-6)),
  )
  if preset is not None:
    kwargs["n_beams"] = PRESETS[preset].n_beams
    kwargs["replan_every"] = PRESETS[preset].replan_every
  kwargs.update(overrides)
  if "plan_window" not in overrides:
    reach = plan_reach_cells(kwargs["max_range_cells"], kwargs["res"])
    kwargs["plan_window"] = auto_plan_window(kwargs["height"], kwargs["width"], reach,
                                             kwargs["max_inflation_cells"])
  return SimConfig(**kwargs)
