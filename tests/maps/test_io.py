"""Tests for jaxplore.maps.io: map_server loading, saving and conservative resampling."""

from __future__ import annotations

import math
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from PIL import Image
from scipy import ndimage

from conftest import SHARED_MAPS, needs_shared_maps
from jaxplore.maps import GridMap, MapError, load_map, resample, save_map


# MAPS.md's tables: size (W x H cells), free m², largest 4-connected free component m².
MAPS_TABLE = {
    "tb3_world": (384, 384, 20, 20),
    "houseexpo_0004d52d": (204, 164, 59, 59),
    "tb3_house": (384, 384, 94, 94),
    "houseexpo_0a1b29db": (228, 218, 119, 119),
    "fr101": (281, 542, 157, 157),
    "fr079": (911, 368, 294, 288),
    "husky_playpen": (1984, 1984, 373, 373),
    "intel": (579, 581, 451, 451),
    "aces": (1129, 1134, 817, 773),
    "mit_csail": (1597, 1208, 867, 830),
    "willow": (566, 608, 1092, 1087),
    "mit_killian": (2491, 1990, 3724, 2862),
    "fr_campus": (2788, 2428, 32748, 31043),
    "explore_bench/corner": (250, 250, 279.5, 279.5),
    "explore_bench/corridor": (250, 250, 272.6, 272.6),
    "explore_bench/loop": (250, 250, 190.4, 190.4),
    "explore_bench/loop_with_corridor": (250, 250, 302.4, 302.4),
    "explore_bench/room": (250, 250, 378.3, 378.3),
    "explore_bench/room_with_corner": (250, 250, 366.9, 366.9),
}


def _largest_component_m2(grid: GridMap) -> float:
  labels, count = ndimage.label(grid.free)
  return float(np.bincount(labels.ravel())[1:].max()) * grid.res**2 if count else 0.0


def _write_yaml(path: Path, **overrides) -> Path:
  meta = {"image": "map.pgm", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0,
          "occupied_thresh": 0.65, "free_thresh": 0.196}
  meta.update(overrides)
  meta = {key: value for key, value in meta.items() if value is not None}
  path.write_text(yaml.safe_dump(meta))
  return path


def _write_image(path: Path, pixels: np.ndarray, mode: str | None = None) -> Path:
  Image.fromarray(pixels, mode=mode).save(path)
  return path


def _small_map(tmp_path: Path, **overrides) -> Path:
  """A 4x5 grey map: free inside, occupied frame."""
  pixels = np.full((4, 5), 254, dtype=np.uint8)
  pixels[[0, -1], :] = 0
  pixels[:, [0, -1]] = 0
  _write_image(tmp_path / "map.pgm", pixels)
  return _write_yaml(tmp_path / "map.yaml", **overrides)


# --- The shared maps ------------------------------------------------------------------------


@needs_shared_maps
def test_every_shared_map_is_in_the_table():
  yaml_files = list(SHARED_MAPS.glob("*.yaml")) + list(SHARED_MAPS.glob("explore_bench/*.yaml"))
  found = {str(path.relative_to(SHARED_MAPS).with_suffix("")) for path in yaml_files}
  assert found == set(MAPS_TABLE)


@needs_shared_maps
@pytest.mark.parametrize("map_name", sorted(MAPS_TABLE))
def test_shared_map_matches_maps_md(map_name):
  width, height, free_m2, largest_m2 = MAPS_TABLE[map_name]
  started = time.perf_counter()
  grid = load_map(SHARED_MAPS / f"{map_name}.yaml")
  elapsed = time.perf_counter() - started
  assert grid.name == Path(map_name).name
  assert grid.shape == (height, width)
  assert grid.free_area == pytest.approx(free_m2, rel=0.01)
  assert _largest_component_m2(grid) == pytest.approx(largest_m2, rel=0.01)
  assert elapsed < 5.0, f"loading {map_name} took {elapsed:.2f} s"


