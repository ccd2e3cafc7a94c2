"""Quantities along every root path of a predecessor tree at once, by pointer jumping.

A shortest-path tree from one Dijkstra holds every candidate path. Summing a value
along the path from the root to *every* node, or finding each node's nearest ancestor with a
property, takes O(log depth) rounds of gathers: after round r every node knows the sum over its
2^r nearest path nodes and points at its 2^r-th ancestor.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def _rounds(n_nodes: int) -> int:
  return max(1, math.ceil(math.log2(max(n_nodes, 2)))) + 1


def path_sums(pred_flat, values):
  """``out[v] = Σ values[u]`` over the nodes ``u`` on the path from the root to ``v`` (inclusive).

  Args:
    pred_flat: i32[N] parent of each node, -1 at the root and at nodes outside the tree.
    values: f32[N, C] per-node values.
  Returns:
    f32[N, C]. Nodes outside the tree get their own value.
  """
  n = pred_flat.shape[0]

  def cond(carry):
    _, anc, r = carry
    return jnp.any(anc >= 0) & (r < _rounds(n))

  def body(carry):
    acc, anc, r = carry
    has = anc >= 0
    safe = jnp.where(has, anc, 0)
    acc = acc + jnp.where(has[:, None], acc[safe], 0.0)
    anc = jnp.where(has, anc[safe], -1)
    return acc, anc, r + 1

  acc, _, _ = jax.lax.while_loop(cond, body, (values, pred_flat, jnp.int32(0)))
  return acc


def nearest_ancestor(pred_flat, ok):
  """The nearest ancestor-or-self of every node with ``ok`` set, or -1 if none.

  Args:
    pred_flat: i32[N] parents (-1 at the root).
    ok: bool[N].
  """
  n = pred_flat.shape[0]
  idx = jnp.arange(n, dtype=jnp.int32)
  jump = jnp.where(ok, idx, pred_flat)

  def cond(carry):
    jump, changed, r = carry
    return changed & (r < _rounds(n))

  def body(carry):
    jump, _, r = carry
    safe = jnp.where(jump >= 0, jump, 0)
    new = jnp.where(jump >= 0, jump[safe], -1)
    return new, jnp.any(new != jump), r + 1

  jump, _, _ = jax.lax.while_loop(cond, body, (jump, jnp.bool_(True), jnp.int32(0)))
  safe = jnp.where(jump >= 0, jump, 0)
  return jnp.where((jump >= 0) & ok[safe], jump, -1)
