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

import dataclasses
import math
import numbers
import os
from pathlib import Path
from typing import BinaryIO

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


def load_map(yaml_path: str | os.PathLike, *, name: str | None = None,
             res: float | None = None) -> GridMap:
  """Loads a ROS ``map_server`` map (YAML + PGM/PNG) as a ground-truth grid.

  With ``res``, the grid is `resample`'s of the full map, read a strip of image rows at a time:
  a binary PGM (``map_server``'s format) is never held whole, so a map larger than memory can
  be read at a coarser resolution; other images are decoded whole first.

  Args:
    yaml_path: the map's YAML file; its ``image`` is read relative to the YAML's folder.
    name: label of the returned grid; defaults to the YAML file's stem.
    res: optional resolution in metres per cell, at least the map's (see `resample`).

  Returns:
    A `GridMap` with row 0 at the bottom (the image is flipped), unknown pixels occupied, and
    ``origin`` from the YAML's first two ``origin`` entries.

  Raises:
    MapError: the YAML is missing or unparseable, a key is missing or invalid (thresholds
      outside [0, 1] or ``free_thresh >= occupied_thresh``, a non-positive resolution, a
      non-zero yaw, an unsupported ``mode``), the image is missing, unreadable or would not fit
      in memory (80% of what is available), the map has no free cell, or ``res`` is not valid
      for `resample`.
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
      or not all(_is_number(value) and math.isfinite(value) for value in origin)):
    raise MapError(f"{where}: origin must be a list [x, y, yaw] of finite numbers, "
                   f"got {origin!r}")
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
  name = yaml_path.stem if name is None else name
  image = _MapImage(image_path, where)
  try:
    plan = None if res is None else _coarse_plan(name, (image.height, image.width), resolution,
                                                  res)
    shape = (image.height, image.width) if plan is None else plan.shape
    need = image.read_bytes(shape)
    have = _available_bytes()
    if need > 0.8 * have:
      raise MapError(f"{where}: image {str(image_path)!r} is {image.width} x {image.height} "
                     f"pixels ({image.width * image.height / 1e6:.0f} Mpx), {image.how}; reading "
                     f"it into a {shape[1]} x {shape[0]} grid takes about {need / 2**30:.1f} GiB, "
                     f"more than 80% of the {have / 2**30:.1f} GiB available: use a coarser "
                     f"resolution, or downsample the image first (and its YAML's resolution)")
    # Image row 0 is the top (largest y); grid row 0 is the bottom: image rows [r0, r1) are grid
    # rows [height - r1, height - r0), in reverse.
    occupied = np.empty(shape, bool) if plan is None else plan.empty()
    any_free = False
    for row0, free in image.free_strips(bool(negate), free_thresh):
      grid_row0 = image.height - row0 - len(free)
      any_free = any_free or bool(free.any())
      if plan is None:
        occupied[grid_row0:grid_row0 + len(free)] = ~free[::-1]
      else:
        plan.reduce_into(occupied, ~free[::-1], grid_row0)
  finally:
    image.close()
  if not any_free:
    raise MapError(f"{where}: the map has no free cell (image {str(image_path)!r}, "
                   f"free_thresh {free_thresh}, negate {int(negate)})")
  if plan is None:
    grid_res = resolution
  else:
    assert res is not None  # a plan is only made for a res
    grid_res = float(res)
  return GridMap(
      occupied=occupied if plan is None else plan.pad(occupied),
      res=grid_res,
      origin=(float(origin[0]), float(origin[1])),
      name=name,
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
  plan = _coarse_plan(grid.name, grid.shape, grid.res, res)
  if plan is None:
    return GridMap(grid.occupied, grid.res, grid.origin, grid.name)
  coarse = plan.empty()
  plan.reduce_into(coarse, grid.occupied, 0)
  return GridMap(plan.pad(coarse), res, grid.origin, grid.name)


@dataclasses.dataclass(frozen=True)
class _CoarsePlan:
  """Where each fine row and column falls in a coarser grid (`resample`'s rule)."""

  rows: np.ndarray  # int64[H]: the coarse row of each fine row (grid order, row 0 at the bottom)
  col_starts: np.ndarray  # first fine column of each run of equal coarse columns
  hit_cols: np.ndarray  # the coarse column of each run
  shape: tuple[int, int]
  pad_row: bool  # the last coarse row reaches past the fine grid: occupied
  pad_col: bool

  def empty(self) -> np.ndarray:
    return np.zeros(self.shape, bool)

  def reduce_into(self, coarse: np.ndarray, occupied: np.ndarray, row0: int) -> None:
    """ORs fine grid rows ``row0 .. row0 + len(occupied) - 1`` into ``coarse`` in place.

    Rows and columns map to coarse indices that never decrease, so each coarse index is one run
    (`numpy.logical_or.reduceat`); a coarse row split between two calls gets the OR of both.
    """
    hit_rows, row_starts = np.unique(self.rows[row0:row0 + len(occupied)], return_index=True)
    by_rows = np.logical_or.reduceat(occupied, row_starts, axis=0)
    coarse[np.ix_(hit_rows, self.hit_cols)] |= np.logical_or.reduceat(
        by_rows, self.col_starts, axis=1)

  def pad(self, coarse: np.ndarray) -> np.ndarray:
    if self.pad_row:
      coarse[-1, :] = True
    if self.pad_col:
      coarse[:, -1] = True
    return coarse


def _coarse_plan(name: str, shape: tuple[int, int], fine_res: float,
                 res: float) -> _CoarsePlan | None:
  """Validates a resampling resolution (see `resample`) and plans it; None for ``fine_res``."""
  if not (_is_number(res) and math.isfinite(res) and res > 0):
    raise MapError(f"map {name!r}: resample resolution must be a positive number, got {res!r}")
  if res < fine_res * (1 - _EPS):
    raise MapError(f"map {name!r}: cannot resample from {fine_res} m/cell to the finer "
                   f"{res} m/cell (only coarser)")
  if abs(res - fine_res) <= _EPS * fine_res:
    return None
  ratio = fine_res / res
  height, width = shape
  coarse_height = math.ceil(height * ratio - _EPS)
  coarse_width = math.ceil(width * ratio - _EPS)
  if min(coarse_height, coarse_width) < 3:
    raise MapError(f"map {name!r}: resampling {width}x{height} cells to {res} m/cell "
                   f"leaves {coarse_width}x{coarse_height}, under the 3x3 minimum")
  rows = np.floor(np.arange(height) * ratio + _EPS).astype(np.int64)
  cols = np.floor(np.arange(width) * ratio + _EPS).astype(np.int64)
  hit_cols, col_starts = np.unique(cols, return_index=True)
  return _CoarsePlan(rows=rows, col_starts=col_starts, hit_cols=hit_cols,
                     shape=(coarse_height, coarse_width),
                     pad_row=coarse_height > height * ratio + _EPS,
                     pad_col=coarse_width > width * ratio + _EPS)


# A map is classified in strips of image rows of about this many pixels, so that reading it at a
# coarser resolution never holds a full-size array: a binary PGM streams from the file; other
# images are decoded whole by Pillow first (it cannot decode PNG rows on demand).
STRIP_PIXELS = 1 << 22
# Bytes per pixel of a strip's temporaries, at most: an RGBA strip's crop and converted copy,
# its bands, three uint16 channels, their sum, the free mask and its flipped complement; a PGM
# strip's samples (1 or 2 bytes), free mask and complement.
STRIP_BYTES_PER_PIXEL = 24
PGM_STRIP_BYTES_PER_PIXEL = 4
# Bytes per cell of the grid being filled, and of the copy `GridMap` makes of it.
GRID_BYTES_PER_CELL = 2
# Image modes read through Pillow, and the channels whose sum gives the grey value.
_PILLOW_CHANNELS = {"1": 1, "L": 1, "LA": 1, "P": 3, "RGB": 3, "RGBA": 3}


class _MapImage:
  """An open map image: its size, what reading it holds, and its free mask strip by strip.

  A binary PGM (P5, ``map_server``'s format) is read from the file a strip of rows at a time, at
  8 or 16 bits. Other images are decoded whole by Pillow, then classified a strip at a time.
  """

  def __init__(self, image_path: Path, where: str):
    self.path, self.where = image_path, where
    self._file: BinaryIO | None = None
    self._image: Image.Image | None = None
    if not image_path.is_file():
      raise MapError(f"{where}: image file {str(image_path)!r} not found")
    try:
      with open(image_path, "rb") as f:
        is_pgm = f.read(2) == b"P5"
      if is_pgm:
        self._open_pgm()
      else:
        self._open_pillow()
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as e:
      self.close()
      if isinstance(e, MapError):
        raise
      raise MapError(f"{where}: image {str(image_path)!r} is unreadable ({e})") from e

  def _open_pgm(self) -> None:
    self._file = file = open(self.path, "rb")  # closed by close()
    file.read(2)
    tokens: list[int] = []
    while len(tokens) < 3:  # width, height, maxval; '#' starts a comment to the line's end
      token = b""
      while True:
        c = file.read(1)
        if c == b"#":
          while c not in (b"\n", b"\r", b""):
            c = file.read(1)
          if token:
            break
          continue
        if c == b"" or c.isspace():
          if token or c == b"":
            break
          continue
        token += c
        if len(token) > 10:  # Pillow's limit too: no header field of a PGM is longer
          break
      if not token.isdigit() or len(token) > 10:
        field = token.decode(errors="replace")
        raise MapError(f"{self.where}: image {str(self.path)!r} is unreadable (binary PGM header "
                       f"field {field!r} is not a positive integer of at most 10 digits)")
      tokens.append(int(token))
    # One whitespace byte (read with the last token) separates the header from the pixels.
    self.width, self.height, self.maxval = tokens
    if not (self.width > 0 and self.height > 0 and 0 < self.maxval < 65536):
      raise MapError(f"{self.where}: image {str(self.path)!r} is unreadable (binary PGM of "
                     f"{self.width} x {self.height} pixels, maxval {self.maxval})")
    self._dtype = np.dtype(np.uint8 if self.maxval < 256 else ">u2")
    self._offset = file.tell()
    need = self.width * self.height * self._dtype.itemsize
    have = os.fstat(file.fileno()).st_size - self._offset
    if have < need:
      raise MapError(f"{self.where}: image {str(self.path)!r} is truncated: {have} bytes of "
                     f"pixels, {self.width} x {self.height} at {8 * self._dtype.itemsize} bits "
                     f"take {need}")
    self.whole_bytes = 0
    self.how = "a binary PGM, read in strips of rows"

  def _open_pillow(self) -> None:
    # Pillow refuses images above ~179 Mpx as decompression bombs; a map's size is checked
    # against the memory reading it takes instead (load_map).
    bomb_limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
      self._image = image = Image.open(self.path)
    finally:
      Image.MAX_IMAGE_PIXELS = bomb_limit
    self.width, self.height = image.size
    mode = image.mode
    if mode not in _PILLOW_CHANNELS:
      deep = " (16-bit grey is read from binary PGM (P5) only)" if mode.startswith("I") else ""
      raise MapError(f"{self.where}: image {str(self.path)!r} has unsupported pixel mode "
                     f"{mode!r}{deep} (8-bit grey, palette, RGB or RGBA only)")
    # Pillow holds 1 byte per pixel for these modes and 4 for the others; its plain-text PGM
    # (P2) decoder also holds the pixels twice more while decoding.
    per_pixel = 1 if mode in ("1", "L", "P") else 4
    if image.format == "PPM":
      per_pixel += 2
    self.whole_bytes = self.width * self.height * per_pixel
    self.how = (f"a {image.format or 'image'} file, decoded whole "
                f"({self.whole_bytes / 2**30:.1f} GiB: only binary PGM is read in strips)")

  def strip_rows(self) -> int:
    return max(1, min(self.height, STRIP_PIXELS // self.width))

  def read_bytes(self, shape: tuple[int, int]) -> int:
    """Peak memory of reading the image into a grid of ``shape``: the decoded image if Pillow
    decodes it whole, one strip's temporaries and the grid."""
    per_pixel = PGM_STRIP_BYTES_PER_PIXEL if self._file is not None else STRIP_BYTES_PER_PIXEL
    strip = self.strip_rows() * self.width * per_pixel
    return self.whole_bytes + strip + shape[0] * shape[1] * GRID_BYTES_PER_CELL

  def free_strips(self, negate: bool, free_thresh: float):
    """Yields ``(first image row, bool[rows, W] free mask)`` down the image (row 0 at the top).

    A pixel is free if its occupancy ``p`` is below ``free_thresh``: ``p = (255 - v) / 255`` of
    its grey value ``v`` (``v / 255`` with ``negate``); ``(maxval - v) / maxval`` for a 16-bit
    PGM. Pillow scales an 8-bit PGM's samples to 0-255 (``round(v / maxval * 255)``).
    """
    rows = self.strip_rows()
    try:
      if self._file is not None:
        if self.maxval < 256:
          grey = np.arange(256) / self.maxval * 255
          lookup = _free_table(np.minimum(255, np.round(grey)), 255, negate, free_thresh)
        else:
          grey = np.minimum(np.arange(65536), self.maxval)
          lookup = _free_table(grey, self.maxval, negate, free_thresh)
        self._file.seek(self._offset)
        for row0 in range(0, self.height, rows):
          count = min(rows, self.height - row0) * self.width
          samples = np.fromfile(self._file, self._dtype, count).reshape(-1, self.width)
          yield row0, lookup[samples]
        return
      image = self._image
      assert image is not None  # not a binary PGM: the constructor opened it with Pillow
      bomb_limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
      try:
        image.load()
      finally:
        Image.MAX_IMAGE_PIXELS = bomb_limit
      channels = _PILLOW_CHANNELS[image.mode]
      # Classify each possible channel sum once, then look pixels up: float arithmetic per
      # pixel costs seconds on the largest public maps.
      lookup = _free_table(np.arange(255 * channels + 1) / channels, 255, negate, free_thresh)
      for row0 in range(0, self.height, rows):
        strip = image.crop((0, row0, self.width, min(self.height, row0 + rows)))
        if strip.mode == "P":
          strip = strip.convert("RGBA")
        elif strip.mode == "1":
          strip = strip.convert("L")
        if channels == 1:
          channel_sum = np.asarray(strip.getchannel(0), dtype=np.uint16)
        else:
          red, green, blue = (np.asarray(band, dtype=np.uint16) for band in strip.split()[:3])
          channel_sum = red + green + blue
        yield row0, lookup[channel_sum]
    except (OSError, ValueError, SyntaxError) as e:
      raise MapError(f"{self.where}: image {str(self.path)!r} is unreadable ({e})") from e

  def close(self) -> None:
    for handle in (self._file, self._image):
      if handle is not None:
        handle.close()
    self._file = self._image = None


def _free_table(grey: np.ndarray, full: int, negate: bool, free_thresh: float) -> np.ndarray:
  """Free (occupancy below ``free_thresh``) per grey level, ``full`` being white."""
  occupancy = grey / full if negate else (full - grey) / full
  # Unknown (between the thresholds) and occupied are both occupied in the truth, so only
  # free_thresh decides; occupied_thresh is still validated like map_server does.
  return occupancy < free_thresh


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