@needs_shared_maps
def test_explore_bench_start_is_free_and_rows_are_flipped():
  # MAPS.md: the Gazebo start is world (8, 8), image pixel (row, col) = (44, 205); (6, 6) and
  # (64, 185) for corner.
  for name, (x, y), (image_row, image_col) in [
      ("corridor", (8.0, 8.0), (44, 205)), ("corner", (6.0, 6.0), (64, 185))]:
    grid = load_map(SHARED_MAPS / "explore_bench" / f"{name}.yaml")
    row, col = grid.world_to_cell(x, y)
    assert (row, col) == (grid.shape[0] - 1 - image_row, image_col)
    assert not grid.occupied[row, col]
    pixels = np.asarray(Image.open(SHARED_MAPS / "explore_bench" / f"{name}.pgm"))
    np.testing.assert_array_equal(grid.free, pixels[::-1] == 254)


@needs_shared_maps
def test_willow_walls_in_the_unknown_band_are_occupied():
  pixels = np.asarray(Image.open(SHARED_MAPS / "willow.pgm"))
  grid = load_map(SHARED_MAPS / "willow.yaml")
  wall_grey = (pixels >= 90) & (pixels <= 204)
  assert wall_grey.sum() > 1000
  assert grid.occupied[::-1][wall_grey].all()


@needs_shared_maps
def test_resample_intel_to_coarser_cells():
  fine = load_map(SHARED_MAPS / "intel.yaml")
  coarse = resample(fine, 0.2)
  assert coarse.res == 0.2 and coarse.origin == fine.origin and coarse.name == "intel"
  # 579 x 0.048 / 0.2 = 138.96 -> 139 columns; 581 rows -> 139.44 -> 140.
  assert coarse.shape == (140, 139)
  rows = np.floor(np.arange(fine.shape[0]) * 0.24 + 1e-9).astype(int)
  cols = np.floor(np.arange(fine.shape[1]) * 0.24 + 1e-9).astype(int)
  # Conservative: a coarse free cell holds only free fine cells.
  assert not (coarse.free[rows[:, None], cols[None, :]] & fine.occupied).any()
  assert 0.75 * fine.free_area < coarse.free_area < fine.free_area
  assert _largest_component_m2(coarse) > 0.75 * _largest_component_m2(fine)


# --- Pixel semantics ------------------------------------------------------------------------


def test_rows_are_flipped_on_load(tmp_path):
  pixels = np.full((5, 4), 254, dtype=np.uint8)
  pixels[0, :] = 0  # The image's top row: the largest y.
  _write_image(tmp_path / "map.pgm", pixels)
  grid = load_map(_write_yaml(tmp_path / "map.yaml", origin=[1.5, -2.0, 0.0]))
  assert grid.occupied[-1].all() and not grid.occupied[:-1].any()
  assert grid.origin == (1.5, -2.0) and grid.res == 0.1
  assert grid.name == "map"
  assert load_map(tmp_path / "map.yaml", name="other").name == "other"


def test_grey_thresholds_and_unknown_is_occupied(tmp_path):
  # p = (255 - v) / 255: 254 -> 0.004 free; 205 -> 0.196078 unknown (not < 0.196);
  # 206 -> 0.192 free; 89 -> 0.651 occupied; 90 -> 0.647 unknown; 0 occupied.
  values = np.array([[254, 205, 206, 89, 90, 0]], dtype=np.uint8)
  _write_image(tmp_path / "map.pgm", np.repeat(values, 3, axis=0))
  grid = load_map(_write_yaml(tmp_path / "map.yaml"))
  np.testing.assert_array_equal(grid.free[0], [True, False, True, False, False, False])


def test_rgb_uses_the_mean_of_the_three_channels(tmp_path):
  pixels = np.zeros((3, 4, 3), dtype=np.uint8)
  pixels[:, 0] = (255, 255, 250)  # mean 253.3 -> free
  pixels[:, 1] = (255, 255, 0)    # mean 170 -> p 0.33, unknown -> occupied
  pixels[:, 2] = (0, 255, 255)    # mean 170 -> occupied
  pixels[:, 3] = (240, 255, 225)  # mean 240 -> p 0.059, free
  _write_image(tmp_path / "map.png", pixels, "RGB")
  grid = load_map(_write_yaml(tmp_path / "map.yaml", image="map.png"))
  np.testing.assert_array_equal(grid.free[0], [True, False, False, True])


