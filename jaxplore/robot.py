"""One robot: its state, its reset and its motion step (single-robot pure functions).

The engine batches these with ``vmap`` at the edge. One motion step (:func:`step`): drive toward
the next waypoint (or turn to the look-at cell), unless the robot's disc at that waypoint would
touch an occupied cell of the truth that its belief does not hold as occupied (a collision: the
robot stays, its path ends, and the cells it touched become occupied in its belief, as a bumper
would tell it) or, nearer than where it stands, one its belief holds (walls mapped since it
planned: its path ends and it plans again) -> dead-reckon the estimate and propagate Σ
(Li et al. 2020, Eq 16-17) -> scan the truth from the true pose -> relocalise if the scan ends on
enough well-mapped walls -> integrate the scan into the belief at the *estimated* pose -> the
SLAM pose graph (keyframes and loop closures, :mod:`jaxplore.posegraph`; only when the run keeps
one) -> the planner's step hook (only when it has one: li2020 updates its entropy map there) ->
metrics -> termination.

With the ``scan_matching`` SLAM model the robot steers by its estimate instead (pure pursuit
along a straight run of its path, :func:`_lookahead`), the true pose moved by the same command,
and a true wall its disc would come nearer to stops it (:func:`_bumps`), whatever its belief
holds (docs/slam.md, "How a SLAM robot moves").

Time spent waiting is not mission time (``time`` counts only steps in which the robot moved or
turned; ``idle_steps`` counts the others: one per arrival, plus any wait of a robot with nothing
to do).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import chex
import jax
import jax.numpy as jnp

from jaxplore import linalg, mapping, motion, posegraph, pytrees, sensor
from jaxplore.config import Params, SimConfig
from jaxplore.errors import ConfigError
from jaxplore.planners import base as planners_base
from jaxplore.slam import model as slam_model
from jaxplore.world import World, cell_centre, cell_of, sample_start, to_cells

RUNNING, COMPLETE, EXHAUSTED, TIMEOUT = 0, 1, 2, 3
REASONS = {RUNNING: "running", COMPLETE: "complete", EXHAUSTED: "exhausted", TIMEOUT: "timeout"}


@pytrees.dataclass(frozen=True)
class State:
  """One robot's whole simulation state (leaves gain a leading batch axis under vmap).

  Attributes:
    key: PRNG key.
    pose: f32[3] true pose (x m, y m, θ rad). pose_est: f32[3] the robot's estimate.
    cov: f32[3, 3] pose covariance Σ of the estimate.
    logodds: f32[H, W] occupancy belief.
    blacklist: bool[H, W] goals found unresolvable (never chosen again).
    waypoints: i32[L, 2] current path; path_len: i32; path_idx: i32 next waypoint.
    goal, look_at, last_goal: i32[2] cells of the current and previous plan.
    steps: i32 motion steps taken (including idle ones); idle_steps: i32.
    since_plan: i32 steps since the last plan; busy: bool the last step moved or turned.
    time: f32 mission time (s); distance: f32 (m).
    entropy: f32 map entropy Σ Ĥ(c) over the grid (nats). covered: f32 reachable cells known free.
    done: bool; reason: i32 (RUNNING, COMPLETE, EXHAUSTED, TIMEOUT).
    collisions: i32 steps in which the robot's disc would have touched an occupied cell.
    stall_box: f32[4] (x min, y min, x max, y max) of the estimated positions since the stall
      watch last restarted; stall_m: f32 metres driven since; stall_covered: f32 ``covered``
      then (see :func:`_watch_stall`).
    on_trail: bool the robot's path was planned along its keyframe trail (a recovery:
      :func:`jaxplore.planning.belief_view`): driven through believed walls' margins as planned.
    memory: the planner's per-robot memory (a pytree; ``()`` for a planner without one).
    graph: the robot's SLAM pose graph (:class:`jaxplore.posegraph.PoseGraph`), or None when
      ``SimConfig.graph_nodes`` is 0.
  """

  key: chex.Array
  pose: chex.Array
  pose_est: chex.Array
  cov: chex.Array
  logodds: chex.Array
  blacklist: chex.Array
  waypoints: chex.Array
  path_len: chex.Array
  path_idx: chex.Array
  goal: chex.Array
  look_at: chex.Array
  last_goal: chex.Array
  steps: chex.Array
  idle_steps: chex.Array
  since_plan: chex.Array
  busy: chex.Array
  time: chex.Array
  distance: chex.Array
  entropy: chex.Array
  covered: chex.Array
  done: chex.Array
  reason: chex.Array
  collisions: chex.Array
  stall_box: chex.Array
  stall_m: chex.Array
  stall_covered: chex.Array
  on_trail: chex.Array
  memory: Any = ()
  graph: Any = None

  if TYPE_CHECKING:  # chex.dataclass adds it at runtime
    def replace(self, **changes: Any) -> State: ...


@pytrees.dataclass(frozen=True)
class Record:
  """Per-step measurements of one robot."""

  entropy: chex.Array  # nats
  distance: chex.Array  # m
  time: chex.Array  # s
  coverage: chex.Array  # fraction of reachable free cells known free
  det_cov: chex.Array  # det Σ
  pose_error: chex.Array  # m, |true xy − estimated xy|
  x: chex.Array  # true position, m
  y: chex.Array
  done: chex.Array  # bool
  # With a pose graph (else None): keyframes, edges and the mean edge D-optimality (NaN: no edge).
  graph_nodes: Any = None
  graph_edges: Any = None
  dopt_mean: Any = None
  # With the scan_matching SLAM model (else None): loop closures in the graph, how many of
  # them are false, near links in the graph, and loop edges (closures or links) the back end
  # revoked.
  loop_closures: Any = None
  false_closures: Any = None
  near_links: Any = None
  revoked: Any = None


def planner_context(config: SimConfig, shape: tuple[int, int] | None = None
                    ) -> planners_base.PlannerContext:
  """What the planner is told of the run (:class:`~jaxplore.planners.base.PlannerContext`), for
  the whole grid or for a window of ``shape`` cells. A planner that reads the pose graph without
  one is refused.
  """
  height, width = shape if shape is not None else (config.height, config.width)
  spec = config.planner
  if spec.needs_pose_graph and not config.graph_nodes:
    raise ConfigError(f"planner {spec.name!r} plans on the SLAM pose graph, but "
                      f"SimConfig.graph_nodes is 0: give it room for the run's keyframes "
                      f"(posegraph.keyframe_bound; jaxplore.resolve.resolve sets it)")
  return planners_base.PlannerContext(
      height=height, width=width, res=config.res, path_capacity=config.path_capacity,
      dijkstra_max_sweeps=config.dijkstra_max_sweeps,
      dijkstra_tiles_after_rounds=config.dijkstra_tiles_after_rounds,
      max_inflation_cells=config.max_inflation_cells, max_steps=config.max_steps,
      settings=spec.settings, strategy=config.strategy)


def robot_view(config: SimConfig, world: World, state: State) -> planners_base.RobotView:
  """The robot as it believes itself to be: estimated pose, its cell, Σ, its position in cells."""
  return planners_base.RobotView(pose=state.pose_est,
                                 cell=cell_of(state.pose_est[:2], world.origin, config.res),
                                 cov=state.cov,
                                 position=to_cells(state.pose_est[:2], world.origin, config.res))


def _sense(config: SimConfig, world: World, params: Params, state: State, key, active,
           odometry=None, first=False):
  """Scan, localise, integrate into the belief and update the running metrics.

  ``active`` (bool) masks every change, so a finished or idle robot's maps stay untouched; such a
  robot casts no beam. Under ``vmap`` the robots are processed one after the other with their
  maps updated in place (:func:`mapping.per_robot` says why that beats a ``vmap`` on a CPU),
  or, with the ``lockstep`` strategy, all at once.

  Localisation: with the ``oracle`` SLAM model, a Kalman update by a measurement of the true pose
  when the scan ends on enough well-mapped walls; with ``scan_matching``, the SLAM model of
  :mod:`jaxplore.slam.model` (``odometry``: the step's measured increment and its covariance;
  ``first``: the scan is the first keyframe's).
  """
  res = config.res
  shape = (config.height, config.width)
  n_cross = config.max_range_cells + 1
  slam = config.slam == "scan_matching"
  lockstep = config.strategy == "lockstep"
  whole_grid = lockstep and config.lockstep_whole_grid_update

  def one(robot, grids, inputs):
    logodds, graph = grids
    (params, pose, pose_est, cov, key, active, angles, dirs, est_dirs, odometry, totals) = inputs
    true_uv = to_cells(pose[:2], world.origin, res)[::-1]  # (col, row) coordinates
    noise_key, _ = jax.random.split(key)
    scan = config.sensor.measure(world.truth_framed, shape, true_uv[0], true_uv[1], angles,
                                 params, res, n_cross, noise_key, active, dirs)
    def seen_from(pose_est, est_dirs=None):
      """The scan as integrated from ``pose_est``, where it is seen from, its end cells and beam
      directions (``est_dirs``: those directions, when already computed)."""
      if config.pose_noise:
        # Integrated where the robot believes it is; beams keep their robot-frame angle.
        est_uv = to_cells(pose_est[:2], world.origin, res)[::-1]
        seen = scan._replace(angles=angles - pose[2] + pose_est[2])
        exact = jnp.bool_(False)
        est_dirs = sensor.directions(seen.angles) if est_dirs is None else est_dirs
      else:
        seen, est_uv, exact = scan, true_uv, params.range_noise <= 0
      end_rows, end_cols = sensor.end_cells(seen, est_uv[0], est_uv[1], exact, est_dirs,
                                            true_origin=(true_uv[0], true_uv[1]), true_dirs=dirs)
      return seen, est_uv, end_rows, end_cols, est_dirs

    if slam:
      offsets = config.sensor.offsets(params, config.n_beams)
      # The robot's graph without its stored scans: those (most of the graph's bytes) stay in
      # the batch's array, written a row per keyframe and read only to close a loop.
      own_graph = jax.tree.map(lambda g: g[robot], graph.replace(ranges=None))
      own_grid = jax.lax.dynamic_index_in_dim(logodds, robot, 0, keepdims=False)
      pose_est, cov, own_graph, frame = _slam_front(config, world, params, own_graph, own_grid,
                                                    scan, offsets, pose, pose_est, cov, active,
                                                    odometry, first)
      slot = jnp.where(frame.new | first, own_graph.n_nodes - 1, own_graph.poses.shape[0])
      ranges = graph.ranges.at[robot, slot].set(frame.stored, mode="drop")
      # As slam_toolbox builds its grid: only keyframes' scans, each re-traced from the
      # keyframe's estimated pose (what a rebuild after a loop closure re-integrates).
      observed = slam_model.keyframe_observation(pose_est, frame.stored, offsets, world.origin,
                                                 res, shape, n_cross, params,
                                                 active=frame.new | first)
      old_end = jnp.float32(0.0)
    else:
      seen, est_uv, end_rows, end_cols, est_dirs = seen_from(pose_est, est_dirs)
      # Relocalisation: enough beams end on occupied cells the belief already knows well.
      # An end off the grid (an estimate near the edge) is no cell the belief knows: 0, not the
      # far edge's cell that a wrapped negative index would read.
      old_end = logodds.at[robot, end_rows, end_cols].get(mode="fill", fill_value=0.0,
                                                          wrap_negative_indices=False)
      well_mapped = (old_end > mapping.logit(params.p_occ)) & (
          mapping.entropy_of_logodds(old_end) < params.reloc_entropy)
      hits = jnp.sum(well_mapped & scan.hit)
      meas_cov = jnp.diag(jnp.stack([params.reloc_var_xy, params.reloc_var_xy,
                                     params.reloc_var_theta]))
      new_est, new_cov = motion.relocalise(pose_est, cov, pose, meas_cov)
      reloc = active & (hits >= params.reloc_min_hits)
      pose_est = jnp.where(reloc, new_est, pose_est)
      cov = jnp.where(reloc, new_cov, cov)

    carried = {}
    if config.pose_noise and not slam:
      # As a SLAM front end does: the scan that relocalised the robot is integrated at the
      # corrected pose (integrated first, a heading error of a degree laid far walls' cells
      # across free space before the correction), and the free cells are carried from the
      # true beams (sensor.mark_observed).
      seen, est_uv, end_rows, end_cols, est_dirs = seen_from(pose_est)
      carried = dict(true_origin=(true_uv[0], true_uv[1]), true_dirs=dirs)
    if not slam:
      observed = sensor.mark_observed(sensor.empty_observation(shape, config.observation_dtype),
                                      shape, seen, est_uv[0], est_uv[1], end_rows, end_cols,
                                      n_cross, active, est_dirs, **carried)

    logodds, d_entropy, d_covered = mapping.integrate_observation(
        logodds, robot, sensor.observation_tiles(observed, shape), world.reachable, params,
        after=jnp.sum(old_end), whole_grid=whole_grid)
    if slam:
      logodds, own_graph, pose_est, rebuilt = _slam_back(config, world, params, own_graph, ranges,
                                                         logodds, robot, offsets, pose, pose_est,
                                                         frame)
      d_entropy = jnp.where(rebuilt.done, rebuilt.entropy - totals[0], d_entropy)
      d_covered = jnp.where(rebuilt.done, rebuilt.covered - totals[1], d_covered)
      graph = jax.tree.map(lambda g, new: g.at[robot].set(new), graph.replace(ranges=None),
                           own_graph).replace(ranges=ranges)
    return (logodds, graph), (pose_est, cov, d_entropy, d_covered)

  # Beam directions are computed here, for the whole batch at once, rather than inside the
  # per-robot loop (see sensor.measure).
  angles = config.sensor.angles(state.pose[2], params, config.n_beams)
  est_angles = angles - state.pose[2] + state.pose_est[2] if config.pose_noise else angles
  if odometry is None:  # no motion (the reset's first scan)
    odometry = (jnp.zeros_like(state.pose), jnp.zeros_like(state.cov), state.pose_est)
  inputs = (params, state.pose, state.pose_est, state.cov, key, active, angles,
            sensor.directions(angles), sensor.directions(est_angles), odometry,
            (state.entropy, state.covered))
  batched = mapping.per_robot(one, lockstep=lockstep)
  graph = state.graph if slam else None
  (logodds, graph), (pose_est, cov, d_entropy, d_covered) = batched((state.logodds, graph),
                                                                     inputs)
  state = state.replace(graph=graph) if slam else state
  return state.replace(pose_est=pose_est, cov=cov, logodds=logodds,
                       entropy=state.entropy + d_entropy, covered=state.covered + d_covered)


class _Keyframe(NamedTuple):
  """What the SLAM front end hands its back end within one step."""

  new: Any  # bool: this scan is a new keyframe
  stored: Any  # f16[n] the scan as a keyframe keeps it (slam.model.stored_scan)
  points: Any  # f32[n', 2] the scan's end points (robot frame, m)
  valid: Any  # bool[n']


class _Rebuilt(NamedTuple):
  done: Any  # bool: the belief was rebuilt from the keyframes
  entropy: Any  # its map entropy, nats
  covered: Any  # its reachable cells believed free


def _slam_front(config, world, params, graph, belief, scan, offsets, pose, pose_est, cov, active,
                odometry, first):
  """The ``scan_matching`` model's front end (:mod:`jaxplore.slam.model`): a keyframe when the
  odometry since the last one has moved or turned far enough, its scan matched against the
  belief; the estimate and Σ updated from an accepted match; the keyframe and its odometry edge
  added to the graph."""
  increment, odometry_cov, before = odometry
  stride = slam_model.sizes(config).stride
  stored = slam_model.stored_scan(scan)
  points, valid = slam_model.scan_points(stored, offsets, config.res, stride)
  acc_pose = jnp.where(active, motion.compound(graph.acc_pose, increment), graph.acc_pose)
  # The uncertainty of the dead-reckoned estimate since the last keyframe (the front end's
  # window) and since the last closure (the loop search's), propagated by Li Eq 17: a heading
  # error grows the position error along the way.
  grow = lambda cov: jnp.where(active, motion.propagate_covariance(cov, before, pose_est,
                                                                   odometry_cov), cov)
  acc_cov = grow(graph.acc_cov)
  n_cap = graph.poses.shape[0]
  moved = jnp.hypot(acc_pose[0], acc_pose[1])
  new = (active & ~jnp.bool_(first) & (graph.n_nodes < n_cap)
         & ((moved >= params.kf_dist) | (jnp.abs(acc_pose[2]) >= params.kf_rot)))

  def register():
    return slam_model.register(config, params, belief, world.origin, points, valid, pose_est,
                               acc_cov)

  match = jax.lax.cond(new, register, lambda: _zeros_like(jax.eval_shape(register)))
  accepted = new & (match.response >= params.slam_min_response)
  # The match and the odometry since the last keyframe, fused by their covariances: along a
  # featureless corridor the match's variance is large and the odometry holds the estimate.
  floor = params.scan_match_sigma ** 2 * jnp.eye(3, dtype=jnp.float32)
  fused, fused_cov = motion.relocalise(pose_est, acc_cov + 1e-3 * floor, match.pose, match.cov)
  # Li's planning covariance Σ takes the match as a measurement (Kalman update).
  _, kalman_cov = motion.relocalise(pose_est, cov, match.pose, match.cov)
  pose_est = jnp.where(accepted, fused, pose_est)
  cov = jnp.where(accepted, kalman_cov, cov)
  # The odometry edge's information, in the previous keyframe's frame (where its relative pose
  # is measured).
  previous = graph.poses[jnp.maximum(graph.n_nodes - 1, 0)]
  edge_cov = jnp.where(accepted, fused_cov, acc_cov + floor)
  info = slam_model.information(slam_model.in_frame(edge_cov, previous[2]))
  # The estimate's uncertainty since the last closure (it gates the loop closures).
  drift_cov = slam_model.drift(params, graph, pose_est, acc_cov + floor, match.cov, accepted)
  keyframe_drift = graph.keyframe_drift.at[jnp.where(new, graph.n_nodes, n_cap)].set(
      drift_cov, mode="drop")
  # The loop search's window: the edges compounded as if independent (Li Eq 17), a bound.
  j1, _ = motion.compounding_jacobians(previous, pose_est)
  search_cov = jnp.where(new, j1 @ graph.search_cov @ j1.T + edge_cov, graph.search_cov)
  graph = graph.replace(acc_pose=acc_pose, acc_cov=acc_cov,
                        search_cov=search_cov, keyframe_drift=keyframe_drift,
                        matches_rejected=(graph.matches_rejected +
                                          (new & ~accepted).astype(jnp.int32)))
  graph = slam_model.add_keyframe(graph, new, pose_est, pose, info)
  return pose_est, cov, graph, _Keyframe(new, stored, points, valid)


def _slam_back(config, world, params, graph, ranges, logodds, robot, offsets, pose, pose_est,
               frame: _Keyframe):
  """The ``scan_matching`` model's loop closure and back end: a new keyframe looks for a
  closure; an accepted one is added, the graph optimised, the estimate moved to the keyframe's
  optimised pose and the belief rebuilt from the keyframes' scans."""
  i = graph.n_nodes - 1
  candidates, ok = slam_model.loop_candidates(config, params, graph, i, pose_est)
  armed = slam_model.loop_armed(graph, pose_est, params)
  tries = frame.new & ok[0] & armed
  # Back in a place it has closed a loop in: a near link instead (Karto's LinkNearChains).
  link = frame.new & ~armed & slam_model.link_due(graph, pose_est, candidates, ok, params)

  own_scans = lambda: jax.lax.dynamic_index_in_dim(ranges, robot, 0, keepdims=False)

  def search():
    return slam_model.close_loop(config, params, graph, own_scans(), i, pose_est, pose,
                                 frame.points, frame.valid, offsets, world.origin, candidates, ok,
                                 link)

  closure = jax.lax.cond(tries | link, search, lambda: _zeros_like(jax.eval_shape(search)))
  before = graph.n_loops
  graph = slam_model.add_loop(graph, closure, i)
  graph = graph.replace(loops_rejected=graph.loops_rejected
                        + (tries & ~closure.found).astype(jnp.int32))
  added = graph.n_loops > before
  closed = added & ~link
  # A near link anchors the estimate to the older keyframes: the drift since (and the bound that
  # sizes the next loop search) starts again from the link's own uncertainty.
  linked = added & link
  graph = slam_model.restart_drift(graph, linked, i, closure.cov)
  graph = graph.replace(linked_at=jnp.where(linked, pose_est[:2], graph.linked_at))

  def back_end(graph, logodds):
    graph = slam_model.optimise(config, params, graph)
    logodds, entropy, covered = slam_model.rebuild(
        logodds, robot, graph, own_scans(), offsets, world.origin, config.res, world.reachable,
        params, config.max_range_cells + 1,
        config.strategy == "lockstep" and config.lockstep_whole_grid_update)
    return graph, logodds, _Rebuilt(jnp.bool_(True), entropy, covered)

  def unchanged(graph, logodds):
    return graph, logodds, _Rebuilt(jnp.bool_(False), jnp.float32(0.0), jnp.float32(0.0))

  graph, logodds, rebuilt = jax.lax.cond(closed, back_end, unchanged, graph, logodds)
  pose_est = jnp.where(closed, graph.poses[i], pose_est)
  # A closure the back end revoked (slam_model.optimise) closed nothing: the drift stands.
  kept = closed & ~graph.loop_revoked[jnp.minimum(before, graph.loops.shape[0] - 1)]
  graph = slam_model.restart_drift(graph, kept, i, jnp.zeros((3, 3), jnp.float32))
  graph = graph.replace(closed_at=jnp.where(kept, pose_est[:2], graph.closed_at))
  return logodds, graph, pose_est, rebuilt


def _zeros_like(shapes):
  return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)


