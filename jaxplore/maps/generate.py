"""Seeded procedural worlds: offices, mazes, open areas with clutter, caves, campuses.

Every generator is pure NumPy, deterministic for a given seed (``np.random.default_rng(seed)``),
and returns a `GridMap` of ``round(width_m / res) x round(height_m / res)`` cells with origin
(0, 0), an occupied border at least one cell thick, and free space that is a single 4-connected
component (smaller components are filled). Passages (doors, corridors, gaps) are at least about
1 m wide, so a robot of radius 0.2 m passes with room to spare.

The random layout is drawn in metres, so the same seed gives the same world at any resolution
(for `maze`, whenever ``corridor_m`` and ``wall_m`` are multiples of ``res``); only the
rasterisation changes. `floor_plan` rasterises a hand-drawn layout of free boxes the same way.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage

from jaxplore.maps.grid import GridMap, MapError

# Rock pieces smaller than this (m²) are interpolation artefacts in `cave`.
_MIN_ROCK_M2 = 0.1

# Offsets of the 4 lattice neighbours (row, col), in the order the maze shuffles.
_LATTICE_STEPS = ((1, 0), (-1, 0), (0, 1), (0, -1))


def office(
    width_m: float,
    height_m: float,
    res: float = 0.1,
    seed: int = 0,
    *,
    corridor_m: float = 2.0,
    door_m: float = 1.2,
    wall_m: float = 0.2,
    room_min_m: float = 3.0,
    room_max_m: float = 7.0,
    corridor_spacing_m: float = 24.0,
    extra_door_prob: float = 0.15,
    name: str = "office",
) -> GridMap:
  """Rooms and corridors with doors, every room reachable.

  The floor is cut recursively (binary space partition). A block longer than
  ``corridor_spacing_m`` is crossed by a corridor near its middle, perpendicular to its long
  side; smaller blocks are split by walls into rooms of ``room_min_m`` to ``room_max_m``
  (free size). Corridors meet in open junctions; every room touching a corridor gets a door to
  it; further doors between neighbouring rooms connect the rest (a random spanning tree, plus
  a door with probability ``extra_door_prob`` where the tree needs none, which adds loops).

  Args:
    width_m: extent along x, metres.
    height_m: extent along y, metres.
    res: metres per cell.
    seed: random seed.
    corridor_m: free width of corridors.
    door_m: door width (>= 1.0 m recommended).
    wall_m: wall thickness; at least one cell.
    room_min_m: smallest free room side.
    room_max_m: a block longer than this (free size) is split further.
    corridor_spacing_m: blocks longer than this get a corridor.
    extra_door_prob: chance of a door between neighbouring rooms already connected.
    name: label of the returned grid.

  Returns:
    The office as a `GridMap`.

  Raises:
    MapError: invalid sizes.
  """
  _check_size(width_m, height_m, res, minimum_m=room_min_m + 2 * wall_m)
  if not 0 < room_min_m <= room_max_m:
    raise MapError(f"office: need 0 < room_min_m <= room_max_m, got {room_min_m}, {room_max_m}")
  if door_m > room_min_m:
    raise MapError(f"office: door_m ({door_m}) must not exceed room_min_m ({room_min_m})")
  occupied = _office_layout(
      width_m, height_m, res, seed, corridor_m=corridor_m, door_m=door_m, wall_m=wall_m,
      room_min_m=room_min_m, room_max_m=room_max_m, corridor_spacing_m=corridor_spacing_m,
      extra_door_prob=extra_door_prob)
  return _finalize(occupied, res, name)


def maze(
    width_m: float,
    height_m: float,
    res: float = 0.1,
    seed: int = 0,
    corridor_m: float = 1.2,
    *,
    wall_m: float = 0.2,
    name: str = "maze",
) -> GridMap:
  """A perfect maze (one path between any two places), by recursive backtracking.

  The maze is carved on a lattice of square cells ``corridor_m`` wide separated by walls
  ``wall_m`` thick (both rounded to whole grid cells, at least one). Lattice cells that do not
  fit in the extent stay occupied.

  Args:
    width_m: extent along x, metres.
    height_m: extent along y, metres.
    res: metres per cell.
    seed: random seed.
    corridor_m: corridor width.
    wall_m: wall thickness.
    name: label of the returned grid.

  Returns:
    The maze as a `GridMap`.

  Raises:
    MapError: invalid sizes, or not even one corridor cell fits.
  """
  n_rows, n_cols = _check_size(width_m, height_m, res, minimum_m=corridor_m + 2 * wall_m)
  corridor_cells = max(1, round(corridor_m / res))
  wall_cells = max(1, round(wall_m / res))
  pitch = corridor_cells + wall_cells
  lattice_rows = (n_rows - wall_cells) // pitch
  lattice_cols = (n_cols - wall_cells) // pitch
  if lattice_rows < 1 or lattice_cols < 1:
    raise MapError(f"maze: {width_m} x {height_m} m is too small for {corridor_m} m corridors")
  rng = np.random.default_rng(seed)

  occupied = np.ones((n_rows, n_cols), dtype=bool)

  def carve_cell(a, b):
    top, left = wall_cells + a * pitch, wall_cells + b * pitch
    occupied[top:top + corridor_cells, left:left + corridor_cells] = False

  visited = np.zeros((lattice_rows, lattice_cols), dtype=bool)
  start = (int(rng.integers(lattice_rows)), int(rng.integers(lattice_cols)))
  visited[start] = True
  carve_cell(*start)
  stack = [start]
  while stack:
    a, b = stack[-1]
    unvisited = [
        (a + da, b + db) for da, db in _LATTICE_STEPS
        if 0 <= a + da < lattice_rows and 0 <= b + db < lattice_cols and not visited[a + da, b + db]
    ]
    if not unvisited:
      stack.pop()
      continue
    a2, b2 = unvisited[int(rng.integers(len(unvisited)))]
    # Knock down the wall between the two lattice cells: the span covering both cells.
    top = wall_cells + min(a, a2) * pitch
    left = wall_cells + min(b, b2) * pitch
    bottom = wall_cells + max(a, a2) * pitch + corridor_cells
    right = wall_cells + max(b, b2) * pitch + corridor_cells
    occupied[top:bottom, left:right] = False
    visited[a2, b2] = True
    stack.append((a2, b2))
  return _finalize(occupied, res, name)


def open_clutter(
    width_m: float,
    height_m: float,
    res: float = 0.1,
    seed: int = 0,
    density: float = 0.08,
    *,
    min_size_m: float = 0.3,
    max_size_m: float = 1.5,
    clearance_m: float = 1.0,
    disc_fraction: float = 0.4,
    name: str = "open_clutter",
) -> GridMap:
  """An open area with random rectangular and disc obstacles.

  Obstacles are placed one by one at random; one that would come closer than ``clearance_m``
  to another obstacle or to the outer wall is rejected, so every gap is at least
  ``clearance_m`` wide and the free space stays connected. Placement stops when the obstacles
  cover ``density`` of the area or after a fixed number of attempts.

  Args:
    width_m: extent along x, metres.
    height_m: extent along y, metres.
    res: metres per cell.
    seed: random seed.
    density: target fraction of the area covered by obstacles.
    min_size_m: smallest obstacle side (rectangle) or diameter (disc).
    max_size_m: largest obstacle side or diameter.
    clearance_m: smallest gap between obstacles, and between obstacles and the outer wall.
    disc_fraction: probability that an obstacle is a disc rather than a rectangle.
    name: label of the returned grid.

  Returns:
    The area as a `GridMap`.

  Raises:
    MapError: invalid sizes or density.
  """
  _check_size(width_m, height_m, res, minimum_m=2 * clearance_m + 1.0)
  if not 0 <= density < 1:
    raise MapError(f"open_clutter: density must be in [0, 1), got {density}")
  rng = np.random.default_rng(seed)
  shapes = _scatter_shapes(
      [], rng, width_m, height_m, density=density, min_size_m=min_size_m,
      max_size_m=max_size_m, clearance_m=clearance_m, disc_fraction=disc_fraction)
  occupied = np.zeros(_grid_shape(width_m, height_m, res), dtype=bool)
  for shape in shapes:
    shape.rasterize(occupied, res)
  return _finalize(occupied, res, name)


def campus(
    width_m: float,
    height_m: float,
    res: float = 0.2,
    seed: int = 0,
    *,
    building_density: float = 0.12,
    building_min_m: float = 6.0,
    building_max_m: float = 16.0,
    building_clearance_m: float = 3.0,
    tree_density: float = 0.01,
    name: str = "campus",
) -> GridMap:
  """Open ground with solid building blocks and scattered trees, like an outdoor campus.

  Args:
    width_m: extent along x, metres.
    height_m: extent along y, metres.
    res: metres per cell.
    seed: random seed.
    building_density: target fraction of the area under buildings.
    building_min_m: smallest building side.
    building_max_m: largest building side.
    building_clearance_m: smallest gap between buildings (and to the outer wall).
    tree_density: target fraction of the area under trees (discs 0.4-1.2 m across, 1.2 m
      clear of everything).
    name: label of the returned grid.

  Returns:
    The campus as a `GridMap`.

  Raises:
    MapError: invalid sizes or densities.
  """
  _check_size(width_m, height_m, res, minimum_m=building_max_m + 2 * building_clearance_m)
  if not (0 <= building_density < 1 and 0 <= tree_density < 1):
    raise MapError(f"campus: densities must be in [0, 1), got {building_density}, {tree_density}")
  rng = np.random.default_rng(seed)
  shapes = _scatter_shapes(
      [], rng, width_m, height_m, density=building_density, min_size_m=building_min_m,
      max_size_m=building_max_m, clearance_m=building_clearance_m, disc_fraction=0.0)
  shapes = _scatter_shapes(
      shapes, rng, width_m, height_m, density=tree_density, min_size_m=0.4, max_size_m=1.2,
      clearance_m=1.2, disc_fraction=1.0)
  occupied = np.zeros(_grid_shape(width_m, height_m, res), dtype=bool)
  for shape in shapes:
    shape.rasterize(occupied, res)
  return _finalize(occupied, res, name)


def cave(
    width_m: float,
    height_m: float,
    res: float = 0.1,
    seed: int = 0,
    *,
    fill: float = 0.44,
    iterations: int = 5,
    cell_m: float = 0.4,
    min_passage_m: float = 1.0,
    name: str = "cave",
) -> GridMap:
  """Cellular-automaton caves, keeping only the largest connected cave.

  A lattice of ``cell_m`` squares starts as rock with probability ``fill``; each iteration a
  square becomes rock if at least 5 of the 9 squares around it (itself included; outside is
  rock) are rock. The lattice is smoothed and interpolated onto the grid. Then only the part
  of the cave swept by a disc of diameter ``min_passage_m`` moving through the largest
  connected region it can reach is kept: narrower passages and every other pocket are filled.

  Args:
    width_m: extent along x, metres.
    height_m: extent along y, metres.
    res: metres per cell.
    seed: random seed.
    fill: initial rock probability.
    iterations: automaton steps.
    cell_m: automaton lattice spacing, metres (sets the feature size).
    min_passage_m: narrowest passage kept.
    name: label of the returned grid.

  Returns:
    The cave as a `GridMap`.

  Raises:
    MapError: invalid sizes, or no passage of ``min_passage_m`` survives.
  """
  n_rows, n_cols = _check_size(width_m, height_m, res, minimum_m=4 * cell_m)
  rng = np.random.default_rng(seed)
  lattice_rows = math.ceil(height_m / cell_m)
  lattice_cols = math.ceil(width_m / cell_m)
  rock = rng.random((lattice_rows, lattice_cols)) < fill
  rock[[0, -1], :] = True
  rock[:, [0, -1]] = True
  kernel = np.ones((3, 3), dtype=np.int32)
  for _ in range(iterations):
    rock_count = ndimage.convolve(rock.astype(np.int32), kernel, mode="constant", cval=1)
    rock = rock_count >= 5
  field = ndimage.gaussian_filter(rock.astype(np.float64), sigma=0.6, mode="constant", cval=1.0)
  # Sample the lattice field at every grid-cell centre (lattice coordinates of those centres).
  rows = (np.arange(n_rows) + 0.5) * res / cell_m - 0.5
  cols = (np.arange(n_cols) + 0.5) * res / cell_m - 0.5
  row_grid, col_grid = np.meshgrid(rows, cols, indexing="ij")
  occupied = ndimage.map_coordinates(field, [row_grid, col_grid], order=1, mode="nearest") > 0.5
  occupied[[0, -1], :] = True
  occupied[:, [0, -1]] = True
  # Interpolation leaves a few rock slivers a cell or two wide in open space; clear them.
  rock_labels, _ = ndimage.label(occupied)
  rock_sizes = np.bincount(rock_labels.ravel())
  occupied &= (rock_sizes >= _MIN_ROCK_M2 / res**2)[rock_labels]

  disc = _disc(min_passage_m / 2 / res)
  disc_centres = ndimage.binary_erosion(~occupied, structure=disc, border_value=0)
  if not disc_centres.any():
    raise MapError(f"cave: no passage {min_passage_m} m wide survived (seed {seed})")
  disc_centres = _largest_component_mask(disc_centres)
  swept = ndimage.binary_dilation(disc_centres, structure=disc)
  return _finalize(occupied | ~swept, res, name)


def floor_plan(
    width_m: float,
    height_m: float,
    res: float,
    free_boxes: list[tuple[float, float, float, float]],
    *,
    name: str = "floor_plan",
) -> GridMap:
  """A hand-drawn world: solid everywhere except the given free boxes.

  Args:
    width_m: extent along x, metres.
    height_m: extent along y, metres.
    res: metres per cell.
    free_boxes: ``(x0, y0, x1, y1)`` in metres; cells ``[round(x0 / res), round(x1 / res))``
      (and the same for y) become free. Rooms, corridors and door openings are all boxes.
    name: label of the returned grid.

  Returns:
    The world as a `GridMap` (largest free component only, 1-cell border).

  Raises:
    MapError: invalid sizes or no free cell.
  """
  n_rows, n_cols = _check_size(width_m, height_m, res, minimum_m=3 * res)
  occupied = np.ones((n_rows, n_cols), dtype=bool)
  for x0, y0, x1, y1 in free_boxes:
    r0, r1 = _to_cell(y0, res), _to_cell(y1, res)
    c0, c1 = _to_cell(x0, res), _to_cell(x1, res)
    occupied[max(r0, 0):r1, max(c0, 0):c1] = False
  return _finalize(occupied, res, name)


# --- Layout helpers -------------------------------------------------------------------------


def _office_layout(width_m, height_m, res, seed, *, corridor_m, door_m, wall_m, room_min_m,
                   room_max_m, corridor_spacing_m, extra_door_prob) -> np.ndarray:
  """The office's occupancy before `_finalize` (tests check that no room is left unconnected)."""
  rng = np.random.default_rng(seed)
  rooms = _partition_floor(
      _Rect(0.0, 0.0, float(width_m), float(height_m)), rng,
      corridor_m=corridor_m, wall_m=wall_m, room_min_m=room_min_m, room_max_m=room_max_m,
      corridor_spacing_m=corridor_spacing_m)
  raster = _Raster(width_m, height_m, res, wall_m)
  for rect in rooms:
    raster.carve_interior(rect)
  _connect_rooms(rooms, raster, rng, door_m=door_m, wall_m=wall_m, extra_door_prob=extra_door_prob)
  return raster.occupied