def test_rgba_ignores_alpha(tmp_path):
  pixels = np.zeros((3, 3, 4), dtype=np.uint8)
  pixels[:, 0] = (255, 255, 255, 0)    # transparent white: still free
  pixels[:, 1] = (0, 0, 0, 255)
  pixels[:, 2] = (230, 230, 230, 255)  # intel's grey background: unknown at free_thresh 0.04
  _write_image(tmp_path / "map.png", pixels, "RGBA")
  grid = load_map(_write_yaml(tmp_path / "map.yaml", image="map.png", free_thresh=0.04))
  np.testing.assert_array_equal(grid.free[0], [True, False, False])
  grid = load_map(_write_yaml(tmp_path / "map.yaml", image="map.png", free_thresh=0.196))
  np.testing.assert_array_equal(grid.free[0], [True, False, True])


def test_negate_inverts_grey(tmp_path):
  values = np.array([[0, 255, 20, 128]], dtype=np.uint8)
  _write_image(tmp_path / "map.png", np.repeat(values, 3, axis=0))
  grid = load_map(_write_yaml(tmp_path / "map.yaml", image="map.png", negate=1))
  # With negate, p = v / 255: 0 free, 255 occupied, 20 -> 0.078 free, 128 -> 0.5 unknown.
  np.testing.assert_array_equal(grid.free[0], [True, False, True, False])


def test_palette_and_bilevel_images(tmp_path):
  pixels = np.array([[0, 255, 255]] * 3, dtype=np.uint8)
  Image.fromarray(pixels).convert("P").save(tmp_path / "palette.png")
  Image.fromarray(pixels).convert("1").save(tmp_path / "bilevel.png")
  for image in ("palette.png", "bilevel.png"):
    grid = load_map(_write_yaml(tmp_path / "map.yaml", image=image))
    np.testing.assert_array_equal(grid.free[0], [False, True, True])


def test_explicit_trinary_mode_is_accepted(tmp_path):
  assert load_map(_small_map(tmp_path, mode="trinary")).free.sum() == 6


# --- Bad inputs -----------------------------------------------------------------------------


def test_missing_yaml(tmp_path):
  with pytest.raises(MapError, match="nope.yaml.*not found"):
    load_map(tmp_path / "nope.yaml")


def test_unparseable_yaml(tmp_path):
  path = tmp_path / "broken.yaml"
  path.write_text("image: [map.pgm\nresolution: 0.1\n")
  with pytest.raises(MapError, match="broken.yaml.*not parseable"):
    load_map(path)


def test_yaml_that_is_not_a_mapping(tmp_path):
  path = tmp_path / "list.yaml"
  path.write_text("- 1\n- 2\n")
  with pytest.raises(MapError, match="list.yaml"):
    load_map(path)


@pytest.mark.parametrize("key", ["image", "resolution", "origin", "negate", "occupied_thresh",
                                 "free_thresh"])
def test_missing_key(tmp_path, key):
  path = _small_map(tmp_path, **{key: None})
  with pytest.raises(MapError, match=f"map.yaml.*missing key.*{key}"):
    load_map(path)


def test_missing_image(tmp_path):
  path = _write_yaml(tmp_path / "map.yaml", image="ghost.pgm")
  with pytest.raises(MapError, match="ghost.pgm.*not found"):
    load_map(path)


