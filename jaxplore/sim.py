"""The batched exploration engine: ``reset``, ``step``, planning and rollouts.

Single-robot pure functions, batched at the edge with ``vmap`` (STYLE.md practice 4). A robot
plans when it needs to: when its last step was idle (its path is done or blocked and it already
faces its look-at cell, or it never planned) or when ``replan_every`` steps have passed since its
last plan. Planning is by far the most expensive part of a step, and ``lax.cond`` under ``vmap``
would run it for every robot (DESIGN.md), so :func:`plan_where_needed` loops over the robots
that need a plan, one after another, and leaves the others untouched. Time spent waiting is not
mission time (``time`` counts only steps in which the robot moved or turned; ``idle_steps``
counts the others: one per arrival, plus any wait of a robot with nothing to do).

One motion step (:func:`step`): drive toward the next waypoint (or turn to the look-at cell) →
dead-reckon the estimate and propagate Σ (Li Eq 16–17) → scan the truth from the true pose →
relocalise if the scan ends on enough well-mapped walls → integrate the scan into the belief at
the *estimated* pose → update the entropy map within ``R_u`` (Li Eq 3) → metrics → termination.
"""

from __future__ import annotations

import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from jaxplore import mapping, motion, posegraph, sensor
from jaxplore.config import ConfigError, Params, SimConfig, window_margin
from jaxplore.maps.grid import GridMap
from jaxplore.planners import base as planners_base

RUNNING, COMPLETE, EXHAUSTED, TIMEOUT = 0, 1, 2, 3
REASONS = {RUNNING: "running", COMPLETE: "complete", EXHAUSTED: "exhausted", TIMEOUT: "timeout"}


@chex.dataclass(frozen=True)
class World:
  """The ground truth shared by every robot of a batch (pass with ``in_axes=None``).

  Attributes:
    occupied: bool[H, W] truth (outside the grid counts as occupied).
    truth_framed: bool[(H + 2) * (W + 2)] the truth with an occupied border, flat (for the lidar).
    reachable: bool[H, W] free cells 4-connected to the start area; coverage is measured on it.
    start_ok: bool[H, W] where random starts are drawn: the largest 8-connected component of the
      reachable cells with clearance > r_robot.
    n_reachable: f32 number of reachable cells.
    origin: f32[2] metres of the lower-left corner of cell (0, 0).
  """

  occupied: chex.Array
  truth_framed: chex.Array
  reachable: chex.Array
  start_ok: chex.Array
  n_reachable: chex.Array
  origin: chex.Array


def make_world(grid: GridMap, r_robot: float, start_xy=None) -> World:
  """Builds the device-side :class:`World` of a map (host side; validates the start).

  Args:
    grid: the truth map.
    r_robot: the robot radius in metres (largest in the batch), for start clearance.
    start_xy: optional (x, y) start in metres; the reachable area is its 4-connected free
      component. Without it, the largest free component is used and starts are sampled in it.
  Raises:
    ConfigError: a start outside the map, inside a wall, or too close to one.
  """
  free = grid.free
  labels, count = ndimage.label(free)
  if count == 0:
    raise ConfigError(f"map {grid.name!r} has no free cell")
  clearance = ndimage.distance_transform_edt(free)  # cells, centre to nearest occupied centre
  radius = r_robot / grid.res
  if start_xy is not None:
    i, j = grid.world_to_cell(start_xy[0], start_xy[1])
    h, w = grid.shape
    if not (0 <= i < h and 0 <= j < w):
      raise ConfigError(f"start {tuple(start_xy)} m is outside the map {grid.name!r} "
                        f"(x in [{grid.origin[0]}, {grid.origin[0] + w * grid.res}], "
                        f"y in [{grid.origin[1]}, {grid.origin[1] + h * grid.res}])")
    if grid.occupied[i, j]:
      raise ConfigError(f"start {tuple(start_xy)} m is inside a wall of map {grid.name!r} (cell {i}, {j})")
    if clearance[i, j] <= radius:
      raise ConfigError(f"start {tuple(start_xy)} m is {clearance[i, j] * grid.res:.2f} m from a wall, "
                        f"closer than the robot radius {r_robot} m")
    reachable = labels == labels[i, j]
  else:
    sizes = ndimage.sum_labels(free, labels, index=np.arange(1, count + 1))
    reachable = labels == (1 + int(np.argmax(sizes)))
  start_ok = reachable & (clearance > radius)
  if start_xy is None and start_ok.any():
    # Random starts only where the robot can reach most of the map: the largest 8-connected
    # component of the cells it fits in (a closet behind a door narrower than the robot is free
    # and reachable for coverage, but a robot started there could never leave it).
    fits, n_fits = ndimage.label(start_ok, structure=np.ones((3, 3), bool))
    fit_sizes = ndimage.sum_labels(start_ok, fits, index=np.arange(1, n_fits + 1))
    start_ok = fits == (1 + int(np.argmax(fit_sizes)))
  if not start_ok.any():
    raise ConfigError(f"map {grid.name!r}: no free cell has clearance above the robot radius {r_robot} m")
  return World(occupied=jnp.asarray(grid.occupied),
               truth_framed=sensor.frame_truth(jnp.asarray(grid.occupied)), reachable=jnp.asarray(reachable),
               start_ok=jnp.asarray(start_ok), n_reachable=jnp.float32(reachable.sum()),
               origin=jnp.asarray(grid.origin, jnp.float32))