def reset(config: SimConfig, world: World, params: Params, key, start_pose=None) -> State:
  """A robot at its start with an empty belief, after its first scan.

  Args:
    start_pose: f32[3] (x, y, θ) or None to sample a start cell and heading from ``key``.
  """
  h, w, L = config.height, config.width, config.path_capacity
  key, k_start, k_scan = jax.random.split(key, 3)
  if start_pose is None:
    cell, theta = sample_start(world, k_start)
    xy = cell_centre(cell, world.origin, config.res)
    pose = jnp.concatenate([xy, theta[None]]).astype(jnp.float32)
  else:
    pose = jnp.asarray(start_pose, jnp.float32)
  cell = cell_of(pose[:2], world.origin, config.res)
  zeros_i2 = jnp.zeros((2,), jnp.int32) - 1
  state = State(
      key=key, pose=pose, pose_est=pose, cov=jnp.eye(3, dtype=jnp.float32) * params.sigma0,
      logodds=jnp.zeros((h, w), jnp.float32),
      blacklist=jnp.zeros((h, w), bool),
      waypoints=jnp.broadcast_to(cell, (L, 2)).astype(jnp.int32), path_len=jnp.int32(0),
      path_idx=jnp.int32(0), goal=zeros_i2, look_at=cell, last_goal=zeros_i2,
      steps=jnp.int32(0), idle_steps=jnp.int32(0), since_plan=jnp.int32(0), busy=jnp.bool_(False),
      time=jnp.float32(0), distance=jnp.float32(0),
      entropy=jnp.float32(h * w * mapping.LN2), covered=jnp.float32(0),
      done=jnp.bool_(False), reason=jnp.int32(RUNNING), collisions=jnp.int32(0),
      stall_box=jnp.concatenate([pose[:2], pose[:2]]), stall_m=jnp.float32(0),
      stall_covered=jnp.float32(0), on_trail=jnp.bool_(False),
      memory=config.planner.initial_memory(planner_context(config), params),
      graph=(posegraph.init(pose, config.graph_nodes, config.graph_loops,
                            beams=config.n_beams if config.slam == "scan_matching" else 0)
             if config.graph_nodes else None))
  state = _sense(config, world, params, state, k_scan, jnp.bool_(True), first=True)
  state = _step_hook(config, world, params, state, jnp.bool_(True), jnp.bool_(True))
  return _check_complete(world, params, state)


