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
from collections.abc import Iterable
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxplore import posegraph, pytrees
from jaxplore.errors import ConfigError, shown
from jaxplore.sensors import SENSORS, RaySensor, get_sensor
from jaxplore.settings import LENGTH_LIMIT_M, check_length, declared, setting

# The SLAM models (SimConfig.slam; jaxplore.slam.model).
SLAM_MODELS = ("oracle", "scan_matching")
# Each SLAM model's default SimConfig.map_hole_cells: a SLAM map has holes of a few cells where
# walls drawn from keyframes a fraction of a cell apart leave evidence both ways (4 cells: 0.16
# m² at 0.2 m, below explore_lite's min_frontier_size of 0.75 m of frontier).
MAP_HOLE_CELLS = {"oracle": 0, "scan_matching": 4}
# Each SLAM model's default SimConfig.trail: under the oracle the belief's walls are the truth's,
# and a cell the robot drove through is traversable anyway.
TRAIL = {"oracle": 0, "scan_matching": 1}

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

  The fields users set by name (``sensor``, ``slam``, the SLAM model's search sizes, ...) are
  declared with :func:`jaxplore.settings.setting`: their help, range and unit are there (and in
  ``jaxplore settings``); the others are sized by :func:`config_for` or given by the run.

  The ``lockstep_*`` fields and ``observation_dtype`` are tuning choices of the engine whose
  defaults won or lost on measurements (``experiments/bench_lockstep_variants.py`` compares
  them; its numbers are in ``experiments/results/bench_lockstep_variants_gpu.md``); no value
  changes a result, but for ``lockstep_whole_grid_update``, which sums the map's entropy change
  in another order.

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
    planner: the planner (a :class:`jaxplore.planners.PlannerSpec`, its static settings inside
      it); a registered name given here is looked up on construction.
    pose_noise: corrupt odometry and dead-reckon the estimate; when False the estimate
      is the true pose (the covariance is still propagated for planning).
    max_inflation_cells: static bound of the robot radius in cells (``Params.r_robot``).
    dijkstra_max_sweeps: bound on cone-sweep rounds of the shortest-path kernel.
    dijkstra_tiles_after_rounds: the solver's ``tiles_after_rounds``
      (:func:`jaxplore.graph.shortest_paths`): rounds of whole-grid sweeps after which a plan not
      yet settled is finished tile by tile; 0 (the default) = never. The built-in worlds' plans
      settle in few rounds, where the tiles do not pay, and they add compile time to every
      solver in the program; the solver alone finishes narrow mazes sooner with them, but the
      engine, whose plans are mostly windowed, ran a maze at the same rate with them
      (docs/performance.md, experiments/results/bench_dijkstra.md).
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
    strategy: how the batch is executed (:data:`STRATEGIES`): ``"per_robot"`` walks the robots
      one (or ``plan_chunk``) at a time through the irregular stages, ``"lockstep"`` runs each
      stage as one kernel over the whole batch; ``"auto"`` (the default) is resolved on
      construction by :func:`resolve_strategy` from the default JAX backend.
    lockstep_min_chunk: under ``lockstep``, the fewest robots a planning round takes together
      (:func:`jaxplore.planning.lockstep_plan_chunk`).
    lockstep_small_chunks: under ``lockstep``, the smaller chunks a whole-grid round takes
      instead of its own when one holds every robot that needs a plan (a ladder of factor 4;
      ``()`` = always the round's own chunk; :func:`jaxplore.planning.plan_where_needed`).
    lockstep_leftovers_by_need: under ``lockstep``, the whole-grid round after a window (the
      plans the window could not certify) takes a small chunk by need as well; False: always
      chunks of ``lockstep_min_chunk``.
    lockstep_whole_grid_update: under ``lockstep``, a scan updates the robot's whole belief grid
      at once; False: a loop over the tiles it observed, as ``per_robot`` does
      (:func:`jaxplore.mapping.integrate_observation`).
    observation_dtype: the dtype of a scan's observation buffer
      (:func:`jaxplore.sensor.empty_observation`): ``"int8"`` or ``"int32"``.
  """

  height: int
  width: int
  res: float
  n_beams: int = 360
  max_range_cells: int = 60
  path_capacity: int = 256
  replan_every: int = 8
  max_steps: int = 2000
  planner: Any = "nearest_frontier"
  pose_noise: bool = False
  max_inflation_cells: int = 3
  dijkstra_max_sweeps: int = 512
  dijkstra_tiles_after_rounds: int = 0
  plan_chunk: int = 4
  plan_window: int = 0
  graph_nodes: int = 0
  graph_loops: int = 256
  max_loop_cells: int = 40
  sensor: Any = setting("lidar", "the range sensor (jaxplore.sensors): lidar or depth_cone; a "
                        "preset may choose it; from Python, a sensor object", owner="sensor",
                        static=True, choices=tuple(SENSORS), objects=RaySensor)
  slam: str = setting("oracle", "the SLAM model: oracle relocalises by the true pose; "
                      "scan_matching runs a graph SLAM on the robot's own map (turns pose_noise "
                      "on); the planner's paper's where it brings one (li2020, ahmed, ags and "
                      "the REG family: scan_matching)", owner="slam", static=True,
                      choices=SLAM_MODELS)
  slam_match_beams: int = setting(90, "scan points a match scores (every n_beams // "
                                  "slam_match_beams-th beam)", owner="slam", static=True, ge=1,
                                  integer=True)
  slam_smear: float = setting(0.1, "std of the front end's correlation field around each wall "
                              "(correlation_search_space_smear_deviation)", owner="slam",
                              unit="m", static=True, gt=0)
  slam_search_m: float = setting(0.25, "largest half-width of the front end's search (3σ of the "
                                 "odometry since the last keyframe, at least res where res is "
                                 "below this)", owner="slam",
                                 unit="m", static=True, gt=0)
  slam_steps: int = setting(5, "coarse candidates on each side of the prediction in x, y, θ",
                            owner="slam", static=True, ge=1, integer=True)
  slam_fine_steps: int = setting(3, "fine candidates on each side of the coarse best",
                                 owner="slam", static=True, ge=1, integer=True)
  loop_search_m: float = setting(2.0, "largest half-width of a loop closure's search (3σ of the "
                                 "odometry since the last closure)", owner="slam", unit="m",
                                 static=True, gt=0)
  loop_smear: float = setting(0.1, "std of a loop closure's correlation field", owner="slam",
                              unit="m", static=True, gt=0)
  loop_steps: int = setting(10, "coarse candidates on each side in x and y, loop closures",
                            owner="slam", static=True, ge=1, integer=True)
  loop_candidates: int = setting(10, "older keyframes whose scans make a loop closure's local "
                                 "map", owner="slam", static=True, ge=1, integer=True)
  slam_iterations: int = setting(10, "most Gauss-Newton / Levenberg-Marquardt iterations of a "
                                 "pose-graph optimisation", owner="slam", static=True, ge=1,
                                 integer=True)
  map_hole_cells: int = setting(-1, "unknown specks of at most this many cells enclosed by known "
                                "ones are holes, no frontier (-1: 4 with scan_matching, 0 with "
                                "the oracle)", owner="planning", static=True, ge=-1,
                                integer=True)
  trail: int = setting(-1, "plan through the cells the robot's keyframe trajectory crossed even "
                       "within its radius of a believed wall (1), or not (0); -1: 1 with "
                       "scan_matching, 0 with the oracle (needs a pose graph)", owner="planning",
                       static=True, ge=-1, le=1, integer=True)
  strategy: str = "auto"
  lockstep_min_chunk: int = 64
  lockstep_small_chunks: tuple[int, ...] = (4, 16, 64, 256, 1024, 4096)
  lockstep_leftovers_by_need: bool = True
  lockstep_whole_grid_update: bool = True
  observation_dtype: str = "int8"

  def __post_init__(self):
    from jaxplore.planners import get_planner  # the planners import this module
    object.__setattr__(self, "planner", get_planner(self.planner))
    if self.strategy not in STRATEGIES:
      raise ConfigError(f"strategy must be one of {', '.join(STRATEGIES)}, got {self.strategy!r}")
    object.__setattr__(self, "strategy", resolve_strategy(self.strategy))
    for name in ("height", "width", "n_beams", "max_range_cells", "path_capacity", "replan_every",
                 "max_steps", "dijkstra_max_sweeps", "plan_chunk", "lockstep_min_chunk"):
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
    chunks = self.lockstep_small_chunks
    if isinstance(chunks, (int, np.integer)) or not all(
        isinstance(size, (int, np.integer)) and size >= 1 for size in chunks):
      raise ConfigError(f"lockstep_small_chunks must be positive integers, got {chunks!r}")
    object.__setattr__(self, "lockstep_small_chunks", tuple(int(size) for size in chunks))
    if self.observation_dtype not in ("int8", "int32"):
      raise ConfigError(f"observation_dtype must be int8 or int32, got {self.observation_dtype!r}")
    if not isinstance(self.plan_window, (int, np.integer)) or self.plan_window < 0:
      raise ConfigError(f"plan_window must be a non-negative integer, got {self.plan_window!r}")
    if not (math.isfinite(self.res) and self.res > 0):
      raise ConfigError(f"res must be a positive number of metres, got {self.res!r}")
    for name, declaration in STATIC_SETTINGS.items():
      object.__setattr__(self, name, declaration.convert(getattr(self, name), name))
    object.__setattr__(self, "sensor", get_sensor(self.sensor))
    for name, declaration in declared(type(self.sensor)).items():  # a sensor's own settings
      declaration.check(getattr(self.sensor, name), f"sensor {self.sensor.name!r}: {name}")
    if self.map_hole_cells == -1:
      object.__setattr__(self, "map_hole_cells", MAP_HOLE_CELLS[self.slam])
    if self.slam == "scan_matching":
      object.__setattr__(self, "pose_noise", True)
      if not self.graph_nodes:
        raise ConfigError("slam='scan_matching' keeps a pose graph: graph_nodes must be > 0 "
                          "(posegraph.keyframe_bound; jaxplore.resolve.resolve sets it)")
    if self.trail == -1:
      object.__setattr__(self, "trail", TRAIL[self.slam])
    if self.trail and not self.graph_nodes:
      raise ConfigError("trail=1 plans along the keyframe trajectory of the robot's pose graph: "
                        "it needs one (pose_graph=True, or slam='scan_matching')")

  @property
  def n_epochs(self) -> int:
    """Planning rounds needed to cover ``max_steps``."""
    return -(-self.max_steps // self.replan_every)


# The static settings users set by name (``--set``), as SimConfig declares them.
STATIC_SETTINGS = declared(SimConfig)


@pytrees.dataclass(frozen=True)
class Params:
  """Traced numbers of the simulator; every leaf is a float32 scalar (or batched under vmap).

  Each field is declared once (:func:`jaxplore.settings.setting`: default, range, unit, owner,
  help); ``jaxplore settings`` lists them. Units: metres, seconds, radians, log-odds. Planner
  weights live in ``planner`` (a dict of scalars, so every planner can add its own without the
  simulator knowing them).
  """

  r_max: Any = setting(15.0, "the sensor's range", owner="sensor", unit="m", gt=0)
  fov: Any = setting(math.radians(190.0), "the sensor's field of view", owner="sensor",
                     unit="rad", gt=0, le=2 * math.pi)
  range_noise: Any = setting(0.0, "std of the Gaussian error of each measured range (the lidar); "
                             "of a range of 1 m, growing with its square (the depth cone)",
                             owner="sensor", unit="m", ge=0)
  min_range: Any = setting(0.0, "the sensor reports nothing along a beam whose obstacle is "
                           "nearer than this", owner="sensor", unit="m", ge=0)
  l_free: Any = setting(-1.0, "inverse sensor model: added to a cell a beam passes through",
                        owner="belief", unit="log-odds", lt=0)
  l_occ: Any = setting(2.0, "inverse sensor model: added to the cell a beam ends in",
                       owner="belief", unit="log-odds", gt=0)
  l_min: Any = setting(-5.0, "a cell's belief is clamped to at least this", owner="belief",
                       unit="log-odds", lt=0)
  l_max: Any = setting(5.0, "and at most this", owner="belief", unit="log-odds", gt=0)
  p_free: Any = setting(0.35, "a cell with P(occupied) below this is believed free",
                        owner="belief", gt=0, lt=0.5)
  p_occ: Any = setting(0.65, "a cell with P(occupied) above this is believed occupied",
                       owner="belief", gt=0.5, lt=1)
  v_max: Any = setting(0.25, "the robot's speed", owner="robot", unit="m/s", gt=0)
  w_max: Any = setting(1.0, "the robot's turn rate", owner="robot", unit="rad/s", gt=0)
  dt: Any = setting(0.4, "a motion step's duration (unset: res / v_max, one cell per step)",
                    owner="robot", unit="s", gt=0)
  r_robot: Any = setting(0.2, "the robot's radius: paths keep this clear of believed walls",
                         owner="robot", unit="m", ge=0)
  # One odometry noise model: zero-mean Gaussian increments of a wheeled robot, Li et al.'s V_n
  # (Eq 16, with these scales) for the covariance Σ of Eq 17 and li2020's paths, the odometry
  # edges of the pose graph, and, with ``pose_noise``, the simulated odometry error.
  odom_noise_d: Any = setting(0.03, "odometry: std of the distance (and lateral) error per metre "
                              "driven (Li et al. Eq 16's V_n; simulated with pose noise)",
                              owner="odometry", ge=0)
  odom_noise_phi: Any = setting(0.03, "odometry: std of the heading error per radian turned",
                                owner="odometry", ge=0)
  sigma0: Any = setting(1e-4, "the initial pose covariance (diagonal)", owner="localisation",
                        unit="m², rad²", gt=0)
  reloc_min_hits: Any = setting(20.0, "oracle SLAM: beams that must end on well-mapped occupied "
                                "cells for a relocalisation", owner="localisation", ge=0)
  reloc_entropy: Any = setting(0.3, "oracle SLAM: a cell is well mapped below this entropy",
                               owner="localisation", unit="nats", ge=0)
  reloc_var_xy: Any = setting(1e-3, "oracle SLAM: the relocalisation's measurement variance",
                              owner="localisation", unit="m²", gt=0)
  reloc_var_theta: Any = setting(1e-3, "and its heading variance", owner="localisation",
                                 unit="rad²", gt=0)
  # SLAM pose graph (jaxplore.posegraph; Karto's settings in Ahmed et al.'s configuration)
  kf_dist: Any = setting(0.3, "a keyframe every kf_dist of odometry ...", owner="pose graph",
                         unit="m", gt=0)
  kf_rot: Any = setting(0.3, "... or kf_rot of turn", owner="pose graph", unit="rad", gt=0)
  scan_match_sigma: Any = setting(0.018, "std of a scan match (odometry edges' floor, loop "
                                  "closures)", owner="pose graph", unit="m, rad", gt=0)
  loop_radius: Any = setting(4.0, "a loop closes to a keyframe within this distance ...",
                             owner="pose graph", unit="m", gt=0)
  loop_min_age: Any = setting(15.0, "... at least this many keyframes older ...",
                              owner="pose graph", ge=1)
  loop_max_turn: Any = setting(math.pi / 2, "... whose heading differs by at most this",
                               owner="pose graph", unit="rad", ge=0, le=math.pi)
  # The scan_matching SLAM model (jaxplore.slam.model). Karto's scan matcher settings, as
  # slam_toolbox's mapper_params_online_async.yaml sets them:
  slam_min_response: Any = setting(0.1, "a weaker scan match is refused "
                                   "(link_match_minimum_response_fine)", owner="slam", ge=0, le=1)
  slam_distance_penalty: Any = setting(0.5, "distance_variance_penalty", owner="slam",
                                       unit="m²", gt=0)
  slam_angle_penalty: Any = setting(1.0, "angle_variance_penalty", owner="slam", unit="rad²",
                                    gt=0)
  slam_min_distance_penalty: Any = setting(0.5, "minimum_distance_penalty", owner="slam", ge=0,
                                           le=1)
  slam_min_angle_penalty: Any = setting(0.9, "minimum_angle_penalty", owner="slam", ge=0, le=1)
  slam_min_angle: Any = setting(math.radians(2.0), "the angular search's half-width, at least "
                                "...", owner="slam", unit="rad", gt=0)
  slam_max_angle: Any = setting(0.349, "... and at most (coarse_search_angle_offset; at least "
                                "slam_min_angle)", owner="slam", unit="rad", gt=0, le=math.pi)
  loop_min_response: Any = setting(0.45, "a weaker loop closure is refused "
                                   "(loop_match_minimum_response_fine)", owner="slam", ge=0, le=1)
  # Not Karto's 3.0 (loop_match_maximum_variance_coarse, for its sharp 8 m window at 5 cm): on
  # our blunter 5-20 cm fields a larger variance marks an aliased place (doors alike along a
  # corridor), where closures were a metre off (experiments/results/slam_closure_audit.md).
  loop_max_variance: Any = setting(0.09, "a loop closure's match with a larger positional "
                                   "variance is refused (0.09: a standard deviation of 0.3 m)",
                                   owner="slam", unit="m²", gt=0)
  # Not Karto's (its 8 m window has no such gate); a closure whose own bound this far excludes
  # the truth is counted false.
  loop_gate: Any = setting(11.34, "a closure's pose must lie within this Mahalanobis distance² "
                           "of the estimate (chi-square, 3 dof, 99 %)", owner="slam", gt=0)
  # Not Karto's (it keeps every closure it accepts): a false closure bends the whole graph to
  # fit it, and shows at the optimum as an edge the rest of the graph disagrees with.
  loop_revoke_chi2: Any = setting(16.27, "at the back end's optimum, a loop edge whose "
                                  "Mahalanobis error² exceeds this is taken out again and the "
                                  "graph optimised without it (chi-square, 3 dof, 99.9 %; 0: "
                                  "never, as Karto)", owner="slam", ge=0)
  # Karto's LinkNearChains (link_scan_maximum_distance 1.5 m): where the robot drives again
  # through a place it has closed a loop in, its keyframes are matched against the older ones
  # there, so that the next optimisation keeps the revisit where the old map has it (matched
  # scan-to-map, the chain alone bends as if its edges were independent).
  link_radius: Any = setting(1.5, "after a loop closure, a new keyframe within this of an older "
                             "one is matched against it and linked to it (a near link; 0: "
                             "never)", owner="slam", unit="m", ge=0)
  link_spacing: Any = setting(1.0, "... at most one near link per this distance driven",
                              owner="slam", unit="m", ge=0)
  link_min_response: Any = setting(0.1, "a weaker near link is refused "
                                   "(link_match_minimum_response_fine)", owner="slam", ge=0, le=1)
  coverage_goal: Any = setting(0.99, "fraction of the reachable free area that completes an "
                               "episode (above 1: only the planner or the budget ends it)",
                               owner="episode", gt=0)
  # As explore_lite's progress_timeout: a robot circling between goals gives its goal up.
  stall_m: Any = setting(15.0, "a robot that drives this far within stall_span, its map gaining "
                         "no free cell, has its current goal blacklisted (0: never)",
                         owner="planning", unit="m", ge=0)
  stall_span: Any = setting(3.0, "the diagonal of the box of positions a stalled robot stays in",
                            owner="planning", unit="m", gt=0)
  planner: Any = dataclasses.field(default_factory=dict)  # planner weights (name -> scalar)


PARAM_SETTINGS = declared(Params)
PARAM_FIELDS = tuple(PARAM_SETTINGS)


@dataclasses.dataclass(frozen=True)
class Preset:
  """A paper's sensor and robot: parameter overrides and static sizes.

  Attributes:
    sensor: the range sensor (:data:`jaxplore.sensors.SENSORS`).
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
  sensor: str = "lidar"


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
    # Intel RealSense D435 (datasheet, D400 series): 87° horizontal depth field of view, depth
    # from ~0.3 m, error under 2 % at 2 m (4 cm: 1 cm at 1 m growing with the square).
    "depth_camera": Preset(
        "depth_camera", "a depth camera's cone (RealSense D435-like): 4 m, 87°, from 0.3 m, "
        "error 1 cm at 1 m growing with the square", dict(r_max=4.0, fov=math.radians(87.0),
        range_noise=0.01, min_range=0.3, v_max=0.3, w_max=1.0), n_beams=160,
        sensor="depth_cone"),
}


# Settings that no longer exist, and what took their place (named in the error a user gets).
RETIRED = {"sigma_d": "odom_noise_d", "sigma_phi": "odom_noise_phi"}


def retired_hint(names) -> str:
  """The start of an unknown-setting error for names that were removed: what replaced them."""
  gone = sorted(set(map(str, names)) & set(RETIRED))
  if not gone:
    return ""
  return ("; ".join(f"{name!r} was removed: Li et al.'s V_n is the odometry noise model now, "
                    f"set {RETIRED[name]!r}" for name in gone) + ". ")


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
    raise ConfigError(f"{retired_hint(unknown)}unknown parameter(s) {sorted(unknown)}; valid: "
                      f"{', '.join(PARAM_FIELDS)}")
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
  """Raises :class:`ConfigError` naming the first NaN or out-of-range value (host side, before
  compute).

  Works on scalar or batched leaves (every element is checked).
  """
  def check(name, arr, ok, what):
    arr = np.asarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
      raise ConfigError(f"parameter {name} is NaN or infinite: {shown(arr, ~np.isfinite(arr))}")
    if not np.all(ok(arr)):
      raise ConfigError(f"parameter {name} must be {what}, got {shown(arr, ~ok(arr))}")

  p = params
  for name, declaration in PARAM_SETTINGS.items():
    declaration.check(getattr(p, name))
  max_r = config.max_range_cells * config.res
  check("r_max", p.r_max, lambda a: a <= max_r + 1e-6,
        f"<= max_range_cells * res = {max_r:.3g} m (raise SimConfig.max_range_cells)")
  near = np.asarray(p.min_range, np.float64) >= np.asarray(p.r_max, np.float64)
  if np.any(near):
    raise ConfigError(f"min_range {shown(p.min_range, near)} m is not below r_max "
                      f"{shown(p.r_max, near)} m: the sensor would see nothing")
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
  max_rr = config.max_inflation_cells * config.res
  check("r_robot", p.r_robot, lambda a: a <= max_rr + 1e-6,
        f"<= max_inflation_cells * res = {max_rr:.3g} m (raise SimConfig.max_inflation_cells)")
  if config.graph_nodes:
    max_r = config.max_loop_cells * config.res
    check("loop_radius", p.loop_radius, lambda a: a <= max_r + 1e-6,
          f"<= max_loop_cells * res = {max_r:.3g} m (raise SimConfig.max_loop_cells)")
    posegraph.check_capacity(config.graph_nodes, config.max_steps, p)
  check("slam_max_angle", p.slam_max_angle, lambda a: a >= np.asarray(p.slam_min_angle),
        ">= slam_min_angle")
  for name, value in p.planner.items():
    check(f"planner.{name}", value, lambda a: np.ones_like(a, bool), "finite")


def window_margin(max_inflation_cells: int) -> int:
  """Cells along a window's inner edges whose belief masks may differ from the whole grid's
  (inflation, the escape zone and frontier tests look up to this far); planning avoids them."""
  return 2 * max_inflation_cells + 3


# Distance (m) around the robot a planning window is sized for. The nearest frontier is usually
# this close whatever the sensor range: frontiers also open at the edges of the field of view and
# behind nearby obstacles. A smaller window leaves many more plans uncertified (each planned
# again on the whole grid), a larger one certifies few more and costs more per plan: the shares
# of plans certified by window size are in experiments/results/plan_window.md.
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
  than that, early and late in an episode; smaller windows than 88 cells lost late in an episode
  (experiments/results/plan_window.md).
  """
  side = 8 * math.ceil((2 * reach_cells + 2 * window_margin(max_inflation_cells) + 8) / 8)
  return side if 2 * side * side <= height * width and side < min(height, width) else 0


def config_for(world_shape: tuple[int, int], res: float, params: Params, *,
               preset: str | None = None, planner_given: Iterable[str] = (),
               **overrides) -> SimConfig:
  """A :class:`SimConfig` sized for a world and the largest range/radius in ``params``.

  A planner that sizes static settings of its own from the run (``PlannerSpec.size_settings``:
  li2020's R_e from the lidar, the bound of its update radius) is given them here, but for
  those the user gave: ``planner_given`` names them (what the resolver passes), and so does
  every setting whose value differs from its declared default.
  """
  limit = max(math.hypot(*world_shape) * res, LENGTH_LIMIT_M)
  # Lengths that size buffers are checked before anything is sized from them.
  check_length("r_max", params.r_max, limit, "the lidar's buffers")
  r_max_all = np.asarray(params.r_max, np.float64)
  if np.any(r_max_all <= 0):  # checked here: planners may size from it (li2020's R_e)
    raise ConfigError(f"parameter r_max must be > 0, got {shown(r_max_all, r_max_all <= 0)}")
  check_length("r_robot", params.r_robot, limit, "the robot's inflation kernels")
  check_length("loop_radius", params.loop_radius, limit, "the loop-closure line-of-sight samples")
  r_max = float(np.max(np.asarray(params.r_max)))
  r_robot = float(np.max(np.asarray(params.r_robot)))
  kwargs: dict[str, Any] = dict(
      height=int(world_shape[0]), width=int(world_shape[1]), res=float(res),
      max_range_cells=max(1, math.ceil(r_max / res - 1e-6)),
      max_inflation_cells=max(0, math.ceil(r_robot / res - 1e-6)),
      max_loop_cells=max(1, math.ceil(float(np.max(np.asarray(params.loop_radius))) / res - 1e-6)),
  )
  if preset is not None:
    kwargs["n_beams"] = PRESETS[preset].n_beams
    kwargs["replan_every"] = PRESETS[preset].replan_every
    kwargs["sensor"] = PRESETS[preset].sensor
  kwargs.update(overrides)
  if "plan_window" not in overrides:
    reach = plan_reach_cells(kwargs["max_range_cells"], kwargs["res"])
    kwargs["plan_window"] = auto_plan_window(kwargs["height"], kwargs["width"], reach,
                                             kwargs["max_inflation_cells"])
  config = SimConfig(**kwargs)
  spec = config.planner
  if spec.size_settings is None:
    return config
  given = frozenset(planner_given) | spec.changed_settings()
  sized = spec.size_settings(spec.settings, given, config, params, preset)
  if sized == spec.settings:
    return config
  return dataclasses.replace(config, planner=spec.with_settings(sized))
