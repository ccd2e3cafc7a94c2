"""Dense linear algebra for the engine's compiled programs, safe on a multi-device CPU.

jaxlib 0.10's CPU LAPACK kernels (Cholesky, triangular solve, symmetric eigensolver) split a
batch of matrices over XLA:CPU's intra-op thread pool and block until the pieces are done. In a
compiled loop those kernels already run *on* that pool, so when every pool thread is inside one
at once (one per host device under ``shard_map``: two devices on two cores) each waits for work
queued behind the others, and the process hangs with every thread idle. A call on a single
matrix runs on the calling thread. So on CPU a batch of matrices is factorised one matrix per
call (``jax.custom_batching.sequential_vmap``: ``vmap`` becomes a loop, as the kernels before
0.10 did inside), and on other platforms the batched call is kept.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _per_matrix_on_cpu(fn):
  """``fn`` whose ``vmap`` is a loop of single-matrix calls on CPU, a batched call elsewhere.

  Derivatives are ``fn``'s own (batched kernels: nothing in the engine differentiates these;
  ``sequential_vmap`` alone has no reverse mode)."""
  sequential = jax.custom_batching.sequential_vmap(fn)

  @jax.custom_jvp
  def dispatch(*args):
    return jax.lax.platform_dependent(*args, cpu=sequential, default=fn)

  dispatch.defjvp(lambda primals, tangents: jax.jvp(fn, primals, tangents))
  return dispatch


cholesky = _per_matrix_on_cpu(lambda a: jnp.linalg.cholesky(a))
eigvalsh = _per_matrix_on_cpu(lambda a: jnp.linalg.eigvalsh(a))
_solve_lower = _per_matrix_on_cpu(lambda a, b: jax.scipy.linalg.solve_triangular(a, b, lower=True))
_solve_upper = _per_matrix_on_cpu(lambda a, b: jax.scipy.linalg.solve_triangular(a, b, lower=False))


def solve_triangular(a, b, lower: bool):
  """``a⁻¹ b`` for a triangular ``a`` (:func:`jax.scipy.linalg.solve_triangular`)."""
  return (_solve_lower if lower else _solve_upper)(a, b)


inv = _per_matrix_on_cpu(lambda a: jnp.linalg.inv(a))


def det3(m):
  """Determinant of stacked 3x3 matrices by cofactor expansion along the first row: cheaper than
  an LU factorisation per matrix, and no LAPACK call."""
  return (m[..., 0, 0] * (m[..., 1, 1] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 1])
          - m[..., 0, 1] * (m[..., 1, 0] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 0])
          + m[..., 0, 2] * (m[..., 1, 0] * m[..., 2, 1] - m[..., 1, 1] * m[..., 2, 0]))


def inv3(m):
  """Inverse of stacked 3x3 matrices by the adjugate (no LAPACK call); singular -> inf/NaN."""
  a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
  d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
  g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
  adj = jnp.stack([
      jnp.stack([e * i - f * h, c * h - b * i, b * f - c * e], axis=-1),
      jnp.stack([f * g - d * i, a * i - c * g, c * d - a * f], axis=-1),
      jnp.stack([d * h - e * g, b * g - a * h, a * e - b * d], axis=-1)], axis=-2)
  return adj / det3(m)[..., None, None]


__all__ = ["cholesky", "det3", "eigvalsh", "inv", "inv3", "solve_triangular"]
