"""A plain sequential NumPy/SciPy simulator of jaxplore's exploration loop, for the benchmark.

One robot at a time, ``pose_noise=False``, the nearest-frontier planner: the loop of
``jaxplore/sim.py`` written the way a NumPy programmer would write it without JAX, so that
``experiments/bench_engine.py`` can put the batched engine's robot-steps per second next to a
straightforward sequential implementation of the same work. Nothing here imports the engine.

One motion step (as in ``sim.step``): drive toward the next waypoint (turn first, then drive; or
turn to face the look-at cell) -> propagate the pose covariance (Li Eq 16-17) -> cast the lidar
against the truth -> relocalise (a Kalman update of the covariance) if enough beams end on
well-mapped walls -> add the inverse sensor model once per observed cell -> update the map
entropy and coverage (in the bounding box of the scan's cells, as the engine does in a window
around the robot) -> update the entropy map within ``R_u`` (Li Eq 3) -> termination. Every
``replan_every`` steps, or after an idle step (path done), the robot plans: belief classes, inflation (``scipy.ndimage``), frontier
mask, an 8-connected graph of traversable cells built as a CSR matrix with vectorised NumPy,
``scipy.sparse.csgraph.dijkstra`` from the robot with predecessors, the nearest frontier cell.

Lidar: per scan, vectorised over beams, the same closed-form enumeration of grid-line crossings
as ``jaxplore.sensor`` (the cell entered at every vertical and horizontal grid line, in float64
here and float32 there), so the free and occupied cells agree with the engine's up to float
ties at corners.

Known differences from the engine (same work, not the same bits): equal-cost paths are broken
differently (SciPy's predecessors versus the engine's first tight neighbour), so trajectories
part after the first such tie; float64 here, float32 there; no pose or range noise.

Usage::

  from reference_numpy import run_reference
  result = run_reference(grid, params_dict, config, (x, y, theta), n_steps=300)
  result["steps"], result["coverage"], result["distance"]
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse
from scipy import ndimage
from scipy.sparse.csgraph import dijkstra

LN2 = math.log(2.0)
CORNER_EPS = 1e-3  # cells; as jaxplore.sensor.CORNER_EPS
# The entropy map's settings, as jaxplore.planners.li2020 declares their defaults.
LI2020_DEFAULTS = {"r_e": 0.75, "alpha": 1.5, "entropy_k": 0.5}
NEIGHBOURS_8 = tuple((di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0))
RUNNING, COMPLETE, EXHAUSTED, TIMEOUT = 0, 1, 2, 3
REASONS = {RUNNING: "running", COMPLETE: "complete", EXHAUSTED: "exhausted", TIMEOUT: "timeout"}


# --- belief ----------------------------------------------------------------------------------


def logit(p: float) -> float:
  return math.log(p) - math.log1p(-p)


def softplus(x: np.ndarray) -> np.ndarray:
  return np.logaddexp(0.0, x)


def entropy_of_logodds(logodds: np.ndarray) -> np.ndarray:
  """Cell entropy in nats (Li Eq 2) from log-odds: ``P·softplus(−l) + (1−P)·softplus(l)``."""
  p = 1.0 / (1.0 + np.exp(-logodds))
  return p * softplus(-logodds) + (1.0 - p) * softplus(logodds)


# --- lidar -----------------------------------------------------------------------------------


class LidarScan(NamedTuple):
  """One scan against the truth (cell units).

  Attributes:
    ranges: f64[n] range per beam in cells (``r_max`` if nothing was hit).
    hit: bool[n] the beam stopped on an occupied cell before ``r_max``.
    hit_rows, hit_cols: int[n] the occupied cell that stopped each beam (valid where ``hit``).
    free_rows, free_cols: int[m] every cell some beam passed through before its end, with
      repetitions (beams overlap near the robot).
  """

  ranges: np.ndarray
  hit: np.ndarray
  hit_rows: np.ndarray
  hit_cols: np.ndarray
  free_rows: np.ndarray
  free_cols: np.ndarray


def beam_angles(theta: float, fov: float, n_beams: int) -> np.ndarray:
  """``n_beams`` absolute angles spread over ``fov`` around ``theta`` (a full circle has no repeat)."""
  if n_beams == 1:
    return np.array([theta])
  if fov >= 2 * math.pi - 1e-6:
    return theta - math.pi + fov / n_beams * np.arange(n_beams)
  return theta - 0.5 * fov + fov / (n_beams - 1) * np.arange(n_beams)


def _occupied_at(occupied: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
  """Truth lookup where every cell outside the grid is occupied.

  The grid is framed by one occupied cell and read through flat indices: a beam stops at the
  frame at the latest, and entries past the frame (clipped here) come after its hit.
  """
  h, w = occupied.shape
  framed = np.pad(occupied, 1, constant_values=True).ravel()
  flat = (rows + 1) * (w + 2) + (cols + 1)
  return framed[np.clip(flat, 0, framed.size - 1)]


def scan(occupied: np.ndarray, u0: float, v0: float, angles: np.ndarray, r_max_cells: float,
         n_cross: int) -> LidarScan:
  """Casts every beam of one scan (vectorised over beams and grid-line crossings).

  A beam from (u0, v0) (u = column, v = row coordinate, in cells) enters a new cell each time it
  crosses a vertical line u = integer or a horizontal line v = integer; the distances of the
  successive crossings of each kind form an arithmetic progression. At a vertical crossing the
  beam is listed in its old row (the cell beside a corner it passes), at a horizontal crossing in
  its new column, so a beam aimed between two diagonally touching walls always meets one.

  Args:
    occupied: bool[H, W] ground truth (outside the grid counts as occupied).
    u0, v0: the sensor position in cell units.
    angles: f64[n] absolute beam angles.
    r_max_cells: maximum range in cells.
    n_cross: crossings per axis to enumerate (>= r_max_cells + 1).
  """
  du = np.cos(angles)[:, None]
  dv = np.sin(angles)[:, None]
  k = np.arange(n_cross)[None, :]
  far = float(n_cross + 2)  # stands in for "never" when reading cells off a line: past every range

  def progression(a0, da):
    """(distances to the successive lines a = integer, index along a of the cell entered)."""
    with np.errstate(divide="ignore", invalid="ignore"):
      step = np.where(np.abs(da) < 1e-9, np.inf, 1.0 / np.abs(da))
      first = np.where(da >= 0, math.floor(a0) + 1.0 - a0, a0 - math.floor(a0))
      t = (first + k) * step  # NaN (0 * inf) only for a beam along a line it starts on
    entered = math.floor(a0) + np.where(da >= 0, k + 1, -(k + 1))
    return t, entered

  t_x, col_x = progression(u0, du)  # vertical lines: the column changes
  t_y, row_y = progression(v0, dv)  # horizontal lines: the row changes
  row_x = np.floor(v0 + (np.fmin(t_x, far) - CORNER_EPS) * dv)  # the row the beam leaves
  col_y = np.floor(u0 + (np.fmin(t_y, far) + CORNER_EPS) * du)  # the column after the line
  n = len(angles)
  rows = np.hstack([np.full((n, 1), math.floor(v0)), row_x, row_y]).astype(np.int64)
  cols = np.hstack([np.full((n, 1), math.floor(u0)), col_x, col_y]).astype(np.int64)
  t = np.hstack([np.zeros((n, 1)), t_x, t_y])

  t_blocked = np.where(_occupied_at(occupied, rows, cols) & (t <= r_max_cells), t, np.inf)
  first = np.argmin(t_blocked, axis=1)
  beam = np.arange(n)
  t_hit = t_blocked[beam, first]
  hit = np.isfinite(t_hit)
  ranges = np.minimum(t_hit, r_max_cells)
  hit_rows, hit_cols = rows[beam, first], cols[beam, first]
  is_end = (rows == hit_rows[:, None]) & (cols == hit_cols[:, None]) & hit[:, None]
  free = (t < ranges[:, None]) & ~is_end
  return LidarScan(ranges, hit, hit_rows, hit_cols, rows[free], cols[free])


# --- motion and covariance -------------------------------------------------------------------


def wrap_angle(a: float) -> float:
  return math.atan2(math.sin(a), math.cos(a))


def drive_toward(pose: np.ndarray, target_xy: np.ndarray, v_max: float, w_max: float, dt: float,
                 translate: bool):
  """Turns toward the target by at most ``w_max·dt``; drives (up to ``v_max·dt``) only once aligned.

  Returns:
    (new pose, distance driven, heading change, arrived at the target).
  """
  dx, dy = target_xy[0] - pose[0], target_xy[1] - pose[1]
  dist = math.hypot(dx, dy)
  desired = math.atan2(dy, dx) if dist > 1e-6 else pose[2]
  error = wrap_angle(desired - pose[2])
  turn = min(max(error, -w_max * dt), w_max * dt)
  aligned = abs(error - turn) < 1e-4
  step = min(v_max * dt, dist) if (aligned and translate) else 0.0
  heading = wrap_angle(pose[2] + turn)
  new_pose = np.array([pose[0] + step * math.cos(heading), pose[1] + step * math.sin(heading), heading])
  arrived = translate and (dist - step < 1e-5)
  return new_pose, step, turn, arrived


def propagate_covariance(cov: np.ndarray, pose_before: np.ndarray, pose_after: np.ndarray,
                         delta_d: float, delta_phi: float, sigma_d: float, sigma_phi: float):
  """Li Eq 17, ``Σ_n = J1 Σ J1ᵀ + J2 V_n J2ᵀ``, with ``V_n`` of Eq 16 and ``J1``, ``J2`` of Eq 12."""
  c, s = math.cos(pose_before[2]), math.sin(pose_before[2])
  j1 = np.array([[1.0, 0.0, pose_before[1] - pose_after[1]],
                 [0.0, 1.0, pose_after[0] - pose_before[0]],
                 [0.0, 0.0, 1.0]])
  j2 = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
  v_n = np.diag([(sigma_d * delta_d) ** 2, (sigma_d * delta_d) ** 2, (sigma_phi * delta_phi) ** 2])
  return j1 @ cov @ j1.T + j2 @ v_n @ j2.T


def relocalised_covariance(cov: np.ndarray, meas_cov: np.ndarray) -> np.ndarray:
  """Kalman update with a direct pose measurement: ``(I − K) Σ`` with ``K = Σ (Σ + R)⁻¹``."""
  gain = cov @ np.linalg.inv(cov + meas_cov)
  new_cov = (np.eye(3) - gain) @ cov
  return 0.5 * (new_cov + new_cov.T)


# --- planning --------------------------------------------------------------------------------


def _shift(framed: np.ndarray, di: int, dj: int) -> np.ndarray:
  """The (H, W) view of an array framed by one cell, shifted: ``out[i, j] = a[i + di, j + dj]``."""
  h, w = framed.shape[0] - 2, framed.shape[1] - 2
  return framed[1 + di : 1 + di + h, 1 + dj : 1 + dj + w]


def frontier_mask(free: np.ndarray, unknown: np.ndarray, occupied: np.ndarray) -> np.ndarray:
  """Free cells with an unknown 8-neighbour; a diagonal one counts unless two walls seal it off."""
  framed_unknown = np.pad(unknown, 1, constant_values=False)
  framed_occupied = np.pad(occupied, 1, constant_values=True)
  seen = np.zeros_like(free)
  for di, dj in NEIGHBOURS_8:
    visible = _shift(framed_unknown, di, dj)
    if di and dj:
      visible = visible & ~(_shift(framed_occupied, di, 0) & _shift(framed_occupied, 0, dj))
    seen |= visible
  return free & seen


def disc(radius_cells: float, max_cells: int) -> np.ndarray:
  """Structuring element: offsets within ``radius_cells`` (centre to centre), at most ``max_cells``."""
  offsets = np.arange(-max_cells, max_cells + 1)
  d2 = offsets[:, None] ** 2 + offsets[None, :] ** 2
  return (d2 <= radius_cells**2 + 1e-6) & (d2 <= max_cells**2)


def grid_graph(traversable: np.ndarray, source: tuple[int, int]) -> scipy.sparse.csr_matrix:
  """The 8-connected graph over traversable cells (node = flat cell index), as CSR.

  An edge u -> v exists when v is traversable and u is traversable or the source (a robot
  standing on a cell that is no longer traversable still plans from it); it weighs 1 or √2 cells.
  """
  h, w = traversable.shape
  index = np.arange(h * w).reshape(h, w)
  may_leave = traversable.copy()
  may_leave[source] = True
  heads, tails, weights = [], [], []
  for di, dj in NEIGHBOURS_8:
    # u = (i, j), v = (i + di, j + dj); both inside the grid.
    u_rows = slice(max(0, -di), h - max(0, di))
    u_cols = slice(max(0, -dj), w - max(0, dj))
    v_rows = slice(max(0, di), h - max(0, -di))
    v_cols = slice(max(0, dj), w - max(0, -dj))
    edge = may_leave[u_rows, u_cols] & traversable[v_rows, v_cols]
    heads.append(index[u_rows, u_cols][edge])
    tails.append(index[v_rows, v_cols][edge])
    weights.append(np.full(np.count_nonzero(edge), math.sqrt(2.0) if di and dj else 1.0))
  heads, tails, weights = np.concatenate(heads), np.concatenate(tails), np.concatenate(weights)
  return scipy.sparse.csr_matrix((weights, (heads, tails)), shape=(h * w, h * w))


def extend_into(dist: np.ndarray, pred: np.ndarray, allowed: np.ndarray, steps: int):
  """Reaches unreached ``allowed`` cells from their best 8-neighbour, ``steps`` Jacobi rounds.

  As ``jaxplore.graph.extend.extend_into``: frontier cells within the robot radius of a wall
  get a distance and a predecessor, so the robot can look at them from the next cell. Only the
  target cells (a thin band along walls) are visited, through their index lists.
  """
  h, w = dist.shape
  rows, cols = np.nonzero(allowed & ~np.isfinite(dist))
  dist, pred = dist.copy(), pred.copy()
  for _ in range(steps):
    framed = np.pad(dist, 1, constant_values=np.inf)  # read the previous round only
    best, best_pred = dist[rows, cols], pred[rows, cols]
    for di, dj in NEIGHBOURS_8:
      candidate = framed[rows + 1 + di, cols + 1 + dj] + (math.sqrt(2.0) if di and dj else 1.0)
      better = candidate < best
      best = np.where(better, candidate, best)
      best_pred = np.where(better, (rows + di) * w + (cols + dj), best_pred)
    dist[rows, cols], pred[rows, cols] = best, best_pred
  return dist, pred


def unknown_neighbour(cell, unknown: np.ndarray, occupied: np.ndarray):
  """The first unknown 8-neighbour of ``cell`` not sealed off by two walls, else ``cell``."""
  h, w = unknown.shape
  inside = lambda r, c: 0 <= r < h and 0 <= c < w
  for di, dj in NEIGHBOURS_8:
    r, c = cell[0] + di, cell[1] + dj
    if not (inside(r, c) and unknown[r, c]):
      continue
    if di and dj:
      wall_a = not inside(cell[0] + di, cell[1]) or occupied[cell[0] + di, cell[1]]
      wall_b = not inside(cell[0], cell[1] + dj) or occupied[cell[0], cell[1] + dj]
      if wall_a and wall_b:
        continue
    return (r, c)
  return tuple(cell)


class Plan(NamedTuple):
  waypoints: list  # [(row, col), ...] from the robot's cell on
  goal: tuple
  look_at: tuple
  valid: bool


def plan_nearest_frontier(logodds: np.ndarray, blacklist: np.ndarray, robot_cell, p: Mapping,
                          res: float, max_inflation_cells: int, capacity: int) -> Plan:
  """Nearest frontier (Yamauchi 1997): the frontier cell with the smallest path cost."""
  free = logodds < logit(p["p_free"])
  occupied = logodds > logit(p["p_occ"])
  unknown = ~(free | occupied)
  if max_inflation_cells > 0:
    inflated = ndimage.binary_dilation(occupied, disc(p["r_robot"] / res, max_inflation_cells))
  else:
    inflated = occupied
  traversable = free & ~inflated
  frontier = frontier_mask(free, unknown, occupied)

  h, w = logodds.shape
  source = int(robot_cell[0]) * w + int(robot_cell[1])
  dist, pred = dijkstra(grid_graph(traversable, tuple(robot_cell)), directed=True, indices=source,
                        return_predecessors=True)
  dist, pred = dist.reshape(h, w), np.where(pred < 0, -1, pred).reshape(h, w)
  dist, pred = extend_into(dist, pred, free & ~traversable, max_inflation_cells + 1)

  candidates = frontier & ~blacklist & np.isfinite(dist)
  if not candidates.any():
    return Plan([], tuple(robot_cell), tuple(robot_cell), False)
  goal_flat = int(np.argmin(np.where(candidates, dist, np.inf)))
  goal = (goal_flat // w, goal_flat % w)

  path = [goal_flat]
  while path[-1] != source:
    path.append(int(pred.flat[path[-1]]))
  path = path[::-1][:capacity]  # source first; a long path keeps the cells followed next
  waypoints = [(cell // w, cell % w) for cell in path]
  for i in range(1, len(waypoints)):  # stop before the first cell the robot cannot stand on
    if not traversable[waypoints[i]]:
      waypoints = waypoints[:i]
      break
  return Plan(waypoints, goal, unknown_neighbour(goal, unknown, occupied), True)


# --- the loop --------------------------------------------------------------------------------


@dataclasses.dataclass
class Robot:
  """One robot's mutable simulation state (host side, float64)."""

  pose: np.ndarray  # (x m, y m, θ rad); the estimate equals it (no pose noise)
  cov: np.ndarray  # 3x3 pose covariance Σ
  logodds: np.ndarray  # f64[H, W]
  entropy_map: np.ndarray  # f64[H, W], Li's I_e
  blacklist: np.ndarray  # bool[H, W]
  look_at: tuple
  waypoints: list = dataclasses.field(default_factory=list)
  path_idx: int = 0
  last_goal: tuple = (-1, -1)
  steps: int = 0
  idle_steps: int = 0
  since_plan: int = 0
  busy: bool = False
  time: float = 0.0
  distance: float = 0.0
  entropy: float = 0.0
  covered: int = 0
  done: bool = False
  reason: int = RUNNING


