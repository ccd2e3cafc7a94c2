"""Tests for jaxplore.maps.generate: determinism, connectivity, passage widths, sizes."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy import ndimage

from jaxplore.maps import GridMap, MapError, resample
from jaxplore.maps import generate

# name -> (generator called as f(width_m, height_m, res, seed), width_m, height_m, res,
#          (lowest, highest) free fraction)
GENERATORS = {
    "office": (generate.office, 30.0, 20.0, 0.1, (0.75, 0.97)),
    "office_coarse": (generate.office, 45.0, 25.0, 0.2, (0.75, 0.97)),
    "maze": (generate.maze, 15.0, 12.0, 0.1, (0.6, 0.9)),
    "open_clutter": (functools.partial(generate.open_clutter, density=0.1), 20.0, 15.0, 0.1,
                     (0.8, 0.95)),
    "cave": (generate.cave, 20.0, 15.0, 0.1, (0.3, 0.8)),
    "campus": (generate.campus, 60.0, 50.0, 0.25, (0.75, 0.95)),
}


def _build(name: str, seed: int) -> GridMap:
  generator, width_m, height_m, res, _ = GENERATORS[name]
  return generator(width_m, height_m, res, seed)


def _disc(radius_cells: float) -> np.ndarray:
  half = int(radius_cells)
  offsets = np.arange(-half, half + 1)
  return offsets[:, None]**2 + offsets[None, :]**2 <= radius_cells**2


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_same_seed_same_world_other_seed_other_world(name):
  first, again, other = _build(name, 3), _build(name, 3), _build(name, 4)
  np.testing.assert_array_equal(first.occupied, again.occupied)
  assert (first.occupied != other.occupied).any()


@pytest.mark.parametrize("name", sorted(GENERATORS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_size_border_connectivity_and_free_fraction(name, seed):
  _, width_m, height_m, res, (lowest, highest) = GENERATORS[name]
  grid = _build(name, seed)
  assert grid.shape == (round(height_m / res), round(width_m / res))
  assert grid.res == res and grid.origin == (0.0, 0.0)
  assert grid.occupied[[0, -1], :].all() and grid.occupied[:, [0, -1]].all()
  _, count = ndimage.label(grid.free)  # 4-connectivity
  assert count == 1
  assert lowest <= grid.free.mean() <= highest


@pytest.mark.parametrize("name", sorted(GENERATORS))
@pytest.mark.parametrize("seed", [0, 1])
def test_a_robot_of_diameter_08_m_reaches_nearly_everything(name, seed):
  # Passages (doors, corridors, gaps) are ~1 m wide: the centres where a 0.8 m disc fits form
  # one connected region, and the disc swept through it covers nearly all free space.
  grid = _build(name, seed)
  disc = _disc(0.4 / grid.res)
  centres = ndimage.binary_erosion(grid.free, structure=disc, border_value=0)
  _, count = ndimage.label(centres)
  assert count == 1
  swept = ndimage.binary_dilation(centres, structure=disc)
  assert swept.sum() >= 0.95 * grid.free.sum()


def test_office_layout_does_not_depend_on_resolution():
  fine = generate.office(30.0, 20.0, 0.05, seed=7)
  coarse = generate.office(30.0, 20.0, 0.1, seed=7)
  # Walls and doors land on the same 0.1 m lines at both resolutions.
  agreement = (resample(fine, 0.1).occupied == coarse.occupied).mean()
  assert agreement > 0.99
  assert fine.free_area == pytest.approx(coarse.free_area, rel=0.05)


@pytest.mark.parametrize("width_m, height_m, res, corridor_spacing_m", [
    (45.0, 25.0, 0.2, 24.0), (30.0, 20.0, 0.1, 24.0), (46.0, 36.0, 0.2, 20.0),
    (17.0, 13.0, 0.1, 12.0), (33.3, 21.7, 0.15, 24.0)])
def test_office_connects_every_room(width_m, height_m, res, corridor_spacing_m):
  # Before the final clean-up fills stray pockets, the doors already join all rooms.
  for seed in range(40):
    occupied = generate._office_layout(
        width_m, height_m, res, seed, corridor_m=2.0, door_m=1.2, wall_m=0.2, room_min_m=3.0,
        room_max_m=7.0, corridor_spacing_m=corridor_spacing_m, extra_door_prob=0.15)
    assert ndimage.label(~occupied)[1] == 1, f"seed {seed}"


def test_office_doors_are_at_least_a_metre_wide():
  grid = generate.office(30.0, 20.0, 0.1, seed=0, door_m=1.0)
  disc = _disc(0.45 / grid.res)
  centres = ndimage.binary_erosion(grid.free, structure=disc, border_value=0)
  assert ndimage.label(centres)[1] == 1


def test_office_small_floor_is_one_connected_set_of_rooms():
  grid = generate.office(12.0, 9.0, 0.1, seed=5)
  assert ndimage.label(grid.free)[1] == 1
  # Several rooms: cutting the doors' wall cells apart leaves more than one region, i.e. the
  # floor really is split by walls.
  opened = ndimage.binary_erosion(grid.free, structure=_disc(0.7 / grid.res), border_value=0)
  assert ndimage.label(opened)[1] >= 2


def test_maze_is_perfect():
  # No loops in a perfect maze: the free region is simply connected, so every wall is joined
  # (8-connected) to the outer wall; a loop would enclose a wall island.
  grid = generate.maze(10.0, 8.0, 0.1, seed=2)
  _, wall_pieces = ndimage.label(grid.occupied, structure=np.ones((3, 3)))
  assert wall_pieces == 1


def test_maze_corridor_width_in_cells():
  grid = generate.maze(10.0, 10.0, 0.05, seed=0, corridor_m=1.2, wall_m=0.2)
  # Wall 4 cells, then the first corridor 24 cells, along the bottom-left lattice cell.
  row = grid.free[4 + 12]
  assert not row[:4].any() and row[4:28].all()


def test_open_clutter_gaps_respect_the_clearance():
  grid = generate.open_clutter(20.0, 20.0, 0.1, seed=1, density=0.2, clearance_m=1.5)
  labels, count = ndimage.label(grid.occupied, structure=np.ones((3, 3)))
  assert count > 5  # Obstacles (plus the outer wall) are separate islands.
  distance_to = [ndimage.distance_transform_edt(labels != k) for k in range(1, count + 1)]
  for k in range(count):
    others = labels != 0
    others &= labels != k + 1
    assert distance_to[k][others].min() * grid.res >= 1.5 - 2 * grid.res


def test_cave_keeps_only_wide_passages():
  grid = generate.cave(20.0, 20.0, 0.1, seed=0, min_passage_m=1.2)
  disc = _disc(0.6 / grid.res)
  centres = ndimage.binary_erosion(grid.free, structure=disc, border_value=0)
  swept = ndimage.binary_dilation(centres, structure=disc)
  np.testing.assert_array_equal(swept & grid.free, grid.free)


def test_floor_plan_boxes():
  grid = generate.floor_plan(5.0, 4.0, 0.1, [(1.0, 1.0, 2.0, 3.0), (2.0, 1.5, 4.0, 2.5),
                                              (4.5, 3.0, 4.8, 3.5)])
  assert grid.shape == (40, 50)
  # The two touching boxes form the single kept component; the far one is filled.
  assert grid.free.sum() == 10 * 20 + 20 * 10
  assert not grid.occupied[10:30, 10:20].any()
  assert grid.occupied[30:35, 45:48].all()


@pytest.mark.parametrize("call, message", [
    (lambda: generate.office(-1.0, 10.0, 0.1, 0), "width_m must be a positive number"),
    (lambda: generate.office(10.0, 10.0, 0.0, 0), "res must be a positive number"),
    (lambda: generate.office(2.0, 10.0, 0.1, 0), "too small"),
    (lambda: generate.office(10.0, 10.0, 0.1, 0, room_min_m=5.0, room_max_m=4.0), "room_min_m"),
    (lambda: generate.maze(1.0, 1.0, 0.1, 0, corridor_m=1.2), "too small"),
    (lambda: generate.open_clutter(10.0, 10.0, 0.1, 0, density=1.5), "density"),
    (lambda: generate.campus(10.0, 10.0, 0.1, 0), "too small"),
    (lambda: generate.office(10.0, 10.0, 5.0, 0), "under 3 cells"),
])
def test_invalid_arguments(call, message):
  with pytest.raises(MapError, match=message):
    call()
