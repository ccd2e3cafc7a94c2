"""Connected-component labelling and the labelled Manhattan distance transform against SciPy."""

import hypothesis
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis.extra import numpy as hnp
from scipy import ndimage

from jaxplore.graph import labels

VARIANTS = pytest.mark.parametrize("variant", [lambda f: f, jax.jit], ids=["eager", "jit"])
EIGHT = np.ones((3, 3), int)
# One shape for the property tests: every example reuses one compiled kernel.
SHAPE = (9, 11)


def same_partition(mask, expected, got):
  """The mask cells are split into the same groups, whatever the label values."""
  pairs = set(zip(expected[mask].tolist(), got[mask].tolist()))
  return (len(pairs) == len({a for a, _ in pairs}) == len({b for _, b in pairs}))


def reference_clusters(mask, max_clusters):
  """SciPy labels, then (size desc, first cell in row-major order asc), the first K kept."""
  lab, count = ndimage.label(mask, structure=EIGHT)
  comps = []
  for k in range(1, count + 1):
    cells = np.argwhere(lab == k)
    first = int(np.min(cells[:, 0] * mask.shape[1] + cells[:, 1]))
    comps.append((-len(cells), first, cells))
  comps.sort(key=lambda c: (c[0], c[1]))
  return count, [(-size, cells) for size, _, cells in comps[:max_clusters]]


@pytest.fixture(scope="module")
def jitted_clusters():
  return jax.jit(lambda m: labels.clusters(m, 8))


@VARIANTS
@pytest.mark.parametrize("density", [0.3, 0.55, 0.75])
def test_components_match_scipy(variant, density):
  mask = np.random.default_rng(int(density * 100)).random((30, 40)) < density
  roots = np.asarray(variant(labels.component_roots)(jnp.asarray(mask)))
  expected, _ = ndimage.label(mask, structure=EIGHT)
  assert np.all(roots[~mask] == -1)
  assert same_partition(mask, expected, roots)
  # Each component is named by its first cell in row-major order.
  flat = np.arange(mask.size).reshape(mask.shape)
  for k in np.unique(expected[mask]):
    assert np.all(roots[expected == k] == flat[expected == k].min())


@VARIANTS
def test_clusters_sizes_centroids_and_order_match_numpy(variant):
  mask = np.random.default_rng(7).random((30, 40)) < 0.4
  count, comps = reference_clusters(mask, 16)
  found = variant(lambda m: labels.clusters(m, 16))(jnp.asarray(mask))
  assert int(found.count) == count > 16  # some components are dropped
  ids = np.asarray(found.ids)
  assert np.asarray(found.valid).all()
  for k, (size, cells) in enumerate(comps):
    assert int(found.size[k]) == size
    np.testing.assert_allclose(np.asarray(found.centroid[k]), cells.mean(axis=0), rtol=1e-6)
    assert np.array_equal(np.argwhere(ids == k), cells)
  kept = sum(size for size, _ in comps)
  assert (ids >= 0).sum() == kept  # cells of dropped components have id -1
  assert np.all(ids[~mask] == -1)


def test_snake_converges_in_few_rounds():
  """A single serpentine corridor: plain min-propagation would need one round per bend."""
  mask = np.zeros((31, 41), bool)
  mask[::2, :] = True
  for r in range(1, 31, 2):
    mask[r, 40 if (r // 2) % 2 == 0 else 0] = True
  roots = np.asarray(labels.component_roots(jnp.asarray(mask), max_rounds=4))
  assert np.all(roots[mask] == 0)


def test_unused_slots_are_empty():
  mask = np.zeros((6, 7), bool)
  mask[1, 1] = mask[4, 4:6] = True
  found = labels.clusters(jnp.asarray(mask), 5)
  assert np.asarray(found.valid).tolist() == [True, True, False, False, False]
  assert np.asarray(found.size).tolist() == [2, 1, 0, 0, 0]
  np.testing.assert_allclose(np.asarray(found.centroid[:2]), [[4.0, 4.5], [1.0, 1.0]])


@hypothesis.settings(max_examples=40, deadline=None, derandomize=True)
@hypothesis.given(mask=hnp.arrays(bool, SHAPE, elements=st.booleans()))
def test_property_clusters_match_scipy(jitted_clusters, mask):
  count, comps = reference_clusters(mask, 8)
  found = jitted_clusters(jnp.asarray(mask))
  ids = np.asarray(found.ids)
  assert int(found.count) == count
  assert int(np.asarray(found.valid).sum()) == min(count, 8)
  for k, (size, cells) in enumerate(comps):
    assert int(found.size[k]) == size
    assert np.array_equal(np.argwhere(ids == k), cells)
    np.testing.assert_allclose(np.asarray(found.centroid[k]), cells.mean(axis=0), rtol=1e-6)


@VARIANTS
def test_nearest_label_manhattan_matches_brute_force(variant):
  rng = np.random.default_rng(3)
  source = np.full((17, 23), -1)
  picks = rng.choice(source.size, 12, replace=False)
  source.ravel()[picks] = rng.integers(0, 5, 12)
  distance, nearest = variant(lambda s: labels.nearest_label_manhattan(s, 5))(jnp.asarray(source))
  cells = np.argwhere(source >= 0)
  grid = np.indices(source.shape).reshape(2, -1).T
  d = np.abs(grid[:, None, :] - cells[None, :, :]).sum(-1)  # [cells, sources]
  best = d.min(axis=1)
  label_at_best = np.where(d == best[:, None], source[cells[:, 0], cells[:, 1]][None, :], 99).min(axis=1)
  np.testing.assert_array_equal(np.asarray(distance).ravel(), best)
  np.testing.assert_array_equal(np.asarray(nearest).ravel(), label_at_best)
  # Same distances as SciPy's taxicab transform.
  np.testing.assert_array_equal(
      np.asarray(distance), ndimage.distance_transform_cdt(source < 0, metric="taxicab"))


def test_nearest_label_without_sources():
  distance, nearest = labels.nearest_label_manhattan(jnp.full((4, 5), -1, jnp.int32), 3)
  assert np.all(np.asarray(nearest) == -1) and np.all(np.asarray(distance) > 1000)


@VARIANTS
@pytest.mark.parametrize("density", [0.15, 0.3])
def test_enclosed_specks_are_the_small_components_off_the_edge_as_scipy_finds_them(variant,
                                                                                   density):
  mask = np.random.default_rng(int(density * 10)).random((20, 24)) < density
  got = np.asarray(variant(lambda m: labels.enclosed_specks(m, 3))(jnp.asarray(mask)))
  lab, count = ndimage.label(mask, structure=EIGHT)
  expected = np.zeros_like(mask)
  for k in range(1, count + 1):
    cells = lab == k
    on_edge = cells[0].any() or cells[-1].any() or cells[:, 0].any() or cells[:, -1].any()
    if cells.sum() <= 3 and not on_edge:
      expected |= cells
  assert expected.any() and (mask & ~expected).any()  # both kinds occur
  np.testing.assert_array_equal(got, expected)
