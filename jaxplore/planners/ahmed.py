"""Ahmed, Frémont & Fantoni 2024, "Active SLAM utility function exploiting path entropy", and its
baseline AGS (Placed & Castellanos 2021, "Fast autonomous robotic exploration using the
underlying graph structure").

Two planners on the robot's SLAM pose graph (:mod:`jaxplore.posegraph`), both committing to a
goal until they reach it:

* ``ags`` — the frontier candidate whose hallucinated pose graph has the most weighted spanning
  trees, ``U1 = n^(1/n)·exp(log det L̃_w / n)`` (Eq 8; Placed & Castellanos' Eq 42).
* ``ahmed`` — Eq 9: ``U = U1 + (1 − E/K)·ρ + γ``, with the path entropy E over the K cells of the
  line robot → candidate (Eq 4–5), ``ρ = 10^β`` (β the number of digits of U1's integer part)
  and ``γ = exp(−λ·dist)`` (Eq 6).

Candidates (the authors' code): the authors group frontier points by MeanShift with a 1.5 m
bandwidth; here frontier cells are grouped by square tiles of ``cluster_m`` = 1.5 m
(:func:`tile_clusters`, the ``max_candidates`` fullest tiles), which likewise splits a long
frontier into pieces of about the bandwidth (whole 8-connected clusters would put the centroid of
a room-sized frontier in the middle of the room). Each group's goal is its centroid cell or its
nearest reachable frontier cell (:func:`jaxplore.frontiers.cluster_goals`), dropped when in the
inflated obstacle band, when the unknown area within ``filter_radius`` is below
``min_unknown_area``, or when within ``min_robot_dist`` of the robot.

Path entropy (Eq 4–5): the cells of the 4-connected digital line from the robot's cell to the
candidate's (each step one row or one column, the cell nearest the segment; the paper draws a
Bresenham line, the reading of the line here is fixed by the paper's "Σ over i, j" of Eq 5);
unknown cells get ``p_unknown`` = 0.1, known ones ``p_known`` = 0.45; entropy in bits; K is the
number of cells (Eq 5's ``Σ m_ij`` is a typo: the code divides by the count).

Hallucinated graph (the authors' ``hallucinateGraph``): along the shortest path to the candidate,
``h = ⌈length / halluc_spacing⌉`` nodes at random distinct path cells (option ``even`` = 1: evenly
spaced) plus one at the candidate, chained onto the last keyframe; each new node faces away from
the previous one. Odometry edge information ``(ODOM_COV⁻¹ / 2)·(1 + u)``, u the unknown fraction
of the cells within ``info_radius`` (D-optimality 21.38·(1 + u)). A new node with structure
around it (occupied fraction within ``info_radius`` above ``halluc_structure``) closes a loop to
the *nearest* keyframe more than ``halluc_loop_age`` keyframes older within ``halluc_loop_radius``
whose sensor footprint overlaps its own by more than ``halluc_overlap`` (the authors close to
every such keyframe: one per node keeps the update's rank bounded). Footprints are two 180°
sectors of the lidar's range: their overlap is taken as that of sectors with a common centre,
``1 − |Δθ|/π`` (the centres are at most 2 m apart for a 6 m range). The authors' loop
information ``|I_j − I|·1.5·loop_diff·occupied`` differences the information matrices of two real
edges, which in this engine's graph differ only by accumulated odometry noise; here the loop
gets the scan matcher's information scaled by the same ``lc_scale·loop_diff·occupied``
(``loop_diff`` = the loop's length in keyframes over the graph's size).

U1 of every candidate at once, without building its graph: the real graph's log-determinant and
the Cholesky factor of its loop capacitance once per plan (:func:`posegraph.logdet_parts`), then
per candidate the pendant chain (``Σ log w``) and a Schur complement over its own loop closures
(:func:`posegraph.extended_logdet`).

Positions: a cell's centre in metres is taken relative to the robot's estimated pose and cell
(``pose + (cell − robot cell)·res``), within half a cell of the world frame.

Plan fields: ``gain`` = the chosen candidate's U; ``cost`` = its path cost (m); ``n_candidates``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import motion, posegraph
from jaxplore.errors import ConfigError, shown
from jaxplore.frontiers import cluster_goals, plan_to, reachable_paths, unknown_neighbour
from jaxplore.graph import labels
from jaxplore.graph.dijkstra import extract_path
from jaxplore.planners import base
from jaxplore.settings import declared, setting


@dataclasses.dataclass(frozen=True)
class AgsWeights:
  """Traced weights of ``ags`` (``params.planner[name]``; sweeping them never recompiles):
  ``ahmed``'s but Eq 4-6's (AGS has no path entropy and no distance decay)."""

  # 100 path points of 0.05 m in the authors' code.
  halluc_spacing: float = setting(5.0, "⌈path length / halluc_spacing⌉ hallucinated nodes along "
                                  "the path to a candidate", unit="m", gt=0)
  even: float = setting(0.0, "hallucinated nodes at 0: random distinct path cells (the "
                        "authors), 1: evenly spaced", ge=0, le=1, integer=True)
  info_radius: float = setting(1.7, "radius of the unknown / occupied fractions around a "
                               "hallucinated node (<= Settings.disc_m)", unit="m", gt=0)
  odom_var_xy: float = setting(0.04, "ODOM_COV of the hallucinated odometry edges: x and y "
                               "variance", unit="m²", gt=0)
  odom_cov_xy: float = setting(0.001, "ODOM_COV: x-y covariance (|odom_cov_xy| < odom_var_xy)",
                               unit="m²")
  odom_var_theta: float = setting(0.008, "ODOM_COV: heading variance", unit="rad²", gt=0)
  halluc_loop_radius: float = setting(2.0, "a hallucinated node closes a loop only to a "
                                      "keyframe within this distance", unit="m", gt=0)
  halluc_loop_age: float = setting(20.0, "a hallucinated node closes a loop only to a "
                                   "keyframe more than this many keyframes older",
                                   unit="keyframes", ge=0)
  halluc_overlap: float = setting(0.15, "a hallucinated node closes a loop only to a keyframe "
                                  "whose sensor footprint overlaps its own by more than this",
                                  ge=0, le=1)
  halluc_structure: float = setting(0.03, "a hallucinated node closes a loop only when its "
                                    "occupied fraction within info_radius exceeds this",
                                    ge=0, le=1)
  lc_scale: float = setting(1.5, "scale of a hallucinated loop's information (the authors' "
                            "1.5·loop_diff·occupied)", ge=0)
  filter_radius: float = setting(1.0, "candidates need min_unknown_area of unknown cells within "
                                 "this radius (<= Settings.disc_m)", unit="m", gt=0)
  min_unknown_area: float = setting(0.45, "unknown area within filter_radius a candidate needs",
                                    unit="m²", ge=0)
  min_robot_dist: float = setting(0.25, "candidates nearer the robot are dropped", unit="m",
                                  ge=0)


@dataclasses.dataclass(frozen=True)
class Weights(AgsWeights):
  """Traced weights of ``ahmed``: AGS's and Eq 4-6's."""

  lambda_: float = setting(0.6, "Eq 6: decay λ of γ = exp(−λ·dist) (per cell with "
                           "gamma_cells = 1)", unit="1/m", ge=0, name="lambda")
  gamma_cells: float = setting(0.0, "Eq 6's dist: 0 in metres, 1 in cells (the authors' code)",
                               ge=0, le=1, integer=True)
  p_unknown: float = setting(0.1, "Eq 4: p of an unknown cell of the path's line", gt=0, lt=1)
  p_known: float = setting(0.45, "Eq 4: p of a known cell of the path's line", gt=0, lt=1)


DEFAULTS = {name: s.default for name, s in declared(Weights).items()}


@dataclasses.dataclass(frozen=True)
class Settings:
  """Static shapes of the planners.

  Attributes:
    max_candidates: frontier clusters scored (the largest ones).
    max_new_nodes: hallucinated nodes per candidate, the one at the candidate included; longer
      paths get this many.
    halluc_path_cells: cells of the path to a candidate that hallucinated nodes may sit on (the
      node at the candidate itself is always placed).
    disc_m: the largest radius (m) of the unknown / occupied counts around a point.
    cluster_m: side (m) of the tiles that group frontier cells into candidates.
  """

  max_candidates: int = setting(32, "frontier clusters scored (the fullest ones)", static=True,
                                ge=1, integer=True)
  max_new_nodes: int = setting(8, "hallucinated nodes per candidate, the one at the candidate "
                               "included; longer paths get this many", static=True, ge=1,
                               integer=True)
  halluc_path_cells: int = setting(1024, "cells of the path to a candidate that hallucinated "
                                   "nodes may sit on (the node at the candidate is always "
                                   "placed)", static=True, ge=1, integer=True)
  disc_m: float = setting(2.0, "the largest radius of the unknown / occupied counts around a "
                          "point (info_radius, filter_radius)", unit="m", static=True, gt=0)
  cluster_m: float = setting(1.5, "side of the square tiles that group frontier cells into "
                             "candidates (the authors' MeanShift bandwidth)", unit="m",
                             static=True, gt=0)


def validate(weights, params, ctx):
  """Host-side checks the declarations cannot make: the radii within the static disc, the
  hallucinated odometry covariance positive definite."""
  settings = ctx.settings
  w = {k: np.asarray(v) for k, v in weights.items()}
  for name in ("info_radius", "filter_radius"):
    bad = w[name] > settings.disc_m + 1e-6
    if np.any(bad):
      raise ConfigError(f"ahmed: {name} must be in (0, {settings.disc_m}] m (Settings.disc_m), "
                        f"got {shown(w[name], bad)}")
  if np.any(w["odom_cov_xy"] ** 2 >= w["odom_var_xy"] ** 2):
    raise ConfigError("ahmed: the hallucinated odometry covariance must be positive definite "
                      f"(|odom_cov_xy| < odom_var_xy), got {shown(w['odom_cov_xy'])} and "
                      f"{shown(w['odom_var_xy'])}")


def _weights(params) -> dict:
  """Every weight of :data:`DEFAULTS` as an f32 leaf (AGS's missing ones at their defaults), so
  both planners hand the same pytree to :func:`_plan`."""
  return {name: jnp.asarray(params.planner.get(name, value), jnp.float32)
          for name, value in DEFAULTS.items()}


def tile_clusters(frontier, tile: int, max_clusters: int) -> labels.Clusters:
  """Frontier cells grouped by ``tile`` x ``tile`` squares; the ``max_clusters`` squares with the
  most frontier cells, fullest first (equal counts: lower tile index first)."""
  height, width = frontier.shape
  tile_rows, tile_cols = -(-height // tile), -(-width // tile)
  n_tiles = tile_rows * tile_cols
  rows = jax.lax.broadcasted_iota(jnp.int32, (height, width), 0)
  cols = jax.lax.broadcasted_iota(jnp.int32, (height, width), 1)
  tile_id = (rows // tile) * tile_cols + cols // tile
  segment = jnp.where(frontier, tile_id, n_tiles).ravel()

  def per_tile(values):
    return jax.ops.segment_sum(values.ravel(), segment, num_segments=n_tiles + 1)[:n_tiles]

  size = per_tile(jnp.ones((height, width), jnp.int32))
  sums = jnp.stack([per_tile(rows.astype(jnp.float32)), per_tile(cols.astype(jnp.float32))],
                   axis=-1)
  k = min(max_clusters, n_tiles)
  top, chosen = jax.lax.top_k(size, k)
  valid = top > 0
  mean = sums[chosen] / jnp.maximum(top, 1)[:, None].astype(jnp.float32)
  centroid = jnp.where(valid[:, None], mean, 0.0)
  slot = jnp.full((n_tiles + 1,), -1, jnp.int32).at[chosen].set(
      jnp.where(valid, jnp.arange(k, dtype=jnp.int32), -1))
  ids = jnp.where(frontier, slot[tile_id], -1)
  if k < max_clusters:
    pad = max_clusters - k
    top = jnp.concatenate([top, jnp.zeros((pad,), top.dtype)])
    centroid = jnp.concatenate([centroid, jnp.zeros((pad, 2), centroid.dtype)])
    valid = jnp.concatenate([valid, jnp.zeros((pad,), bool)])
  return labels.Clusters(ids=ids, size=top.astype(jnp.int32), centroid=centroid, valid=valid,
                         count=jnp.sum(size > 0).astype(jnp.int32))


# --- path entropy (Eq 4-5) -----------------------------------------------------------------------


def line_cells(start, end, n_max: int):
  """The 4-connected digital line from ``start`` to ``end`` (i32[2] cells): after s steps it has
  made ``round(s·|dr| / T)`` row moves (T = |dr| + |dc|, halves rounded up), the choice that
  keeps each cell nearest the segment. Returns (cells i32[n_max, 2], count i32 = T + 1)."""
  d = (end - start).astype(jnp.int32)
  steps = jnp.abs(d)
  total = steps[0] + steps[1]
  s = jnp.arange(n_max, dtype=jnp.int32)
  row_moves = jnp.floor(s.astype(jnp.float32) * steps[0].astype(jnp.float32)
                        / jnp.maximum(total, 1).astype(jnp.float32) + 0.5).astype(jnp.int32)
  col_moves = s - row_moves
  moves = jnp.stack([jnp.sign(d[0]) * row_moves, jnp.sign(d[1]) * col_moves], axis=-1)
  cells = start[None, :] + moves
  return cells, total + 1


def binary_entropy_bits(p):
  return -(p * jnp.log2(p) + (1.0 - p) * jnp.log2(1.0 - p))


def path_entropy(unknown, start, end, p_unknown, p_known, n_max: int):
  """Eq 4–5: ``E/K`` over the line's cells, ``E = Σ H₂(p)`` in bits with p = ``p_unknown`` on
  unknown cells and ``p_known`` elsewhere, K the number of cells."""
  cells, count = line_cells(start, end, n_max)
  on_line = jnp.arange(n_max) < count
  is_unknown = unknown.at[cells[:, 0], cells[:, 1]].get(mode="fill", fill_value=True)
  bits = jnp.where(is_unknown, binary_entropy_bits(p_unknown), binary_entropy_bits(p_known))
  return jnp.sum(jnp.where(on_line, bits, 0.0)) / count.astype(jnp.float32)


# --- neighbourhood fractions ---------------------------------------------------------------------


def disc_counts(masks, cell, radius_cells, window: int):
  """Cells within ``radius_cells`` of ``cell`` (centre distance) that lie in the grid, and how many
  of them are set in each of ``masks`` (bool[C, H, W]). ``window`` (static) bounds the radius."""
  offsets = jnp.arange(-window, window + 1)
  dr, dc = jnp.meshgrid(offsets, offsets, indexing="ij")
  inside_disc = (dr * dr + dc * dc).astype(jnp.float32) <= radius_cells * radius_cells + 1e-6
  rows, cols = cell[0] + dr, cell[1] + dc
  height, width = masks.shape[-2:]
  in_grid = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width) & inside_disc
  values = masks[:, jnp.clip(rows, 0, height - 1), jnp.clip(cols, 0, width - 1)] & in_grid[None]
  return jnp.sum(in_grid), jnp.sum(values, axis=(-2, -1))


# --- hallucination -------------------------------------------------------------------------------


def hallucinated_nodes(path, length, n_new: int, count, even, key):
  """Indices along a path of the hallucinated nodes before the one at its end.

  Args:
    path: i32[L, 2] path cells (source first); length: valid cells.
    n_new: static slots (``max_new_nodes − 1``). count: how many nodes to place (≤ n_new).
    even: evenly spaced (True) or random distinct cells (the authors).
  Returns:
    (index i32[n_new] ascending, valid bool[n_new]); nodes sit on cells 1 … length − 2.
  """
  capacity = path.shape[0]
  idx = jnp.arange(capacity)
  eligible = (idx >= 1) & (idx <= length - 2)
  count = jnp.minimum(count, jnp.sum(eligible))
  noise = jax.random.uniform(key, (capacity,))
  _, chosen = jax.lax.top_k(jnp.where(eligible, -noise, -2.0), n_new)
  k = jnp.arange(n_new)
  random_valid = k < count
  chosen = jnp.sort(jnp.where(random_valid, chosen, capacity))
  spaced = jnp.floor((k + 1).astype(jnp.float32) * (length - 1).astype(jnp.float32)
                     / (count + 1).astype(jnp.float32) + 0.5).astype(jnp.int32)
  index = jnp.where(even, jnp.where(random_valid, spaced, capacity), chosen)
  valid = k < count
  return jnp.minimum(index, capacity - 1).astype(jnp.int32), valid


class _Context:
  """Per-plan quantities shared by every candidate."""

  def __init__(self, graph, parts, odom_dopt, sm_info, masks, window, res, robot, w):
    self.graph, self.parts, self.odom_dopt, self.sm_info = graph, parts, odom_dopt, sm_info
    self.masks, self.window, self.res, self.robot, self.w = masks, window, res, robot, w


def _to_metres(cells, robot: base.RobotView, res: float):
  """Cell centres relative to the robot's pose (see the module docstring)."""
  delta = (cells - robot.cell[None, :]).astype(jnp.float32) * res
  return robot.pose[None, :2] + jnp.stack([delta[:, 1], delta[:, 0]], axis=-1)


def candidate_logdet(c: _Context, node_cells, node_valid):
  """``(log det, node count)`` of the graph hallucinated along ``node_cells`` (i32[P, 2], a valid
  prefix ``node_valid``) for one candidate."""
  graph, w = c.graph, c.w
  xy = _to_metres(node_cells, c.robot, c.res)
  last = graph.n_nodes - 1
  prev = jnp.concatenate([graph.poses[last, :2][None, :], xy[:-1]], axis=0)
  theta = jnp.arctan2(xy[:, 1] - prev[:, 1], xy[:, 0] - prev[:, 0])
  radius_cells = w["info_radius"] / c.res
  n_cells, counts = jax.vmap(
      lambda cell: disc_counts(c.masks, cell, radius_cells, c.window))(node_cells)
  n_cells = jnp.maximum(n_cells, 1).astype(jnp.float32)
  unknown_frac = counts[:, 0] / n_cells
  occupied_frac = counts[:, 1] / n_cells
  new_w = c.odom_dopt * (1.0 + unknown_frac)

  n_cap = graph.poses.shape[0]
  p = jnp.arange(node_cells.shape[0])
  node_id = graph.n_nodes + p  # graph index of each new node
  offset = graph.poses[None, :, :2] - xy[:, None, :]
  dist = jnp.sqrt(jnp.sum(offset * offset, axis=-1))  # [P, N]
  turn = jnp.abs(motion.wrap_angle(graph.poses[None, :, 2] - theta[:, None]))
  overlap = 1.0 - turn / jnp.pi
  old = jnp.arange(n_cap)[None, :].astype(jnp.float32) < (node_id[:, None] - w["halluc_loop_age"])
  ok = (old & (jnp.arange(n_cap)[None, :] < graph.n_nodes) & (dist <= w["halluc_loop_radius"])
        & (overlap > w["halluc_overlap"]))
  score = jnp.where(ok, dist, jnp.inf)
  loop_to = jnp.argmin(score, axis=-1).astype(jnp.int32)
  closes = (node_valid & jnp.isfinite(jnp.min(score, axis=-1))
            & (occupied_frac > w["halluc_structure"]))
  loop_diff = (node_id - loop_to).astype(jnp.float32) / (node_id + 1).astype(jnp.float32)
  loop_w = jnp.where(closes, c.sm_info * w["lc_scale"] * loop_diff * occupied_frac, 0.0)
  logdet = posegraph.extended_logdet(graph, c.parts, new_w, node_valid, loop_to, loop_w)
  return logdet, graph.n_nodes + jnp.sum(node_valid)


def u1_from_logdet(logdet, n):
  """Eq 8 (Placed & Castellanos Eq 42): ``n^(1/n)·exp(logdet / n)``."""
  n = n.astype(jnp.float32)
  return jnp.exp((jnp.log(n) + logdet) / n)


def digits_weight(u1):
  """``ρ = 10^β``, β the number of digits of U1's integer part (1 below 1)."""
  beta = jnp.where(u1 >= 1.0, jnp.floor(jnp.log10(jnp.maximum(u1, 1.0))) + 1.0, 1.0)
  return 10.0 ** beta


def score_candidates(ctx, view: base.BeliefView, robot: base.RobotView, params, key,
                     graph: posegraph.PoseGraph, settings: Settings, with_entropy):
  """Every candidate's utility (Eq 9 for ``ahmed``, U1 alone for ``ags``; ``with_entropy`` may
  be traced).

  Returns (candidates, keep bool[K], utility f32[K] (−inf where not kept), dist f32[H, W], pred,
  parts of U).
  """
  return _score(ctx, view, robot, _weights(params), params.scan_match_sigma, key, graph, settings,
                with_entropy)


def _score(ctx, view, robot, w, scan_match_sigma, key, graph, settings, with_entropy):
  res = ctx.res
  node_cost = jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32)
  dist, pred = reachable_paths(ctx, view, robot, node_cost)
  tile = max(1, int(round(settings.cluster_m / res)))
  found = cluster_goals(ctx, view, robot, dist,
                                  tile_clusters(view.frontier, tile, settings.max_candidates))
  window = int(math.ceil(settings.disc_m / res - 1e-6))
  masks = jnp.stack([view.unknown, view.occupied])

  def unknown_area(goal):
    _, counts = disc_counts(masks[:1], goal, w["filter_radius"] / res, window)
    return counts[0].astype(jnp.float32) * res * res

  keep = (found.valid & ~view.inflated[found.goal[:, 0], found.goal[:, 1]]
          & (jax.vmap(unknown_area)(found.goal) >= w["min_unknown_area"])
          & (found.distance >= w["min_robot_dist"]))

  odom_cov = jnp.array([[w["odom_var_xy"], w["odom_cov_xy"], 0.0],
                        [w["odom_cov_xy"], w["odom_var_xy"], 0.0],
                        [0.0, 0.0, w["odom_var_theta"]]], jnp.float32)
  # D-optimality of ODOM_COV⁻¹ / 2: each eigenvalue halves.
  odom_dopt = 0.5 * posegraph.d_optimality_of_covariance(odom_cov)
  sm_info = 1.0 / scan_match_sigma ** 2
  c = _Context(graph, posegraph.logdet_parts(graph), odom_dopt, sm_info, masks, window, res,
               robot, w)
  n_new = settings.max_new_nodes - 1
  keys = jax.random.split(key, settings.max_candidates)

  def one(goal, path_m, k):
    path, length = extract_path(pred, goal, settings.halluc_path_cells, source=robot.cell)
    count = jnp.clip(jnp.ceil(path_m / w["halluc_spacing"]), 0, n_new).astype(jnp.int32)
    index, valid = hallucinated_nodes(path, length, n_new, count, w["even"] > 0.5, k)
    # Path nodes first (a valid prefix), then the node at the candidate.
    on_path = jnp.concatenate([valid, jnp.array([False])])
    on_cells = path[jnp.concatenate([index, index[-1:]])]
    node_cells = jnp.where(on_path[:, None], on_cells, goal[None, :])
    node_valid = jnp.arange(n_new + 1) <= jnp.sum(valid)
    return candidate_logdet(c, node_cells, node_valid)

  path_m = dist[found.goal[:, 0], found.goal[:, 1]]
  logdet, n_nodes = jax.vmap(one)(found.goal, jnp.where(keep, path_m, 0.0), keys)
  u1 = u1_from_logdet(logdet, n_nodes)
  n_max = ctx.height + ctx.width
  entropy = jax.vmap(lambda goal: path_entropy(view.unknown, robot.cell, goal, w["p_unknown"],
                                                w["p_known"], n_max))(found.goal)
  d = jnp.where(w["gamma_cells"] > 0.5, found.distance / res, found.distance)
  gamma = jnp.exp(-w["lambda"] * d)
  utility = jnp.where(with_entropy, u1 + (1.0 - entropy) * digits_weight(u1) + gamma, u1)
  utility = jnp.where(keep, utility, -jnp.inf)
  return found, keep, utility, dist, pred, {"u1": u1, "entropy": entropy}


