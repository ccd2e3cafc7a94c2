"""Shortest paths on a small dense graph of N nodes (an exploration graph's nodes and edges).

The graph is an f32[N, N] weight matrix, ``inf`` where there is no edge; N is a static capacity
(unused node slots have no edges). Dijkstra's algorithm in its array form: each of at most N
rounds settles the unsettled node of smallest distance (an argmin over N) and relaxes its row of
the matrix (N additions), so a search costs O(N²) vector work and no priority queue. The rounds
run in a ``lax.while_loop`` that stops once no unsettled node has a finite distance.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax


def dijkstra(weights: jax.Array, source) -> tuple[jax.Array, jax.Array]:
  """Single-source shortest paths over a dense weight matrix (Dijkstra 1959).

  Args:
    weights: f32[N, N]; ``weights[u, v]`` >= 0 is the length of the edge u -> v, ``inf`` = none.
    source: i32[]; the source node.

  Returns:
    dist: f32[N] path lengths from ``source`` (0 there, ``inf`` where unreachable).
    pred: i32[N] the previous node on a shortest path; -1 at the source and unreachable nodes.
      Equal distances: the node settled first (the lower index among equal tentative distances)
      wins, and a later equal path does not replace it.
  """
  weights = jnp.asarray(weights, jnp.float32)
  n = weights.shape[0]
  source = jnp.asarray(source, jnp.int32)
  index = jnp.arange(n, dtype=jnp.int32)
  dist = jnp.where(index == source, jnp.float32(0), jnp.float32(jnp.inf))
  pred = jnp.full((n,), -1, jnp.int32)
  settled = jnp.zeros((n,), bool)

  def frontier(dist, settled):
    return jnp.where(settled, jnp.inf, dist)

  def not_done(carry):
    dist, _, settled, rounds = carry
    return (rounds < n) & jnp.any(jnp.isfinite(frontier(dist, settled)))

  def settle(carry):
    dist, pred, settled, rounds = carry
    u = jnp.argmin(frontier(dist, settled)).astype(jnp.int32)
    settled = settled | (index == u)
    through = dist[u] + weights[u]
    better = (through < dist) & ~settled
    return (jnp.where(better, through, dist), jnp.where(better, u, pred), settled, rounds + 1)

  dist, pred, _, _ = lax.while_loop(not_done, settle, (dist, pred, settled, jnp.int32(0)))
  return dist, pred


def first_hop(pred: jax.Array, source, target) -> jax.Array:
  """The node after ``source`` on the path to ``target`` that ``pred`` (from :func:`dijkstra`)
  encodes; ``target`` itself when it is ``source`` or a neighbour of it, -1 when unreachable.

  Walks back from ``target`` at most N steps (a ``lax.while_loop``).
  """
  pred = jnp.asarray(pred, jnp.int32)
  n = pred.shape[0]
  source = jnp.asarray(source, jnp.int32)
  target = jnp.asarray(target, jnp.int32)

  def not_done(carry):
    node, steps = carry
    parent = pred[jnp.maximum(node, 0)]
    return (node >= 0) & (parent != source) & (parent >= 0) & (steps < n)

  def back(carry):
    node, steps = carry
    return pred[node], steps + 1

  node, _ = lax.while_loop(not_done, back, (target, jnp.int32(0)))
  reaches = (target == source) | (pred[jnp.maximum(node, 0)] == source)
  return jnp.where(reaches & (node >= 0), node, -1).astype(jnp.int32)