def _step_hook(config: SimConfig, world: World, params: Params, state: State, moved, running
               ) -> State:
  """The planner's step hook (``PlannerSpec.step_hook``) after the scan just integrated; the
  memory of a robot that is not ``running`` stays as it is.

  Under ``vmap`` the robots run one after the other with their memories updated in place, as
  the scan's integration does (:func:`mapping.per_robot`; a memory may hold maps), or, with the
  ``lockstep`` strategy, all at once."""
  spec = config.planner
  hook = spec.step_hook
  if hook is None:
    return state
  ctx = planner_context(config)

  def one(robot, grids, inputs):
    memory, logodds = grids
    params, view, moved, running = inputs
    pick = lambda grid: jax.lax.dynamic_index_in_dim(grid, robot, 0, keepdims=False)
    own = jax.tree.map(pick, memory)
    # One robot at a time, a finished robot skips the hook (a select of both under lockstep).
    new = jax.lax.cond(running, lambda: hook(ctx, params, own, view, pick(logodds), moved),
                       lambda: own)
    memory = jax.tree.map(lambda grid, leaf: jax.lax.dynamic_update_index_in_dim(
        grid, leaf, robot, 0), memory, new)
    return (memory, logodds), ()

  batched = mapping.per_robot(one, lockstep=config.strategy == "lockstep")
  (memory, _), _ = batched((state.memory, state.logodds),
                           (params, robot_view(config, world, state), moved, running))
  return state.replace(memory=memory)


