"""The REG family's geometry against oracles: a finely sampled ray, a plain Python reading of
circular runs, Monte-Carlo sampling of the coverable width and a loop over the LSR definition."""

import math

import jax.numpy as jnp
import numpy as np
from conftest import EAGER_AND_JIT

from jaxplore.planners import reg_kernels as K

BINS = 120


def random_classes(rng, h=40, w=44):
  """A belief of free space with unknown blobs and occupied specks (0 free, 1 unknown, 2 occ)."""
  classes = np.zeros((h, w), np.int32)
  classes[rng.random((h, w)) < 0.04] = K.OCCUPIED
  classes[rng.random((h, w)) < 0.03] = K.UNKNOWN
  classes[:, :3] = K.UNKNOWN
  classes[30:, 25:] = K.UNKNOWN
  return classes


def sampled_ray(classes, uv, angle, radius, step=1e-3):
  """Brute force: walk the ray in tiny steps; returns (rho, obstacle, near_corner) where
  near_corner flags a ray passing within 2e-3 cells of a grid corner before it stops (there the
  exact traversal's corner rule and a sampled ray may disagree)."""
  h, w = classes.shape
  d = np.array([math.cos(angle), math.sin(angle)])
  s = np.arange(0.0, radius + 2.0, step)
  points = np.asarray(uv)[None, :] + s[:, None] * d[None, :]
  cols, rows = np.floor(points[:, 0]).astype(int), np.floor(points[:, 1]).astype(int)
  inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
  kind = np.full(s.shape, K.OCCUPIED)
  kind[inside] = classes[rows[inside], cols[inside]]
  blocked = kind != K.FREE
  stop = int(np.argmax(blocked)) if blocked.any() else len(s) - 1
  t_stop = s[stop] if blocked.any() else np.inf
  corner = np.abs(points - np.round(points)).max(axis=1) < 2e-3
  return (min(t_stop, radius), bool(kind[stop] == K.OCCUPIED and t_stop < radius),
          bool(corner[: stop + 1].any()))


@EAGER_AND_JIT
def test_lsr_rays_match_a_finely_sampled_ray(transform):
  rng = np.random.default_rng(0)
  rays = transform(lambda c, uv, r: K.lsr_rays(c, uv, r, n_cross=24, bins=BINS))
  angles = np.asarray(K.bin_angles(BINS))
  compared = mismatches = 0
  for trial in range(3):
    classes = random_classes(rng)
    classes[18:23, 18:23] = K.FREE
    uv = np.array([20.0, 20.0]) + rng.uniform(-1.5, 1.5, 2)
    if trial == 2:  # from a blocked cell every ray has length 0 and meets an obstacle
      classes[int(uv[1]), int(uv[0])] = K.OCCUPIED
    radius = 12.0 + 8 * trial
    got = rays(jnp.asarray(classes), jnp.asarray(uv, jnp.float32), radius)
    if trial == 2:
      assert bool(jnp.all(got.rho == 0.0)) and bool(jnp.all(got.obstacle))
    for b in range(BINS):
      rho, obstacle, near_corner = sampled_ray(classes, uv, angles[b], radius)
      if near_corner:
        continue
      compared += 1
      # The sampled ray enters a cell up to one step after the exact entry distance.
      mismatches += not (abs(float(got.rho[b]) - rho) <= 2e-3 and bool(got.obstacle[b]) == obstacle)
  assert compared > 0.9 * 3 * BINS
  assert mismatches == 0


def python_runs(mask):
  """Maximal circular runs as (start, length), read off the circle bin by bin."""
  n = len(mask)
  if all(mask):
    return [(0, n)]
  if not any(mask):
    return []
  first_unset = mask.index(False)
  runs = []
  k = 0
  while k < n:
    b = (first_unset + k) % n
    if mask[b] and not mask[(b - 1) % n]:
      length = 0
      while mask[(b + length) % n] and length < n:
        length += 1
      runs.append((b, length))
    k += 1
  return runs