def test_corrupt_image(tmp_path):
  (tmp_path / "map.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
  path = _write_yaml(tmp_path / "map.yaml", image="map.png")
  with pytest.raises(MapError, match="map.png.*unreadable"):
    load_map(path)


def test_unsupported_pixel_mode(tmp_path):
  Image.fromarray(np.full((4, 4), 1000, dtype=np.uint16)).save(tmp_path / "deep.png")  # 16-bit
  path = _write_yaml(tmp_path / "map.yaml", image="deep.png")
  with pytest.raises(MapError, match="deep.png.*mode"):
    load_map(path)


def test_no_free_cell(tmp_path):
  _write_image(tmp_path / "map.pgm", np.full((4, 4), 205, dtype=np.uint8))
  path = _write_yaml(tmp_path / "dark.yaml")
  with pytest.raises(MapError, match="dark.yaml.*no free cell"):
    load_map(path)


@pytest.mark.parametrize("overrides, message", [
    ({"occupied_thresh": 1.5}, "occupied_thresh must be in"),
    ({"free_thresh": -0.1}, "free_thresh must be in"),
    ({"free_thresh": 0.7}, "free_thresh .* must be below occupied_thresh"),
    ({"free_thresh": 0.65}, "free_thresh .* must be below occupied_thresh"),
    ({"free_thresh": "low"}, "free_thresh must be a number"),
    ({"resolution": 0}, "resolution must be positive"),
    ({"resolution": -0.05}, "resolution must be positive"),
    ({"resolution": "fine"}, "resolution must be a number"),
    ({"origin": [0.0, 0.0, 0.5]}, "yaw must be 0"),
    ({"origin": [0.0, 0.0]}, "origin must be a list"),
    ({"origin": [float("nan"), 0.0, 0.0]}, "origin must be a list .* of finite numbers"),
    ({"origin": [0.0, float("inf"), 0.0]}, "origin must be a list .* of finite numbers"),
    ({"negate": 2}, "negate must be 0 or 1"),
    ({"mode": "scale"}, "mode 'scale' is not supported"),
])
def test_bad_values(tmp_path, overrides, message):
  path = _small_map(tmp_path, **overrides)
  with pytest.raises(MapError, match=f"map.yaml.*{message}"):
    load_map(path)


# --- Saving ---------------------------------------------------------------------------------


@pytest.mark.parametrize("res, origin", [(0.1, (0.0, 0.0)), (0.048, (-12.5, 3.25)),
                                         (0.05, (-50.0, -50.0))])
def test_save_load_round_trip(tmp_path, res, origin):
  occupied = np.random.default_rng(0).random((37, 53)) < 0.3
  occupied[0, 0] = False
  grid = GridMap(occupied, res, origin, "round_trip")
  save_map(grid, tmp_path / "round_trip.yaml")
  assert (tmp_path / "round_trip.pgm").is_file()
  loaded = load_map(tmp_path / "round_trip.yaml")
  np.testing.assert_array_equal(loaded.occupied, grid.occupied)
  assert loaded.res == grid.res and loaded.origin == grid.origin and loaded.name == "round_trip"
  pixels = np.asarray(Image.open(tmp_path / "round_trip.pgm"))
  assert set(np.unique(pixels)) <= {0, 254}
  np.testing.assert_array_equal(pixels[::-1] == 0, occupied)


def test_save_into_missing_folder(tmp_path):
  grid = GridMap(np.zeros((3, 3), bool), 0.1)
  with pytest.raises(MapError, match="folder not found"):
    save_map(grid, tmp_path / "no" / "such" / "map.yaml")


# --- Resampling -----------------------------------------------------------------------------


def _resample_oracle(occupied: np.ndarray, res_fine: str, res_coarse: str) -> np.ndarray:
  """Plain loops in exact rational arithmetic: the rule, cell by cell."""
  fine, coarse = Fraction(res_fine), Fraction(res_coarse)
  height, width = occupied.shape
  coarse_height = math.ceil(height * fine / coarse)
  coarse_width = math.ceil(width * fine / coarse)
  result = np.zeros((coarse_height, coarse_width), dtype=bool)
  for big_row in range(coarse_height):
    for big_col in range(coarse_width):
      # Part of this coarse cell lies outside the fine grid: counts as occupied.
      if (big_row + 1) * coarse > height * fine or (big_col + 1) * coarse > width * fine:
        result[big_row, big_col] = True
        continue
      for row in range(height):
        if not big_row * coarse <= row * fine < (big_row + 1) * coarse:
          continue
        for col in range(width):
          if big_col * coarse <= col * fine < (big_col + 1) * coarse and occupied[row, col]:
            result[big_row, big_col] = True
  return result


RESOLUTION_PAIRS = [("0.05", "0.1"), ("0.05", "0.15"), ("0.048", "0.2"), ("0.1", "0.25"),
                    ("0.1", "0.3"), ("0.045", "0.1"), ("0.1", "0.1"), ("0.05", "0.07")]


@settings(max_examples=40, deadline=None)
@given(height=st.integers(3, 30), width=st.integers(3, 30), density=st.floats(0.0, 0.3),
       seed=st.integers(0, 2**16), pair=st.sampled_from(RESOLUTION_PAIRS))
def test_resample_matches_loop_oracle(height, width, density, seed, pair):
  res_fine, res_coarse = pair
  ratio = Fraction(res_fine) / Fraction(res_coarse)
  assume(min(height, width) * ratio > 2)  # At least 3 coarse cells across.
  occupied = np.random.default_rng(seed).random((height, width)) < density
  grid = GridMap(occupied, float(res_fine), (-1.0, 2.0), "random")
  coarse = resample(grid, float(res_coarse))
  expected = _resample_oracle(occupied, res_fine, res_coarse)
  np.testing.assert_array_equal(coarse.occupied, expected)
  assert coarse.res == float(res_coarse) and coarse.origin == (-1.0, 2.0)


def test_resample_integer_factor_by_hand():
  occupied = np.zeros((5, 6), dtype=bool)
  occupied[2, 1] = True
  coarse = resample(GridMap(occupied, 0.1), 0.2)
  # 5 rows -> 3 coarse rows, the last one half outside the grid (occupied).
  expected = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 1]], dtype=bool)
  np.testing.assert_array_equal(coarse.occupied, expected)


