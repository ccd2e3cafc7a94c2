"""The ground-truth world: a host-side occupancy grid with its metric frame.

Convention used everywhere in jaxplore: ``occupied[i, j]`` is the cell whose lower-left corner
is at ``(origin[0] + j * res, origin[1] + i * res)`` in metres, i.e. row ``i`` grows with ``y``
(the *opposite* of image rows: ``map_server`` images have row 0 at the top, so loaders flip).
"""

from __future__ import annotations

import dataclasses

import numpy as np


class MapError(ValueError):
  """A map file or grid that cannot be used, with a message naming the problem."""


@dataclasses.dataclass(frozen=True, eq=False)
class GridMap:
  """A ground-truth occupancy grid.

  Attributes:
    occupied: bool[H, W]; True = occupied (unknown pixels of a loaded map count as occupied).
    res: metres per cell.
    origin: (x, y) in metres of the lower-left corner of cell (0, 0).
    name: a label for tables and figures.
  """

  occupied: np.ndarray
  res: float
  origin: tuple[float, float] = (0.0, 0.0)
  name: str = "map"

  def __post_init__(self):
    occ = np.asarray(self.occupied)
    if occ.ndim != 2 or occ.shape[0] < 3 or occ.shape[1] < 3:
      raise MapError(f"map {self.name!r}: occupancy grid must be 2-D and at least 3x3, got shape "
                     f"{occ.shape}")
    if not (np.isfinite(self.res) and self.res > 0):
      raise MapError(f"map {self.name!r}: resolution must be a positive number of metres, got "
                     f"{self.res!r}")
    object.__setattr__(self, "occupied", occ.astype(bool))
    object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))
    object.__setattr__(self, "res", float(self.res))

  @property
  def shape(self) -> tuple[int, int]:
    return self.occupied.shape

  @property
  def free(self) -> np.ndarray:
    return ~self.occupied

  @property
  def free_area(self) -> float:
    """Free area in m²."""
    return float(self.free.sum()) * self.res**2

  @property
  def extent_m(self) -> tuple[float, float]:
    """(width, height) of the grid in metres."""
    h, w = self.shape
    return w * self.res, h * self.res

  def world_to_cell(self, x, y):
    """Metres -> integer (row, col); may fall outside the grid."""
    i = np.floor((np.asarray(y) - self.origin[1]) / self.res).astype(np.int64)
    j = np.floor((np.asarray(x) - self.origin[0]) / self.res).astype(np.int64)
    return i, j

  def cell_to_world(self, i, j):
    """Integer (row, col) -> metres of the cell centre."""
    x = self.origin[0] + (np.asarray(j) + 0.5) * self.res
    y = self.origin[1] + (np.asarray(i) + 0.5) * self.res
    return x, y
