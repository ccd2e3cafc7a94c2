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
from jaxplore.frontiers import plan_to, reachable_paths
from jaxplore.planners import base


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


NEAREST_FRONTIER = base.planner(
    "nearest_frontier", plan_nearest_frontier, windowed=True,
    summary="go to the frontier cell with the smallest path cost")


def plan_fd(config, view: base.BeliefView, robot: base.RobotView, params, key) -> base.Plan:
  """Nearest frontier that never returns to a reached frontier goal (Ahmed et al.'s FD).

  The planning is :func:`plan_nearest_frontier`'s (it already skips blacklisted and unreachable
  frontier cells); the registration asks the engine to blacklist the goal once the robot has
  reached the end of its path.
  """
  return plan_nearest_frontier(config, view, robot, params, key)


FD = base.planner(
    "fd", plan_fd, blacklist_on_arrival=True, windowed=True,
    summary="nearest frontier, each frontier goal blacklisted once reached (Ahmed's FD)")
