"""Tests for jaxplore.maps.worlds: named worlds, load_world, reachability, table, rendering."""

from __future__ import annotations


import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from conftest import SHARED_MAPS, needs_shared_maps
from jaxplore.maps import (
    WORLDS,
    GridMap,
    MapError,
    get_world,
    largest_component,
    load_world,
    reachable_mask,
    render_png,
    resample,
    save_map,
    world_table,
)


# The free areas documented in jaxplore/maps/worlds.py (m²).
DOCUMENTED_FREE_M2 = {
    "open": 372,
    "office": 1029,
    "lab": 197,
    "building": 1520,
    "campus": 3962,
    "corridors": 173,
    "maze": 329,
    "cave": 274,
}


def test_documented_worlds_are_the_built_in_ones():
  assert set(WORLDS) == set(DOCUMENTED_FREE_M2)
  for name, spec in WORLDS.items():
    assert spec.name == name and spec.description and spec.res > 0


@pytest.mark.parametrize("name", sorted(DOCUMENTED_FREE_M2))
def test_world_free_area_size_and_connectivity(name):
  grid = get_world(name)
  assert grid.name == name and grid.res == WORLDS[name].res
  assert grid.free_area == pytest.approx(DOCUMENTED_FREE_M2[name], rel=0.15)
  assert max(grid.shape) <= 256, "built-in worlds stay within 256 x 256 cells"
  assert ndimage.label(grid.free)[1] == 1


def test_paper_scales():
  assert get_world("open").extent_m == pytest.approx((20.0, 20.0))
  assert get_world("office").extent_m == pytest.approx((45.0, 25.0))
  assert get_world("maze").extent_m == pytest.approx((20.0, 20.0))
  assert get_world("lab").free_area == pytest.approx(200, rel=0.15)
  assert get_world("building").free_area == pytest.approx(1500, rel=0.15)
  assert get_world("campus").free_area == pytest.approx(4000, rel=0.15)


@pytest.mark.parametrize("name", sorted(WORLDS))
def test_default_start_is_free_reachable_and_clear(name):
  start = WORLDS[name].start
  assert start is not None, f"built-in world {name} has no default start"
  grid = get_world(name)
  row, col = grid.world_to_cell(*start)
  assert not grid.occupied[row, col]
  assert largest_component(grid)[row, col]
  clearance_m = ndimage.distance_transform_edt(grid.free)[row, col] * grid.res
  assert clearance_m >= 0.5


def test_worlds_are_deterministic_and_returned_as_copies():
  first = get_world("office")
  first.occupied[:] = True
  again = get_world("office")
  assert again.free.any()
  np.testing.assert_array_equal(again.occupied, WORLDS["office"].builder(0.2).occupied)


def test_unknown_world_names_the_valid_ones():
  with pytest.raises(MapError) as error:
    get_world("nope")
  message = str(error.value)
  assert "'nope'" in message
  for name in WORLDS:
    assert name in message


def test_native_resolution_given_explicitly():
  np.testing.assert_array_equal(get_world("lab", res=0.1).occupied, get_world("lab").occupied)


def test_coarser_resolution_resamples():
  coarse = get_world("open", res=0.25)
  np.testing.assert_array_equal(coarse.occupied, resample(get_world("open"), 0.25).occupied)
  assert coarse.res == 0.25


def test_finer_resolution_regenerates_the_same_layout():
  fine = get_world("office", res=0.1)
  native = get_world("office")
  assert fine.res == 0.1 and fine.shape == (250, 450)
  assert fine.free_area == pytest.approx(native.free_area, rel=0.05)
  # Same walls: downsampling the fine world only thickens some of them (by one coarse cell
  # where a 2-cell wall straddles two coarse cells); it never opens a native wall.
  downsampled = resample(fine, 0.2)
  assert not (downsampled.free & native.occupied).any()
  assert (downsampled.occupied == native.occupied).mean() > 0.95


def test_load_world_by_name_and_unknown_spec():
  np.testing.assert_array_equal(load_world("maze").occupied, get_world("maze").occupied)
  with pytest.raises(MapError, match="not a built-in world.*office"):
    load_world("nope")
  with pytest.raises(MapError, match="ghost.yaml.*not found"):
    load_world("ghost.yaml")


