"""The frontier machinery the engine offers planners (jaxplore/frontiers.py)."""

import numpy as np
import jax
import jax.numpy as jnp

from conftest import EAGER_AND_JIT
from jaxplore import frontiers, mapping


def unknown_neighbour_numpy(cell, unknown, occupied):
  """The rule in a plain loop: the first 8-neighbour (in ``mapping.NEIGHBOURS_8`` order) that is
  unknown and, for a diagonal, not sealed off by two occupied cells; outside the grid nothing is
  unknown and everything is occupied."""
  h, w = unknown.shape
  inside = lambda r, c: 0 <= r < h and 0 <= c < w
  is_unknown = lambda r, c: inside(r, c) and unknown[r, c]
  is_occupied = lambda r, c: not inside(r, c) or occupied[r, c]
  r0, c0 = cell
  if not inside(r0, c0):
    return cell
  for di, dj in mapping.NEIGHBOURS_8:
    if not is_unknown(r0 + di, c0 + dj):
      continue
    if di and dj and is_occupied(r0 + di, c0) and is_occupied(r0, c0 + dj):
      continue
    return (r0 + di, c0 + dj)
  return cell


@EAGER_AND_JIT
def test_unknown_neighbour_is_the_first_open_unknown_neighbour_by_numpy(transform):
  rng = np.random.default_rng(3)
  find = transform(frontiers.unknown_neighbour)
  h, w = 7, 9
  found_one = sealed = 0
  for _ in range(12):
    unknown = rng.random((h, w)) < 0.25
    occupied = ~unknown & (rng.random((h, w)) < 0.5)
    # Every cell, the borders and corners included, and two cells off the grid.
    cells = [(r, c) for r in range(h) for c in range(w)] + [(-1, 3), (h, w)]
    for cell in cells:
      got = tuple(np.asarray(find(jnp.asarray(cell, jnp.int32), jnp.asarray(unknown),
                                  jnp.asarray(occupied))))
      want = unknown_neighbour_numpy(cell, unknown, occupied)
      assert got == want, (cell, got, want)
      found_one += want != cell
      sealed += want == cell and any(
          0 <= cell[0] + di < h and 0 <= cell[1] + dj < w and unknown[cell[0] + di, cell[1] + dj]
          for di, dj in mapping.NEIGHBOURS_8)
  assert found_one > 100 and sealed > 0  # both answers occur, and a diagonal seal decided one


def test_unknown_neighbour_under_vmap_keeps_each_cells_answer():
  rng = np.random.default_rng(4)
  unknown = rng.random((6, 6)) < 0.3
  occupied = ~unknown & (rng.random((6, 6)) < 0.5)
  cells = jnp.asarray([(r, c) for r in range(6) for c in range(6)], jnp.int32)
  got = jax.vmap(frontiers.unknown_neighbour, in_axes=(0, None, None))(
      cells, jnp.asarray(unknown), jnp.asarray(occupied))
  want = [unknown_neighbour_numpy(tuple(c), unknown, occupied) for c in np.asarray(cells)]
  np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
