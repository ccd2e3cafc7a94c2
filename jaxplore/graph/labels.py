"""Connected components of boolean grids (8-connectivity), compacted into a fixed number of
clusters, and a labelled Manhattan distance transform.

Used to group frontier cells into frontiers (Godoy-Calvo 2023 §4.1, Eq 12: candidates are the
centroids of 8-connected frontier clusters) and to give every cell its nearest frontier cluster
(Algorithm 1's Manhattan neighbourhoods).

Labelling, without a Python loop over cells: every cell of the mask starts as its own parent (its
flat index ``r * W + c``). One *round* takes, for every cell, the smallest parent among itself
and its 8 neighbours in the mask, and lowers both the cell's parent and the parent's parent to it
(*hooking* whole trees onto smaller labels, not only cells); then pointer jumping
``parent = parent[parent]`` flattens every tree to depth one. Parents only decrease and always
stay in the cell's component, and a round that changes nothing leaves every component pointing
at its smallest flat index. Hooking whole trees and jumping let a label travel far in one round
(in the spirit of Shiloach-Vishkin): a 31 x 41 serpentine corridor and a 41 x 41 spiral converge
in 2 rounds, random masks in 3, where plain min-propagation needs one round per cell of the
longest path through a component.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxplore import mapping

# Keys above this mean "no source reached" in the labelled distance transform.
_NO_SOURCE = 1 << 30


class Clusters(NamedTuple):
  """The largest connected components of a mask, at most ``max_clusters`` of them.

  Clusters are sorted by size, largest first; equal sizes by their smallest flat index
  ``r * W + c`` (so the order is deterministic). Components beyond ``max_clusters`` are dropped:
  their cells get id -1 as if they were not in the mask.

  Attributes:
    ids: i32[H, W]; the cluster index of each cell, -1 outside the mask or in a dropped component.
    size: i32[K]; cells per cluster (0 for unused slots).
    centroid: f32[K, 2]; mean (row, col) index of the cluster's cells (0 for unused slots).
    valid: bool[K]; the slot holds a cluster.
    count: i32[]; components found in the mask, including dropped ones.
  """

  ids: jax.Array
  size: jax.Array
  centroid: jax.Array
  valid: jax.Array
  count: jax.Array  # type: ignore[assignment]  # a field: shadows tuple.count by design


def component_roots(mask: jax.Array, max_rounds: int | None = None) -> jax.Array:
  """8-connected components of ``mask``, each labelled by its smallest flat index.

  Args:
    mask: bool[H, W].
    max_rounds: static bound on hook-and-jump rounds; None = H * W, a safety net only (every
      round lowers at least one label while the labelling is unfinished; real masks converge
      in a few rounds, see the module docstring).

  Returns:
    i32[H, W]: for every mask cell, the flat index ``r * W + c`` of the first cell (in row-major
    order) of its component; -1 outside the mask.
  """
  height, width = mask.shape
  n = height * width
  sink = jnp.int32(n)  # parent of every cell outside the mask; larger than any real label
  flat = jnp.arange(n, dtype=jnp.int32)
  # One extra slot, parent[n] = n, absorbs the hooks of cells outside the mask.
  parent = jnp.concatenate([jnp.where(mask.ravel(), flat, sink), sink[None]])
  if max_rounds is None:
    max_rounds = n

  def lowest_around(parent):
    """min(parent) over each mask cell and its mask 8-neighbours; the sink elsewhere."""
    grid = parent[:n].reshape(height, width)
    framed = mapping.frame(grid, sink)
    lowest = grid
    for di, dj in mapping.NEIGHBOURS_8:
      lowest = jnp.minimum(lowest, mapping.shifted(framed, di, dj))
    return jnp.where(mask, lowest, sink).ravel()

  def jump_to_roots(parent):
    def not_flat(carry):
      return carry[1]

    def jump(carry):
      parent, _ = carry
      grand = parent[parent]
      return grand, jnp.any(grand != parent)

    return lax.while_loop(not_flat, jump, (parent, jnp.bool_(True)))[0]

  def not_converged(carry):
    _, rounds, changed = carry
    return changed & (rounds < max_rounds)

  def hook_and_jump(carry):
    parent, rounds, _ = carry
    lowest = lowest_around(parent)
    hooked = parent.at[parent[:n]].min(lowest).at[:n].min(lowest)
    hooked = jump_to_roots(hooked)
    return hooked, rounds + 1, jnp.any(hooked != parent)

  parent, _, _ = lax.while_loop(not_converged, hook_and_jump,
                                (parent, jnp.int32(0), jnp.bool_(True)))
  return jnp.where(mask, parent[:n].reshape(height, width), -1)


def enclosed_specks(mask: jax.Array, max_cells: int, max_rounds: int | None = None) -> jax.Array:
  """bool[H, W]: the cells of ``mask``'s 8-connected components of at most ``max_cells`` cells
  that do not touch the grid's edge (what lies beyond the edge may join them to more)."""
  height, width = mask.shape
  n = height * width
  roots = component_roots(mask, max_rounds).ravel()
  in_mask = mask.ravel()
  segment = jnp.where(in_mask, roots, n)
  size = jax.ops.segment_sum(in_mask.astype(jnp.int32), segment, num_segments=n + 1)
  border = jnp.ones((height, width), bool).at[1:-1, 1:-1].set(False).ravel()
  open_edge = jax.ops.segment_max((in_mask & border).astype(jnp.int32), segment, num_segments=n + 1)
  speck = (size <= max_cells) & (open_edge <= 0)
  return (in_mask & speck[segment]).reshape(height, width)