def plan_graph(ctx, view, robot, params, key, graph, settings: Settings,
               with_entropy) -> base.Plan:
  """The plan to the candidate of largest utility; no plan without a valid candidate."""
  return plan_and_scores(ctx, view, robot, params, key, graph, settings, with_entropy)[0]


def plan_and_scores(ctx, view, robot, params, key, graph, settings: Settings, with_entropy):
  """(Plan, candidates, keep, utility, U1, E/K): the plan and what it was chosen from."""
  return _plan(ctx, view, robot, _weights(params), params.scan_match_sigma, key, graph,
               jnp.asarray(with_entropy), settings)


# One compiled program for both planners when called eagerly (inlined under an outer jit).
@functools.partial(jax.jit, static_argnames=("ctx", "settings"))
def _plan(ctx, view, robot, w, scan_match_sigma, key, graph, with_entropy, settings):
  found, keep, utility, dist, pred, parts = _score(ctx, view, robot, w, scan_match_sigma, key,
                                                   graph, settings, with_entropy)
  best = jnp.argmax(utility)
  valid = jnp.isfinite(utility[best])
  goal = found.goal[best]
  cells, length, _ = plan_to(ctx, view, robot, pred, goal, valid)
  look_at = unknown_neighbour(found.look_at[best], view.unknown, view.occupied)
  plan = base.Plan(waypoints=cells, length=length, goal=goal, look_at=look_at, valid=valid,
                   gain=jnp.where(valid, utility[best], 0.0).astype(jnp.float32),
                   cost=jnp.where(valid, dist[goal[0], goal[1]], jnp.inf).astype(jnp.float32),
                   n_candidates=jnp.sum(keep).astype(jnp.int32))
  return plan, found, keep, utility, parts["u1"], parts["entropy"]


