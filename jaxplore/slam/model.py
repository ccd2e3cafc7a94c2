"""The ``scan_matching`` SLAM model: one robot's graph SLAM, as Karto / slam_toolbox run it.

Every motion step the robot dead-reckons its estimate from noisy odometry. When the odometry
since the last keyframe has moved ``kf_dist`` metres or turned ``kf_rot`` radians, the scan is a
new keyframe (Karto's ``minimum_travel_distance`` / ``minimum_travel_heading``):

1. **Front end** (:func:`register`): the scan is registered against the robot's *own belief*
   (never the truth) around the dead-reckoned prediction by correlative scan matching
   (:func:`jaxplore.slam.scan_matching.match`, Olson 2009), over a window of three standard
   deviations of the odometry covariance accumulated since the last keyframe. A match whose
   response is at least ``slam_min_response`` replaces the estimate, and Li et al.'s planning
   covariance Σ (Eq 16-17) takes it as a measurement of covariance the match's (a Kalman update);
   otherwise the robot dead-reckons on.
2. The keyframe joins the graph: its estimated and true pose, its scan, and an odometry edge from
   the previous keyframe (the relative pose of the two estimates; the match's information, or the
   odometry's when the match was refused).
3. **Loop closure** (:func:`close_loop`): the scan is matched against a local map drawn from the
   stored scans of up to ``loop_candidates`` older keyframes (at least ``loop_min_age`` keyframes
   back, within ``loop_radius`` of the estimate), over a window of three standard deviations of
   the odometry covariance accumulated since the last closure. A closure is accepted at a
   response of at least ``loop_min_response`` and a positional variance of at most
   ``loop_max_variance`` (Karto's thresholds) and within ``loop_gate`` (Mahalanobis distance²)
   of the estimate, measured against the drift since the last closure (:func:`drift`); it is
   *false* when the truth's relative pose lies outside its own 99 % bound (counted, never
   corrected: a real SLAM cannot tell).
4. **Back end** on a closure: SE(2) pose-graph optimisation of every keyframe
   (:func:`jaxplore.slam.optimiser.optimise`), the estimate set to the current keyframe's
   optimised pose, and the belief rebuilt from the keyframes' stored scans at the optimised poses
   (:func:`rebuild`), as Karto and slam_toolbox build their occupancy grids.

One graph: the keyframes, edges and D-optimality weights are the
:class:`jaxplore.posegraph.PoseGraph` the graph-aware planners read (Ahmed et al. 2024; Placed &
Castellanos 2021): an edge's weight is the D-optimality of its information matrix.

All functions are of one robot and fixed shapes; the engine calls them inside its per-robot step
(:mod:`jaxplore.robot`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplore import linalg, mapping, motion, sensor
from jaxplore.posegraph import PoseGraph
from jaxplore.slam import optimiser, scan_matching
from jaxplore.world import cell_of, to_cells


def d_optimality_of_information(info):
  """``det(Ω)^(1/3)`` of a 3x3 information matrix: the D-optimality edge weight of Ahmed Eq 8
  (``exp(Σ log λ_i / 3)``) without an eigensolver."""
  return jnp.cbrt(jnp.maximum(linalg.det3(info), 0.0))


def information(cov):
  """The information matrix of a 3x3 covariance, symmetrised."""
  info = linalg.inv3(cov)
  return 0.5 * (info + jnp.swapaxes(info, -1, -2))


def in_frame(cov, theta):
  """A world-frame (x, y, θ) covariance expressed in the frame of a pose with heading ``theta``
  (the frame an edge's relative pose is measured in): ``Rᵀ Σ R``."""
  c, s = jnp.cos(theta), jnp.sin(theta)
  zero, one = jnp.zeros_like(c), jnp.ones_like(c)
  rot = jnp.array([[c, -s, zero], [s, c, zero], [zero, zero, one]])
  return rot.T @ cov @ rot


# --- scans ---------------------------------------------------------------------------------------


def beam_offsets(params, n_beams: int):
  """f32[n] the beams' angles in the robot's frame (:func:`jaxplore.sensor.beam_angles` at 0)."""
  return sensor.beam_angles(jnp.float32(0.0), params.fov, n_beams)


def stored_scan(scan: sensor.Scan):
  """f16[n]: a scan as a keyframe keeps it: the range in cells, negated for a beam that hit
  nothing (so a range alone says whether the beam ended on an obstacle)."""
  return jnp.where(scan.hit, scan.ranges, -scan.ranges).astype(jnp.float16)


# A measured range ends on a wall's face, and the wall's cell centre lies half a cell further on
# average: a scan's end points are matched that much further into the surface they hit. Karto's
# 1 cm correlation grid makes the difference negligible; on 5-20 cm grids it is not (a point
# exactly on a face falls in the free cell in front of it for a beam travelling toward -x or -y,
# one cell short: a bias of a cell in loop closures).
END_PUSH_CELLS = 0.5
# End points nearer than this (cells) are neighbours on one surface (:func:`end_points`,
# :func:`facing`).
NEIGHBOUR_CELLS = 3.0


def _neighbours(x, y, hit, res: float):
  """For each end point (f32[n] ``x``, ``y`` in beam order), its next and previous beam's end
  points and whether each lies on the same surface (a hit within :data:`NEIGHBOUR_CELLS`)."""
  def neighbour(shift):
    nx, ny, nh = (jnp.roll(a, shift) for a in (x, y, hit))
    return nx, ny, nh & (jnp.hypot(nx - x, ny - y) <= NEIGHBOUR_CELLS * res)

  return neighbour(-1), neighbour(1)


def end_points(ranges, offsets, res: float):
  """Every beam's end point in the robot's frame (f32[n, 2] m) moved :data:`END_PUSH_CELLS` into
  the surface it hit, along that surface's normal, and whether it hit (bool[n]). ``ranges`` as
  :func:`stored_scan` gives them.

  The normal is the perpendicular of the line through the neighbouring beams' end points (one
  neighbour: the line to it); a point with neither (a lone return) is moved along its beam.
  Moved along their beams instead, the points of a beam grazing a wall slid along the wall rather
  than into it: matched against a map drawn at the true poses from the true pose, a willow robot's
  keyframes came out 1.9 cm and 0.25 degrees off the truth (median; 4 cm and 0.8 degrees at the
  90th percentile), 1.3 cm and 0.0 degrees (4.2 cm, 0.2 degrees) along the normals, and 0.0 and
  0.0 (p90 too) against the map :func:`keyframe_observation` draws."""
  r = jnp.abs(ranges.astype(jnp.float32)) * res
  hit = ranges > 0
  cos, sin = jnp.cos(offsets), jnp.sin(offsets)
  x, y = r * cos, r * sin
  (nx1, ny1, near1), (nx0, ny0, near0) = _neighbours(x, y, hit, res)
  tx = jnp.where(near1, nx1, x) - jnp.where(near0, nx0, x)
  ty = jnp.where(near1, ny1, y) - jnp.where(near0, ny0, y)
  length = jnp.hypot(tx, ty)
  on_surface = (near1 | near0) & (length > 1e-6)
  safe = jnp.where(on_surface, length, 1.0)
  normal_x, normal_y = -ty / safe, tx / safe
  into = jnp.where(normal_x * cos + normal_y * sin < 0, -1.0, 1.0)  # away from the sensor
  push_x = jnp.where(on_surface, into * normal_x, cos)
  push_y = jnp.where(on_surface, into * normal_y, sin)
  push = jnp.where(hit, END_PUSH_CELLS * res, 0.0)
  return jnp.stack([x + push * push_x, y + push * push_y], axis=-1), hit


def scan_points(ranges, offsets, res: float, stride: int):
  """Every ``stride``-th beam's end point (:func:`end_points`; f32[n', 2] m, robot frame) and
  whether it ended on an obstacle (bool[n']): the points a scan match scores. ``ranges`` as
  :func:`stored_scan` gives them."""
  points, hit = end_points(ranges, offsets, res)
  return points[::stride], hit[::stride]


def crop(grid, origin, res: float, centre_xy, side: tuple[int, int]):
  """The ``side`` (rows, cols) window of ``grid`` nearest to being centred on ``centre_xy``
  (inside the grid) and the metres of its lower-left corner."""
  cell = cell_of(centre_xy, origin, res)
  r0 = mapping.window_start(cell[0], side[0], grid.shape[0])
  c0 = mapping.window_start(cell[1], side[1], grid.shape[1])
  window = jax.lax.dynamic_slice(grid, (r0, c0), side)
  return window, origin + res * jnp.stack([c0, r0]).astype(jnp.float32)


class Sizes(NamedTuple):
  """Static sizes of the SLAM model, from a :class:`jaxplore.config.SimConfig`."""

  stride: int  # every stride-th beam is scored by a match
  crop: tuple[int, int]  # the belief window the front end matches against
  loop_crop: tuple[int, int]  # the local map a loop closure is matched against
  smear_cells: int  # the correlation field's kernel radius, front end
  loop_smear_cells: int  # and loop closure
  window: scan_matching.Window  # coarse search, front end
  loop_window: scan_matching.Window  # coarse search, loop closure
  fine: scan_matching.Window


def sizes(config) -> Sizes:
  """The static sizes a :class:`~jaxplore.config.SimConfig` implies."""
  res = config.res
  stride = max(1, config.n_beams // config.slam_match_beams)

  def side(search_m):
    half = config.max_range_cells + math.ceil(search_m / res) + 2
    return (min(2 * half + 1, config.height), min(2 * half + 1, config.width))

  smear = lambda sigma: max(1, scan_matching.smear_radius(sigma, res))
  return Sizes(stride=stride, crop=side(config.slam_search_m), loop_crop=side(config.loop_search_m),
               smear_cells=smear(config.slam_smear), loop_smear_cells=smear(config.loop_smear),
               window=scan_matching.Window(config.slam_steps, config.slam_steps),
               loop_window=scan_matching.Window(config.loop_steps, config.slam_steps),
               fine=scan_matching.Window(config.slam_fine_steps, config.slam_fine_steps))


def _penalties(params):
  return scan_matching.Penalties(
      distance_deviation=params.slam_distance_penalty, angle_deviation=params.slam_angle_penalty,
      minimum_distance=params.slam_min_distance_penalty,
      minimum_angle=params.slam_min_angle_penalty)


def _half_extents(cov, params, max_xy: float, min_xy):
  """The search's half-widths: three standard deviations of ``cov``, within bounds."""
  sigma_xy = jnp.sqrt(jnp.maximum(jnp.maximum(cov[0, 0], cov[1, 1]), 0.0))
  sigma_theta = jnp.sqrt(jnp.maximum(cov[2, 2], 0.0))
  half_xy = jnp.clip(3.0 * sigma_xy, min_xy, max_xy)
  half_angle = jnp.clip(3.0 * sigma_theta, params.slam_min_angle, params.slam_max_angle)
  return half_xy, half_angle


# --- front end -----------------------------------------------------------------------------------


def register(config, params, logodds, origin, points, valid, prior, odometry_cov):
  """The front end: the scan's end points (robot frame) matched against the robot's belief
  around ``prior`` (:class:`jaxplore.slam.scan_matching.Match`)."""
  sz = sizes(config)
  occupied = logodds > mapping.logit(params.p_occ)
  window, corner = crop(occupied, origin, config.res, prior[:2], sz.crop)
  field = scan_matching.smear(window, config.res, config.slam_smear, sz.smear_cells)
  half_xy, half_angle = _half_extents(odometry_cov, params, config.slam_search_m, config.res)
  return scan_matching.match(field, corner, config.res, points, valid, prior, half_xy, half_angle,
                             sz.window, sz.fine, _penalties(params))


# --- the graph -----------------------------------------------------------------------------------


def current_drift(graph: PoseGraph):
  """The newest keyframe's uncertainty since the last loop closure or near link (:func:`drift`):
  it gates the closures (:func:`close_loop`)."""
  assert graph.keyframe_drift is not None  # the scan_matching graph's
  return graph.keyframe_drift[jnp.maximum(graph.n_nodes - 1, 0)]


def drift(params, graph: PoseGraph, pose, odometry_cov, match_cov, matched):
  """The uncertainty of a new keyframe at ``pose`` (world frame) since the last loop closure or
  near link. ``odometry_cov``: the odometry's since the previous keyframe; ``match_cov``: the
  scan match's, when ``matched`` (both world frame).

  Dead-reckoned, it is the previous keyframe's compounded with the odometry's (Li Eq 17).
  Matched, the scan was placed against the map the recent keyframes drew, not against the
  previous keyframe alone, and the errors of successive matches do not add up as independent
  edges' would: on willow and intel the heading drift over 150 edges was 0.6-2.2° where the
  edges compounded as independent claimed 6° (``experiments/results/slam_closure_audit.md``).
  The match is then a measurement of the pose relative to the oldest keyframe of the front end's
  local chain (the keyframes since the last closure or link that are younger than any loop
  candidate, fewer than ``loop_min_age`` keyframes back; older ones are the loop search's): that
  keyframe's drift compounded with the match's covariance. It is fused with the dead-reckoned
  prediction (a Kalman update, :func:`jaxplore.motion.relocalise`): where the match holds the
  pose (a corner) the drift stays the anchor's, where it cannot (along a corridor, the match's
  variance large) it grows with the odometry, keyframe by keyframe.
  """
  assert graph.keyframe_drift is not None and graph.drift_from is not None  # scan_matching's
  i = graph.n_nodes
  last = jnp.maximum(i - 1, 0)
  oldest_local = jnp.floor(i.astype(jnp.float32) - params.loop_min_age).astype(jnp.int32) + 1
  anchor = jnp.clip(jnp.maximum(oldest_local, graph.drift_from), 0, last)

  def compounded(k, cov, increment_cov):
    j1, _ = motion.compounding_jacobians(graph.poses[k], pose)
    return j1 @ cov @ j1.T + increment_cov

  predicted = compounded(last, graph.keyframe_drift[last], odometry_cov)
  anchored = compounded(anchor, graph.keyframe_drift[anchor], match_cov)
  _, fused = motion.relocalise(pose, predicted, pose, anchored)
  return jnp.where(matched, fused, predicted)


def restart_drift(graph: PoseGraph, where, i, cov) -> PoseGraph:
  """Where ``where``: the drift counted from keyframe ``i`` again, with ``cov`` its uncertainty
  (0 after a loop closure, a near link's own covariance after a link)."""
  assert graph.keyframe_drift is not None and graph.drift_from is not None  # scan_matching's
  assert graph.search_cov is not None
  n_cap = graph.poses.shape[0]
  return graph.replace(
      search_cov=jnp.where(where, cov, graph.search_cov),
      drift_from=jnp.where(where, i, graph.drift_from),
      keyframe_drift=graph.keyframe_drift.at[jnp.where(where, i, n_cap)].set(cov, mode="drop"))


def add_keyframe(graph: PoseGraph, new, pose, truth, info) -> PoseGraph:
  """Keyframe ``n_nodes`` at the estimate ``pose`` (and ``truth``), joined to the previous
  keyframe by an edge of information ``info`` (nothing when ``new`` is False). Its scan is the
  caller's to store (:attr:`PoseGraph.ranges` row ``n_nodes``: the engine keeps the batch's
  scans apart, written a row at a time)."""
  n_cap = graph.poses.shape[0]
  i = graph.n_nodes
  slot = jnp.where(new, i, n_cap)
  previous = graph.poses[jnp.maximum(i - 1, 0)]
  put = lambda a, v: a.at[slot].set(v.astype(a.dtype), mode="drop")
  return graph.replace(
      poses=put(graph.poses, pose), truth=put(graph.truth, truth),
      chain_measured=put(graph.chain_measured, motion.between(previous, pose)),
      chain_info=put(graph.chain_info, info),
      chain_w=put(graph.chain_w, d_optimality_of_information(info)),
      n_nodes=i + new.astype(jnp.int32),
      acc_pose=jnp.where(new, 0.0, graph.acc_pose), acc_cov=jnp.where(new, 0.0, graph.acc_cov))


class Closure(NamedTuple):
  """A loop-closure search's outcome."""

  found: jax.Array  # bool: accepted
  older: jax.Array  # i32 the older keyframe the edge joins
  measured: jax.Array  # f32[3] the new keyframe's pose in the older one's frame
  info: jax.Array  # f32[3, 3]
  false: jax.Array  # bool: measured is wrong by more than the false-closure tolerance
  pose: jax.Array  # f32[3] the matched pose
  cov: jax.Array  # f32[3, 3] its covariance (world frame)
  link: jax.Array  # bool: a near link, not a loop closure


def facing(x, y, hit, origin_xy, view_xy, res: float):
  """Which of a scan's end points (f32[n] ``x``, ``y`` in beam order, seen from ``origin_xy``)
  lie on a wall face that ``view_xy`` sees from the same side: Karto's ``FindValidPoints``,
  which drops the points of walls whose far side the matched scan is on (a robot in the next
  room would otherwise match its wall's near face to the far face). A point's face runs to its
  neighbouring beam's end point (the next, else the previous), when that lies within
  :data:`NEIGHBOUR_CELLS`; a point with neither is dropped."""
  (nx1, ny1, near1), (nx0, ny0, near0) = _neighbours(x, y, hit, res)
  nx, ny = jnp.where(near1, nx1, nx0), jnp.where(near1, ny1, ny0)
  dx, dy = nx - x, ny - y
  side = lambda p: dx * (p[1] - y) - dy * (p[0] - x)
  return hit & (near1 | near0) & (side(origin_xy) * side(view_xy) > 0)


def local_map(graph: PoseGraph, ranges, candidates, ok, offsets, res: float, centre_xy, side,
              origin):
  """bool[side]: the end points of the candidate keyframes' stored scans (``ranges``, f16[N, B]
  as :func:`stored_scan` gives them) at their estimated
  poses (those facing ``centre_xy``, :func:`facing`), drawn into a window of the grid's lattice
  around ``centre_xy``; and its corner (m)."""
  rows, cols = cell_of(centre_xy, origin, res) - jnp.array([side[0] // 2, side[1] // 2])
  corner = origin + res * jnp.stack([cols, rows]).astype(jnp.float32)

  def ends(k):
    scan = ranges[k]
    pose = graph.poses[k]
    angle = pose[2] + offsets
    r = jnp.abs(scan.astype(jnp.float32)) * res
    seen = facing(pose[0] + r * jnp.cos(angle), pose[1] + r * jnp.sin(angle), scan > 0,
                  pose[:2], centre_xy, res)
    points, _ = end_points(scan, offsets, res)
    world = motion.rotate(pose[2], points) + pose[None, :2]
    return world[:, 0], world[:, 1], seen

  x, y, hit = jax.vmap(ends)(candidates)
  hit = hit & ok[:, None]
  r = jnp.floor((y - corner[1]) / res).astype(jnp.int32)
  c = jnp.floor((x - corner[0]) / res).astype(jnp.int32)
  r = jnp.where(hit, r, side[0])  # out of the window: dropped
  grid = jnp.zeros(side, bool).at[r.ravel(), c.ravel()].set(True, mode="drop",
                                                            wrap_negative_indices=False)
  return grid, corner


def loop_candidates(config, params, graph: PoseGraph, i, pose):
  """The older keyframes a loop closure of keyframe ``i`` (at ``pose``) is matched against: up to
  ``loop_candidates`` nearest within ``loop_radius``, at least ``loop_min_age`` keyframes older,
  never one linked to ``i`` by a chain of keyframes that stayed within the radius (Karto's
  near-linked scans; here some keyframe between the two lay outside it: the robot left and came
  back). Returns (i32[K] candidates nearest first, bool[K] which are real)."""
  n_cap = graph.poses.shape[0]
  index = jnp.arange(n_cap)
  offset = graph.poses[:, :2] - pose[None, :2]
  dist = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
  between = (index < i) & (dist > params.loop_radius)
  left_after = jnp.flip(jax.lax.cummax(jnp.flip(between.astype(jnp.int32)))).astype(bool)
  left_after = jnp.concatenate([left_after[1:], jnp.zeros((1,), bool)])  # some k > j left
  eligible = ((index.astype(jnp.float32) <= i.astype(jnp.float32) - params.loop_min_age)
              & (dist <= params.loop_radius) & left_after)
  score, candidates = jax.lax.top_k(jnp.where(eligible, -dist, -jnp.inf),
                                    min(config.loop_candidates, n_cap))
  return candidates, jnp.isfinite(score)


def close_loop(config, params, graph: PoseGraph, ranges, i, pose, truth, points, valid, offsets,
               origin, candidates, ok, link=False) -> Closure:
  """Looks for a loop closure of the new keyframe ``i`` (at estimate ``pose``, true ``truth``)
  against the ``candidates`` (:func:`loop_candidates`; their scans in ``ranges``).

  With ``link`` (a traced bool) it makes a near link instead (Karto's ``LinkNearChains``): the
  robot is back in a place it has closed a loop in, its estimate just matched against a belief
  drawn from those older keyframes, so the search is the front end's (a window of three
  standard deviations of the drift since the closure, at most ``slam_search_m``) and the match
  is accepted at a response of ``link_min_response``."""
  assert graph.truth is not None and graph.search_cov is not None  # the scan_matching graph's
  sz = sizes(config)
  occupied, corner = local_map(graph, ranges, candidates, ok, offsets, config.res, pose[:2],
                               sz.loop_crop, origin)
  field = scan_matching.smear(occupied, config.res, config.loop_smear, sz.loop_smear_cells)
  # The window from the bound (search_cov), the gate below from the drift.
  loop_xy, loop_angle = _half_extents(graph.search_cov, params, config.loop_search_m, config.res)
  link_xy, link_angle = _half_extents(graph.search_cov, params, config.slam_search_m, config.res)
  half_xy = jnp.where(link, link_xy, loop_xy)
  half_angle = jnp.where(link, link_angle, loop_angle)
  # Karto matches a loop closure without the odometry penalty (TryCloseLoop: doPenalize false),
  # and a near chain too (LinkNearChains).
  m = scan_matching.match(field, corner, config.res, points, valid, pose, half_xy, half_angle,
                          sz.loop_window, sz.fine, scan_matching.NO_PENALTIES)
  older = candidates[0]
  measured = motion.between(graph.poses[older], m.pose)
  info = information(in_frame(m.cov, graph.poses[older, 2]))
  # False: the truth lies outside the closure's own 99 % bound (the edge claims a certainty it
  # does not have). Along a corridor a closure is uncertain, and says so: not false.
  miss = measured - motion.between(graph.truth[older], truth)
  miss = miss.at[2].set(motion.wrap_angle(miss[2]))
  false = miss @ info @ miss > params.loop_gate
  # A closure must agree with where the robot believes it is, within the uncertainty of that
  # belief and of the match (a Mahalanobis gate, chi-square with 3 degrees of freedom): two
  # alike rooms a few metres apart otherwise make a false closure.
  innovation = m.pose - pose
  innovation = innovation.at[2].set(motion.wrap_angle(innovation[2]))
  gate = innovation @ linalg.inv3(current_drift(graph) + m.cov) @ innovation
  # A best pose on the search window's outermost candidates is no peak: the scan fits better
  # still beyond the window, and on willow such closures turned the robot by 20+ degrees.
  inner = (config.loop_steps - 0.5) / config.loop_steps
  inside = ((jnp.max(jnp.abs(innovation[:2])) <= inner * half_xy)
            & (jnp.abs(innovation[2]) <= inner * half_angle))
  min_response = jnp.where(link, params.link_min_response, params.loop_min_response)
  found = (ok[0] & (m.response >= min_response) & (gate <= params.loop_gate)
           & (jnp.maximum(m.cov[0, 0], m.cov[1, 1]) <= params.loop_max_variance) & inside)
  return Closure(found=found, older=older, measured=measured, info=info,
                 false=false, pose=m.pose, cov=m.cov, link=jnp.asarray(link))


def link_due(graph: PoseGraph, pose, candidates, ok, params):
  """Whether a new keyframe at ``pose`` makes a near link (:func:`close_loop` with ``link``):
  its nearest candidate lies within ``link_radius``, it is ``link_spacing`` from the last near
  link, and a quarter of the loop list is still free (kept for loop closures). The caller asks
  only where no loop closure is due (:func:`loop_armed`)."""
  assert graph.linked_at is not None  # the scan_matching graph's
  gap = pose[:2] - graph.poses[candidates[0], :2]
  near = ok[0] & (jnp.hypot(gap[0], gap[1]) <= params.link_radius)
  since = pose[:2] - graph.linked_at
  spaced = ~jnp.all(jnp.isfinite(graph.linked_at)) | (jnp.hypot(since[0], since[1])
                                                       >= params.link_spacing)
  m_cap = graph.loops.shape[0]
  return near & spaced & (graph.n_loops < m_cap - m_cap // 4)


def loop_armed(graph: PoseGraph, pose, params):
  """Whether the robot may look for a loop closure: never yet closed one, or has since moved
  more than ``loop_radius`` from where it did (Karto finds no closure among scans already linked
  to the new one: after a closure, the revisited place is linked)."""
  assert graph.closed_at is not None  # the scan_matching graph's
  offset = pose[:2] - graph.closed_at
  return ~jnp.all(jnp.isfinite(graph.closed_at)) | (jnp.hypot(offset[0], offset[1])
                                                    > params.loop_radius)


def add_loop(graph: PoseGraph, closure: Closure, i) -> PoseGraph:
  """The closure's (or near link's) edge (older keyframe -> keyframe ``i``) when found and there
  is room."""
  m_cap = graph.loops.shape[0]
  room = graph.n_loops < m_cap
  write = closure.found & room
  slot = jnp.where(write, graph.n_loops, m_cap)
  put = lambda a, v: a.at[slot].set(v.astype(a.dtype), mode="drop")
  return graph.replace(
      loops=put(graph.loops, jnp.stack([closure.older, i])),
      loop_w=put(graph.loop_w, d_optimality_of_information(closure.info)),
      loop_measured=put(graph.loop_measured, closure.measured),
      loop_info=put(graph.loop_info, closure.info), loop_false=put(graph.loop_false, closure.false),
      loop_link=put(graph.loop_link, closure.link),
      loop_revoked=put(graph.loop_revoked, jnp.bool_(False)),
      loop_chi2=put(graph.loop_chi2, jnp.float32(0.0)),
      n_loops=graph.n_loops + write.astype(jnp.int32),
      loops_dropped=graph.loops_dropped + (closure.found & ~room).astype(jnp.int32))


def graph_edges(graph: PoseGraph) -> optimiser.Edges:
  """The odometry and loop edges of ``graph`` as the optimiser takes them (revoked loop edges
  not valid)."""
  assert graph.chain_measured is not None and graph.chain_info is not None  # scan_matching's
  assert graph.loop_measured is not None and graph.loop_info is not None
  assert graph.loop_revoked is not None
  n_cap = graph.poses.shape[0]
  k = jnp.arange(1, n_cap)
  loops_in = (jnp.arange(graph.loops.shape[0]) < graph.n_loops) & ~graph.loop_revoked
  return optimiser.Edges(
      src=jnp.concatenate([k - 1, graph.loops[:, 0]]).astype(jnp.int32),
      dst=jnp.concatenate([k, graph.loops[:, 1]]).astype(jnp.int32),
      measured=jnp.concatenate([graph.chain_measured[1:], graph.loop_measured]),
      information=jnp.concatenate([graph.chain_info[1:], graph.loop_info]),
      valid=jnp.concatenate([k < graph.n_nodes, loops_in]))


def loop_chi2(graph: PoseGraph):
  """f32[M] each loop edge's squared Mahalanobis error ``rᵀ Ω r`` at the graph's poses
  (``r`` GTSAM's ``BetweenFactor`` error, :func:`jaxplore.slam.optimiser.between_error`); 0 for
  the unused slots. At the optimum of a consistent graph it is about χ² with 3 degrees of freedom
  or less (the edge shares its error with the rest of the graph)."""
  assert graph.loop_measured is not None and graph.loop_info is not None
  n_cap = graph.poses.shape[0]
  src = jnp.clip(graph.loops[:, 0], 0, n_cap - 1)
  dst = jnp.clip(graph.loops[:, 1], 0, n_cap - 1)
  r = jax.vmap(optimiser.between_error)(graph.poses[src], graph.poses[dst], graph.loop_measured)
  chi2 = jnp.einsum("ei,eij,ej->e", r, graph.loop_info, r)
  return jnp.where(jnp.arange(graph.loops.shape[0]) < graph.n_loops, chi2, 0.0)


WOODBURY_LOOPS = 32
# The most loop edges one back-end run revokes (each one more optimisation).
MAX_REVOCATIONS = 3


def _optimised(config, graph: PoseGraph) -> PoseGraph:
  """Every keyframe's pose re-estimated from all edges in the graph (keyframe 0 fixed)."""
  valid = jnp.arange(graph.poses.shape[0]) < graph.n_nodes
  # The preconditioner takes up to WOODBURY_LOOPS closures exactly (a 3K x 3K factorisation
  # per iteration, K the loop slots it covers); any further ones are left to the conjugate
  # gradients, which then need more iterations. A robot closes a loop once per visit to an
  # old place: a few dozen in an episode.
  result = optimiser.optimise(graph.poses, valid, graph_edges(graph),
                              max_iterations=config.slam_iterations,
                              loop_capacity=min(WOODBURY_LOOPS, graph.loops.shape[0]),
                              cg_max_iterations=50)
  poses = jnp.where(valid[:, None], result.poses, graph.poses)
  poses = poses.at[:, 2].set(motion.wrap_angle(poses[:, 2]))
  return graph.replace(poses=poses, loop_chi2=loop_chi2(graph.replace(poses=poses)))


def optimise(config, params, graph: PoseGraph) -> PoseGraph:
  """The back end: every keyframe's pose re-estimated from all edges (keyframe 0 fixed), then
  the graph checked for a loop edge that disagrees with the rest.

  A false loop closure (two alike places taken for one) bends the whole graph to fit it, and
  Karto keeps it. Here, at the optimum, the loop edge of largest ``rᵀ Ω r`` (:func:`loop_chi2`)
  is revoked when that exceeds ``loop_revoke_chi2`` (0: never) and the graph optimised again
  from the poses it had before, up to :data:`MAX_REVOCATIONS` times: the χ² test of a
  measurement against the graph's prediction, as an incremental smoother such as iSAM applies
  it. A true closure after a long drift passes it: the drift's uncertainty lets the chain take
  up its correction."""
  assert graph.optimisations is not None and graph.loop_revoked is not None
  start = graph.poses

  def worst(graph):
    chi2 = jnp.where(graph.loop_revoked, -jnp.inf, graph.loop_chi2)
    return jnp.argmax(chi2), jnp.max(chi2)

  def again(carry):
    graph, passes = carry
    return (passes == 0) | ((passes <= MAX_REVOCATIONS) & (params.loop_revoke_chi2 > 0)
                            & (worst(graph)[1] > params.loop_revoke_chi2))

  # One loop for the first optimisation and each one after a revocation: the optimiser is
  # compiled once (it is most of the SLAM step's compile time).
  def optimise_once_more(carry):
    graph, passes = carry
    edge = worst(graph)[0]
    revoke = passes > 0  # the first pass optimises the graph as it is
    revoked = graph.loop_revoked.at[edge].set(graph.loop_revoked[edge] | revoke)
    graph = graph.replace(poses=start, loop_revoked=revoked,
                          loop_w=graph.loop_w.at[edge].set(jnp.where(revoke, 0.0,
                                                                     graph.loop_w[edge])))
    return _optimised(config, graph), passes + 1

  optimisations = graph.optimisations + 1
  graph, _ = jax.lax.while_loop(again, optimise_once_more, (graph, jnp.int32(0)))
  return graph.replace(optimisations=optimisations)


# --- the map from the keyframes ------------------------------------------------------------------


# Crossings walked per loop iteration when a keyframe's beams are counted (all beams at once).
COUNT_BLOCK = 8


def _crossing(b: sensor.Beams, u0, v0, k, vertical: bool):
  """Entry distance (inf when the beam never crosses such a line) and cell (i32) of crossing
  ``k`` (f32, broadcast against the beams) of the vertical (``u`` integer) or horizontal grid
  lines, listed as :mod:`jaxplore.sensor` lists them (a side cell at a corner)."""
  b = jax.tree.map(lambda a: a.reshape((1,) * (jnp.ndim(k) - a.ndim) + a.shape), b)
  t0, step, sign = (b.t0_u, b.step_u, b.sign_u) if vertical else (b.t0_v, b.step_v, b.sign_v)
  t = jnp.where(jnp.isfinite(step), t0 + k * jnp.where(jnp.isfinite(step), step, 0.0), jnp.inf)
  at = lambda a0, da, eps: jnp.floor(a0 + jnp.where(jnp.isfinite(t), t + eps, 0.0) * da)
  entered = lambda a0: (jnp.floor(a0) + sign * (k + 1)).astype(jnp.int32)
  if vertical:
    return t, at(v0, b.dv, -sensor.CORNER_EPS).astype(jnp.int32), entered(u0)
  return t, entered(v0), at(u0, b.du, sensor.CORNER_EPS).astype(jnp.int32)


class Ends(NamedTuple):
  """Where the beams of a scan end on the grid (:func:`end_crossings`), f32/i32/bool[n] each."""

  t: jax.Array  # cells from the origin to the crossing
  rows: jax.Array  # the cell it enters
  cols: jax.Array
  k: jax.Array  # f32: which crossing of its kind it is (0: the nearest to the origin)
  vertical: jax.Array  # bool: a crossing of a vertical grid line (u integer)


def end_crossings(u0, v0, dirs, ranges, n_cross: int) -> Ends:
  """Where each beam of a keyframe's scan, re-traced from (u0, v0) (cells) along ``dirs``, ends:
  the grid line crossing nearest to its measured range (f32[n], cells) and the cell that crossing
  enters.

  A range ends on an obstacle's face, and on the belief's lattice a face is a cell edge: the
  crossing nearest to the end point is the face, the cell beyond it the obstacle. A pose error
  shorter than half the gap to the neighbouring crossings still finds that cell. (The end point
  pushed half a cell along its beam instead, :data:`END_PUSH_CELLS`, left the cell it had
  entered wherever the beam entered near a corner -- a wall's end, a door jamb, a diagonal
  wall -- and drew the free cell beside or behind it: one hit in 15 at the true poses on willow.)
  """
  b = sensor.beams(u0, v0, None, dirs)

  def nearest(vertical):
    t0, step = (b.t0_u, b.step_u) if vertical else (b.t0_v, b.step_v)
    k = jnp.round((ranges - t0) / jnp.where(jnp.isfinite(step), step, 1.0))
    k = jnp.clip(jnp.where(jnp.isfinite(step), k, 0.0), 0.0, n_cross - 1.0)
    return (*_crossing(b, u0, v0, k, vertical), k)

  x, y = nearest(True), nearest(False)
  vertical = jnp.abs(x[0] - ranges) <= jnp.abs(y[0] - ranges)
  pick = lambda j: jnp.where(vertical, x[j], y[j])
  return Ends(t=pick(0), rows=pick(1), cols=pick(2), k=pick(3), vertical=vertical)


def _tiled(grid):
  """An (H, W) int8 observation in the layout of :func:`jaxplore.sensor.empty_observation`."""
  h, w = grid.shape
  t = sensor.OBS_TILE
  n_rows, n_cols = -(-h // t), -(-w // t)
  padded = jnp.pad(grid, ((0, n_rows * t - h), (0, n_cols * t - w)))
  tiles = padded.reshape(n_rows, t, n_cols, t).transpose(0, 2, 1, 3).ravel()
  return jnp.concatenate([tiles, jnp.zeros((1,), grid.dtype)])


def keyframe_counts(pose, scan, offsets, origin, res: float, shape, n_cross: int, active=True):
  """How many of a keyframe's beams (its stored scan, f16[B], :func:`stored_scan`, re-traced from
  its estimated ``pose``) end in each cell and how many pass through it: (hits, passes), i32[H, W]
  each (nothing when ``active`` is False). A beam that hit ends in the cell beyond the grid line
  crossing nearest to its range (:func:`end_crossings`) and passes every cell it entered before
  that crossing; one that hit nothing passes every cell it entered before its range."""
  h, w = shape
  sink = h * w
  ranges = scan.astype(jnp.float32)
  hit = ranges > 0
  r = jnp.abs(ranges)
  dirs = sensor.directions(pose[2] + offsets)
  v0, u0 = to_cells(pose[:2], origin, res)
  ends = end_crossings(u0, v0, dirs, r, n_cross)
  t_end = jnp.where(hit, ends.t, r)
  b = sensor.beams(u0, v0, None, dirs)

  def index(rows, cols, ok):
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    return jnp.where(ok & inside, rows * w + cols, sink)

  hits = jnp.zeros((sink + 1,), jnp.int32).at[index(ends.rows, ends.cols, hit & active)].add(
      1, mode="promise_in_bounds")
  start = index(jnp.floor(v0).astype(jnp.int32), jnp.floor(u0).astype(jnp.int32), True)
  passes = jnp.zeros((sink + 1,), jnp.int32).at[start].add(
      jnp.sum((t_end > 0) & active).astype(jnp.int32), mode="promise_in_bounds")
  block = jnp.arange(COUNT_BLOCK, dtype=jnp.float32)[:, None]

  def body(carry):
    k0, passes = carry
    k = k0.astype(jnp.float32) + block
    entries = []
    for vertical in (True, False):
      t, rows, cols = _crossing(b, u0, v0, k, vertical)
      # On the end crossing's own kind of grid line, the crossings before it by their count
      # (their distances, computed again, may round either way of the end's).
      before = jnp.where((hit & (ends.vertical == vertical))[None], k < ends.k[None],
                         t < t_end[None])
      entries.append(index(rows, cols, before & (k < n_cross)))
    return k0 + COUNT_BLOCK, passes.at[jnp.concatenate(entries).ravel()].add(
        1, mode="promise_in_bounds")

  # Crossing k is at least k cells away: none past the longest beam is passed.
  furthest = jnp.where(active, jnp.max(t_end), -1.0)
  _, passes = jax.lax.while_loop(lambda c: (c[0] < n_cross) & (c[0] <= furthest), body,
                                 (jnp.int32(0), passes))
  return hits[:sink].reshape(shape), passes[:sink].reshape(shape)


def keyframe_observation(pose, scan, offsets, origin, res: float, shape, n_cross: int, params,
                         active=True):
  """What a keyframe's stored scan says about the grid seen from its estimated ``pose`` (the
  observation layout of :func:`jaxplore.sensor.mark_observed`: 1 seen free, 2 seen occupied;
  nothing when ``active`` is False): each cell's beams (:func:`keyframe_counts`) weighed as the
  inverse sensor model weighs an observation, ``l_occ`` per beam that ended in it and ``l_free``
  per beam that passed through it; occupied where that sum is positive, free where negative.

  Counted beam by beam, as Karto's grid counts each ray's hit and pass-through. Marked the way
  the oracle marks a scan (a cell any beam ended in is occupied, whatever the beams that passed
  through it), one beam ending a fraction of a cell short -- a beam grazing a wall, a pose a few
  centimetres off -- drew a second layer of wall in front of the one the scan's other beams had
  just passed through: redrawn at the estimated poses of 4-robot runs on willow, intel and office,
  the cells clear of the truth's walls by the robot's radius that the belief blocked fell from
  164-605 to 45-341 a robot."""
  hits, passes = keyframe_counts(pose, scan, offsets, origin, res, shape, n_cross, active)
  evidence = params.l_occ * hits + params.l_free * passes
  observed = jnp.where(evidence > 0, 2, jnp.where(evidence < 0, 1, 0)).astype(jnp.int8)
  return _tiled(observed)


def rebuild(logodds, robot, graph: PoseGraph, ranges, offsets, origin, res: float, reachable,
            params, n_cross: int, whole_grid: bool):
  """Robot ``robot``'s belief (in the batch ``logodds``, f32[R, H, W]) re-integrated from its
  keyframes' scans (``ranges``, f16[N, B]) at their poses. Returns ``(logodds, entropy, covered)``:
  the new belief and its map entropy (nats) and count of reachable cells believed free."""
  _, h, w = logodds.shape
  logodds = jax.lax.dynamic_update_index_in_dim(logodds, jnp.zeros((h, w), logodds.dtype), robot, 0)

  def one(k, logodds):
    observed = keyframe_observation(graph.poses[k], ranges[k], offsets, origin, res, (h, w),
                                    n_cross, params)
    logodds, _, _ = mapping.integrate_observation(
        logodds, robot, sensor.observation_tiles(observed, (h, w)), reachable, params,
        whole_grid=whole_grid)
    return logodds

  logodds = jax.lax.fori_loop(0, graph.n_nodes, one, logodds)
  grid = jax.lax.dynamic_index_in_dim(logodds, robot, 0, keepdims=False)
  entropy = jnp.sum(mapping.entropy_of_logodds(grid))
  covered = jnp.sum(reachable & (grid < mapping.logit(params.p_free))).astype(jnp.float32)
  return logodds, entropy, covered


__all__ = ["COUNT_BLOCK", "END_PUSH_CELLS", "MAX_REVOCATIONS", "NEIGHBOUR_CELLS", "WOODBURY_LOOPS",
           "Closure", "Ends", "Sizes", "add_keyframe", "add_loop", "beam_offsets", "close_loop",
           "crop", "d_optimality_of_information", "end_crossings", "end_points", "facing",
           "graph_edges", "in_frame", "information", "keyframe_counts", "keyframe_observation",
           "link_due", "local_map", "loop_armed", "loop_candidates", "loop_chi2", "optimise",
           "rebuild", "register", "scan_points", "sizes", "stored_scan"]
