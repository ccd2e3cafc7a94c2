"""How a keyframe's scan is matched (jaxplore.slam.model.end_points): end points moved into their
surface along its normal."""

import jax.numpy as jnp
import numpy as np

from jaxplore.slam import model


def test_end_points_move_into_a_straight_wall_along_its_normal():
  """A wall along x = 1 m seen from the origin: every end point with a neighbour on the wall moves
  half a cell to x = 1 m + res / 2 and keeps its y (moved along their beams, the grazing ones
  would slide along the wall and stop short of that line); a lone return moves along its beam."""
  res = 0.1
  offsets = jnp.linspace(-1.1, 1.1, 61)
  ranges = (1.0 / res) / np.cos(np.asarray(offsets))
  stored = jnp.asarray(ranges, jnp.float16)
  r = np.abs(np.asarray(stored, np.float64)) * res  # what the keyframe kept
  points, hit = model.end_points(stored, offsets, res)
  points = np.asarray(points, np.float64)
  assert bool(hit.all())
  np.testing.assert_allclose(points[:, 0], 1.0 + 0.5 * res, atol=2e-3)
  np.testing.assert_allclose(points[:, 1], r * np.sin(np.asarray(offsets)), atol=1e-3)
  along_beam = (r + 0.5 * res) * np.cos(np.asarray(offsets))
  assert np.max(np.abs(along_beam - (1.0 + 0.5 * res))) > 0.02
  # One return among beams that hit nothing: no surface to take a normal from.
  lone = jnp.asarray(np.where(np.arange(61) == 30, 10.0, -150.0), jnp.float16)
  points, hit = model.end_points(lone, offsets, res)
  np.testing.assert_allclose(np.asarray(points[30]), [1.05, 0.0], atol=1e-6)
  assert int(hit.sum()) == 1
  # A beam that hit nothing ends at its range, unmoved.
  np.testing.assert_allclose(np.asarray(points[0]), 15.0 * np.array([np.cos(-1.1), np.sin(-1.1)]),
                             rtol=1e-3)