def test_resample_refuses_finer_and_bad_values():
  grid = GridMap(np.zeros((4, 4), bool), 0.1, name="fine")
  with pytest.raises(MapError, match="'fine'.*finer"):
    resample(grid, 0.05)
  for bad in (0.0, -1.0, float("nan"), "0.2"):
    with pytest.raises(MapError, match="positive number"):
      resample(grid, bad)
  with pytest.raises(MapError, match="under the 3x3 minimum"):
    resample(grid, 0.2)


def test_resample_to_same_resolution_is_a_copy():
  occupied = np.random.default_rng(1).random((6, 7)) < 0.5
  grid = GridMap(occupied, 0.05, (1.0, 1.0), "same")
  same = resample(grid, 0.05)
  np.testing.assert_array_equal(same.occupied, grid.occupied)
  assert same.occupied is not grid.occupied


def test_a_map_above_pillows_bomb_limit_loads_and_one_beyond_memory_is_refused(tmp_path,
                                                                               monkeypatch):
  """Pillow refuses images over 2 x MAX_IMAGE_PIXELS (a 20000 x 20000 map) as decompression
  bombs; a map is checked against the memory reading it takes instead."""
  from jaxplore.maps import io
  pixels = np.full((40, 60), 254, np.uint8)
  pixels[10, :30] = 0
  yaml_path = _write_yaml(tmp_path / "map.yaml", image="map.png")
  _write_image(tmp_path / "map.png", pixels)
  monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # 2400 px is a "bomb" now
  with pytest.raises(Image.DecompressionBombError):
    Image.open(tmp_path / "map.png")
  grid = load_map(yaml_path)
  np.testing.assert_array_equal(grid.occupied, pixels[::-1] < 200)
  assert Image.MAX_IMAGE_PIXELS == 100  # restored
  monkeypatch.setattr(io, "_available_bytes", lambda: 10_000)
  with pytest.raises(MapError, match=r"60 x 40 pixels .* more than 80% of the"):
    load_map(yaml_path)


# --- Reading big maps at a coarser resolution ------------------------------------------------


def _write_pgm(path: Path, samples: np.ndarray, maxval: int = 255, plain: bool = False) -> Path:
  """A PGM written by hand (binary P5 or plain-text P2), with map_saver's header comment."""
  height, width = samples.shape
  header = f"{'P2' if plain else 'P5'}\n# CREATOR: map_saver.cpp 0.050 m/pix\n{width} {height}\n"
  header += f"{maxval}\n"
  if plain:
    body = "\n".join(" ".join(map(str, row)) for row in samples).encode() + b"\n"
  else:
    body = samples.astype(np.uint8 if maxval < 256 else ">u2").tobytes()
  path.write_bytes(header.encode() + body)
  return path


