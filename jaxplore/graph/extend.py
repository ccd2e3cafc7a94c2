"""Reaching just past the traversable set: frontier goals often lie within the robot's radius of
a wall, where the robot cannot stand but can look from next door."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from jaxplore import mapping


def extend_into(dist, pred, allowed, steps: int):
  """Extends a shortest-path field by ``steps`` Jacobi relaxations into ``allowed`` cells.

  Cells of ``allowed`` that are still unreached get the distance of their best 8-neighbour plus
  the step length (1 or √2 cells) and that neighbour as predecessor; traversable cells keep their
  values, so no path ever passes *through* an extended cell to reach a traversable one.

  Args:
    dist: f32[H, W] distances (inf where unreached).
    pred: i32[H, W] flat predecessor indices (-1 where none).
    allowed: bool[H, W] cells that may be reached by extension.
    steps: static number of relaxation rounds.
  Returns:
    (dist, pred) extended.
  """
  h, w = dist.shape
  flat = jnp.arange(h * w, dtype=jnp.int32).reshape(h, w)
  target = allowed & ~jnp.isfinite(dist)
  framed_flat = mapping.frame(flat, -1)

  def relax(_, carry):
    # A loop, not an unrolled Python loop: XLA would fuse each step into the next one's 8
    # neighbour reads and evaluate it 8 times per cell.
    dist, pred = carry
    framed = mapping.frame(dist, jnp.inf)
    best = dist
    best_pred = pred
    for di, dj in mapping.NEIGHBOURS_8:
      step = math.sqrt(2.0) if di and dj else 1.0
      cand = mapping.shifted(framed, di, dj) + step
      better = target & (cand < best)
      best = jnp.where(better, cand, best)
      best_pred = jnp.where(better, mapping.shifted(framed_flat, di, dj), best_pred)
    return best, best_pred

  return jax.lax.fori_loop(0, steps, relax, (dist, pred))
