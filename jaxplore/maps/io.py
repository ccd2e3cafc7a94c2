"""Reading and writing ROS ``map_server`` maps, and coarsening a grid.

A ``map_server`` map is a YAML file that names an image (PGM or PNG) and says how to read it::

  image: intel.png          # relative to the YAML's folder
  resolution: 0.048         # metres per pixel
  origin: [0.0, 0.0, 0.0]   # x, y, yaw of the lower-left pixel
  negate: 0
  occupied_thresh: 0.65
  free_thresh: 0.196
  mode: trinary             # optional; the only mode supported here

Each pixel's grey value ``v`` (the mean of R, G and B for colour images; alpha is ignored) gives
``p = (255 - v) / 255`` (``v / 255`` with ``negate``). The pixel is free if ``p < free_thresh``,
occupied if ``p > occupied_thresh`` and unknown otherwise. Unknown pixels are occupied in the
ground truth: some maps draw their walls in the unknown band (willow).
"""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from jaxplore.maps.grid import GridMap, MapError

_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")

# What `save_map` writes: map_saver's values and thresholds.
_SAVE_FREE_VALUE = 254
_SAVE_OCCUPIED_VALUE = 0
_SAVE_OCCUPIED_THRESH = 0.65
_SAVE_FREE_THRESH = 0.196

# Slack for comparing resolutions and for float index arithmetic: map resolutions are short
# decimals, so exact ratios sit far (> 1e-6) from this.
_EPS = 1e-9


def load_map(yaml_path: str | os.PathLike, *, name: str | None = None) -> GridMap:
  """Loads a ROS ``map_server`` map (YAML + PGM/PNG) as a ground-truth grid.

  Args:
    yaml_path: the map's YAML file; its ``image`` is read relative to the YAML's folder.
    name: label of the returned grid; defaults to the YAML file's stem.

  Returns:
    A `GridMap` with row 0 at the bottom (the image is flipped), unknown pixels occupied, and
    ``origin`` from the YAML's first two ``origin`` entries.

  Raises:
    MapError: the YAML is missing or unparseable, a key is missing or invalid (thresholds
      outside [0, 1] or ``free_thresh >= occupied_thresh``, a non-positive resolution, a
      non-zero yaw, an unsupported ``mode``), the image is missing or unreadable, or the map
      has no free cell.
  """
  yaml_path = Path(yaml_path)
  where = f"map YAML {str(yaml_path)!r}"
  if not yaml_path.is_file():
    raise MapError(f"{where}: file not found")
  try:
    with open(yaml_path, encoding="utf-8") as f:
      meta = yaml.safe_load(f)
  except (yaml.YAMLError, UnicodeDecodeError, OSError) as e:
    raise MapError(f"{where}: not parseable as YAML ({e})") from e
  if not isinstance(meta, dict):
    raise MapError(f"{where}: expected a mapping of keys ({', '.join(_REQUIRED_KEYS)}), "
                   f"got {type(meta).__name__}")
  missing = [key for key in _REQUIRED_KEYS if key not in meta]
  if missing:
    raise MapError(f"{where}: missing key(s) {', '.join(missing)}")

  resolution = _number(meta, "resolution", where)
  if not resolution > 0:
    raise MapError(f"{where}: resolution must be positive, got {resolution!r}")
  origin = meta["origin"]
  if (not isinstance(origin, (list, tuple)) or len(origin) != 3
      or not all(_is_number(value) for value in origin)):
    raise MapError(f"{where}: origin must be a list [x, y, yaw] of numbers, got {origin!r}")
  if abs(float(origin[2])) > _EPS:
    raise MapError(f"{where}: origin yaw must be 0 (rotated maps are not supported), "
                   f"got {origin[2]!r}")
  negate = meta["negate"]
  if negate not in (0, 1) or not isinstance(negate, (bool, int)):
    raise MapError(f"{where}: negate must be 0 or 1, got {negate!r}")
  occupied_thresh = _number(meta, "occupied_thresh", where)
  free_thresh = _number(meta, "free_thresh", where)
  for key, value in (("occupied_thresh", occupied_thresh), ("free_thresh", free_thresh)):
    if not 0.0 <= value <= 1.0:
      raise MapError(f"{where}: {key} must be in [0, 1], got {value!r}")
  if free_thresh >= occupied_thresh:
    raise MapError(f"{where}: free_thresh ({free_thresh}) must be below occupied_thresh "
                   f"({occupied_thresh})")
  mode = meta.get("mode", "trinary")
  if mode != "trinary":
    raise MapError(f"{where}: mode {mode!r} is not supported (only 'trinary')")
  image_name = meta["image"]
  if not isinstance(image_name, str) or not image_name:
    raise MapError(f"{where}: image must be a file name, got {image_name!r}")

  image_path = yaml_path.parent / image_name
  channel_sum, n_channels = _read_channel_sum(image_path, where)
  # Classify each possible channel sum once, then look pixels up: float arithmetic per pixel
  # costs ~1 s on the 6.8-Mpixel maps.
  grey_levels = np.arange(255 * n_channels + 1) / n_channels
  if negate:
    occupancy = grey_levels / 255.0
  else:
    occupancy = (255.0 - grey_levels) / 255.0
  # Unknown (between the thresholds) and occupied are both occupied in the truth, so only
  # free_thresh decides; occupied_thresh is still validated like map_server does.
  free = (occupancy < free_thresh)[channel_sum]
  if not free.any():
    raise MapError(f"{where}: the map has no free cell (image {str(image_path)!r}, "
                   f"free_thresh {free_thresh}, negate {int(negate)})")
  return GridMap(
      # Image row 0 is the top (largest y); grid row 0 is the bottom.
      occupied=np.ascontiguousarray(~free[::-1]),
      res=resolution,
      origin=(float(origin[0]), float(origin[1])),
      name=yaml_path.stem if name is None else name,
  )


