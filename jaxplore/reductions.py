"""Arg-reductions over whole grids, in a form XLA:CPU runs fast.

``jnp.argmin`` lowers to one *variadic* reduce over (value, index) pairs. XLA:CPU does not vectorise
that reduce, and it fuses the whole computation producing the values into it, so a planner's score
(frontier masks, distances, blocked bands: hundreds of operations per cell) is then evaluated one
cell at a time, several times slower than computing the scores and reducing them with a plain
``min`` (``experiments/results/design_notes_cpu.md``). A plain ``min``/``max`` is vectorised; these
functions reduce each row with it, take the variadic reduce only over the ``H`` row results, and
re-evaluate the values of the one chosen row.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _arg_extreme(values: jax.Array, width: int | None, reduce, arg_reduce) -> jax.Array:
  flat = values.ndim == 1
  if flat:
    if width is None or values.shape[0] % width:
      raise ValueError(f"a flat array of {values.shape[0]} values needs the grid width that "
                       f"divides it, got {width}")
    values = values.reshape(-1, width)
  elif values.ndim != 2:
    raise ValueError(f"expected a 1-D or 2-D array, got shape {values.shape}")
  row = arg_reduce(reduce(values, axis=1))
  col = arg_reduce(values[row])
  return (row * values.shape[1] + col).astype(jnp.int32)


def argmin(values: jax.Array, width: int | None = None) -> jax.Array:
  """The row-major flat index of the first minimum of ``values``, as ``jnp.argmin(values.ravel())``.

  Args:
    values: f32[H, W], or f32[H * W] with ``width`` = W. NaN counts as the minimum (first NaN),
      as in ``jnp.argmin``.
    width: the row length of a flat ``values``.
  Returns:
    i32[] flat index.
  """
  return _arg_extreme(values, width, jnp.min, jnp.argmin)


def argmax(values: jax.Array, width: int | None = None) -> jax.Array:
  """The row-major flat index of the first maximum, as ``jnp.argmax(values.ravel())`` (see
  :func:`argmin`)."""
  return _arg_extreme(values, width, jnp.max, jnp.argmax)