def _watch_stall(params: Params, state: State, moved_m) -> State:
  """Counts the metres a robot drives while it stays within ``stall_span`` (the diagonal of
  the box of its estimated positions) and its belief gains no free cell: a robot that drives
  ``stall_m`` so is going round in circles (two goals chosen in turn, each step toward one
  making the other look nearer), and its next planning round blacklists its current goal
  (:func:`jaxplore.planning._plan_round`). Leaving the span or a new free cell restarts the
  watch. explore_lite's ``progress_timeout`` plays this part on real robots."""
  xy = state.pose_est[:2]
  box = jnp.concatenate([jnp.minimum(state.stall_box[:2], xy),
                         jnp.maximum(state.stall_box[2:], xy)])
  span = box[2:] - box[:2]
  restart = (jnp.sqrt(jnp.sum(span * span)) > params.stall_span) | (
      state.covered > state.stall_covered)
  return state.replace(stall_box=jnp.where(restart, jnp.concatenate([xy, xy]), box),
                       stall_m=jnp.where(restart, 0.0, state.stall_m + moved_m),
                       stall_covered=jnp.where(restart, state.covered, state.stall_covered))


def _check_complete(world: World, params: Params, state: State) -> State:
  complete = ~state.done & (state.covered >= params.coverage_goal * world.n_reachable - 1e-3)
  return state.replace(done=state.done | complete,
                       reason=jnp.where(complete, COMPLETE, state.reason))


