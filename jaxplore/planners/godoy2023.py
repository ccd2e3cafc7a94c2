"""Godoy-Calvo et al. 2023, "Dynamic entropy-based method for exploring frontiers".

Two planners:

* ``frt`` — the paper's frontier baseline, Eq 12: ``U' = C_d·d − C_i·A``.
* ``ig`` — the paper's method, Eq 3: ``U = C_d·d − C_i·f·I`` with the expectation function of
  Eq 4 / Figure 1, the information gain of Eq 9 and the obstacle factor of Eq 5 (Algorithm 1).

Shared by ``frt`` and ``ig`` (§4.1: "only the centroids of the frontiers are candidates"):
frontier cells (:func:`jaxplore.mapping.frontier`) are grouped into 8-connected clusters
(:func:`jaxplore.graph.labels.clusters`, the :data:`MAX_CLUSTERS` largest). A cluster's candidate
goal is its centroid cell if the robot can stand there (traversable, reached by the engine's
Dijkstra, not blacklisted), else the cluster's frontier cell nearest to the centroid among those
the Dijkstra reaches and the blacklist allows. A cluster with neither is no candidate, so a
frontier seen through a gap the robot cannot pass never traps a planner. ``d`` is the Euclidean
distance robot → candidate in metres (Eq 3: "distancia euclídea"), measured between cell centres.
The path to the chosen candidate comes from the same Dijkstra (``reachable_paths``/``plan_to``).

Units and the paper's ambiguities (decisions):

* ``A`` (Eq 12) is the number of frontier cells in the cluster, as the paper says ("número de
  celdas"); ``I`` (Eq 9) is a sum over cells. Both therefore grow as the resolution gets finer;
  the paper's weights (Table 2) were tuned on 0.05 m gmapping maps. Scale ``C_i`` by
  ``res / 0.05`` (Frt) or ``(res / 0.05)²`` (IG) to keep the paper's balance (Eq 10) at another
  resolution.
* Entropy is in bits (log2): Eq 1 leaves the base open; the authors' released code
  (Godoy-Calvo et al. 2022, ``frontier_search.cpp``) uses ``log2``.
* ``D`` is in metres. Its default, 5.5 m, is the Husky's lidar range (the ``godoy_open``
  preset), not a value the authors released: their launch files set ``expected_radius`` to 0.3,
  0.4 or 2 m. 5.5 m is what makes ``I`` of the order of Table 1 (thousands of bits for a few
  metres of frontier at 0.05 m). Figure 1 illustrates Eq 4 with ``D`` = 5 cells.
* Distances inside Algorithm 1 are Manhattan distances in cells, ``P = min(d / (2D), 0.5)`` with
  ``d`` and ``D`` in the same unit (Figure 1: frontier cells 0, then 0.1 per cell for D = 5), and
  a cell is in the neighbourhood when ``d ≤ D`` (Algorithm 1's test).
* Each cell counts for its *nearest* cluster only (one labelled distance transform,
  :func:`jaxplore.graph.labels.nearest_label_manhattan`) instead of one BFS per cluster as in
  Algorithm 1: where two clusters' neighbourhoods overlap, the overlap goes to the nearer one
  (ties: the larger cluster). Identical to Algorithm 1 when clusters are more than 2D apart.
* Algorithm 1's region (the BFS from a frontier cell through cells within ``D``) is the whole
  set of cells within Manhattan distance ``D`` of the cluster: walls do not stop it, and its
  Free count includes the cluster's own frontier cells (they are free and at distance 0).
* ``f = 1 − k_f·Occupied/Known`` with ``Known = Free + Occupied``; ``Known`` is never 0 (the
  cluster's own cells are free), guarded anyway.
* ``d_path`` (not in the paper; default 0): 1 replaces the Euclidean ``d`` by the Dijkstra path
  cost to the candidate. With Euclidean ``d`` and the engine's frequent replanning (every
  ``replan_every`` steps, about 1 s; the authors' explorer replanned at ``planner_frequency``
  0.33 Hz, every 3 s, and at once on arrival) a robot whose path to the best goal first detours
  away from it can oscillate forever between two far goals of nearly equal cost: each step along
  one path raises that goal's Euclidean distance and lowers the other's. With the path cost a
  step along the chosen path lowers its cost by the step and raises any other by at most the
  step, so the choice stands until the information terms change.
* The authors' code (``frontier_search.cpp``) departs from the paper in two ways offered here:
  it drops frontiers shorter than ``min_frontier_size`` (frontier cells x resolution; released
  value 0.5 m, the default here; 0 keeps every cluster), and it measures ``d`` from the robot to
  the frontier's cell nearest to it (``d_nearest`` = 1; default 0, the paper's distance to the
  candidate). A dropped cluster is no candidate and, for IG, claims no neighbourhood cells.

Plan fields: ``gain`` is the utility the planner maximised, ``−U'`` (Frt) or ``−U`` (IG); ``cost``
is the Dijkstra path cost to the goal (m); ``n_candidates`` the clusters with a candidate goal.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplore import mapping
from jaxplore.frontiers import (
  Candidates,
  cluster_goals,
  plan_to,
  reachable_paths,
  unknown_neighbour,
)
from jaxplore.graph import labels
from jaxplore.planners import base
from jaxplore.settings import setting

# Frontier clusters scored per planning round; smaller clusters beyond this many are ignored.
MAX_CLUSTERS = 128

# Help of the weights frt and ig share, none of them the paper's (see the module docstring).
_D_PATH = "0: d is the Euclidean distance (the paper); 1: the Dijkstra path cost"
_D_NEAREST = ("0: Euclidean d to the candidate (the paper); 1: to the cluster's cell nearest "
              "the robot (the authors' code)")
_MIN_FRONTIER_SIZE = ("clusters shorter than this (cells × res) are no candidates (the authors' "
                      "code; 0 keeps every cluster)")


@dataclasses.dataclass(frozen=True)
class FrtWeights:
  """Traced weights of ``frt`` (``params.planner[name]``; sweeping them never recompiles)."""

  C_d: float = setting(10.0, "Eq 12: C_d, weight of the distance d (per metre)")
  C_i: float = setting(1.0, "Eq 12: C_i, weight of the cluster's frontier cells A (scale by "
                       "res / 0.05 at another resolution)")
  d_path: float = setting(0.0, _D_PATH, ge=0, le=1, integer=True)
  d_nearest: float = setting(0.0, _D_NEAREST, ge=0, le=1, integer=True)
  min_frontier_size: float = setting(0.5, _MIN_FRONTIER_SIZE, unit="m", ge=0)


@dataclasses.dataclass(frozen=True)
class IgWeights:
  """Traced weights of ``ig`` (``params.planner[name]``; sweeping them never recompiles)."""

  C_d: float = setting(10.0, "Eq 3: C_d, weight of the distance d (per metre)")
  C_i: float = setting(0.01, "Eq 3: C_i, weight of f·I, I in bits (scale by (res / 0.05)² at "
                       "another resolution)")
  k_f: float = setting(10.0, "Eq 5: k_f, obstacle weight of f = 1 − k_f·Occupied/Known")
  D: float = setting(5.5, "Eq 4 and Algorithm 1: D, a cluster's neighbourhood radius "
                     "(Manhattan)", unit="m", gt=0)
  d_path: float = setting(0.0, _D_PATH, ge=0, le=1, integer=True)
  d_nearest: float = setting(0.0, _D_NEAREST, ge=0, le=1, integer=True)
  min_frontier_size: float = setting(0.5, _MIN_FRONTIER_SIZE, unit="m", ge=0)


FRT_DEFAULTS = {f.name: f.default for f in dataclasses.fields(FrtWeights)}
IG_DEFAULTS = {f.name: f.default for f in dataclasses.fields(IgWeights)}


def _weights(params, defaults: dict) -> dict:
  return {name: params.planner.get(name, value) for name, value in defaults.items()}


def frontier_candidates(config, view: base.BeliefView, robot: base.RobotView, dist,
                        min_frontier_size=0.0) -> Candidates:
  """Clusters the frontier and picks each cluster's goal (§4.1; see the module docstring).

  Args:
    config: the planner context.
    view: the robot's belief.
    robot: the robot.
    dist: f32[H, W] path cost from the robot (``reachable_paths``), inf where unreachable.
    min_frontier_size: clusters with ``size · res`` below this (m) are no candidates.
  """
  return cluster_goals(config, view, robot, dist, labels.clusters(view.frontier, MAX_CLUSTERS),
                       min_frontier_size)


def expected_occupancy(distance, radius_cells):
  """Eq 4 (Figure 1): ``P = min(d / (2D), 0.5)``, d the Manhattan distance to the frontier."""
  return jnp.minimum(distance.astype(jnp.float32) / (2.0 * radius_cells), 0.5)


def entropy_bits(p):
  """Eq 1 per cell in bits: ``−P log2 P − (1−P) log2(1−P)``."""
  return mapping.entropy_of_probability(p) / math.log(2.0)


class Neighbourhoods(NamedTuple):
  """Algorithm 1's per-cluster results (nearest-cluster assignment, see the module docstring).

  Attributes:
    expectation: f32[H, W] Eq 4's P at unknown cells within D of a kept cluster, else NaN.
    info: f32[K] Eq 9: ``I = Σ Ĥ(P)`` over the cluster's unknown cells within D, bits.
    free: i32[K] known free cells within D (Algorithm 1's ``Free``).
    occupied: i32[K] known occupied cells within D (``Occupied``).
    factor: f32[K] Eq 5: ``f = 1 − k_f·Occupied/Known``.
  """

  expectation: jax.Array
  info: jax.Array
  free: jax.Array
  occupied: jax.Array
  factor: jax.Array


def neighbourhoods(view: base.BeliefView, cluster_ids, num_clusters: int, radius_cells,
                   k_f) -> Neighbourhoods:
  """Algorithm 1 for every cluster at once: Eq 4's expectation, Eq 9's I and Eq 5's f.

  Args:
    view: the belief (``unknown``, ``free``, ``occupied`` masks).
    cluster_ids: i32[H, W] cluster index of frontier cells, -1 elsewhere.
    num_clusters: static number of cluster slots K.
    radius_cells: D in cells (traced).
    k_f: the obstacle weight of Eq 5 (traced).
  """
  distance, nearest = labels.nearest_label_manhattan(cluster_ids, num_clusters)
  radius_cells = jnp.maximum(radius_cells, 1e-6)
  # Slack for D / res landing a rounding error below a whole number of cells.
  within = (nearest >= 0) & (distance.astype(jnp.float32) <= radius_cells + 1e-4)
  expectation = expected_occupancy(distance, radius_cells)
  expected_unknown = within & view.unknown
  segment = jnp.where(within, nearest, num_clusters).ravel()

  def per_cluster(values):
    return jax.ops.segment_sum(values.ravel(), segment,
                               num_segments=num_clusters + 1)[:num_clusters]

  info = per_cluster(jnp.where(expected_unknown, entropy_bits(expectation), 0.0))
  free = per_cluster((within & view.free).astype(jnp.int32))
  occupied = per_cluster((within & view.occupied).astype(jnp.int32))
  known = jnp.maximum(free + occupied, 1).astype(jnp.float32)
  factor = 1.0 - k_f * occupied.astype(jnp.float32) / known
  return Neighbourhoods(expectation=jnp.where(expected_unknown, expectation, jnp.nan), info=info,
                        free=free, occupied=occupied, factor=factor)


def _plan_lowest_cost(config, view, robot, dist, pred, candidates: Candidates, cost) -> base.Plan:
  """The plan to the candidate of lowest ``cost`` (f32[K]); no plan without a valid candidate."""
  score = jnp.where(candidates.valid, cost, jnp.inf)
  best = jnp.argmin(score)
  valid = jnp.isfinite(score[best])
  goal = candidates.goal[best]
  cells, length, _ = plan_to(config, view, robot, pred, goal, valid)
  look_at = unknown_neighbour(candidates.look_at[best], view.unknown, view.occupied)
  return base.Plan(waypoints=cells, length=length, goal=goal, look_at=look_at, valid=valid,
                   gain=jnp.where(valid, -score[best], 0.0).astype(jnp.float32),
                   cost=jnp.where(valid, dist[goal[0], goal[1]], jnp.inf).astype(jnp.float32),
                   n_candidates=jnp.sum(candidates.valid).astype(jnp.int32))


def _distance(candidates: Candidates, dist, w):
  """Eq 3's d per candidate, m: the Dijkstra path cost (``d_path`` = 1), else the Euclidean
  distance to the candidate goal or (``d_nearest`` = 1) to the cluster's nearest cell."""
  path = dist[candidates.goal[:, 0], candidates.goal[:, 1]]
  euclidean = jnp.where(w["d_nearest"] > 0.5, candidates.nearest, candidates.distance)
  return jnp.where(w["d_path"] > 0.5, path, euclidean)


def _paths(config, view, robot):
  node_cost = jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32)
  return reachable_paths(config, view, robot, node_cost)