class ReferenceSimulator:
  """The sequential simulator of one robot on one world.

  Args:
    occupied: bool[H, W] truth. res: m/cell. origin: (x, y) m of cell (0, 0)'s corner.
    params: Params fields by name (floats).
    config: a SimConfig (or a mapping with its n_beams, max_range_cells, path_capacity,
      replan_every, max_steps, max_inflation_cells and optionally pose_noise and r_e).
    start_pose: (x, y, θ).
  """

  def __init__(self, occupied, res, origin, params: Mapping, config, start_pose):
    settings = dict(config) if isinstance(config, Mapping) else dataclasses.asdict(config)
    self.occupied = np.asarray(occupied, bool)
    self.res = float(res)
    self.origin = np.asarray(origin, float)
    self.p = {k: float(v) for k, v in params.items() if not isinstance(v, Mapping)}
    # Li's entropy map is li2020's (R_e a static setting, alpha and k weights): given with the
    # params (or R_e with a mapping config), else li2020's defaults; the map is kept whatever
    # the planner, as the engine kept it before it became li2020's.
    for name, default in LI2020_DEFAULTS.items():
      self.p.setdefault(name, float(settings.get(name, default)))
    self.n_beams = int(settings["n_beams"])
    self.n_cross = int(settings["max_range_cells"]) + 1
    self.capacity = int(settings["path_capacity"])
    self.replan_every = int(settings["replan_every"])
    self.max_steps = int(settings["max_steps"])
    self.max_inflation_cells = int(settings["max_inflation_cells"])
    if settings.get("pose_noise", False) or self.p.get("range_noise", 0.0) > 0:
      raise ValueError("the reference simulates pose_noise=False and range_noise=0 only")
    self.timing = {"scan": 0.0, "belief": 0.0, "plan": 0.0, "motion": 0.0}
    self.free_threshold = logit(self.p["p_free"])

    # Coverage counts the free cells 4-connected to the start (as sim.make_world).
    labels, _ = ndimage.label(~self.occupied)
    start_cell = self.cell_of(np.asarray(start_pose, float))
    self.reachable = labels == labels[start_cell]
    self.n_reachable = int(self.reachable.sum())

    h, w = self.occupied.shape
    self.robot = Robot(pose=np.asarray(start_pose, float), cov=np.eye(3) * self.p["sigma0"],
                       logodds=np.zeros((h, w)), entropy_map=np.full((h, w), LN2),
                       blacklist=np.zeros((h, w), bool), look_at=start_cell, entropy=h * w * LN2)
    self.sense(active=True)
    self.check_complete()

  def cell_of(self, pose) -> tuple[int, int]:
    return (int(math.floor((pose[1] - self.origin[1]) / self.res)),
            int(math.floor((pose[0] - self.origin[0]) / self.res)))

  def cell_centre(self, cell) -> np.ndarray:
    return self.origin + (np.array([cell[1], cell[0]], float) + 0.5) * self.res

  def sense(self, active: bool) -> None:
    """Scan, relocalise, integrate the scan, update entropy/coverage and the entropy map."""
    if not active:  # an idle robot keeps its maps untouched
      return
    robot, p = self.robot, self.p
    t0 = time.perf_counter()
    u0 = (robot.pose[0] - self.origin[0]) / self.res
    v0 = (robot.pose[1] - self.origin[1]) / self.res
    angles = beam_angles(robot.pose[2], p["fov"], self.n_beams)
    lidar = scan(self.occupied, u0, v0, angles, p["r_max"] / self.res, self.n_cross)
    t1 = time.perf_counter()

    h, w = self.occupied.shape
    inside = (lidar.hit_rows >= 0) & (lidar.hit_rows < h) & (lidar.hit_cols >= 0) & (lidar.hit_cols < w)
    occ_rows, occ_cols = lidar.hit_rows[lidar.hit & inside], lidar.hit_cols[lidar.hit & inside]

    # Relocalisation: enough beams end on occupied cells the belief already knows well.
    old_end = robot.logodds[occ_rows, occ_cols]
    well_mapped = (old_end > logit(p["p_occ"])) & (entropy_of_logodds(old_end) < p["reloc_entropy"])
    if np.count_nonzero(well_mapped) >= p["reloc_min_hits"]:
      meas_cov = np.diag([p["reloc_var_xy"], p["reloc_var_xy"], p["reloc_var_theta"]])
      robot.cov = relocalised_covariance(robot.cov, meas_cov)

    # Inverse sensor model, once per observed cell (an occupied observation wins), in the
    # bounding box of the observed cells; entropy and coverage change only there.
    rows = np.concatenate([lidar.free_rows, occ_rows, [math.floor(v0)]])
    cols = np.concatenate([lidar.free_cols, occ_cols, [math.floor(u0)]])
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    seen_free = np.zeros(self.occupied.shape, bool)
    seen_free[lidar.free_rows, lidar.free_cols] = True
    seen_occupied = np.zeros(self.occupied.shape, bool)
    seen_occupied[occ_rows, occ_cols] = True
    seen_free &= ~seen_occupied
    old = robot.logodds[box]
    new = np.clip(old + p["l_free"] * seen_free[box] + p["l_occ"] * seen_occupied[box],
                  p["l_min"], p["l_max"])
    robot.entropy += float(np.sum(entropy_of_logodds(new) - entropy_of_logodds(old)))
    reachable = self.reachable[box]
    robot.covered += int(np.count_nonzero(reachable & (new < self.free_threshold))
                         - np.count_nonzero(reachable & (old < self.free_threshold)))
    robot.logodds[box] = new

    # Li Eq 3 within R_u = α·R_e of the robot.
    radius = p["alpha"] * p["r_e"] / self.res
    r_lo, r_hi = max(0, math.floor(v0 - radius)), min(h, math.ceil(v0 + radius) + 1)
    c_lo, c_hi = max(0, math.floor(u0 - radius)), min(w, math.ceil(u0 + radius) + 1)
    centre_rows = np.arange(r_lo, r_hi)[:, None] + 0.5
    centre_cols = np.arange(c_lo, c_hi)[None, :] + 0.5
    near = (centre_rows - v0) ** 2 + (centre_cols - u0) ** 2 <= radius**2
    window = (slice(r_lo, r_hi), slice(c_lo, c_hi))
    e, k = robot.entropy_map[window], p["entropy_k"]
    robot.entropy_map[window] = np.where(near, k * e + (1 - k) * entropy_of_logodds(robot.logodds[window]), e)
    t2 = time.perf_counter()
    self.timing["scan"] += t1 - t0
    self.timing["belief"] += t2 - t1

  def check_complete(self) -> None:
    robot = self.robot
    if not robot.done and robot.covered >= self.p["coverage_goal"] * self.n_reachable - 1e-3:
      robot.done, robot.reason = True, COMPLETE

  def plan(self) -> None:
    """A planning round: nearest frontier; a goal that cannot be resolved is blacklisted."""
    robot = self.robot
    if robot.done:
      return
    t0 = time.perf_counter()
    cell = self.cell_of(robot.pose)
    result = plan_nearest_frontier(robot.logodds, robot.blacklist, cell, self.p, self.res,
                                   self.max_inflation_cells, self.capacity)
    if not result.valid:
      robot.done, robot.reason = True, EXHAUSTED
      robot.waypoints, robot.path_idx, robot.look_at = [], 0, cell
    else:
      if len(result.waypoints) <= 1 and result.goal == robot.last_goal:
        robot.blacklist[result.goal] = True  # chosen twice while standing on it
      robot.waypoints, robot.path_idx = result.waypoints, min(1, len(result.waypoints))
      robot.look_at, robot.last_goal = result.look_at, result.goal
    robot.since_plan = 0
    self.timing["plan"] += time.perf_counter() - t0

  def step(self) -> None:
    """One motion step (turn, then drive, one waypoint at a time), then sense."""
    robot, p = self.robot, self.p
    if robot.done:
      return
    t0 = time.perf_counter()
    has_waypoint = robot.path_idx < len(robot.waypoints)
    if has_waypoint and self.occupied[robot.waypoints[robot.path_idx]]:
      robot.waypoints = robot.waypoints[: robot.path_idx]  # never drive into a wall
      has_waypoint = False
    target = robot.waypoints[robot.path_idx] if has_waypoint else robot.look_at
    look_needed = tuple(target) != self.cell_of(robot.pose)
    new_pose, delta_d, delta_phi, arrived = drive_toward(
        robot.pose, self.cell_centre(target), p["v_max"], p["w_max"], p["dt"], translate=has_waypoint)
    busy = has_waypoint or (look_needed and abs(delta_phi) > 1e-6)
    if not busy:
      new_pose, delta_d, delta_phi = robot.pose, 0.0, 0.0
    elif has_waypoint and arrived:
      robot.path_idx += 1
    robot.cov = propagate_covariance(robot.cov, robot.pose, new_pose, delta_d, delta_phi,
                                     p["odom_noise_d"], p["odom_noise_phi"])
    robot.pose = new_pose
    robot.steps += 1
    robot.idle_steps += int(not busy)
    robot.since_plan += 1
    robot.busy = busy
    robot.time += p["dt"] if busy else 0.0
    robot.distance += delta_d
    self.timing["motion"] += time.perf_counter() - t0
    self.sense(active=busy)
    self.check_complete()
    if not robot.done and robot.steps >= self.max_steps:
      robot.done, robot.reason = True, TIMEOUT

  @property
  def coverage(self) -> float:
    return self.robot.covered / self.n_reachable