def record(world: World, state: State) -> Record:
  graph = {}
  if state.graph is not None:
    g = state.graph
    edges = g.n_nodes - 1 + g.n_loops
    if g.loop_revoked is not None:  # revoked loop edges are out of the graph (weight 0)
      edges = edges - jnp.sum(g.loop_revoked, axis=-1)
    total = jnp.sum(g.chain_w) + jnp.sum(g.loop_w)
    graph = dict(graph_nodes=g.n_nodes, graph_edges=edges,
                 dopt_mean=jnp.where(edges > 0, total / jnp.maximum(edges, 1), jnp.nan))
    if g.loop_false is not None:
      loops = jnp.arange(g.loop_false.shape[-1]) < g.n_loops[..., None]
      closure = loops & ~g.loop_link & ~g.loop_revoked
      graph.update(loop_closures=jnp.sum(closure, axis=-1),
                   false_closures=jnp.sum(g.loop_false & closure, axis=-1),
                   near_links=jnp.sum(g.loop_link & ~g.loop_revoked, axis=-1),
                   revoked=jnp.sum(loops & g.loop_revoked, axis=-1))
  return Record(entropy=state.entropy, distance=state.distance, time=state.time,
                coverage=state.covered / world.n_reachable, det_cov=linalg.det3(state.cov),
                pose_error=jnp.linalg.norm(state.pose[:2] - state.pose_est[:2]),
                x=state.pose[0], y=state.pose[1], done=state.done, **graph)