def clusters(mask: jax.Array, max_clusters: int, max_rounds: int | None = None) -> Clusters:
  """The connected components of ``mask`` (8-connectivity), compacted to ``max_clusters`` slots.

  Args:
    mask: bool[H, W].
    max_clusters: static number of slots K; the K largest components are kept (ties: the one
      whose first cell comes first in row-major order), the others dropped (cells id -1).
    max_rounds: see :func:`component_roots`.

  Returns:
    A :class:`Clusters`.
  """
  height, width = mask.shape
  n = height * width
  roots = component_roots(mask, max_rounds).ravel()
  in_mask = mask.ravel()
  flat = jnp.arange(n, dtype=jnp.int32)
  segment = jnp.where(in_mask, roots, n)
  size_at_root = jax.ops.segment_sum(in_mask.astype(jnp.int32), segment, num_segments=n + 1)[:n]
  is_root = in_mask & (roots == flat)
  slots = min(max_clusters, n)
  # top_k is stable: equal sizes come out in increasing flat index of their root. On float32
  # XLA:CPU runs a dedicated top-k (far faster than on int32, which sorts everything); sizes
  # below 2^24 are exact in float32.
  top_score, top_root = lax.top_k(jnp.where(is_root, size_at_root, -1).astype(jnp.float32), slots)
  top_size = top_score.astype(jnp.int32)
  valid = top_size > 0
  slot_of_root = jnp.full((n,), -1, jnp.int32).at[jnp.where(valid, top_root, n)].set(
      jnp.arange(slots, dtype=jnp.int32), mode="drop")
  ids = jnp.where(in_mask, slot_of_root[jnp.clip(roots, 0, n - 1)], -1)
  size = jnp.where(valid, top_size, 0)

  segment = jnp.where(ids >= 0, ids, slots)
  rows = (flat // width).astype(jnp.float32)
  cols = (flat % width).astype(jnp.float32)
  sum_rows = jax.ops.segment_sum(rows, segment, num_segments=slots + 1)[:slots]
  sum_cols = jax.ops.segment_sum(cols, segment, num_segments=slots + 1)[:slots]
  centroid = (jnp.stack([sum_rows, sum_cols], axis=-1) /
              jnp.maximum(size, 1)[:, None].astype(jnp.float32))

  if slots < max_clusters:
    pad = max_clusters - slots
    size = jnp.pad(size, (0, pad))
    centroid = jnp.pad(centroid, ((0, pad), (0, 0)))
    valid = jnp.pad(valid, (0, pad))
  return Clusters(ids=ids.reshape(height, width), size=size, centroid=centroid, valid=valid,
                  count=jnp.sum(is_root).astype(jnp.int32))


def nearest_to_centroid(found: Clusters, eligible: jax.Array) -> jax.Array:
  """i32[K]: the flat index (row-major) of each cluster's ``eligible`` cell nearest to its
  centroid, ties to the first in row-major order; ``H * W`` for a cluster with none."""
  height, width = found.ids.shape
  slots = found.size.shape[0]
  rows = jax.lax.broadcasted_iota(jnp.int32, (height, width), 0)
  cols = jax.lax.broadcasted_iota(jnp.int32, (height, width), 1)
  segment = jnp.where(eligible, found.ids, slots).ravel()
  own_centroid = found.centroid[jnp.clip(found.ids, 0, slots - 1)]
  offset_sq = ((rows - own_centroid[..., 0]) ** 2 + (cols - own_centroid[..., 1]) ** 2).ravel()
  # Materialised once: the equality test below must see the very values the minimum was taken
  # over, not a recomputation that XLA may contract differently.
  offset_sq = jax.lax.optimization_barrier(offset_sq)
  best_sq = jax.ops.segment_min(offset_sq, segment, num_segments=slots + 1)
  return jax.ops.segment_min(
      jnp.where(offset_sq == best_sq[segment], jnp.arange(height * width, dtype=jnp.int32),
                height * width),
      segment, num_segments=slots + 1)[:slots]


def nearest_label_manhattan(labels: jax.Array, num_labels: int) -> tuple[jax.Array, jax.Array]:
  """Manhattan (D4) distance from every cell to the nearest labelled cell, and that cell's label.

  Exact, in two separable passes (the L1 distance splits into a row term and a column term):
  along each row, then along each column, each as a forward and a backward cumulative minimum.
  A cell at equal distance from several labels takes the smallest label. Distances are not
  blocked by anything (Godoy-Calvo's Algorithm 1 measures D4 distance through any cell).

  Args:
    labels: i32[H, W]; a label in [0, num_labels) at source cells, -1 elsewhere.
    num_labels: static number of labels.

  Returns:
    (distance i32[H, W] in cells, a large value where there is no source;
     nearest i32[H, W], the label of the nearest source, -1 where there is none).
  """
  stride = jnp.int32(num_labels)
  # (distance, label) packed into one integer that orders lexicographically.
  key = jnp.where(labels >= 0, labels, _NO_SOURCE).astype(jnp.int32)

  def pass_along(key, axis):
    index = lax.broadcasted_iota(jnp.int32, key.shape, axis) * stride
    forward = lax.cummin(key - index, axis=axis) + index
    backward = lax.cummin(key + index, axis=axis, reverse=True) - index
    return jnp.minimum(forward, backward)

  key = pass_along(pass_along(key, 1), 0)
  found = key < _NO_SOURCE // 2
  distance = jnp.where(found, key // stride, _NO_SOURCE)
  nearest = jnp.where(found, key % stride, -1)
  return distance, nearest