def _expected_grid(pixels: np.ndarray, res_fine: float, res: float, free_thresh=0.196,
                   negate=0) -> np.ndarray:
  """The whole-image rule: each pixel classified (numpy), flipped, then `resample`d."""
  grey = np.arange(256.0)  # each pixel's value looked up: float64 pixels of 36 Mpx are slow
  occupancy = grey / 255 if negate else (255 - grey) / 255
  whole = GridMap(~(occupancy < free_thresh)[pixels[::-1]], res_fine, name="whole")
  return resample(whole, res).occupied


def _map_pixels(rng, height: int, width: int, walls: int, speckle: float) -> np.ndarray:
  """Free (254) with random wall segments (0) and scattered unknown (205) and grey pixels."""
  pixels = np.full((height, width), 254, np.uint8)
  for _ in range(walls):
    row, col, length = rng.integers(0, height), rng.integers(0, width), rng.integers(5, 200)
    if rng.random() < 0.5:
      pixels[row, col:col + length] = 0
    else:
      pixels[row:row + length, col] = 0
  spots = int(speckle * height * width)
  pixels[rng.integers(0, height, spots), rng.integers(0, width, spots)] = rng.choice(
      np.array([205, 206, 100, 0], np.uint8), size=spots)
  return pixels


@pytest.mark.parametrize("negate", [0, 1])
def test_strips_of_a_pgm_give_the_whole_image_rule(tmp_path, monkeypatch, negate):
  """Odd sizes and strips of 7 rows: coarse cells that straddle strips, partial last cells."""
  from jaxplore.maps import io, load_world
  rng = np.random.default_rng(negate)
  pixels = _map_pixels(rng, 157, 203, walls=25, speckle=0.002)
  if negate:
    pixels = 255 - pixels
  _write_pgm(tmp_path / "map.pgm", pixels)
  _write_image(tmp_path / "map.png", pixels)
  monkeypatch.setattr(io, "STRIP_PIXELS", 7 * 203)
  for res_fine, res in [(0.05, 0.05), (0.05, 0.15), (0.048, 0.2), (0.05, 0.07), (0.1, 1.0)]:
    pgm = _write_yaml(tmp_path / "pgm.yaml", image="map.pgm", resolution=res_fine, negate=negate)
    png = _write_yaml(tmp_path / "png.yaml", image="map.png", resolution=res_fine, negate=negate)
    expected = _expected_grid(pixels, res_fine, res, negate=negate)
    for yaml_path in (pgm, png):
      grid = load_map(yaml_path, res=res)
      np.testing.assert_array_equal(grid.occupied, expected, err_msg=f"{yaml_path} at {res}")
      assert grid.res == res and grid.name == yaml_path.stem
    np.testing.assert_array_equal(load_world(pgm, res=res).occupied, expected)


def test_a_6000_pixel_pgm_read_20_times_coarser(tmp_path):
  rng = np.random.default_rng(6)
  pixels = _map_pixels(rng, 5993, 6007, walls=3000, speckle=2e-5)
  yaml_path = _write_yaml(tmp_path / "big.yaml", image="big.pgm", resolution=0.05)
  _write_pgm(tmp_path / "big.pgm", pixels)
  grid = load_map(yaml_path, res=1.0)
  expected = _expected_grid(pixels, 0.05, 1.0)
  assert grid.shape == expected.shape == (300, 301)
  assert 0.05 < expected.mean() < 0.95
  np.testing.assert_array_equal(grid.occupied, expected)