def _cells_around(config: SimConfig, world: World, xy):
  """The cells within ``max_inflation_cells + 1`` (Chebyshev) of ``xy``'s cell and their squared
  centre distances from ``xy`` in cells² (from the offsets: metres far from the origin lose the
  last bits that decide a tie). Returns (i32[K, 2], f32[K])."""
  k = config.max_inflation_cells + 1
  span = jnp.arange(-k, k + 1)
  offsets = jnp.stack(jnp.meshgrid(span, span, indexing="ij"), axis=-1).reshape(-1, 2)
  at = to_cells(xy, world.origin, config.res)
  home = jnp.floor(at).astype(jnp.int32)
  inside = at - home - 0.5  # xy from its cell's centre: a waypoint's is 0 up to float32 error
  inside = jnp.where(jnp.abs(inside) < 1e-3, 0.0, inside)
  return home[None, :] + offsets, jnp.sum((offsets - inside[None, :]) ** 2, axis=1)


def _within_radius(config: SimConfig, params: Params, squared):
  """:func:`mapping.within_radius` for the robot's radius, ``squared`` in cells²."""
  return mapping.within_radius(squared, params.r_robot / config.res)


def touched_cells(config: SimConfig, world: World, params: Params, xy):
  """The cells around ``xy`` and which of them the robot's disc there would touch: occupied in
  the truth (outside the map counts as occupied) with their centre within ``r_robot``.

  Centre distances with the planner's inflation's bound and tolerance (:func:`mapping.inflate`:
  within, not only closer than), so a path the belief inflates correctly never collides, and a
  cell the robot can drive to is one its planner can still plan from once the walls around it
  are mapped (with ``r_robot`` a whole number of cells, a strict bound would let the disc into
  cells the inflation closes: a robot as wide as two cells would pass a two-cell gap and be
  trapped behind it). Returns (i32[K, 2] cells, bool[K]).
  """
  cells, squared = _cells_around(config, world, xy)
  occupied = world.occupied.at[cells[:, 0], cells[:, 1]].get(
      mode="fill", fill_value=True, wrap_negative_indices=False)
  return cells, occupied & _within_radius(config, params, squared)


def believed_wall_distance_sq(config: SimConfig, world: World, params: Params, state: State, xy):
  """Squared distance in cells² from ``xy`` (in the belief's frame, where the planner plans) to
  the nearest cell the robot's belief holds occupied, within ``max_inflation_cells + 1`` cells
  (``inf`` beyond); outside the map is no wall, as in the planner's inflation
  (:func:`mapping.inflate`)."""
  cells, squared = _cells_around(config, world, xy)
  logodds = state.logodds.at[cells[:, 0], cells[:, 1]].get(
      mode="fill", fill_value=-jnp.inf, wrap_negative_indices=False)
  return jnp.min(jnp.where(logodds > mapping.logit(params.p_occ), squared, jnp.inf))


def _in_belief_frame(config: SimConfig, world: World, true_pose, estimate, points):
  """The belief's cells of points (f32[K, 2], metres, the truth's frame): each point as the
  robot sees it from its ``true_pose``, placed at its ``estimate``."""
  turn = estimate[2] - true_pose[2]
  seen = motion.rotate(turn, points - true_pose[None, :2]) + estimate[None, :2]
  return jax.vmap(cell_of, in_axes=(0, None, None))(seen, world.origin, config.res)


def _centres(config: SimConfig, world: World, cells):
  return jax.vmap(cell_centre, in_axes=(0, None, None))(cells, world.origin, config.res)


def _bumps(config: SimConfig, world: World, params: Params, xy, new_xy):
  """The cells around ``new_xy`` and which of them stop a move of the robot's disc from ``xy``
  to ``new_xy``: the true walls (:func:`touched_cells`) the disc would touch there, when the
  move brings it nearer to the nearest true wall. Sliding along a wall or backing off one it
  already touches goes on, as a bumper allows: a robot whose estimate put it against a wall
  can leave it. Returns (i32[K, 2], bool[K])."""
  cells, squared_new = _cells_around(config, world, new_xy)
  walls = world.occupied.at[cells[:, 0], cells[:, 1]].get(mode="fill", fill_value=True,
                                                          wrap_negative_indices=False)
  touching = walls & _within_radius(config, params, squared_new)
  at = to_cells(xy, world.origin, config.res)
  squared_old = jnp.sum((cells + 0.5 - at[None, :]) ** 2, axis=1)
  nearer = (jnp.min(jnp.where(walls, squared_new, jnp.inf))
            < jnp.min(jnp.where(walls, squared_old, jnp.inf)) - 1e-4)
  return cells, touching & nearer


def _believed_wall(params: Params, logodds, cells):
  """Whether the belief holds each of its ``cells`` as occupied (outside the map: yes)."""
  held = logodds.at[cells[:, 0], cells[:, 1]].get(mode="fill", fill_value=jnp.inf,
                                                  wrap_negative_indices=False)
  return held > mapping.logit(params.p_occ)


def _believed_occupied(config: SimConfig, world: World, params: Params, state: State, cells):
  """Whether the robot's belief holds each truth cell as occupied (outside the map: yes)."""
  return _believed_wall(params, state.logodds, _in_belief_frame(
      config, world, state.pose, state.pose_est, _centres(config, world, cells)))


