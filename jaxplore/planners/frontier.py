"""Nearest frontier (Yamauchi 1997; Li et al. 2020's "Method 11") and FD (Ahmed et al.).

Frontier = belief-free cell with an unknown 8-neighbour (:func:`jaxplore.mapping.frontier`); the
robot goes to the frontier cell with the smallest path cost over the 8-connected traversable
graph (one Dijkstra from the robot). Frontier cells within the robot radius of a wall are
reached by looking from the nearest traversable cell (:func:`jaxplore.graph.extend.extend_into`).
``fd`` is the same planner with every frontier goal blacklisted once reached (Ahmed et al.'s
"FD"). Both pick the candidate of smallest unit-cost path, so the engine may plan them on a
window around the robot first (``windowed``; :mod:`jaxplore.planners.window`).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplore import reductions
from jaxplore.graph.dijkstra import extract_path, shortest_paths
from jaxplore.graph.extend import extend_into
from jaxplore.planners import base


def reachable_paths(config, view: base.BeliefView, robot: base.RobotView, node_cost):
  """One Dijkstra from the robot over traversable cells, extended into the other free cells.

  Returns (dist in metres f32[H, W], pred i32[H, W]).
  """
  sp = shortest_paths(node_cost, robot.cell, max_sweeps=config.dijkstra_max_sweeps,
                      tiles_after_rounds=config.dijkstra_tiles_after_rounds)
  dist, pred = extend_into(sp.dist, sp.pred, view.free & ~view.traversable,
                           config.max_inflation_cells + 1)
  return dist * config.res, pred


def plan_to(config, view: base.BeliefView, robot: base.RobotView, pred, goal, valid):
  """Waypoints from the robot to ``goal``, cut before the first non-traversable cell."""
  cells, length = extract_path(pred, goal, config.path_capacity, source=robot.cell)
  on_free_ground = view.traversable[cells[:, 0], cells[:, 1]]
  index = jnp.arange(config.path_capacity)
  blocked_at = jnp.min(jnp.where((index >= 1) & ~on_free_ground, index, config.path_capacity))
  length = jnp.where(valid, jnp.minimum(length, blocked_at), 0)
  look_at = base.unknown_neighbour(goal, view.unknown, view.occupied)
  return cells, length.astype(jnp.int32), look_at


@base.register("nearest_frontier", summary="go to the frontier cell with the smallest path cost",
               windowed=True)
def plan_nearest_frontier(config, view: base.BeliefView, robot: base.RobotView, params, key):
  node_cost = jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32)
  dist, pred = reachable_paths(config, view, robot, node_cost)
  candidates = view.frontier & ~view.blacklist & jnp.isfinite(dist)
  score = jnp.where(candidates, dist, jnp.inf)
  flat = reductions.argmin(score)
  goal = jnp.stack([flat // config.width, flat % config.width]).astype(jnp.int32)
  cost = score.ravel()[flat]
  valid = jnp.isfinite(cost)
  cells, length, look_at = plan_to(config, view, robot, pred, goal, valid)
  return base.Plan(waypoints=cells, length=length, goal=goal, look_at=look_at, valid=valid,
                   gain=jnp.float32(0), cost=cost,
                   n_candidates=jnp.sum(candidates).astype(jnp.int32))


@base.register("fd",
               summary="nearest frontier, each frontier goal blacklisted once reached (Ahmed's FD)",
               blacklist_on_arrival=True, windowed=True)
def plan_fd(config, view: base.BeliefView, robot: base.RobotView, params, key) -> base.Plan:
  """Nearest frontier that never returns to a reached frontier goal (Ahmed et al.'s FD).

  The planning is :func:`plan_nearest_frontier`'s (it already skips blacklisted and unreachable
  frontier cells); the registration asks the engine to blacklist the goal once the robot has
  reached the end of its path.
  """
  return plan_nearest_frontier(config, view, robot, params, key)
