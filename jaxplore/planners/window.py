"""Planning on a window around the robot, certified as the whole grid's answer.

A planner that picks the candidate with the smallest path cost over unit node costs (each step
costing at least its length in metres: nearest frontier, FD) registers ``windowed=True``; the
engine then plans it first on a square window of the belief around the robot. Cells within
:func:`jaxplore.config.window_margin` of an edge of the window that is not an edge of the grid
may see belief masks (inflation, frontier tests) that differ from the whole grid's, so they are
blocked (:func:`restrict`). Every path from the robot out of the remaining cells costs at least
``edge`` cells (the Chebyshev distance to the first blocked cell); a plan that costs less is
therefore the whole grid's nearest candidate, with a shortest path: it is *certified*
(:func:`certified`). Otherwise (or when the window holds no candidate) the engine plans again on
the whole grid. Planning work then follows the distance to the nearest candidate, not the size
of the map.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplore.planners.base import BeliefView, Plan


def restrict(view: BeliefView, cell, origin, grid_shape: tuple[int, int], margin: int):
  """Blocks the cells near the window's inner edges.

  Args:
    view: the belief view of the window (its masks computed on the window alone).
    cell: i32[2] the robot's cell in window coordinates.
    origin: i32[2] the window's top-left cell in the grid.
    grid_shape: (H, W) of the whole grid.
    margin: cells along an inner edge whose masks may differ from the whole grid's.
  Returns:
    (view with those cells neither free, traversable nor frontier; ``edge``: i32, the Chebyshev
    distance in cells from the robot to the nearest blocked cell, large when none).
  """
  rows, cols = view.free.shape
  r = jnp.arange(rows)[:, None]
  c = jnp.arange(cols)[None, :]
  inner = (origin[0] > 0, origin[0] + rows < grid_shape[0],
           origin[1] > 0, origin[1] + cols < grid_shape[1])
  blocked = ((inner[0] & (r < margin)) | (inner[1] & (r >= rows - margin)) |
             (inner[2] & (c < margin)) | (inner[3] & (c >= cols - margin)))
  view = view.replace(free=view.free & ~blocked, traversable=view.traversable & ~blocked,
                      frontier=view.frontier & ~blocked)
  far = jnp.int32(grid_shape[0] + grid_shape[1])
  edge = jnp.min(jnp.stack([
      jnp.where(inner[0], cell[0] - (margin - 1), far),
      jnp.where(inner[1], rows - margin - cell[0], far),
      jnp.where(inner[2], cell[1] - (margin - 1), far),
      jnp.where(inner[3], cols - margin - cell[1], far)]))
  return view, edge


def certified(plan: Plan, edge, res: float):
  """Whether a window's plan is the whole grid's: valid and cheaper than leaving the window."""
  return plan.valid & (plan.cost < edge.astype(jnp.float32) * res)


def to_grid(plan: Plan, origin) -> Plan:
  """A window's plan in grid coordinates (negative cells, unused waypoints, stay as they are)."""
  shift = lambda cells: jnp.where(cells >= 0, cells + origin[None, :], cells)
  return plan.replace(waypoints=shift(plan.waypoints), goal=plan.goal + origin,
                      look_at=plan.look_at + origin)