def plan_frt(config, view: base.BeliefView, robot: base.RobotView, params, key) -> base.Plan:
  """Frontier utility, Godoy-Calvo Eq 12: ``U' = C_d·d − C_i·A``, lowest wins.

  ``d``: Euclidean distance robot → candidate (m), or the path cost with ``d_path = 1``;
  ``A``: frontier cells in the cluster.
  Returns a plan with ``gain = −U'``.
  """
  w = _weights(params, FRT_DEFAULTS)
  dist, pred = _paths(config, view, robot)
  candidates = frontier_candidates(config, view, robot, dist, w["min_frontier_size"])
  d = _distance(candidates, dist, w)
  cost = w["C_d"] * d - w["C_i"] * candidates.clusters.size.astype(jnp.float32)
  return _plan_lowest_cost(config, view, robot, dist, pred, candidates, cost)


FRT = base.planner("frt", plan_frt, defaults=FrtWeights,
                   summary="Godoy-Calvo Eq 12: frontier cluster of lowest C_d·d − C_i·size")


def plan_ig(config, view: base.BeliefView, robot: base.RobotView, params, key) -> base.Plan:
  """Dynamic entropy frontiers, Godoy-Calvo Eq 3: ``U = C_d·d − C_i·f·I``, lowest wins.

  ``I`` from Eq 4 and 9, ``f`` from Eq 5, both by Algorithm 1 (nearest-cluster assignment of
  cells, see the module docstring); ``d`` as in :func:`plan_frt`. Returns ``gain = −U``.
  """
  w = _weights(params, IG_DEFAULTS)
  dist, pred = _paths(config, view, robot)
  candidates = frontier_candidates(config, view, robot, dist, w["min_frontier_size"])
  clusters = candidates.clusters
  # Clusters dropped by min_frontier_size claim no cells (the authors' code drops them first).
  kept = clusters.size.astype(jnp.float32) * config.res >= w["min_frontier_size"] - 1e-6
  ids = jnp.where((clusters.ids >= 0) & kept[jnp.clip(clusters.ids, 0, MAX_CLUSTERS - 1)],
                  clusters.ids, -1)
  hood = neighbourhoods(view, ids, MAX_CLUSTERS, w["D"] / config.res, w["k_f"])
  d = _distance(candidates, dist, w)
  cost = w["C_d"] * d - w["C_i"] * hood.factor * hood.info
  return _plan_lowest_cost(config, view, robot, dist, pred, candidates, cost)


IG = base.planner("ig", plan_ig, defaults=IgWeights,
                  summary="Godoy-Calvo Eq 3: frontier cluster of lowest C_d·d − C_i·f·I "
                          "(expected entropy)")