@dataclasses.dataclass(frozen=True)
class _Rect:
  """An axis-aligned rectangle in metres; ``is_corridor`` marks corridor strips."""

  x0: float
  y0: float
  x1: float
  y1: float
  is_corridor: bool = False

  @property
  def size(self) -> tuple[float, float]:
    return self.x1 - self.x0, self.y1 - self.y0


def _snap(x: float) -> float:
  """Rounds a layout coordinate to 0.1 m so walls land on the same cells at 0.1, 0.05, ... m."""
  return round(x * 10.0) / 10.0


def _partition_floor(floor: _Rect, rng, *, corridor_m, wall_m, room_min_m, room_max_m,
                     corridor_spacing_m) -> list[_Rect]:
  """Cuts the floor into rooms and corridors; each rectangle owns its wall on its low sides.

  A rectangle's free size is its size minus ``wall_m`` (the wall on its low-x and low-y sides;
  its high sides are the neighbour's wall or the outer wall), so sizes here include one wall.
  """
  min_part = room_min_m + wall_m
  corridor_part = corridor_m + wall_m
  parts: list[_Rect] = []
  pending = [floor]
  while pending:
    rect = pending.pop()
    width, height = rect.size
    along_x = width >= height
    length = width if along_x else height
    start = rect.x0 if along_x else rect.y0
    if length > corridor_spacing_m and length >= 2 * min_part + corridor_part:
      # The corridor crosses the long side near the middle.
      low = start + max(min_part, 0.35 * length - corridor_part / 2)
      high = start + min(length - min_part - corridor_part, 0.65 * length - corridor_part / 2)
      cut = _snap(rng.uniform(low, high)) if high > low else _snap(low)
      corridor_end = _snap(cut + corridor_part)
      pieces = [(start, cut, False), (cut, corridor_end, True),
                (corridor_end, start + length, False)]
    elif length > room_max_m + wall_m and length >= 2 * min_part:
      cut = _snap(rng.uniform(start + min_part, start + length - min_part))
      # Snapping may have pushed the cut past a limit; keep both parts at least min_part.
      cut = min(max(cut, start + min_part), start + length - min_part)
      pieces = [(start, cut, False), (cut, start + length, False)]
    else:
      parts.append(rect)
      continue
    for lo, hi, is_corridor in pieces:
      if along_x:
        piece = _Rect(lo, rect.y0, hi, rect.y1, is_corridor)
      else:
        piece = _Rect(rect.x0, lo, rect.x1, hi, is_corridor)
      (parts if is_corridor else pending).append(piece)
  # A stable order (by position) so the door draws do not depend on the traversal order.
  return sorted(parts, key=lambda r: (r.y0, r.x0))