@chex.dataclass(frozen=True)
class State:
  """One robot's whole simulation state (leaves gain a leading batch axis under vmap).

  Attributes:
    key: PRNG key.
    pose: f32[3] true pose (x m, y m, θ rad). pose_est: f32[3] the robot's estimate.
    cov: f32[3, 3] pose covariance Σ of the estimate.
    logodds: f32[H, W] occupancy belief. entropy_map: f32[H, W] Li's I_e.
    blacklist: bool[H, W] goals found unresolvable (never chosen again).
    waypoints: i32[L, 2] current path; path_len: i32; path_idx: i32 next waypoint.
    goal, look_at, last_goal: i32[2] cells of the current and previous plan.
    steps: i32 motion steps taken (including idle ones); idle_steps: i32.
    since_plan: i32 steps since the last plan; busy: bool the last step moved or turned.
    time: f32 mission time (s); distance: f32 (m).
    entropy: f32 map entropy Σ Ĥ(c) over the grid (nats). covered: f32 reachable cells known free.
    done: bool; reason: i32 (RUNNING, COMPLETE, EXHAUSTED, TIMEOUT).
    graph: the robot's SLAM pose graph (:class:`jaxplore.posegraph.PoseGraph`), or None when
      ``SimConfig.graph_nodes`` is 0.
  """

  key: chex.Array
  pose: chex.Array
  pose_est: chex.Array
  cov: chex.Array
  logodds: chex.Array
  entropy_map: chex.Array
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
  graph: posegraph.PoseGraph | None = None


@chex.dataclass(frozen=True)
class Record:
  """Per-step measurements of one robot (SPEC §5)."""

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
  graph_nodes: chex.Array | None = None
  graph_edges: chex.Array | None = None
  dopt_mean: chex.Array | None = None


def to_cells(xy, origin, res):
  """Metres -> continuous cell coordinates (row, col)."""
  return jnp.stack([(xy[1] - origin[1]) / res, (xy[0] - origin[0]) / res])


def cell_of(xy, origin, res):
  return jnp.floor(to_cells(xy, origin, res)).astype(jnp.int32)


def cell_centre(cell, origin, res):
  """Integer (row, col) -> metres (x, y) of the centre."""
  return jnp.stack([origin[0] + (cell[1] + 0.5) * res, origin[1] + (cell[0] + 0.5) * res])


