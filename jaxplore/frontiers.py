"""Frontier machinery the engine offers every planner, whichever paper it comes from.

* :func:`reachable_paths`: one shortest-path solve from the robot over the believed-traversable
  cells, extended into the free cells within the robot radius of a wall (reached by looking
  from the nearest traversable cell, :func:`jaxplore.graph.extend.extend_into`).
* :func:`plan_to`: the waypoints from the robot to a goal along those paths.
* :func:`unknown_neighbour`: the unknown cell a robot arriving at a frontier goal faces.
* :func:`cluster_goals`: a goal per group of frontier cells (:func:`jaxplore.graph.labels.
  clusters`), as explore_lite picks them: the centroid if the robot can stand there, else the
  group's reachable cell nearest the centroid.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp

from jaxplore.graph import labels
from jaxplore.graph.dijkstra import extract_path
from jaxplore.graph.extend import extend_into

if TYPE_CHECKING:  # the planner contract's types (jaxplore.planners imports this module)
  from jaxplore.planners.base import BeliefView, RobotView
from jaxplore import mapping


def reachable_paths(config, view: BeliefView, robot: RobotView, node_cost):
  """One Dijkstra from the robot over traversable cells, extended into the other free cells.

  Returns (dist in metres f32[H, W], pred i32[H, W]).
  """
  sp = config.shortest_paths(node_cost, robot.cell)
  dist, pred = extend_into(sp.dist, sp.pred, view.free & ~view.traversable,
                           config.max_inflation_cells + 1)
  return dist * config.res, pred


def plan_to(config, view: BeliefView, robot: RobotView, pred, goal, valid):
  """Waypoints from the robot to ``goal``, cut before the first non-traversable cell."""
  cells, length = extract_path(pred, goal, config.path_capacity, source=robot.cell)
  on_free_ground = view.traversable[cells[:, 0], cells[:, 1]]
  index = jnp.arange(config.path_capacity)
  blocked_at = jnp.min(jnp.where((index >= 1) & ~on_free_ground, index, config.path_capacity))
  length = jnp.where(valid, jnp.minimum(length, blocked_at), 0)
  look_at = unknown_neighbour(goal, view.unknown, view.occupied)
  return cells, length.astype(jnp.int32), look_at


class Candidates(NamedTuple):
  """One candidate goal per frontier cluster.

  Attributes:
    clusters: the frontier clusters (:class:`jaxplore.graph.labels.Clusters`, K slots).
    goal: i32[K, 2] the cell to drive to (centroid or nearest reachable cluster cell).
    look_at: i32[K, 2] the cluster cell nearest to the centroid that the robot can reach (or
      the goal), whose unknown neighbour the robot faces on arrival.
    valid: bool[K] the cluster has a candidate goal (and is at least ``min_frontier_size`` long).
    distance: f32[K] Euclidean distance robot → goal, m.
    nearest: f32[K] Euclidean distance robot → the cluster's nearest cell, m.
  """

  clusters: labels.Clusters
  goal: jax.Array
  look_at: jax.Array
  valid: jax.Array
  distance: jax.Array
  nearest: jax.Array


def cluster_goals(config, view: BeliefView, robot: RobotView, dist,
                  found: labels.Clusters, min_frontier_size=0.0) -> Candidates:
  """Each group of frontier cells' goal: its centroid cell if the robot can stand there, else its
  cell nearest the centroid that the Dijkstra reaches and the blacklist allows; groups shorter
  than ``min_frontier_size`` metres (cells x res) are no candidates."""
  height, width = view.frontier.shape
  slots = found.size.shape[0]
  reachable = jnp.isfinite(dist) & ~view.blacklist

  centroid_cell = jnp.clip(jnp.round(found.centroid).astype(jnp.int32), 0,
                           jnp.array([[height - 1, width - 1]], jnp.int32))
  centroid_ok = (view.traversable & reachable)[centroid_cell[:, 0], centroid_cell[:, 1]]

  eligible = (found.ids >= 0) & reachable
  nearest_flat = labels.nearest_to_centroid(found, eligible)
  has_eligible = nearest_flat < height * width
  nearest_cell = jnp.stack([nearest_flat // width, nearest_flat % width], axis=-1).astype(jnp.int32)

  goal = jnp.where(centroid_ok[:, None], centroid_cell, nearest_cell)
  look_at = jnp.where(has_eligible[:, None], nearest_cell, goal)
  long_enough = found.size.astype(jnp.float32) * config.res >= min_frontier_size - 1e-6
  valid = found.valid & (centroid_ok | has_eligible) & long_enough
  offset = (goal - robot.cell[None, :]).astype(jnp.float32)
  distance = jnp.sqrt(jnp.sum(offset * offset, axis=-1)) * config.res
  # The authors' code measures d to the frontier's cell nearest to the robot (any of its cells).
  rows = jax.lax.broadcasted_iota(jnp.int32, (height, width), 0)
  cols = jax.lax.broadcasted_iota(jnp.int32, (height, width), 1)
  to_robot = ((rows - robot.cell[0]) ** 2 + (cols - robot.cell[1]) ** 2).astype(jnp.float32)
  member = jnp.where(found.ids >= 0, found.ids, slots).ravel()
  nearest = jnp.sqrt(jax.ops.segment_min(to_robot.ravel(), member, num_segments=slots + 1)[:slots])
  return Candidates(clusters=found, goal=goal, look_at=look_at, valid=valid, distance=distance,
                    nearest=jnp.where(found.valid, nearest, jnp.inf) * config.res)


def unknown_neighbour(cell, unknown, occupied):
  """The first 8-neighbour of ``cell`` (in ``mapping.NEIGHBOURS_8`` order) inside the grid that is
  unknown and not sealed off by two occupied cells, else ``cell``.

  Used as a look-at point: facing it lets a narrow field of view observe what made ``cell`` a
  frontier.
  """
  h, w = unknown.shape
  inside = (cell[0] >= 0) & (cell[0] < h) & (cell[1] >= 0) & (cell[1] < w)
  # The 3 x 3 cells around ``cell``, outside the grid not unknown and occupied. (Indexing the
  # grids cell by cell wrapped a neighbour at row or column -1 round to the far border.)
  patch = lambda grid, fill: jax.lax.dynamic_slice(
      jnp.pad(grid, 1, constant_values=fill), (cell[0], cell[1]), (3, 3))
  unknown, occupied = patch(unknown, False), patch(occupied, True)
  ok = []
  for di, dj in mapping.NEIGHBOURS_8:
    open_ = unknown[1 + di, 1 + dj]
    if di != 0 and dj != 0:
      open_ = open_ & ~(occupied[1 + di, 1] & occupied[1, 1 + dj])
    ok.append(open_)
  ok = jnp.stack(ok) & inside
  step = jnp.asarray(mapping.NEIGHBOURS_8, jnp.int32)[jnp.argmax(ok)]
  return jnp.where(jnp.any(ok), cell + step, cell).astype(cell.dtype)