def run_reference(grid, params_dict: Mapping[str, Any], config, start_pose, n_steps: int) -> dict:
  """Runs one robot for ``n_steps`` motion steps (or until it is done), planning every
  when its last step was idle or ``config.replan_every`` steps after its last plan, as the
  engine's robots do (``jaxplore.sim.needs_plan``).

  Args:
    grid: the truth (anything with ``occupied``, ``res``, ``origin``: a ``jaxplore.maps.GridMap``).
    params_dict: ``jaxplore.config.Params`` fields by name (floats; a ``planner`` dict is ignored).
    config: a ``jaxplore.config.SimConfig`` (or a mapping with the same field names).
    start_pose: (x, y, θ) in metres and radians.
    n_steps: motion steps to simulate.

  Returns:
    A dict: ``steps`` (motion steps taken while running), ``coverage`` (fraction of the
    reachable free cells believed free), ``distance`` (m), and ``time`` (s), ``entropy``
    (nats), ``idle_steps``, ``det_cov``, ``reason``, ``coverage_curve`` (after each step),
    ``wall_s`` (seconds spent, setup excluded) and ``timing`` (seconds per phase).
  """
  sim = ReferenceSimulator(grid.occupied, grid.res, grid.origin, params_dict, config, start_pose)
  sim.timing = dict.fromkeys(sim.timing, 0.0)  # the reset's first scan is not part of the loop
  robot = sim.robot
  curve = []
  t0 = time.perf_counter()
  for t in range(n_steps):
    if robot.done:
      break
    if not robot.busy or robot.since_plan >= sim.replan_every:
      sim.plan()
    sim.step()
    curve.append(sim.coverage)
  wall = time.perf_counter() - t0
  return dict(steps=robot.steps, coverage=sim.coverage, distance=robot.distance, time=robot.time,
              entropy=robot.entropy, idle_steps=robot.idle_steps,
              det_cov=float(np.linalg.det(robot.cov)), reason=REASONS[robot.reason],
              coverage_curve=np.asarray(curve), wall_s=wall, timing=dict(sim.timing))