class _Raster:
  """Rasterises the metric layout: walls ``wall_cells`` thick on each rectangle's low sides."""

  def __init__(self, width_m, height_m, res, wall_m):
    self.res = res
    self.n_rows, self.n_cols = _grid_shape(width_m, height_m, res)
    self.wall_cells = max(1, round(wall_m / res))
    self.occupied = np.ones((self.n_rows, self.n_cols), dtype=bool)

  def cell(self, metres: float) -> int:
    return _to_cell(metres, self.res)

  def interior_rows(self, y0, y1) -> tuple[int, int]:
    return self.cell(y0) + self.wall_cells, min(self.cell(y1), self.n_rows - self.wall_cells)

  def interior_cols(self, x0, x1) -> tuple[int, int]:
    return self.cell(x0) + self.wall_cells, min(self.cell(x1), self.n_cols - self.wall_cells)

  def carve_interior(self, rect: _Rect):
    r0, r1 = self.interior_rows(rect.y0, rect.y1)
    c0, c1 = self.interior_cols(rect.x0, rect.x1)
    self.occupied[r0:r1, c0:c1] = False

  def open_wall(self, line: float, vertical: bool, lo: float, hi: float, full: bool):
    """Opens the wall on ``line`` (x if vertical, else y) between ``lo`` and ``hi`` metres.

    With ``full``, the whole shared interior span opens (a corridor junction); otherwise the
    cells of ``[lo, hi)``.
    """
    wall_lo = self.cell(line)
    if full:
      span = self.interior_rows(lo, hi) if vertical else self.interior_cols(lo, hi)
    else:
      span = (self.cell(lo), self.cell(hi))
    if vertical:
      self.occupied[span[0]:span[1], wall_lo:wall_lo + self.wall_cells] = False
    else:
      self.occupied[wall_lo:wall_lo + self.wall_cells, span[0]:span[1]] = False


