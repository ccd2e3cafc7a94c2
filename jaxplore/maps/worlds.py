"""Named built-in worlds, reachability, a summary table and a PNG renderer.

The built-in worlds are generated from fixed seeds (no data files), at the scales the papers
use: Godoy-Calvo's open 20 x 20 m area and 45 x 25 m office, Li's ~200 m² lab, ~1,500 m²
building and ~4,000 m² campus (the areas Li's Table 1 reports as covered), a LIRMM-like
corridor loop (Toriz), a maze and a cave. Native resolutions keep every grid within 256 x 256
cells for batched simulation; `get_world` gives any other resolution (coarser by conservative
resampling, finer by drawing the same layout again).

=========  =============  ============  ===========  =========
name       cells (W x H)  res (m/cell)  extent (m)   free (m²)
=========  =============  ============  ===========  =========
open       200 x 200      0.1           20 x 20      372
office     225 x 125      0.2           45 x 25      1,029
lab        170 x 130      0.1           17 x 13      197
building   230 x 180      0.2           46 x 36      1,520
campus     240 x 216      0.3           72 x 64.8    3,962
corridors  250 x 180      0.1           25 x 18      173
maze       200 x 200      0.1           20 x 20      329
cave       250 x 200      0.1           25 x 20      274
=========  =============  ============  ===========  =========

All free space of each world is one 4-connected component (reachable = free).
`load_world` accepts either a built-in name or the path of a ``map_server`` YAML, so a command
line can take ``--world office`` and ``--world ../shared/maps/intel.yaml`` alike.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy import ndimage

from jaxplore.maps import generate
from jaxplore.maps.grid import GridMap, MapError
from jaxplore.maps.io import load_map, resample

# Relative slack when comparing resolutions.
_RES_TOL = 1e-9


@dataclasses.dataclass(frozen=True)
class WorldSpec:
  """A named built-in world.

  Attributes:
    name: the key in `WORLDS`.
    description: one line for tables and ``--help``.
    builder: ``builder(res) -> GridMap``; draws the same layout at any resolution.
    res: native resolution, metres per cell.
    start: default robot start (x, y) in metres, or None to let the caller choose.
    regenerable: whether ``builder`` may be called at a resolution finer than ``res``.
  """

  name: str
  description: str
  builder: Callable[[float], GridMap]
  res: float
  start: tuple[float, float] | None = None
  regenerable: bool = True


def _corridors(res: float) -> GridMap:
  """A LIRMM-like corridor loop (2 m wide) around a block, with side rooms and a dead end."""
  door = 1.2
  boxes = [
      # The loop: bottom, top, left and right corridors.
      (3.5, 3.5, 21.5, 5.5), (3.5, 12.5, 21.5, 14.5), (3.5, 3.5, 5.5, 14.5),
      (19.5, 3.5, 21.5, 14.5),
      # A dead-end corridor off the left side.
      (0.3, 8.0, 3.5, 10.0),
      # Side rooms outside the loop, each with its door through a 0.2 m wall.
      (6.0, 0.3, 10.0, 3.3), (7.4, 3.3, 7.4 + door, 3.5),
      (14.0, 0.3, 19.0, 3.3), (16.0, 3.3, 16.0 + door, 3.5),
      (9.0, 14.7, 13.5, 17.7), (10.5, 14.5, 10.5 + door, 14.7),
      (21.7, 7.0, 24.7, 11.0), (21.5, 8.4, 21.7, 8.4 + door),
      # One room inside the loop, entered from the bottom corridor.
      (6.0, 5.7, 10.0, 9.0), (7.4, 5.5, 7.4 + door, 5.7),
  ]
  return generate.floor_plan(25.0, 18.0, res, boxes, name="corridors")


WORLDS: dict[str, WorldSpec] = {
    spec.name: spec for spec in (
        WorldSpec(
            "open", "20 x 20 m open area with a few box and disc obstacles (Godoy-Calvo)",
            lambda res: generate.open_clutter(20.0, 20.0, res, seed=0, density=0.05, name="open"),
            res=0.1, start=(2.0, 2.0)),
        WorldSpec(
            "office", "45 x 25 m office: corridors, rooms, 1.2 m doors (Godoy-Calvo)",
            lambda res: generate.office(45.0, 25.0, res, seed=0, name="office"),
            res=0.2, start=(23.5, 13.5)),
        WorldSpec(
            "lab", "17 x 13 m small office floor, ~200 m² free (Li's fr101-sized map)",
            lambda res: generate.office(17.0, 13.0, res, seed=1, corridor_spacing_m=12.0,
                                        name="lab"),
            res=0.1, start=(8.6, 1.0)),
        WorldSpec(
            "building", "46 x 36 m office building, ~1,500 m² free (Li)",
            lambda res: generate.office(46.0, 36.0, res, seed=2, corridor_spacing_m=20.0,
                                        name="building"),
            res=0.2, start=(23.5, 18.0)),
        WorldSpec(
            "campus", "72 x 65 m open campus with buildings and trees, ~4,000 m² free (Li)",
            lambda res: generate.campus(72.0, 64.8, res, seed=0, name="campus"),
            res=0.3, start=(36.0, 32.0)),
        WorldSpec(
            "corridors", "25 x 18 m LIRMM-like loop of 2 m corridors with side rooms (Toriz)",
            _corridors, res=0.1, start=(4.5, 4.5)),
        WorldSpec(
            "maze", "20 x 20 m perfect maze, 1.2 m corridors, 0.2 m walls",
            lambda res: generate.maze(20.0, 20.0, res, seed=0, corridor_m=1.2, name="maze"),
            res=0.1, start=(0.8, 0.8)),
        WorldSpec(
            "cave", "25 x 20 m cellular-automaton cave, passages >= 1 m",
            lambda res: generate.cave(25.0, 20.0, res, seed=0, name="cave"),
            res=0.1, start=(5.0, 5.0)),
    )
}


def get_world(name: str, res: float | None = None) -> GridMap:
  """Builds a named world.

  Args:
    name: a key of `WORLDS`.
    res: resolution in metres per cell; None for the world's native one. Coarser than native
      resamples the native grid conservatively (`resample`); finer regenerates the same layout.

  Returns:
    A new `GridMap` (callers may modify its array).

  Raises:
    MapError: unknown name (the message lists the valid ones), or a finer ``res`` for a world
      that cannot be regenerated.
  """
  spec = WORLDS.get(name)
  if spec is None:
    raise MapError(f"unknown world {name!r}; built-in worlds: {', '.join(WORLDS)}")
  if res is not None and abs(float(res) - spec.res) <= _RES_TOL * spec.res:
    res = None
  if res is not None and res < spec.res:
    _check_finer(spec, float(res))
  grid = _cached_world(name, None if res is None else float(res))
  return GridMap(grid.occupied.copy(), grid.res, grid.origin, grid.name)


# A grid's cells are indexed with int32 on the device.
MAX_CELLS = 2**31 - 1
# Drawing a world with this many times its native cells or more is announced before it is drawn.
FINE_FACTOR = 16


def _check_finer(spec: WorldSpec, res: float) -> None:
  """Refuses (MapError) a resolution whose grid could not be indexed, and warns on stderr, with
  the cells and the resolution, before drawing a world at ``FINE_FACTOR`` times its native cells
  or more (every step and planning round grows with the cells)."""
  import math
  import sys
  native = _cached_world(spec.name, None)
  h, w = native.shape
  fine_h, fine_w = (math.ceil(n * spec.res / res - 1e-9) for n in (h, w))
  cells = fine_h * fine_w
  if cells > MAX_CELLS:
    raise MapError(f"world {spec.name!r} at {res:g} m/cell would be {fine_w} x {fine_h} = "
                   f"{cells:.3g} cells, more than the {MAX_CELLS:.3g} a grid may hold; use a "
                   f"coarser --res (native {spec.res:g} m/cell)")
  if cells >= FINE_FACTOR * h * w:
    print(f"jaxplore: warning: world {spec.name!r} at {res:g} m/cell is {fine_w} x {fine_h} = "
          f"{cells:,} cells, {cells / (h * w):.0f}x its {w} x {h} cells at its native "
          f"{spec.res:g} m/cell: every step and planning round costs about that much more",
          file=sys.stderr)


@functools.lru_cache(maxsize=32)
def _cached_world(name: str, res: float | None) -> GridMap:
  spec = WORLDS[name]
  if res is None:
    return spec.builder(spec.res)
  if res > spec.res:
    return resample(_cached_world(name, None), res)
  if not spec.regenerable:
    raise MapError(f"world {name!r} exists only at {spec.res} m/cell or coarser, not {res}")
  return spec.builder(res)


def load_world(spec: str | os.PathLike, res: float | None = None) -> GridMap:
  """A built-in world by name, or a ``map_server`` map by the path of its YAML.

  Args:
    spec: a key of `WORLDS`, or a path to a ``.yaml``/``.yml`` file.
    res: optional resolution; a loaded map can only be made coarser (`resample`), and is
      read at it directly (`load_map`).

  Returns:
    The world as a `GridMap`.

  Raises:
    MapError: ``spec`` is neither a built-in world nor a map file, or the map cannot be
      loaded or resampled.
  """
  if res is not None and not (isinstance(res, (int, float, np.integer, np.floating))
                              and np.isfinite(res) and res > 0):
    raise MapError(f"res must be a positive number of metres per cell, got {res!r}")
  if isinstance(spec, str) and spec in WORLDS:
    return get_world(spec, res)
  path = Path(spec)
  if path.suffix.lower() not in (".yaml", ".yml") and not path.is_file():
    raise MapError(f"unknown world {str(spec)!r}: not a built-in world ({', '.join(WORLDS)}) "
                   "and not a map YAML file")
  # Read at ``res`` directly: a binary PGM is then never held at its full size.
  return load_map(path, res=res)


def reachable_mask(grid: GridMap, start_cell: tuple[int, int]) -> np.ndarray:
  """The 4-connected free component containing ``start_cell``.

  Args:
    grid: the world.
    start_cell: (row, col) of a free cell.

  Returns:
    bool[H, W], True on the cells reachable from ``start_cell``.

  Raises:
    MapError: ``start_cell`` is outside the grid or occupied.
  """
  row, col = (int(v) for v in start_cell)
  height, width = grid.shape
  if not (0 <= row < height and 0 <= col < width):
    raise MapError(
        f"map {grid.name!r}: start cell {(row, col)} is outside the {height}x{width} grid")
  if grid.occupied[row, col]:
    raise MapError(f"map {grid.name!r}: start cell {(row, col)} is occupied")
  labels, _ = ndimage.label(grid.free)
  return labels == labels[row, col]


def largest_component(grid: GridMap) -> np.ndarray:
  """The largest 4-connected free component, bool[H, W] (all False if nothing is free)."""
  labels, count = ndimage.label(grid.free)
  if count == 0:
    return np.zeros(grid.shape, dtype=bool)
  sizes = np.bincount(labels.ravel())
  sizes[0] = 0
  return labels == np.argmax(sizes)


def world_table() -> list[dict]:
  """One row per built-in world, at its native resolution, for ``jaxplore maps``.

  Returns:
    Dicts with ``name``, ``width_cells``, ``height_cells``, ``res`` (m/cell), ``width_m``,
    ``height_m``, ``free_m2``, ``reachable_m2`` (largest 4-connected free component),
    ``start`` ((x, y) metres or None) and ``description``.
  """
  rows = []
  for name, spec in WORLDS.items():
    grid = get_world(name)
    height, width = grid.shape
    width_m, height_m = grid.extent_m
    rows.append({
        "name": name,
        "width_cells": width,
        "height_cells": height,
        "res": grid.res,
        "width_m": round(width_m, 6),
        "height_m": round(height_m, 6),
        "free_m2": round(grid.free_area, 2),
        "reachable_m2": round(float(largest_component(grid).sum()) * grid.res**2, 2),
        "start": spec.start,
        "description": spec.description,
    })
  return rows


def render_png(
    grid: GridMap,
    path: str | os.PathLike,
    trajectories: Sequence[np.ndarray] | np.ndarray | None = None,
    *,
    title: str | None = None,
    dpi: int = 150,
) -> None:
  """Draws the grid (free white, occupied black, metric axes) and optional robot paths.

  Args:
    grid: the world.
    path: the PNG file to write.
    trajectories: robot paths in metres: one array [T, 2] of (x, y), a stack [B, T, 2], or a
      sequence of [T_b, 2] arrays. Each starts with a circle and ends with a cross.
    title: figure title; defaults to the grid's name.
    dpi: resolution of the PNG.
  """
  # The object-oriented API without pyplot: no global figure state, no GUI backend.
  from matplotlib.backends.backend_agg import FigureCanvasAgg
  from matplotlib.figure import Figure

  width_m, height_m = grid.extent_m
  x0, y0 = grid.origin
  fig_width = 8.0
  fig_height = float(np.clip(fig_width * height_m / width_m, 2.5, 12.0)) + 0.6
  fig = Figure(figsize=(fig_width, fig_height))
  FigureCanvasAgg(fig)
  ax = fig.add_subplot()
  ax.imshow(grid.occupied, origin="lower", cmap="gray_r", vmin=0, vmax=1,
            interpolation="nearest", extent=(x0, x0 + width_m, y0, y0 + height_m))
  if trajectories is not None:
    if not isinstance(trajectories, (list, tuple)):
      # One array (NumPy or JAX): [T, 2] is one path, [B, T, 2] a stack of them.
      trajectories = np.asarray(trajectories, dtype=float)
      if trajectories.ndim == 2:
        trajectories = [trajectories]
    for index, trajectory in enumerate(trajectories):
      trajectory = np.asarray(trajectory, dtype=float)
      if trajectory.ndim != 2 or trajectory.shape[-1] != 2:
        raise ValueError(f"trajectory {index} must have shape [T, 2], got {trajectory.shape}")
      if len(trajectory) == 0:
        continue
      color = f"C{index % 10}"
      ax.plot(trajectory[:, 0], trajectory[:, 1], color=color, linewidth=1.0)
      ax.plot(*trajectory[0], marker="o", color=color, markersize=5)
      ax.plot(*trajectory[-1], marker="x", color=color, markersize=6)
  ax.set_xlabel("x (m)")
  ax.set_ylabel("y (m)")
  ax.set_title(grid.name if title is None else title)
  ax.set_aspect("equal")
  fig.tight_layout()
  fig.savefig(os.fspath(path), dpi=dpi)