def _feel_collision(config: SimConfig, world: World, params: Params, state: State, cells, felt):
  """The belief's ``cells`` the robot bumped into (``felt``) become occupied. A contact is
  certain, unlike a scan: their log-odds go to ``l_max`` whatever the belief held (one ``l_occ``
  would leave a cell believed free still free). Map entropy and coverage follow."""
  h, w = config.height, config.width
  inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
  felt = felt & inside
  rows = jnp.where(felt, cells[:, 0], h)  # row h is dropped by the scatter
  old = state.logodds.at[cells[:, 0], cells[:, 1]].get(mode="fill", fill_value=0.0,
                                                       wrap_negative_indices=False)
  new = jnp.broadcast_to(params.l_max, old.shape)
  logodds = state.logodds.at[rows, cells[:, 1]].set(new, mode="drop", wrap_negative_indices=False)
  free_threshold = mapping.logit(params.p_free)
  reachable = world.reachable.at[cells[:, 0], cells[:, 1]].get(mode="fill", fill_value=False,
                                                               wrap_negative_indices=False)
  d_entropy = jnp.sum(jnp.where(felt, mapping.entropy_of_logodds(new) -
                                mapping.entropy_of_logodds(old), 0.0))
  d_covered = jnp.sum(jnp.where(felt & reachable, (new < free_threshold).astype(jnp.float32) -
                                (old < free_threshold).astype(jnp.float32), 0.0))
  return state.replace(logodds=logodds, entropy=state.entropy + d_entropy,
                       covered=state.covered + d_covered)


LOOKAHEAD_CELLS = 2.0


def _lookahead(config: SimConfig, world: World, state: State):
  """The index of the waypoint a robot steering by its estimate heads for: the farthest of its
  next few waypoints within :data:`LOOKAHEAD_CELLS` of the estimate along a straight run of
  the path (pure pursuit that never cuts a corner the planner's clearance was measured around),
  or the next one; the waypoints before it count as passed. A correction of the estimate by a
  fraction of a cell (a keyframe's scan match) then bends the heading a little instead of
  putting a waypoint one cell ahead behind the robot, which would turn it around."""
  ahead = int(LOOKAHEAD_CELLS) + 2
  k = jnp.arange(ahead)
  idx = state.path_idx + k
  # The run starts at the waypoint last passed (the robot's own cell after a plan).
  previous = state.waypoints[jnp.clip(state.path_idx - 1, 0, config.path_capacity - 1)]
  cells = state.waypoints[jnp.minimum(idx, config.path_capacity - 1)]
  steps = cells - jnp.concatenate([previous[None], cells[:-1]])
  straight = jnp.cumprod(jnp.all(steps == steps[:1], axis=1)).astype(bool)
  straight = straight.at[0].set(True)
  centres = _centres(config, world, cells)
  near = jnp.linalg.norm(centres - state.pose_est[None, :2], axis=1) <= (
      LOOKAHEAD_CELLS + 1e-3) * config.res
  return state.path_idx + jnp.max(jnp.where(near & straight & (idx < state.path_len), k, 0))