def _shared_wall(a: _Rect, b: _Rect):
  """The wall two rectangles share: (line, vertical, lo, hi) or None if they do not touch."""
  tol = 1e-6
  for low, high in ((a, b), (b, a)):
    if abs(low.x1 - high.x0) < tol:
      lo, hi = max(a.y0, b.y0), min(a.y1, b.y1)
      if hi > lo + tol:
        return high.x0, True, lo, hi
    if abs(low.y1 - high.y0) < tol:
      lo, hi = max(a.x0, b.x0), min(a.x1, b.x1)
      if hi > lo + tol:
        return high.y0, False, lo, hi
  return None


def _connect_rooms(rects, raster, rng, *, door_m, wall_m, extra_door_prob):
  """Cuts doors so that every rectangle is reachable; see `office`."""
  margin = 0.1  # Keep door jambs off the perpendicular walls.
  parent = list(range(len(rects)))

  def root(i):
    while parent[i] != i:
      parent[i] = parent[parent[i]]
      i = parent[i]
    return i

  def join(i, j) -> bool:
    ri, rj = root(i), root(j)
    if ri == rj:
      return False
    parent[ri] = rj
    return True

  def cut_door(wall):
    line, vertical, lo, hi = wall
    first, last = lo + wall_m + margin, hi - margin - door_m
    start = _snap(rng.uniform(first, last)) if last > first else first
    start = min(max(start, first), max(first, last))
    raster.open_wall(line, vertical, start, start + door_m, full=False)

  walls = {}
  for i in range(len(rects)):
    for j in range(i + 1, len(rects)):
      wall = _shared_wall(rects[i], rects[j])
      if wall is not None:
        walls[i, j] = wall

  def fits_door(wall):
    return wall[3] - wall[2] - wall_m >= door_m + 2 * margin

  for (i, j), wall in walls.items():
    if rects[i].is_corridor and rects[j].is_corridor:
      raster.open_wall(*wall, full=True)
      join(i, j)
  for i, rect in enumerate(rects):
    if rect.is_corridor:
      continue
    corridor_walls = [
        (wall[3] - wall[2], pair) for pair, wall in walls.items()
        if i in pair and rects[pair[0] + pair[1] - i].is_corridor and fits_door(wall)
    ]
    if corridor_walls:
      _, pair = max(corridor_walls)
      cut_door(walls[pair])
      join(*pair)
  room_pairs = [
      pair for pair, wall in walls.items()
      if not (rects[pair[0]].is_corridor or rects[pair[1]].is_corridor) and fits_door(wall)
  ]
  for index in rng.permutation(len(room_pairs)):
    pair = room_pairs[index]
    # Draw the coin for every pair so the sequence of draws does not depend on the joins.
    extra = rng.random() < extra_door_prob
    if join(*pair) or extra:
      cut_door(walls[pair])