def _sense(config: SimConfig, world: World, params: Params, state: State, key, active):
  """Scan, relocalise, integrate into the belief, update the entropy map and the running metrics.

  ``active`` (bool) masks every change, so a finished or idle robot's maps stay untouched; such a
  robot casts no beam. Under ``vmap`` the robots are processed one after the other with their
  maps updated in place (:func:`mapping.per_robot` says why that beats a ``vmap`` here).
  """
  res = config.res
  shape = (config.height, config.width)
  n_cross = config.max_range_cells + 1

  def one(robot, grids, inputs):
    logodds, entropy_map = grids
    params, pose, pose_est, cov, key, active, angles, dirs, est_dirs = inputs
    true_uv = to_cells(pose[:2], world.origin, res)[::-1]  # (col, row) coordinates
    noise_key, _ = jax.random.split(key)
    scan = sensor.measure(world.truth_framed, shape, true_uv[0], true_uv[1], angles, params.r_max / res,
                          n_cross, key=noise_key, noise_cells=params.range_noise / res, active=active,
                          dirs=dirs)
    if config.pose_noise:
      # The scan is integrated where the robot believes it is; beams keep their robot-frame angle.
      est_uv = to_cells(pose_est[:2], world.origin, res)[::-1]
      scan = scan._replace(angles=angles - pose[2] + pose_est[2])
      exact = jnp.bool_(False)
    else:
      est_uv = true_uv
      exact = params.range_noise <= 0
    end_rows, end_cols = sensor.end_cells(scan, est_uv[0], est_uv[1], exact, est_dirs)
    observed = sensor.mark_observed(sensor.empty_observation(shape), shape, scan, est_uv[0], est_uv[1],
                                    end_rows, end_cols, n_cross, active, est_dirs)

    # Relocalisation (SPEC §1): enough beams end on occupied cells the belief already knows well.
    old_end = logodds.at[robot, end_rows, end_cols].get(mode="fill", fill_value=0.0)
    well_mapped = (old_end > mapping.logit(params.p_occ)) & (
        mapping.entropy_of_logodds(old_end) < params.reloc_entropy)
    hits = jnp.sum(well_mapped & scan.hit)
    meas_cov = jnp.diag(jnp.stack([params.reloc_var_xy, params.reloc_var_xy, params.reloc_var_theta]))
    new_est, new_cov = motion.relocalise(pose_est, cov, pose, meas_cov)
    reloc = active & (hits >= params.reloc_min_hits)
    pose_est = jnp.where(reloc, new_est, pose_est)
    cov = jnp.where(reloc, new_cov, cov)

    logodds, d_entropy, d_covered = mapping.integrate_observation(
        logodds, robot, sensor.observation_tiles(observed, shape), world.reachable, params,
        after=jnp.sum(old_end))
    ru_cells = jnp.where(active, params.alpha * params.r_e / res, 0.0)
    entropy_map = mapping.update_entropy_map(
        entropy_map, logodds, to_cells(pose_est[:2], world.origin, res), ru_cells, params.entropy_k,
        2 * config.max_update_radius_cells + 3, robot=robot)
    return (logodds, entropy_map), (pose_est, cov, d_entropy, d_covered)

  # Beam directions are computed here, for the whole batch at once, rather than inside the
  # per-robot loop (see sensor.measure).
  angles = sensor.beam_angles(state.pose[2], params.fov, config.n_beams)
  est_angles = angles - state.pose[2] + state.pose_est[2] if config.pose_noise else angles
  inputs = (params, state.pose, state.pose_est, state.cov, key, active, angles,
            sensor.directions(angles), sensor.directions(est_angles))
  (logodds, entropy_map), (pose_est, cov, d_entropy, d_covered) = mapping.per_robot(one)(
      (state.logodds, state.entropy_map), inputs)
  return state.replace(pose_est=pose_est, cov=cov, logodds=logodds, entropy_map=entropy_map,
                       entropy=state.entropy + d_entropy, covered=state.covered + d_covered)