SUMMARY_AHMED = ("Ahmed et al. 2024 Eq 9: frontier of largest U1 (hallucinated spanning trees) "
                 "+ path entropy + γ")
SUMMARY_AGS = ("Placed & Castellanos' AGS: frontier of largest U1 (hallucinated pose graph's "
               "spanning trees)")


def plan_ahmed(ctx, view: base.BeliefView, robot: base.RobotView, params, key) -> base.Plan:
  """Eq 9: ``U = U1 + (1 − E/K)·ρ + γ``, largest wins (see the module docstring)."""
  return plan_graph(ctx, view, robot, params, key, view.pose_graph, ctx.settings,
                    with_entropy=True)


AHMED = base.planner("ahmed", plan_ahmed, defaults=Weights, summary=SUMMARY_AHMED,
                     settings=Settings(), validate=validate, needs_pose_graph=True,
                     commits=True, slam="scan_matching")


def plan_ags(ctx, view: base.BeliefView, robot: base.RobotView, params, key) -> base.Plan:
  """AGS: ``U = U1`` (Eq 8), largest wins; ahmed's candidates and hallucination."""
  return plan_graph(ctx, view, robot, params, key, view.pose_graph, ctx.settings,
                    with_entropy=False)


AGS = base.planner("ags", plan_ags, defaults=AgsWeights, summary=SUMMARY_AGS,
                   settings=Settings(), validate=validate, needs_pose_graph=True, commits=True,
                   slam="scan_matching")