def save_map(grid: GridMap, yaml_path: str | os.PathLike) -> None:
  """Writes a grid as a ``map_server`` map that `load_map` reads back to the same grid.

  The image is a binary PGM beside the YAML, with the YAML's stem: 254 = free, 0 = occupied
  (``map_saver``'s values), thresholds 0.65 / 0.196.

  Args:
    grid: the grid to write.
    yaml_path: the YAML file to write; its folder must exist.

  Raises:
    MapError: the folder does not exist.
  """
  yaml_path = Path(yaml_path)
  if not yaml_path.parent.is_dir():
    raise MapError(f"cannot save map {grid.name!r} to {str(yaml_path)!r}: folder not found")
  image_path = yaml_path.with_suffix(".pgm")
  pixels = np.where(grid.occupied[::-1], _SAVE_OCCUPIED_VALUE, _SAVE_FREE_VALUE).astype(np.uint8)
  Image.fromarray(pixels, mode="L").save(image_path)
  meta = {
      "image": image_path.name,
      # float() so PyYAML writes plain numbers (repr precision: they read back exactly).
      "resolution": float(grid.res),
      "origin": [float(grid.origin[0]), float(grid.origin[1]), 0.0],
      "negate": 0,
      "occupied_thresh": _SAVE_OCCUPIED_THRESH,
      "free_thresh": _SAVE_FREE_THRESH,
      "mode": "trinary",
  }
  with open(yaml_path, "w", encoding="utf-8") as f:
    yaml.safe_dump(meta, f, sort_keys=False, default_flow_style=None)