def test_pgm_sample_depths(tmp_path):
  """8-bit PGMs with maxval below 255 read as Pillow scales them; 16-bit PGMs (which Pillow
  cannot read as grey) give p = (maxval - v) / maxval; plain-text PGM (P2) reads through Pillow;
  16-bit P2 is refused with the way out."""
  rng = np.random.default_rng(3)
  yaml_path = _write_yaml(tmp_path / "map.yaml", image="map.pgm")
  for maxval in (15, 100):
    samples = rng.integers(0, maxval + 1, (9, 11))
    _write_pgm(tmp_path / "map.pgm", samples, maxval)
    pillow_grey = np.asarray(Image.open(tmp_path / "map.pgm"))
    np.testing.assert_array_equal(load_map(yaml_path).occupied,
                                  _expected_grid(pillow_grey, 0.1, 0.1))
  for maxval in (1000, 65535):
    samples = rng.integers(0, maxval + 1, (9, 11))
    samples[0, :3] = (0, maxval, round(maxval * 0.9))
    _write_pgm(tmp_path / "map.pgm", samples, maxval)
    free = (maxval - samples) / maxval < 0.196
    np.testing.assert_array_equal(load_map(yaml_path).free, free[::-1])
  pixels = _map_pixels(rng, 12, 14, walls=3, speckle=0.1)
  _write_pgm(tmp_path / "map.pgm", pixels, plain=True)
  np.testing.assert_array_equal(load_map(yaml_path, res=0.3).occupied,
                                _expected_grid(pixels, 0.1, 0.3))
  _write_pgm(tmp_path / "map.pgm", rng.integers(0, 1001, (9, 11)), 1000, plain=True)
  with pytest.raises(MapError, match="map.pgm.*mode 'I'.*16-bit grey is read from binary PGM"):
    load_map(yaml_path)


@pytest.mark.parametrize("content, message", [
    (b"P5\n4 3\n255\n" + bytes(11), "truncated: 11 bytes of pixels, 4 x 3 at 8 bits take 12"),
    (b"P5\n4 3\n65535\n" + bytes(12), "truncated: 12 bytes .* at 16 bits take 24"),
    (b"P5\n4 -3\n255\n" + bytes(12), "unreadable .*'-3' is not a positive integer"),
    (b"P5\n4 3\n0\n" + bytes(12), r"unreadable .*maxval 0\)"),
    (b"P5\n4 3", "unreadable .*'' is not a positive integer"),
    (b"P5\n4 3\n" + bytes(range(50, 58)) * 100, "unreadable .*'234567"),
])
def test_broken_binary_pgm(tmp_path, content, message):
  (tmp_path / "map.pgm").write_bytes(content)
  with pytest.raises(MapError, match=f"map.yaml.*map.pgm.*{message}"):
    load_map(_write_yaml(tmp_path / "map.yaml"))


def test_memory_check_counts_a_whole_decode_but_only_a_strip_of_a_pgm(tmp_path, monkeypatch):
  from jaxplore.maps import io
  pixels = _map_pixels(np.random.default_rng(4), 400, 600, walls=20, speckle=0.0)
  _write_pgm(tmp_path / "map.pgm", pixels)
  _write_image(tmp_path / "map.png", pixels)
  monkeypatch.setattr(io, "STRIP_PIXELS", 10 * 600)
  strip_and_grid = 10 * 600 * io.STRIP_BYTES_PER_PIXEL + 40 * 60 * io.GRID_BYTES_PER_CELL
  # Room for a strip and the 60 x 40 grid, not for the 600 x 400 decoded PNG (1 byte a pixel).
  monkeypatch.setattr(io, "_available_bytes", lambda: int((strip_and_grid + 200_000) / 0.8))
  pgm = load_map(_write_yaml(tmp_path / "pgm.yaml", image="map.pgm"), res=1.0)
  np.testing.assert_array_equal(pgm.occupied, _expected_grid(pixels, 0.1, 1.0))
  with pytest.raises(MapError, match=r"600 x 400 pixels .*decoded whole \(0.0 GiB: only binary "
                     r"PGM is read in strips\); reading it into a 60 x 40 grid takes about"):
    load_map(_write_yaml(tmp_path / "png.yaml", image="map.png"), res=1.0)
  with pytest.raises(MapError, match=r"read in strips of rows; reading it into a 600 x 400 grid"):
    load_map(_write_yaml(tmp_path / "pgm.yaml", image="map.pgm"))


def test_binary_pgm_header_with_comments_reads_as_pillow_reads_it(tmp_path):
  pixels = _map_pixels(np.random.default_rng(5), 6, 7, walls=2, speckle=0.2)
  header = b"P5 # made by hand\n7\t# width\n\n6\r255\n"
  (tmp_path / "map.pgm").write_bytes(header + pixels.tobytes())
  np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "map.pgm")), pixels)
  np.testing.assert_array_equal(load_map(_write_yaml(tmp_path / "map.yaml")).occupied,
                                _expected_grid(pixels, 0.1, 0.1))