@EAGER_AND_JIT
def test_circular_runs_match_a_python_reading(transform):
  rng = np.random.default_rng(1)
  runs_of = transform(K.circular_runs)
  masks = [np.ones(BINS, bool), np.zeros(BINS, bool), np.arange(BINS) % 2 == 0]
  wrap = np.zeros(BINS, bool)
  wrap[:5] = wrap[-7:] = True  # one run across the seam
  masks.append(wrap)
  masks += [rng.random(BINS) < p for p in (0.2, 0.5, 0.8, 0.95)]
  for mask in masks:
    got = runs_of(jnp.asarray(mask))
    count = int(got.count)
    starts, lengths = np.asarray(got.start)[:count], np.asarray(got.length)[:count]
    pairs = sorted(zip(starts.tolist(), lengths.tolist()))
    assert pairs == sorted(python_runs(mask.tolist()))
    assert not np.any(np.asarray(got.valid)[count:]) and np.all(np.asarray(got.length)[count:] == 0)


def test_coverable_width_matches_monte_carlo():
  rng = np.random.default_rng(2)
  psi = rng.uniform(-math.pi, math.pi, 200_000)
  for r, radius, rho in ((0.5, 4.0, 4.0), (0.5, 4.0, 3.0), (0.3, 4.0, 4.0), (0.7, 2.0, 2.5),
                         (0.5, 4.0, 1.0)):
    # Points of the arc of radius rho at angle psi from the step direction; the next node at r·rho.
    gap_sq = rho**2 + (r * rho) ** 2 - 2 * r * rho**2 * np.cos(psi)
    expected = 2 * math.pi * np.mean(gap_sq <= radius**2)
    got = float(K.coverable_width(jnp.float32(rho), jnp.float32(r), jnp.float32(radius)))
    assert abs(got - expected) < 0.02, (r, radius, rho, got, expected)
  np.testing.assert_allclose(float(K.coverable_width(4.0, 0.5, 4.0)), 2 * math.acos(0.25),
                             rtol=1e-6)


