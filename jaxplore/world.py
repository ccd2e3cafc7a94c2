"""The world a batch of robots explores: the ground truth and where robots may start (host side).

:func:`make_world` turns a :class:`~jaxplore.maps.grid.GridMap` into the device-side
:class:`World` shared by every robot of a batch (passed with ``in_axes=None``, never copied per
robot), after checking a given start; the coordinate helpers convert between metres and cells.
Cells are (row, col); row 0 holds the lowest y.
"""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from jaxplore import pytrees, sensor
from jaxplore.config import ConfigError
from jaxplore.maps.grid import GridMap


@pytrees.dataclass(frozen=True)
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
  # Cells, centre to the nearest occupied centre; outside the map counts as occupied.
  clearance = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1]
  radius = r_robot / grid.res
  if start_xy is not None:
    i, j = grid.world_to_cell(start_xy[0], start_xy[1])
    h, w = grid.shape
    if not (0 <= i < h and 0 <= j < w):
      raise ConfigError(f"start {tuple(start_xy)} m is outside the map {grid.name!r} "
                        f"(x in [{grid.origin[0]}, {grid.origin[0] + w * grid.res}], "
                        f"y in [{grid.origin[1]}, {grid.origin[1] + h * grid.res}])")
    if grid.occupied[i, j]:
      raise ConfigError(f"start {tuple(start_xy)} m is inside a wall of map {grid.name!r} "
                        f"(cell {i}, {j})")
    nearest = start_clearance(grid, start_xy, r_robot)
    if nearest < r_robot:
      raise ConfigError(f"start {tuple(start_xy)} m is {nearest:.3f} m from the centre of an "
                        f"occupied cell (outside the map counts as occupied), closer than the "
                        f"robot radius {r_robot:g} m: its disc would touch it")
    reachable = labels == labels[i, j]
  else:
    sizes = ndimage.sum_labels(free, labels, index=np.arange(1, count + 1))
    reachable = labels == (1 + int(np.argmax(sizes)))
  start_ok = reachable & (clearance > radius)
  if not start_ok.any():
    raise ConfigError(f"map {grid.name!r}: no free cell has clearance above the robot radius "
                      f"{r_robot} m")
  # Where the disc's centre can go: the 8-connected component of the cells it fits in, the
  # start's (random starts: the largest, so that no robot starts in a closet it cannot leave).
  fits, n_fits = ndimage.label(start_ok, structure=np.ones((3, 3), bool))
  start_label = fits[i, j] if start_xy is not None else 0
  if start_label == 0:
    start_label = 1 + int(np.argmax(ndimage.sum_labels(start_ok, fits, np.arange(1, n_fits + 1))))
  centres = fits == start_label
  if start_xy is None:
    start_ok = centres
  # Coverage counts the free cells the robot can come up to: within sqrt(2) (radius + 1) cells
  # of a place its centre reaches (the corners of a room included), not a room behind a gap
  # narrower than its disc, which it could never complete.
  reachable = reachable & (ndimage.distance_transform_edt(~centres) <= math.sqrt(2) * (radius + 1))
  return World(occupied=jnp.asarray(grid.occupied),
               truth_framed=sensor.frame_truth(jnp.asarray(grid.occupied)),
               reachable=jnp.asarray(reachable),
               start_ok=jnp.asarray(start_ok), n_reachable=jnp.float32(reachable.sum()),
               origin=jnp.asarray(grid.origin, jnp.float32))


def start_clearance(grid: GridMap, xy, r_robot: float) -> float:
  """Metres from the point ``xy`` to the nearest occupied cell centre within ``r_robot`` (and a
  cell), outside the map counting as occupied: the test the motion model's disc collision makes
  (:func:`jaxplore.robot.touched_cells`), the same on every edge and wall. ``inf`` when none is
  that close."""
  i, j = grid.world_to_cell(xy[0], xy[1])
  k = int(np.ceil(r_robot / grid.res)) + 1
  rows, cols = np.meshgrid(np.arange(i - k, i + k + 1), np.arange(j - k, j + k + 1), indexing="ij")
  h, w = grid.shape
  inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
  occupied = np.ones(rows.shape, bool)
  occupied[inside] = grid.occupied[rows[inside], cols[inside]]
  x, y = grid.cell_to_world(rows, cols)
  distance = np.hypot(x - xy[0], y - xy[1])
  return float(distance[occupied].min()) if occupied.any() else float("inf")


def to_cells(xy, origin, res):
  """Metres -> continuous cell coordinates (row, col)."""
  return jnp.stack([(xy[1] - origin[1]) / res, (xy[0] - origin[0]) / res])


def cell_of(xy, origin, res):
  return jnp.floor(to_cells(xy, origin, res)).astype(jnp.int32)


def cell_centre(cell, origin, res):
  """Integer (row, col) -> metres (x, y) of the centre."""
  return jnp.stack([origin[0] + (cell[1] + 0.5) * res, origin[1] + (cell[0] + 0.5) * res])


def sample_start(world: World, key):
  """A pose drawn uniformly over ``world.start_ok`` cells (centre) with a uniform heading."""
  k_cell, k_theta = jax.random.split(key)
  h, w = world.occupied.shape
  logits = jnp.where(world.start_ok.ravel(), 0.0, -jnp.inf)
  flat = jax.random.categorical(k_cell, logits)
  cell = jnp.stack([flat // w, flat % w])
  theta = jax.random.uniform(k_theta, (), minval=-jnp.pi, maxval=jnp.pi)
  return cell, theta