def step(config: SimConfig, world: World, params: Params, state: State) -> tuple[State, Record]:
  """One motion step of one robot (see the module docstring for the order of events)."""
  res = config.res
  key, k_noise, k_sense = jax.random.split(state.key, 3)
  running = ~state.done
  slam = config.slam == "scan_matching"
  path_idx = _lookahead(config, world, state) if slam else state.path_idx
  has_waypoint = path_idx < state.path_len
  idx = jnp.minimum(path_idx, config.path_capacity - 1)
  target = jnp.where(has_waypoint, state.waypoints[idx], state.look_at)
  # A waypoint the truth says is occupied ends the path, and the robot feels it like a bump: a
  # scan integrated at a slightly wrong pose can leave a wall cell believed free, and a planner
  # would send the robot to that "frontier" again and again (seen with pose noise on `campus`).
  # (With SLAM the waypoint is a cell of the belief, whose frame is not the truth's: the
  # collision check below decides.)
  blocked = has_waypoint & world.occupied[target[0], target[1]] & (not slam)
  state = _feel_collision(config, world, params, state,
                          _in_belief_frame(config, world, state.pose, state.pose_est,
                                           _centres(config, world, target[None])),
                          (running & blocked)[None])
  path_len = jnp.where(blocked, path_idx, state.path_len)
  has_waypoint = has_waypoint & ~blocked
  # A path planned before the walls beside it were mapped would take the disc onto walls the
  # belief now holds (no collision: known walls are the planner's to avoid), into cells its
  # planner no longer plans through, and a robot that drove on was left in narrow pockets it
  # could not plan out of. It stops and replans instead; a step away from walls mapped inside
  # its radius (the planner's escape route) goes on.
  next_xy = cell_centre(target, world.origin, res)
  wall_ahead = believed_wall_distance_sq(config, world, params, state, next_xy)
  # Both in the belief's frame, as the planner saw them: it plans from the estimated pose's
  # cell, so "here" is that cell's centre (measured from the estimate itself, a sub-mm offset
  # from the centre made a waypoint beside the same wall "nearer" and cut every path there).
  here = cell_centre(cell_of(state.pose_est[:2], world.origin, res), world.origin, res)
  wall_here = believed_wall_distance_sq(config, world, params, state, here)
  # (A path along the robot's own trail goes through such margins by design: the planner chose
  # it because no other way led out.)
  closes_in = (has_waypoint & ~state.on_trail & _within_radius(config, params, wall_ahead)
               & (wall_ahead < wall_here))
  path_len = jnp.where(closes_in, path_idx, path_len)
  has_waypoint = has_waypoint & ~closes_in
  target = jnp.where(has_waypoint, target, state.look_at)
  target_xy = cell_centre(target, world.origin, res)
  if slam:
    # The robot steers by its estimate, as a real one does: the turn and drive that take the
    # estimate toward the target move the true pose. The belief around it was drawn from the
    # same estimate, so it passes the walls it believes in; a true wall its disc would touch is
    # a collision whatever the belief holds (the belief's walls may lie elsewhere).
    look_needed = jnp.any(target != cell_of(state.pose_est[:2], world.origin, res))
    command = motion.drive_toward(state.pose_est, target_xy, params.v_max, params.w_max,
                                  params.dt, translate=has_waypoint)
    heading = motion.wrap_angle(state.pose[2] + command.delta_phi)
    true_xy = state.pose[:2] + command.delta_d * jnp.stack([jnp.cos(heading), jnp.sin(heading)])
    drive = command._replace(pose=jnp.concatenate([true_xy, heading[None]]))
    # Where the true robot ends when its estimate reaches the target: there, as the oracle's
    # robot at its waypoint, its disc must be clear of the truth's walls (the planner measured
    # clearance at cell centres, not along the segments between them).
    offset = motion.rotate(state.pose[2] - state.pose_est[2], target_xy - state.pose_est[:2])
    end_true = jnp.concatenate([state.pose[:2] + offset, state.pose[2:]])
    touched, touching = _bumps(config, world, params, state.pose[:2], end_true[:2])
  else:
    look_needed = jnp.any(target != cell_of(state.pose[:2], world.origin, res))
    drive = motion.drive_toward(state.pose, target_xy, params.v_max, params.w_max, params.dt,
                                translate=has_waypoint)
    touched, touching = touched_cells(config, world, params, target_xy)
    touching = touching & ~_believed_occupied(config, world, params, state, touched)
  collided = running & has_waypoint & (drive.delta_d > 0) & jnp.any(touching)
  path_len = jnp.where(collided, path_idx, path_len)
  has_waypoint = has_waypoint & ~collided
  busy = running & ~collided & (
      has_waypoint | (look_needed & (jnp.abs(drive.delta_phi) > 1e-6)))
  delta_d = jnp.where(busy, drive.delta_d, 0.0)
  delta_phi = jnp.where(busy, drive.delta_phi, 0.0)
  pose = jnp.where(busy, drive.pose, state.pose)
  path_idx = path_idx + (busy & has_waypoint & drive.arrived).astype(jnp.int32)

  # Odometry: the estimate is dead-reckoned from the (possibly noisy) increment; Σ by Eq 17
  # with V_n of Eq 16 scaled by the odometry noise, the error simulated with pose noise.
  odo = motion.increment(delta_d, delta_phi)
  v_n = motion.odometry_covariance(delta_d, delta_phi, params.odom_noise_d,
                                   params.odom_noise_phi)
  if config.pose_noise:
    error_std = jnp.stack([params.odom_noise_d * jnp.abs(delta_d),
                           params.odom_noise_d * jnp.abs(delta_d),
                           params.odom_noise_phi * jnp.abs(delta_phi)])
    odo = odo + error_std * jax.random.normal(k_noise, (3,))
  estimate_before = state.pose_est
  pose_est = motion.compound(state.pose_est, odo)
  cov = motion.propagate_covariance(state.cov, state.pose_est, pose_est, v_n)
  if not config.pose_noise:
    pose_est = pose

  if slam:
    # What a bumper tells: something at the disc's edge, toward each wall touched, placed in the
    # robot's own frame. Where the belief already holds that wall a little farther off (the
    # estimate is off by a fraction of a cell), this thickens it toward the robot, so the next
    # plan keeps the clearance the truth needs instead of bumping on the same line again.
    toward = _centres(config, world, touched) - end_true[None, :2]
    toward = toward / jnp.maximum(jnp.linalg.norm(toward, axis=1, keepdims=True), 1e-6)
    felt_cells = _in_belief_frame(config, world, end_true,
                                  jnp.concatenate([target_xy, state.pose_est[2:]]),
                                  end_true[None, :2] + params.r_robot * toward)
    felt = touching & collided
    # Where the belief holds all of that already, the robot is nearer to the wall than it
    # believes, and a plan from the same belief would take the same step into it again: the
    # bump then blocks the waypoint it was driving to, which the next plan avoids.
    known = jnp.all(~felt | _believed_wall(params, state.logodds, felt_cells))
    own = cell_of(state.pose_est[:2], world.origin, res)
    felt_cells = jnp.concatenate([felt_cells, target[None]])
    felt = jnp.concatenate([felt, (collided & known & jnp.any(target != own))[None]])
  else:
    felt_cells = _in_belief_frame(config, world, state.pose, state.pose_est,
                                  _centres(config, world, touched))
    felt = touching & collided
  state = _feel_collision(config, world, params, state, felt_cells, felt)
  state = state.replace(key=key, pose=pose, pose_est=pose_est, cov=cov, path_len=path_len,
                        path_idx=path_idx, steps=state.steps + running.astype(jnp.int32),
                        idle_steps=state.idle_steps + (running & ~busy).astype(jnp.int32),
                        since_plan=state.since_plan + 1, busy=busy,
                        time=state.time + jnp.where(busy, params.dt, 0.0),
                        distance=state.distance + delta_d,
                        collisions=state.collisions + collided.astype(jnp.int32))
  # The measured increment, its covariance and the estimate it moved (the SLAM model's input).
  state = _sense(config, world, params, state, k_sense, busy,
                 odometry=(odo, v_n, estimate_before))
  state = _watch_stall(params, state, delta_d)
  if config.graph_nodes and config.slam == "oracle":
    # Keyframes at the estimate after relocalisation; odometry edges with V_n; line of sight in
    # the updated belief, sampled at most half a cell apart (loop_radius <= max_loop_cells * res).
    state = state.replace(graph=posegraph.observe(
        state.graph, state.pose_est, v_n, motion.increment(delta_d, delta_phi), busy,
        state.logodds, world.origin, res, params, 2 * config.max_loop_cells + 2))
  state = _step_hook(config, world, params, state, busy, running)
  state = _check_complete(world, params, state)
  timeout = ~state.done & (state.steps >= config.max_steps)
  state = state.replace(done=state.done | timeout, reason=jnp.where(timeout, TIMEOUT, state.reason))
  return state, record(world, state)