@dataclasses.dataclass(frozen=True)
class _Shape:
  """A rectangle (half-sizes) or a disc (``half_x`` = radius) centred at (x, y), metres."""

  is_disc: bool
  x: float
  y: float
  half_x: float
  half_y: float

  @property
  def area(self) -> float:
    return math.pi * self.half_x**2 if self.is_disc else 4 * self.half_x * self.half_y

  def gap_to(self, other: _Shape) -> float:
    """Distance between the two shapes' boundaries (<= 0 if they overlap)."""
    if self.is_disc and other.is_disc:
      return math.hypot(self.x - other.x, self.y - other.y) - self.half_x - other.half_x
    if self.is_disc or other.is_disc:
      disc, rect = (self, other) if self.is_disc else (other, self)
      dx = max(abs(disc.x - rect.x) - rect.half_x, 0.0)
      dy = max(abs(disc.y - rect.y) - rect.half_y, 0.0)
      return math.hypot(dx, dy) - disc.half_x
    dx = max(abs(self.x - other.x) - self.half_x - other.half_x, 0.0)
    dy = max(abs(self.y - other.y) - self.half_y - other.half_y, 0.0)
    return math.hypot(dx, dy) if dx > 0 or dy > 0 else -1.0

  def rasterize(self, occupied: np.ndarray, res: float):
    """Marks the cells whose centres lie inside the shape (and the cell of its centre)."""
    n_rows, n_cols = occupied.shape
    r0 = max(0, int(math.floor((self.y - self.half_y) / res)))
    r1 = min(n_rows, int(math.ceil((self.y + self.half_y) / res)) + 1)
    c0 = max(0, int(math.floor((self.x - self.half_x) / res)))
    c1 = min(n_cols, int(math.ceil((self.x + self.half_x) / res)) + 1)
    ys = (np.arange(r0, r1) + 0.5) * res
    xs = (np.arange(c0, c1) + 0.5) * res
    if self.is_disc:
      inside = (ys[:, None] - self.y)**2 + (xs[None, :] - self.x)**2 <= self.half_x**2
    else:
      inside = ((np.abs(ys[:, None] - self.y) <= self.half_y)
                & (np.abs(xs[None, :] - self.x) <= self.half_x))
    occupied[r0:r1, c0:c1] |= inside
    centre_row, centre_col = int(self.y // res), int(self.x // res)
    if 0 <= centre_row < n_rows and 0 <= centre_col < n_cols:
      occupied[centre_row, centre_col] = True


def _scatter_shapes(shapes, rng, width_m, height_m, *, density, min_size_m, max_size_m,
                    clearance_m, disc_fraction) -> list[_Shape]:
  """Adds random shapes (rejection sampling) until they cover ``density`` of the new area."""
  shapes = list(shapes)
  # The outer wall is one grid cell; keep clear of it as if it were up to 0.3 m thick.
  wall_margin = clearance_m + 0.3
  target_area = density * width_m * height_m
  placed_area = 0.0
  mean_area = ((min_size_m + max_size_m) / 2)**2
  attempts = 200 + int(50 * target_area / mean_area)
  for _ in range(attempts):
    if placed_area >= target_area:
      break
    is_disc = rng.random() < disc_fraction
    size_x, size_y = rng.uniform(min_size_m, max_size_m, size=2)
    half_x = size_x / 2
    half_y = half_x if is_disc else size_y / 2
    x_low, x_high = wall_margin + half_x, width_m - wall_margin - half_x
    y_low, y_high = wall_margin + half_y, height_m - wall_margin - half_y
    if x_high <= x_low or y_high <= y_low:
      continue
    x, y = float(rng.uniform(x_low, x_high)), float(rng.uniform(y_low, y_high))
    shape = _Shape(bool(is_disc), x, y, float(half_x), float(half_y))
    if all(shape.gap_to(other) >= clearance_m for other in shapes):
      shapes.append(shape)
      placed_area += shape.area
  return shapes


# --- Grid helpers ---------------------------------------------------------------------------


def _to_cell(metres: float, res: float) -> int:
  """The grid line nearest to a coordinate, halves rounded up.

  The slack makes 22.3 and 22.299999999999997 (the same layout line reached by different
  float sums) land on the same cell at 0.2 m/cell, where they sit exactly half-way.
  """
  return int(math.floor(metres / res + 0.5 + 1e-6))


def _grid_shape(width_m: float, height_m: float, res: float) -> tuple[int, int]:
  return int(round(height_m / res)), int(round(width_m / res))


def _check_size(width_m, height_m, res, *, minimum_m: float) -> tuple[int, int]:
  """Validates the extent and resolution; returns the grid shape (rows, cols)."""
  for label, value in (("width_m", width_m), ("height_m", height_m), ("res", res)):
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value)
            and value > 0):
      raise MapError(f"{label} must be a positive number, got {value!r}")
  if min(width_m, height_m) < minimum_m:
    raise MapError(f"a {width_m} x {height_m} m world is too small for these settings "
                   f"(needs at least {minimum_m:.2f} m on each side)")
  n_rows, n_cols = _grid_shape(width_m, height_m, res)
  if min(n_rows, n_cols) < 3:
    raise MapError(f"a {width_m} x {height_m} m world at {res} m/cell is under 3 cells across")
  return n_rows, n_cols


def _disc(radius_cells: float) -> np.ndarray:
  """A digital disc structuring element of the given radius in cells."""
  half = int(math.floor(radius_cells))
  offsets = np.arange(-half, half + 1)
  return offsets[:, None]**2 + offsets[None, :]**2 <= radius_cells**2 + 1e-9


def _largest_component_mask(mask: np.ndarray) -> np.ndarray:
  """The largest 4-connected component of a boolean mask (all False if the mask is empty)."""
  labels, count = ndimage.label(mask)
  if count == 0:
    return np.zeros_like(mask, dtype=bool)
  sizes = np.bincount(labels.ravel())
  sizes[0] = 0
  return labels == np.argmax(sizes)


def _finalize(occupied: np.ndarray, res: float, name: str) -> GridMap:
  """Adds the 1-cell border and fills every free component but the largest."""
  occupied = occupied.copy()
  occupied[[0, -1], :] = True
  occupied[:, [0, -1]] = True
  free = _largest_component_mask(~occupied)
  if not free.any():
    raise MapError(f"generated world {name!r} has no free cell")
  return GridMap(~free, res, (0.0, 0.0), name)