def sample_start(world: World, key):
  """A pose drawn uniformly over ``world.start_ok`` cells (centre) with a uniform heading."""
  k_cell, k_theta = jax.random.split(key)
  h, w = world.occupied.shape
  logits = jnp.where(world.start_ok.ravel(), 0.0, -jnp.inf)
  flat = jax.random.categorical(k_cell, logits)
  cell = jnp.stack([flat // w, flat % w])
  theta = jax.random.uniform(k_theta, (), minval=-jnp.pi, maxval=jnp.pi)
  return cell, theta


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
      entropy_map=jnp.full((h, w), mapping.LN2, jnp.float32),
      blacklist=jnp.zeros((h, w), bool),
      waypoints=jnp.broadcast_to(cell, (L, 2)).astype(jnp.int32), path_len=jnp.int32(0),
      path_idx=jnp.int32(0), goal=zeros_i2, look_at=cell, last_goal=zeros_i2,
      steps=jnp.int32(0), idle_steps=jnp.int32(0), since_plan=jnp.int32(0), busy=jnp.bool_(False),
      time=jnp.float32(0), distance=jnp.float32(0),
      entropy=jnp.float32(h * w * mapping.LN2), covered=jnp.float32(0),
      done=jnp.bool_(False), reason=jnp.int32(RUNNING),
      graph=posegraph.init(pose, config.graph_nodes, config.graph_loops) if config.graph_nodes else None)
  state = _sense(config, world, params, state, k_scan, jnp.bool_(True))
  return _check_complete(world, params, state)


def _check_complete(world: World, params: Params, state: State) -> State:
  complete = ~state.done & (state.covered >= params.coverage_goal * world.n_reachable - 1e-3)
  return state.replace(done=state.done | complete,
                       reason=jnp.where(complete, COMPLETE, state.reason))


def record(world: World, state: State) -> Record:
  graph = {}
  if state.graph is not None:
    g = state.graph
    edges = g.n_nodes - 1 + g.n_loops
    total = jnp.sum(g.chain_w) + jnp.sum(g.loop_w)
    graph = dict(graph_nodes=g.n_nodes, graph_edges=edges,
                 dopt_mean=jnp.where(edges > 0, total / jnp.maximum(edges, 1), jnp.nan))
  return Record(entropy=state.entropy, distance=state.distance, time=state.time,
                coverage=state.covered / world.n_reachable, det_cov=jnp.linalg.det(state.cov),
                pose_error=jnp.linalg.norm(state.pose[:2] - state.pose_est[:2]),
                x=state.pose[0], y=state.pose[1], done=state.done, **graph)


def step(config: SimConfig, world: World, params: Params, state: State) -> tuple[State, Record]:
  """One motion step of one robot (see the module docstring for the order of events)."""
  res = config.res
  key, k_noise, k_sense = jax.random.split(state.key, 3)
  running = ~state.done
  has_waypoint = state.path_idx < state.path_len
  idx = jnp.minimum(state.path_idx, config.path_capacity - 1)
  target = jnp.where(has_waypoint, state.waypoints[idx], state.look_at)
  # Collisions are impossible by construction: a waypoint the truth says is occupied ends the path.
  blocked = has_waypoint & world.occupied[target[0], target[1]]
  path_len = jnp.where(blocked, state.path_idx, state.path_len)
  has_waypoint = has_waypoint & ~blocked
  target = jnp.where(has_waypoint, target, state.look_at)
  target_xy = cell_centre(target, world.origin, res)
  look_needed = jnp.any(target != cell_of(state.pose[:2], world.origin, res))
  drive = motion.drive_toward(state.pose, target_xy, params.v_max, params.w_max, params.dt,
                              translate=has_waypoint)
  busy = running & (has_waypoint | (look_needed & (jnp.abs(drive.delta_phi) > 1e-6)))
  delta_d = jnp.where(busy, drive.delta_d, 0.0)
  delta_phi = jnp.where(busy, drive.delta_phi, 0.0)
  pose = jnp.where(busy, drive.pose, state.pose)
  path_idx = state.path_idx + (busy & has_waypoint & drive.arrived).astype(jnp.int32)

  # Odometry: the estimate is dead-reckoned from the (possibly noisy) increment; Σ by Eq 17.
  odo = motion.increment(delta_d, delta_phi)
  v_n = motion.odometry_covariance(delta_d, delta_phi, params.sigma_d, params.sigma_phi)
  if config.pose_noise:
    odo = odo + jnp.sqrt(jnp.diag(v_n)) * jax.random.normal(k_noise, (3,))
  pose_est = motion.compound(state.pose_est, odo)
  cov = motion.propagate_covariance(state.cov, state.pose_est, pose_est, v_n)
  if not config.pose_noise:
    pose_est = pose

  state = state.replace(key=key, pose=pose, pose_est=pose_est, cov=cov, path_len=path_len,
                        path_idx=path_idx, steps=state.steps + running.astype(jnp.int32),
                        idle_steps=state.idle_steps + (running & ~busy).astype(jnp.int32),
                        since_plan=state.since_plan + 1, busy=busy,
                        time=state.time + jnp.where(busy, params.dt, 0.0),
                        distance=state.distance + delta_d)
  state = _sense(config, world, params, state, k_sense, busy)
  if config.graph_nodes:
    # Keyframes at the estimate after relocalisation; line of sight in the updated belief. The
    # samples are half a cell apart for loops up to the sensor's range (validate_params).
    state = state.replace(graph=posegraph.observe(
        state.graph, state.pose_est, v_n, motion.increment(delta_d, delta_phi), busy, state.logodds,
        world.origin, res, params, 2 * config.max_range_cells + 2))
  state = _check_complete(world, params, state)
  timeout = ~state.done & (state.steps >= config.max_steps)
  state = state.replace(done=state.done | timeout, reason=jnp.where(timeout, TIMEOUT, state.reason))
  return state, record(world, state)


def belief_view(config: SimConfig, params: Params, state: State, robot_cell) -> planners_base.BeliefView:
  """The planner's view of one robot's belief (masks computed once per planning round).

  Traversable cells are free cells clear of believed walls by the robot radius, plus the free
  cells of the inflated zone connected to the robot within ``max_inflation_cells + 1`` steps: a
  robot that newly mapped walls left inside the inflated zone can still drive out of it.
  """
  free, occupied, unknown = mapping.classify(state.logodds, params)
  inflated = mapping.inflate(occupied, params.r_robot / config.res, config.max_inflation_cells)
  escape_zone = free & inflated
  escape = jnp.zeros(free.shape, bool).at[robot_cell[0], robot_cell[1]].set(True, mode="drop") & escape_zone
  # A loop, not unrolled: XLA would fuse each step into the next one's 8 neighbour reads.
  escape = jax.lax.fori_loop(0, config.max_inflation_cells + 1,
                             lambda _, e: e | (mapping.any_neighbour(e) & escape_zone), escape)
  return planners_base.BeliefView(
      logodds=state.logodds, entropy_map=state.entropy_map, free=free, occupied=occupied,
      unknown=unknown, inflated=inflated, traversable=(free & ~inflated) | escape,
      frontier=mapping.frontier(free, unknown, occupied),
      blacklist=state.blacklist)


def robot_view(config: SimConfig, world: World, state: State) -> planners_base.RobotView:
  return planners_base.RobotView(pose=state.pose_est, cell=cell_of(state.pose_est[:2], world.origin, config.res),
                                 cov=state.cov)


def _window_origin(config: SimConfig, cell, side: int):
  """Top-left cell of the ``side``-wide window centred on ``cell``, shifted to lie in the grid."""
  return jnp.stack([jnp.clip(cell[0] - side // 2, 0, config.height - side),
                    jnp.clip(cell[1] - side // 2, 0, config.width - side)]).astype(jnp.int32)


_MAP_FIELDS = ("logodds", "entropy_map", "blacklist")


def crop_maps(state: State, origin, shape) -> State:
  """``state`` with its maps cut to the ``shape`` region at ``origin`` (what a window plans on)."""
  crop = lambda grid: jax.lax.dynamic_slice(grid, (origin[0], origin[1]), shape)
  return state.replace(**{name: crop(getattr(state, name)) for name in _MAP_FIELDS})


def _propose(config: SimConfig, params: Params, state: State, robot, origin, key):
  """The planner's plan on the region of the grid that ``state``'s maps hold, at ``origin``.

  Returns (plan in grid coordinates, certified). The region is the whole grid or a window
  around the robot. Cells within :func:`window_margin` of an edge of the window that is not an
  edge of the grid may see masks that differ from the whole grid's, so they are blocked. Every
  path from the robot out of the remaining cells costs at least ``edge`` cells (the Chebyshev
  distance to the first blocked cell); a plan that costs less is therefore the whole grid's
  nearest candidate, with a shortest path: it is *certified*. Otherwise (or when the window
  holds no candidate) the caller plans on the whole grid. A plan on the whole grid is always
  certified.
  """
  spec = planners_base.get_planner(config.planner)
  rows, cols = state.logodds.shape
  local = dataclasses.replace(config, height=rows, width=cols, plan_window=0)
  cell = robot.cell - origin
  view = belief_view(local, params, state, cell)
  whole_grid = (rows, cols) == (config.height, config.width)
  if whole_grid:
    certified = jnp.bool_(True)
  else:
    margin = window_margin(config.max_inflation_cells)
    r = jnp.arange(rows)[:, None]
    c = jnp.arange(cols)[None, :]
    inner = (origin[0] > 0, origin[0] + rows < config.height, origin[1] > 0, origin[1] + cols < config.width)
    blocked = ((inner[0] & (r < margin)) | (inner[1] & (r >= rows - margin)) |
               (inner[2] & (c < margin)) | (inner[3] & (c >= cols - margin)))
    view = view.replace(free=view.free & ~blocked, traversable=view.traversable & ~blocked,
                        frontier=view.frontier & ~blocked)
    far = jnp.int32(config.height + config.width)
    edge = jnp.min(jnp.stack([
        jnp.where(inner[0], cell[0] - (margin - 1), far), jnp.where(inner[1], rows - margin - cell[0], far),
        jnp.where(inner[2], cell[1] - (margin - 1), far), jnp.where(inner[3], cols - margin - cell[1], far)]))

  result = spec.plan(local, view, robot.replace(cell=cell), params, key)
  if not whole_grid:
    certified = result.valid & (result.cost < edge.astype(jnp.float32) * config.res)
  to_grid = lambda cells: jnp.where(cells >= 0, cells + origin[None, :], cells)
  result = result.replace(waypoints=to_grid(result.waypoints), goal=result.goal + origin,
                          look_at=result.look_at + origin)
  return result, certified


@chex.dataclass(frozen=True)
class PlanOutcome:
  """What one planning round changes in one robot's state.

  Attributes:
    state: the robot's state with its new plan; its map leaves are not meaningful (a round
      reads the maps of a region of the grid and writes nothing but ``marks`` to them).
    marks: i32[2, 2] goal cells to blacklist (the goal the robot arrived at, a stuck goal).
    mark: bool[2] which of ``marks`` apply.
    certified: bool; False when a window could not certify its plan: then nothing changes.
  """

  state: State
  marks: chex.Array
  mark: chex.Array
  certified: chex.Array


def _plan_round(config: SimConfig, world: World, params: Params, state: State, origin) -> PlanOutcome:
  """One robot's planning round on the region of the grid that ``state``'s maps hold.

  ``state`` is one robot's state whose map leaves are the whole grid (``origin`` = (0, 0)) or,
  for a ``windowed`` planner, a window at ``origin`` (:func:`crop_maps`). A robot whose planner
  finds no candidate ends ``exhausted`` (unless already complete). A goal chosen twice in a row
  while the robot already stands on it cannot be resolved from here and is blacklisted, so no
  robot waits on it forever.
  """
  spec = planners_base.get_planner(config.planner)
  key, k_plan = jax.random.split(state.key)
  running = ~state.done
  arrival_goal = state.goal
  arrived = jnp.bool_(False)
  if spec.blacklist_on_arrival:
    arrived = running & (state.path_len > 0) & (state.path_idx >= state.path_len)
    local_goal = state.goal - origin
    state = state.replace(blacklist=state.blacklist.at[local_goal[0], local_goal[1]].max(
        arrived, mode="drop", wrap_negative_indices=False))
  robot = robot_view(config, world, state)
  result, certified = _propose(config, params, state, robot, origin, k_plan)
  stuck = running & result.valid & (result.length <= 1) & jnp.all(result.goal == state.last_goal)
  exhausted = running & ~result.valid
  install = running & result.valid
  state = state.replace(
      key=key, since_plan=jnp.int32(0),
      waypoints=jnp.where(install, result.waypoints, state.waypoints),
      path_len=jnp.where(install, result.length, 0),
      path_idx=jnp.where(install, jnp.minimum(1, result.length), 0),
      goal=jnp.where(install, result.goal, state.goal),
      look_at=jnp.where(install, result.look_at, robot.cell),
      last_goal=jnp.where(install, result.goal, state.last_goal),
      done=state.done | exhausted,
      reason=jnp.where(exhausted, EXHAUSTED, state.reason))
  return PlanOutcome(state=state, marks=jnp.stack([arrival_goal, result.goal]),
                     mark=jnp.stack([arrived, stuck]), certified=certified)


def _apply_plans(state: State, robots, outcome: PlanOutcome) -> State:
  """Writes the outcomes of robots ``robots`` (i32[C], a batch of outcomes) into the batched
  ``state``: the small leaves of certified outcomes, and their blacklist marks."""
  ok = outcome.certified
  small = {}
  for field in dataclasses.fields(State):
    if field.name in _MAP_FIELDS or field.name == "graph":  # planning never changes the graph
      continue
    old, new = getattr(state, field.name), getattr(outcome.state, field.name)
    keep = ok.reshape(ok.shape + (1,) * (new.ndim - 1))
    small[field.name] = old.at[robots].set(jnp.where(keep, new, old[robots]))
  mark = outcome.mark & ok[:, None]
  rows, cols = outcome.marks[..., 0], outcome.marks[..., 1]
  blacklist = state.blacklist.at[robots[:, None], rows, cols].max(
      mark, mode="drop", wrap_negative_indices=False)
  return state.replace(blacklist=blacklist, **small)


def plan(config: SimConfig, world: World, params: Params, state: State) -> State:
  """One robot's planning round on the whole grid: ask the planner, install the path, handle
  no-op goals (see :func:`_plan_round`)."""
  outcome = _plan_round(config, world, params, state, jnp.zeros((2,), jnp.int32))
  batch = lambda tree: jax.tree.map(lambda x: x[None], tree)
  new = _apply_plans(batch(state), jnp.zeros((1,), jnp.int32), batch(outcome))
  return jax.tree.map(lambda x: x[0], new)


def needs_plan(config: SimConfig, state: State):
  """Whether a robot plans before its next step: it is running, and its last step was idle or
  ``replan_every`` steps have passed since its last plan."""
  return ~state.done & (~state.busy | (state.since_plan >= config.replan_every))


def uses_window(config: SimConfig) -> bool:
  """Whether planning tries a window first (a ``windowed`` planner and a window smaller than the grid)."""
  return (planners_base.get_planner(config.planner).windowed and
          0 < config.plan_window < min(config.height, config.width))


def _plan_robots(config: SimConfig, world: World, params: Params, state: State, need, window: int,
                 chunk: int):
  """:func:`plan` for the robots with ``need`` set, ``chunk`` at a time, on the window of
  ``window`` cells around each (0 = the whole grid). Returns the new state and which robots got
  their plan (all of them on the whole grid; with a window, those whose plan was certified: the
  others keep their state).

  Each robot's maps are read straight from the batch, cropped to its window; a round writes
  back only its small leaves and blacklist marks (:func:`_apply_plans`), never whole maps.
  """
  batch = need.shape[0]
  chunk = min(chunk, batch)
  n_need = jnp.sum(need.astype(jnp.int32))
  order = jnp.nonzero(need, size=batch + chunk, fill_value=-1)[0]
  # A last partial chunk is filled with copies of its own last robot: they plan from the same
  # state and write the same result. (A robot of an earlier chunk would plan a second time,
  # from its new state, and its key would advance twice: the noise it draws next, and so its
  # run, would depend on the batch around it.)
  order = jnp.where(order < 0, order[jnp.maximum(n_need - 1, 0)], order)
  n_chunks = (n_need + chunk - 1) // chunk
  shape = (window, window) if window else (config.height, config.width)

  def plan_chunk(k, carry):
    state, planned = carry
    robots = jax.lax.dynamic_slice(order, (k * chunk,), (chunk,))

    def plan_one(p, robot):
      one = {f.name: jax.tree.map(lambda x: x[robot], getattr(state, f.name))
             for f in dataclasses.fields(State) if f.name not in _MAP_FIELDS}
      cell = cell_of(one["pose_est"][:2], world.origin, config.res)
      origin = _window_origin(config, cell, window) if window else jnp.zeros((2,), jnp.int32)
      corner = (robot, origin[0], origin[1])
      maps = {name: jax.lax.dynamic_slice(getattr(state, name), corner, (1,) + shape)[0]
              for name in _MAP_FIELDS}
      return _plan_round(config, world, p, State(**one, **maps), origin)

    outcome = jax.vmap(plan_one)(jax.tree.map(lambda x: x[robots], params), robots)
    return _apply_plans(state, robots, outcome), planned.at[robots].set(outcome.certified)

  return jax.lax.fori_loop(0, n_chunks, plan_chunk, (state, jnp.zeros_like(need)))


def plan_where_needed(config: SimConfig, world: World, params: Params, state: State) -> State:
  """:func:`plan` for the robots of a batch that need it (:func:`needs_plan`).

  ``params`` and ``state`` carry a leading batch axis. The robots that plan are gathered in
  chunks of ``config.plan_chunk``, planned with ``vmap`` (a chunk of 4 plans about twice as fast
  per robot as one robot alone: the shortest-path sweeps vectorise across the chunk) and
  scattered back in place; robots that do not plan cost nothing, where a batched ``lax.cond``
  would run the planner for all of them. A last partial chunk is filled with repeats of its own
  last robot (its copies compute and write the same result); on the whole grid, the robots
  left over after full chunks plan one at a time instead.

  With a planning window (:func:`uses_window`), every robot first plans on the window around
  it, and only those whose answer the window cannot certify plan again on the whole grid: the
  work follows the distance to the nearest candidate instead of the grid's size.
  """
  need = needs_plan(config, state)
  if uses_window(config):
    state, certified = _plan_robots(config, world, params, state, need, config.plan_window,
                                    config.plan_chunk)
    need = need & ~certified
  # Whole-grid plans are few and dear: the robots left over after full chunks plan one by one
  # rather than in a chunk padded with copies (Explore-Bench room_with_corner, 128 robots,
  # steps 32-64: 0.98x the time; steps 300-332, more robots beyond their window: 0.94x).
  chunk = min(config.plan_chunk, need.shape[0])
  if chunk == 1:
    return _plan_robots(config, world, params, state, need, 0, 1)[0]
  rank = jnp.cumsum(need.astype(jnp.int32)) - 1
  in_full_chunks = rank < (rank[-1] + 1) // chunk * chunk
  state, _ = _plan_robots(config, world, params, state, need & in_full_chunks, 0, chunk)
  state, _ = _plan_robots(config, world, params, state, need & ~in_full_chunks, 0, 1)
  return state


def epoch(config: SimConfig, world: World, params: Params, state: State):
  """``replan_every`` motion steps of the whole batch, each preceded by the plans it needs.

  ``params`` and ``state`` carry a leading batch axis; ``world`` is shared.
  """
  step_batch = jax.vmap(lambda p, s: step(config, world, p, s))

  def body(s, _):
    s = plan_where_needed(config, world, params, s)
    return step_batch(params, s)

  return jax.lax.scan(body, state, None, length=config.replan_every)


def advance_unjitted(config: SimConfig, world: World, params: Params, state: State, n_epochs: int):
  """``n_epochs * replan_every`` steps for a batch; records stacked as [n_epochs * replan_every, B]."""
  def body(s, _):
    return epoch(config, world, params, s)

  state, records = jax.lax.scan(body, state, None, length=n_epochs)
  records = jax.tree.map(lambda r: r.reshape((-1,) + r.shape[2:]), records)
  return state, records


advance = jax.jit(advance_unjitted, static_argnames=("config", "n_epochs"))


@functools.partial(jax.jit, static_argnames=("config",))
def reset_batch(config: SimConfig, world: World, params: Params, keys, start_poses=None):
  """``reset`` for a batch: ``params`` and ``keys`` batched; ``start_poses`` f32[B, 3] or None."""
  if start_poses is None:
    return jax.vmap(lambda p, k: reset(config, world, p, k))(params, keys)
  return jax.vmap(lambda p, k, s: reset(config, world, p, k, s))(params, keys, start_poses)


def broadcast_params(params: Params, batch: int) -> Params:
  """Gives every leaf a leading batch axis (scalars are repeated; batched leaves are checked)."""
  def expand(leaf):
    leaf = jnp.asarray(leaf, jnp.float32)
    if leaf.ndim == 0:
      return jnp.broadcast_to(leaf, (batch,))
    if leaf.shape[0] != batch:
      raise ConfigError(f"a batched parameter has {leaf.shape[0]} values for {batch} robots")
    return leaf
  return jax.tree.map(expand, params)


def rollout(config: SimConfig, world: World, params: Params, keys, start_poses=None):
  """The whole episode for a batch in one compiled call (no early exit, no progress bar).

  :func:`jaxplore.run.run` is the user-facing loop that stops early and shows progress; this is
  the minimal pure form (for tests and embedding).
  Returns (final state, records with leaves [max_steps, B]).
  """
  state = reset_batch(config, world, params, keys, start_poses)
  state, records = advance(config, world, params, state, config.n_epochs)
  records = jax.tree.map(lambda r: r[: config.max_steps], records)
  return state, records


__all__ = [
    "World", "State", "Record", "make_world", "reset", "step", "plan", "needs_plan",
    "plan_where_needed", "uses_window", "epoch", "advance",
    "reset_batch", "rollout", "broadcast_params", "REASONS", "RUNNING", "COMPLETE", "EXHAUSTED",
    "TIMEOUT",
]