def test_load_world_from_a_yaml_path(tmp_path):
  grid = get_world("corridors")
  save_map(grid, tmp_path / "saved.yaml")
  loaded = load_world(str(tmp_path / "saved.yaml"))
  np.testing.assert_array_equal(loaded.occupied, grid.occupied)
  assert loaded.name == "saved"
  coarse = load_world(tmp_path / "saved.yaml", res=0.2)
  np.testing.assert_array_equal(coarse.occupied, resample(grid, 0.2).occupied)
  with pytest.raises(MapError, match="finer"):
    load_world(tmp_path / "saved.yaml", res=0.05)


@needs_shared_maps
def test_load_world_shared_map():
  grid = load_world(str(SHARED_MAPS / "intel.yaml"), res=0.2)
  assert grid.name == "intel" and grid.res == 0.2 and grid.shape == (140, 139)


def _two_rooms() -> GridMap:
  occupied = np.ones((7, 9), dtype=bool)
  occupied[1:6, 1:4] = False  # 15 cells
  occupied[1:3, 5:8] = False  # 6 cells
  occupied[4, 6] = False      # 1 cell, diagonal to nothing free
  return GridMap(occupied, 0.5, name="two_rooms")


def test_reachable_mask():
  grid = _two_rooms()
  left = reachable_mask(grid, (2, 2))
  assert left.sum() == 15 and left[1:6, 1:4].all()
  right = reachable_mask(grid, (1, 7))
  assert right.sum() == 6
  assert reachable_mask(grid, (4, 6)).sum() == 1
  with pytest.raises(MapError, match=r"start cell \(0, 0\) is occupied"):
    reachable_mask(grid, (0, 0))
  with pytest.raises(MapError, match="outside"):
    reachable_mask(grid, (7, 2))


def test_reachable_mask_is_4_connected():
  occupied = np.ones((4, 4), dtype=bool)
  occupied[1, 1] = occupied[2, 2] = False
  assert reachable_mask(GridMap(occupied, 1.0), (1, 1)).sum() == 1


def test_largest_component():
  grid = _two_rooms()
  np.testing.assert_array_equal(largest_component(grid), reachable_mask(grid, (1, 1)))
  assert not largest_component(GridMap(np.ones((3, 3), bool), 1.0)).any()


def test_world_table():
  rows = world_table()
  assert [row["name"] for row in rows] == list(WORLDS)
  for row in rows:
    grid = get_world(row["name"])
    assert (row["height_cells"], row["width_cells"]) == grid.shape
    assert row["res"] == grid.res
    assert (row["width_m"], row["height_m"]) == pytest.approx(grid.extent_m)
    assert row["free_m2"] == pytest.approx(grid.free_area, abs=0.01)
    assert 0 < row["reachable_m2"] <= row["free_m2"] + 1e-9
    assert row["start"] == WORLDS[row["name"]].start


def test_render_png(tmp_path):
  grid = get_world("corridors")
  render_png(grid, tmp_path / "plain.png")
  walk = np.array([[4.5, 4.5], [10.0, 4.5], [20.5, 4.5], [20.5, 13.5]])
  render_png(grid, tmp_path / "one.png", walk, title="one robot")
  render_png(grid, tmp_path / "stack.png", np.stack([walk, walk + 0.2]))
  render_png(grid, tmp_path / "list.png", [walk, walk[:2], np.zeros((0, 2))])
  render_png(grid, tmp_path / "jax.png", jnp.asarray(walk))
  for name in ("plain", "one", "stack", "list", "jax"):
    with Image.open(tmp_path / f"{name}.png") as image:
      assert image.format == "PNG" and image.size[0] > 300
  with pytest.raises(ValueError, match="shape"):
    render_png(grid, tmp_path / "bad.png", [np.zeros((3, 3))])


def test_a_much_finer_world_is_announced_and_an_unindexable_one_refused(capsys):
  with pytest.raises(MapError, match=r"lab.* at 1e-09 m/cell would be .* more than the"):
    get_world("lab", res=1e-9)
  get_world("open", res=0.05)  # 4x the native cells: drawn without a word
  assert "warning" not in capsys.readouterr().err
  get_world("lab", res=0.025)  # 16x
  err = capsys.readouterr().err
  assert "world 'lab' at 0.025 m/cell is 680 x 520 = 353,600 cells, 16x its 170 x 130" in err