@EAGER_AND_JIT
def test_inside_lsr_matches_the_definition(transform):
  rng = np.random.default_rng(3)
  rho = rng.uniform(0.5, 6.0, BINS).astype(np.float32)
  centre = np.array([10.3, 7.9], np.float32)
  points = (centre + rng.uniform(-7, 7, (500, 2))).astype(np.float32)
  inside = transform(K.inside_lsr)
  got = np.asarray(inside(jnp.asarray(points), jnp.asarray(centre), jnp.asarray(rho)))
  width = 2 * math.pi / BINS
  expected = []
  for p in points:
    dx, dy = p - centre
    b = int(((math.atan2(dy, dx) + math.pi) // width)) % BINS
    expected.append(math.hypot(dx, dy) <= rho[b])
  assert got.tolist() == expected
  assert 0 < got.sum() < len(points)


def test_dilate_matches_scipy_maximum_filter():
  from scipy import ndimage
  rng = np.random.default_rng(4)
  mask = rng.random((30, 37)) < 0.02
  for cells in (0, 1, 4):
    expected = ndimage.maximum_filter(mask, size=2 * cells + 1, mode="constant", cval=False)
    np.testing.assert_array_equal(np.asarray(K.dilate(jnp.asarray(mask), cells)), expected)


@EAGER_AND_JIT
def test_shadow_bins_and_midpoints_match_a_python_loop(transform):
  rng = np.random.default_rng(5)
  rho = rng.uniform(0.0, 10.0, BINS).astype(np.float32)
  rho[0], rho[-1] = 9.0, 1.0  # a jump across the seam
  got = np.asarray(transform(K.shadow_bins)(jnp.asarray(rho), jnp.float32(2.5)))
  expected = [any(rho[b] - rho[(b + d) % BINS] > 2.5 for d in (-1, 1)) for b in range(BINS)]
  assert got.tolist() == expected
  assert got[0] and not got[-1]
  centre = np.array([3.0, -2.0], np.float32)
  middles = np.asarray(transform(K.shadow_midpoints)(jnp.asarray(centre), jnp.asarray(rho)))
  width = 2 * math.pi / BINS
  end = lambda b: centre + rho[b] * np.array([math.cos(-math.pi + (b + 0.5) * width),
                                              math.sin(-math.pi + (b + 0.5) * width)])
  for b in range(BINS):
    shorter = (b - 1) % BINS if rho[(b - 1) % BINS] <= rho[(b + 1) % BINS] else (b + 1) % BINS
    np.testing.assert_allclose(middles[b], 0.5 * (end(b) + end(shorter)), atol=1e-4)


def test_a_node_beside_a_corner_sees_the_corridor_behind_it_only_as_a_shadow():
  """An L-shaped corridor: the leg going down from the right end of the horizontal one is seen
  from a node beside the inner corner only above the line through the corner; below it lies the
  corner's shadow (unknown). Every ray that passes the corner ends on the leg's far wall inside
  R (20 cells), so no ray of the LSR reaches R or unknown space that way: only the shadow edge
  beside the corner is free boundary in that direction."""
  h = w = 40
  classes = np.full((h, w), K.OCCUPIED, np.int32)
  classes[20:28, 2:31] = K.FREE  # the horizontal corridor, rows 20-27
  classes[20:40, 23:31] = K.FREE  # the leg, columns 23-30, down to the grid's edge
  node = np.array([20.5, 26.5])
  corner = np.array([23.0, 28.0])  # the inner corner (u, v)
  v, u = np.mgrid[0:h, 0:w].astype(float)
  to_corner = corner - node
  # Unknown: the leg's cells wholly beyond the line from the node through the corner.
  below = np.ones((h, w), bool)
  for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):
    below &= (u + du - node[0]) * to_corner[1] - (v + dv - node[1]) * to_corner[0] < 0
  classes[(v >= 28) & (u >= 23) & (u < 31) & below] = K.UNKNOWN
  rays = K.lsr_rays(jnp.asarray(classes), jnp.asarray(node, jnp.float32), 20.0, 24, BINS)
  obstacle, rho = np.asarray(rays.obstacle), np.asarray(rays.rho)
  angles = np.asarray(K.bin_angles(BINS))
  toward_leg = (angles > 0) & (angles < math.pi / 2)
  assert obstacle[toward_leg].all()  # the rule "free = reaches R or unknown" sees no arc there
  shadow = np.asarray(K.shadow_bins(rays.rho, 0.5 / 0.1))
  # The shadow bin is the first ray that passes the corner: the largest angle below the corner's.
  corner_angle = math.atan2(to_corner[1], to_corner[0])
  passing = np.nonzero(toward_leg & (angles < corner_angle))[0]
  first = passing[np.argmax(angles[passing])]
  assert shadow[first] and rho[first] > 10.0 and rho[first + 1] < 5.0
  # Its ray ends on the far wall next to the unknown shadow.
  end = node + rho[first] * np.array([math.cos(angles[first]), math.sin(angles[first])])
  row, col = int(end[1]), int(end[0])
  assert (classes[row - 1:row + 2, col - 2:col + 1] == K.UNKNOWN).any()
  # The middle of its shadow edge lies by the frontier (free cells beside unknown ones); the
  # other depth jumps, rays grazing the bottom wall toward the left, have their edges' middles on
  # that wall, away from it.
  from scipy import ndimage
  frontier = (classes == K.FREE) & ndimage.binary_dilation(classes == K.UNKNOWN)
  near = ndimage.maximum_filter(frontier, size=2 * 3 + 1, mode="constant", cval=False)
  middles = np.asarray(K.shadow_midpoints(jnp.asarray(node, jnp.float32), rays.rho))
  at = lambda p: near[int(p[1]), int(p[0])]
  grazing = np.nonzero(shadow & obstacle & (angles > math.pi / 2))[0]
  assert at(middles[first]) and len(grazing) >= 1
  assert not any(at(middles[b]) for b in grazing)