def resample(grid: GridMap, res: float) -> GridMap:
  """Coarsens a grid conservatively: a coarse cell is occupied if any fine cell in it is.

  Fine cell ``i`` (its lower edge at ``i * grid.res``) falls in coarse cell
  ``floor(i * grid.res / res)``, per axis, so the factor may be non-integer (0.048 -> 0.2). The
  coarse grid has ``ceil(n * grid.res / res)`` cells per axis; when the last coarse row or
  column reaches past the fine grid, the missing part counts as occupied and so that row or
  column is occupied.

  Args:
    grid: the fine grid.
    res: the new resolution in metres per cell, at least ``grid.res``.

  Returns:
    A new `GridMap` with the same origin and name; the same grid (copied) if ``res`` equals
    ``grid.res``.

  Raises:
    MapError: ``res`` is not a positive number, is finer than ``grid.res``, or leaves fewer
      than 3 cells across.
  """
  if not (_is_number(res) and math.isfinite(res) and res > 0):
    raise MapError(f"map {grid.name!r}: resample resolution must be a positive number, got {res!r}")
  if res < grid.res * (1 - _EPS):
    raise MapError(f"map {grid.name!r}: cannot resample from {grid.res} m/cell to the finer "
                   f"{res} m/cell (only coarser)")
  if abs(res - grid.res) <= _EPS * grid.res:
    return GridMap(grid.occupied, grid.res, grid.origin, grid.name)
  ratio = grid.res / res
  height, width = grid.shape
  coarse_height = math.ceil(height * ratio - _EPS)
  coarse_width = math.ceil(width * ratio - _EPS)
  if min(coarse_height, coarse_width) < 3:
    raise MapError(f"map {grid.name!r}: resampling {width}x{height} cells to {res} m/cell "
                   f"leaves {coarse_width}x{coarse_height}, under the 3x3 minimum")
  rows = np.floor(np.arange(height) * ratio + _EPS).astype(np.int64)
  cols = np.floor(np.arange(width) * ratio + _EPS).astype(np.int64)
  # OR over each coarse cell's fine rows, then columns (rows and cols never decrease, so each
  # coarse index is one run): no array larger than coarse_height x width.
  coarse = np.zeros((coarse_height, coarse_width), bool)
  hit_rows, row_starts = np.unique(rows, return_index=True)
  hit_cols, col_starts = np.unique(cols, return_index=True)
  by_rows = np.logical_or.reduceat(grid.occupied, row_starts, axis=0)
  coarse[np.ix_(hit_rows, hit_cols)] = np.logical_or.reduceat(by_rows, col_starts, axis=1)
  if coarse_height > height * ratio + _EPS:
    coarse[-1, :] = True
  if coarse_width > width * ratio + _EPS:
    coarse[:, -1] = True
  return GridMap(coarse, res, grid.origin, grid.name)


def _read_channel_sum(image_path: Path, where: str) -> tuple[np.ndarray, int]:
  """Sum of the grey (1) or R, G, B (3) channels per pixel, uint16[H, W] in image row order.

  Returns:
    The sums and the number of channels summed (the grey value is their quotient).
  """
  if not image_path.is_file():
    raise MapError(f"{where}: image file {str(image_path)!r} not found")
  # Pillow refuses images above ~179 Mpx as decompression bombs; a map's size is checked here
  # instead, against the memory its decoding takes (a 20000 x 20000 map is 400 Mpx).
  bomb_limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
  try:
    with Image.open(image_path) as image:
      width, height = image.size
      need = width * height * (len(image.getbands()) + DECODE_BYTES_PER_PIXEL)
      have = _available_bytes()
      if need > 0.8 * have:
        raise MapError(f"{where}: image {str(image_path)!r} is {width} x {height} pixels "
                       f"({width * height / 1e6:.0f} Mpx); reading it takes about "
                       f"{need / 2**30:.1f} GiB, more than 80% of the {have / 2**30:.1f} GiB "
                       f"available: downsample the image first (and its YAML's resolution)")
      image.load()
      if image.mode == "P":
        image = image.convert("RGBA")
      elif image.mode == "1":
        image = image.convert("L")
      mode = image.mode
      if mode in ("L", "LA"):
        return np.asarray(image.getchannel(0), dtype=np.uint16), 1
      if mode in ("RGB", "RGBA"):
        red, green, blue = (np.asarray(band, dtype=np.uint16) for band in image.split()[:3])
        return red + green + blue, 3
  except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as e:
    if isinstance(e, MapError):
      raise
    raise MapError(f"{where}: image {str(image_path)!r} is unreadable ({e})") from e
  finally:
    Image.MAX_IMAGE_PIXELS = bomb_limit
  raise MapError(f"{where}: image {str(image_path)!r} has unsupported pixel mode {mode!r} "
                 "(8-bit grey, palette, RGB or RGBA only)")


# Bytes per pixel that reading a map holds besides the decoded bands: the uint16 channel sum,
# the free mask and its flipped copy.
DECODE_BYTES_PER_PIXEL = 4


def _available_bytes() -> int:
  try:
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
  except (ValueError, OSError, AttributeError):
    return 8 << 30


def _is_number(value) -> bool:
  return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _number(meta: dict, key: str, where: str) -> float:
  value = meta[key]
  if not _is_number(value) or not math.isfinite(value):
    raise MapError(f"{where}: {key} must be a number, got {value!r}")
  return float(value)
