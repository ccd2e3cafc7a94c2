"""SE(2) pose-graph optimisation: GTSAM's ``BetweenFactor<Pose2>`` cost minimised by
Levenberg–Marquardt, each step solved by conjugate gradients with a chain-plus-loops
preconditioner; fixed capacity, ``vmap``-able over robots, no LAPACK call.

The graph (one robot's keyframes): N keyframe poses ``x_i = (x, y, θ)`` (``node_valid`` marks the
used ones) and E edges, each a measured pose ``z_e`` of ``dst`` in ``src``'s frame with a 3x3
information matrix ``Ω_e``. The cost is GTSAM's ``NonlinearFactorGraph::error`` of
``BetweenFactor<Pose2>`` factors (Dellaert & Kaess 2017, "Factor graphs for robot perception")::

    F(x) = ½ Σ_e r_eᵀ Ω_e r_e,   r_e = Log(z_e⁻¹ ∘ (x_src⁻¹ ∘ x_dst))

with ``Log`` the SE(2) logarithm, ``V(θ)⁻¹`` applied to the translation (Solà et al. 2018, "A
micro Lie theory for state estimation in robotics", App. C; GTSAM's ``Pose2::Logmap``). Node 0,
the anchor, stays fixed (GTSAM: a prior on the first pose).

Levenberg–Marquardt (Levenberg 1944, Marquardt 1963). Each iteration linearises every edge in the
right perturbation ``x_i ∘ Exp(δ_i)`` (a 3x6 Jacobian per edge, forward-mode autodiff of
``r_e``), solves ``(H + λ diag H) δ = −g`` (``H = Σ J_eᵀ Ω_e J_e``, ``g = Σ J_eᵀ Ω_e r_e``) and
keeps the step unless the cost rises (kept: ``λ /= 10``; dropped: ``λ *= 10``), in a
``lax.while_loop`` that stops after ``max_iterations``, when a step moves no coordinate more than
``step_tol``, or when a step changes the cost by at most ``rtol`` of it.

The linear solve. H is sparse: the odometry chain (edges between i − 1 and i) makes it block
tridiagonal and a loop closure adds two off-diagonal 3x3 blocks. A dense 3N x 3N Cholesky costs
~9N³ flops per iteration (1.2 GFLOP at N = 512, one matrix per call on CPU). Here the steps come
from preconditioned conjugate gradients (Saad 2003, "Iterative methods for sparse linear
systems", Alg. 9.1) with ``H v`` matrix-free over the edge list (each edge's 6x6 block times the
gathered ``(v_src, v_dst)``, scattered back) and the preconditioner ``P = T + Gᵀ G`` of subgraph
preconditioning (Dellaert et al. 2010, "Subgraph-preconditioned conjugate gradients for large
scale SLAM"), the chain being the subgraph:

* T, block tridiagonal: the chain edges and the damping, factorised ``T = (I + L) S (I + L)ᵀ``
  by the block Thomas recursion ``S_i = D_i − C_iᵀ S_{i−1}⁻¹ C_i`` (3x3 inverses by cofactors)
  and solved by block substitution, O(N) sequential steps of 3x3 arithmetic;
* ``Gᵀ G``: up to K loop edges exactly (``G_k = W_k J_k``, ``W_kᵀ W_k = Ω_k``), by the Woodbury
  identity ``P⁻¹ = T⁻¹ − T⁻¹ Gᵀ C⁻¹ G T⁻¹`` with the capacitance ``C = I + G T⁻¹ Gᵀ`` (3K x 3K,
  ``C ⪰ I``). Forming C solves T for the 3K columns of ``Gᵀ`` (O(N K) flops and memory); C is
  factorised once per iteration by a blocked Cholesky written in XLA operations (below: no
  LAPACK, whose batched kernels deadlock this project under ``vmap`` in a compiled loop on a
  multi-device CPU and whose OpenBLAS potrf stalls on busy cores), O(K³).

With every loop in G, ``P = H`` and the conjugate gradients only mop up float32 rounding (2–4
iterations a solve). Loops past K enter T by their diagonal blocks only, and keyframes past a
missing odometry edge get 1e-3 of H's diagonal blocks in T (else T would be singular there); the
conjugate gradients make up the difference, with more iterations. On the chain of 500 keyframes
with 100 loops (N = 512, E = 640, K = 129) an iteration costs ~0.03 GFLOP, where a dense
Cholesky of H costs 1.2 GFLOP, and PCG with H's block tridiagonal part alone needed ~240
iterations a solve; the timings are in ``experiments/results/bench_slam_parts_cpu.md``.

Float32 throughout. ``Exp`` and ``Log`` use series near θ = 0 for ``sin θ / θ`` and
``(θ/2) cot(θ/2)``, and ``1 − cos θ = 2 sin²(θ/2)``, so they hold float32 precision at every
angle; the steps are solved for as increments and the edges relinearised every iteration. Near the
optimum the float32 cost carries noise of ~1e-6 of itself (residuals of poses metres from the
origin), so a cost change within ``rtol`` counts as none: the step is taken and the run ends.

Libraries: JAX only. jaxlie's ``SE2.log`` has GTSAM's definition but computes ``(θ/2) cot(θ/2)``
as ``−(θ/2) sin θ / (cos θ − 1)`` once ``|cos θ − 1| ≥ 1e-5``, which in float32 cancels (a relative
error of ~1e-3 in the translation at θ = 5e-3): too coarse for residuals of centimetres.
lineax's CG (matrix-free, no LAPACK) and optimistix's Levenberg–Marquardt would serve, but the
preconditioner is the part that matters, a CG loop is twenty lines, and neither is a dependency
of the project.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import chex
import jax
import jax.numpy as jnp

from jaxplore import linalg, motion, pytrees

# |x| below which sin(x)/x is taken from its series (float32-exact there; the quotient above).
_SERIES = 0.2
# Bounds of the Levenberg–Marquardt damping; a rejected step at the upper one ends the run.
_LAMBDA_MIN = 1e-9
_LAMBDA_MAX = 1e6
# Share of H's diagonal blocks added to T at keyframes the chain does not tie to node 0.
_UNANCHORED = 1e-3


@pytrees.dataclass(frozen=True)
class Edges:
  """A pose graph's edges, fixed capacity E.

  Attributes:
    src: i32[E] source keyframe. dst: i32[E] destination keyframe.
    measured: f32[E, 3] the measured pose of ``dst`` in ``src``'s frame (x, y m, θ rad).
    information: f32[E, 3, 3] information matrix (inverse covariance) of the measurement, in the
      order (x, y, θ) of GTSAM's Pose2 tangent.
    valid: bool[E] which slots hold an edge (any pattern, not necessarily a prefix).
  """

  src: chex.Array
  dst: chex.Array
  measured: chex.Array
  information: chex.Array
  valid: chex.Array


class Result(NamedTuple):
  """What :func:`optimise` returns."""

  poses: jax.Array  # f32[N, 3] optimised poses (invalid rows and node 0 as given)
  initial_cost: jax.Array  # f32 ½ Σ rᵀ Ω r at the initial poses
  final_cost: jax.Array  # f32 the same at the optimised poses
  iterations: jax.Array  # i32 Levenberg–Marquardt iterations run (rejected steps included)
  converged: jax.Array  # bool a stopping test held before max_iterations ran out
  linear_iterations: jax.Array  # i32 conjugate-gradient iterations, all solves together


# --- SE(2) ---------------------------------------------------------------------------------------


def _sinc(x):
  """``sin x / x``, by its series for ``|x| < 0.2`` (to x⁶: float32-exact) and 1 at 0."""
  small = jnp.abs(x) < _SERIES
  safe = jnp.where(small, 1.0, x)
  x2 = x * x
  return jnp.where(small, 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0)),
                   jnp.sin(safe) / safe)


def expmap(xi):
  """SE(2) exponential ``Exp(u, v, θ)`` as a pose (x, y, θ): translation ``V(θ) (u, v)`` with
  ``V = [[sin θ/θ, −(1 − cos θ)/θ], [(1 − cos θ)/θ, sin θ/θ]]`` (Solà et al. 2018 App. C; GTSAM's
  ``Pose2::Expmap``)."""
  theta = xi[2]
  a = _sinc(theta)
  b = jnp.sin(0.5 * theta) * _sinc(0.5 * theta)  # (1 − cos θ)/θ = 2 sin²(θ/2)/θ
  return jnp.stack([a * xi[0] - b * xi[1], b * xi[0] + a * xi[1], motion.wrap_angle(theta)])


def logmap(pose):
  """SE(2) logarithm (GTSAM's ``Pose2::Logmap``): ``(V(θ)⁻¹ t, θ)`` with
  ``V⁻¹ = [[h cot h, h], [−h, h cot h]]``, ``h = θ/2`` (Solà et al. 2018 App. C); θ in (−π, π]."""
  theta = motion.wrap_angle(pose[2])
  h = 0.5 * theta
  hcot = jnp.cos(h) / _sinc(h)
  return jnp.stack([hcot * pose[0] + h * pose[1], -h * pose[0] + hcot * pose[1], theta])


between = motion.between  # a⁻¹ ∘ b: pose b in a's frame (GTSAM's Pose2::between)


def retract(pose, delta):
  """``x ∘ Exp(δ)``: the right perturbation the optimiser steps in."""
  return motion.compound(pose, expmap(delta))


def between_error(pose_src, pose_dst, measured):
  """GTSAM's ``BetweenFactor<Pose2>`` error ``Log(z⁻¹ ∘ (x_src⁻¹ ∘ x_dst))`` (f32[3])."""
  return logmap(between(measured, between(pose_src, pose_dst)))


# --- cost ----------------------------------------------------------------------------------------


def _live(node_valid, edges: Edges):
  """Edges that count: valid, with both ends valid keyframes."""
  n = node_valid.shape[0]
  src = jnp.clip(edges.src, 0, n - 1)
  dst = jnp.clip(edges.dst, 0, n - 1)
  in_range = (edges.src >= 0) & (edges.src < n) & (edges.dst >= 0) & (edges.dst < n)
  return src, dst, edges.valid & in_range & node_valid[src] & node_valid[dst]


def _residuals(poses, src, dst, measured, live):
  """Per-edge errors f32[E, 3], 0 on dead edges."""
  meas = jnp.where(live[:, None], measured, 0.0)
  r = jax.vmap(between_error)(poses[src], poses[dst], meas)
  return jnp.where(live[:, None], r, 0.0)


def _weighted_cost(r, information, live):
  omega = jnp.where(live[:, None, None], information, 0.0)
  return 0.5 * jnp.sum(jnp.einsum("ei,eij,ej->e", r, omega, r))


def cost(poses, edges: Edges):
  """``½ Σ_e r_eᵀ Ω_e r_e`` over the valid edges (GTSAM's ``NonlinearFactorGraph::error``)."""
  n = poses.shape[0]
  src = jnp.clip(edges.src, 0, n - 1)
  dst = jnp.clip(edges.dst, 0, n - 1)
  r = _residuals(poses, src, dst, edges.measured, edges.valid)
  return _weighted_cost(r, edges.information, edges.valid)


# --- linearisation -------------------------------------------------------------------------------


def _edge_linearisation(pose_src, pose_dst, measured):
  """``r`` and ``∂r/∂(δ_src, δ_dst)`` (3x6) at δ = 0 for ``x ∘ Exp(δ)`` at both ends."""
  def err(d):
    return between_error(retract(pose_src, d[:3]), retract(pose_dst, d[3:]), measured)
  zero = jnp.zeros((6,), pose_src.dtype)
  return err(zero), jax.jacfwd(err)(zero)


class _System(NamedTuple):
  """One iteration's normal equations, by edges; every array 0 on dead edges and fixed nodes."""

  jac: jax.Array  # f32[E, 3, 6] ∂r_e/∂(δ_src, δ_dst)
  blocks: jax.Array  # f32[E, 6, 6] J_eᵀ Ω_e J_e
  grad: jax.Array  # f32[N, 3] g = Σ J_eᵀ Ω_e r_e
  diag: jax.Array  # f32[N, 3, 3] diagonal blocks of H


def _linearise(poses, src, dst, measured, omega, live, free) -> _System:
  n = poses.shape[0]
  r, jac = jax.vmap(_edge_linearisation)(poses[src], poses[dst], measured)
  r = jnp.where(live[:, None], r, 0.0)
  ends = jnp.concatenate([jnp.repeat(free[src][:, None], 3, axis=1),
                          jnp.repeat(free[dst][:, None], 3, axis=1)], axis=1)  # bool[E, 6]
  jac = jnp.where(live[:, None, None] & ends[:, None, :], jac, 0.0)
  blocks = jnp.einsum("eki,ekl,elj->eij", jac, omega, jac)
  b = jnp.einsum("eki,ekl,el->ei", jac, omega, r)
  grad = jnp.zeros((n, 3), poses.dtype).at[src].add(b[:, :3]).at[dst].add(b[:, 3:])
  diag = (jnp.zeros((n, 3, 3), poses.dtype).at[src].add(blocks[:, :3, :3])
          .at[dst].add(blocks[:, 3:, 3:]))
  return _System(jac, blocks, grad, diag)


def _matvec(system: _System, src, dst, damping, v):
  """``(H + diag(damping)) v`` (v, result f32[N, 3]; fixed nodes' rows of H are 0)."""
  ve = jnp.concatenate([v[src], v[dst]], axis=-1)
  y = jnp.einsum("eij,ej->ei", system.blocks, ve)
  return jnp.zeros_like(v).at[src].add(y[:, :3]).at[dst].add(y[:, 3:]) + damping * v


# --- block tridiagonal matrices ------------------------------------------------------------------


def _chol3(m):
  """Lower Cholesky factor of a 3x3 positive-definite matrix, written out (no LAPACK)."""
  l00 = jnp.sqrt(m[0, 0])
  l10 = m[1, 0] / l00
  l20 = m[2, 0] / l00
  l11 = jnp.sqrt(m[1, 1] - l10 * l10)
  l21 = (m[2, 1] - l20 * l10) / l11
  l22 = jnp.sqrt(m[2, 2] - l20 * l20 - l21 * l21)
  zero = jnp.zeros_like(l00)
  return jnp.stack([jnp.stack([l00, zero, zero]), jnp.stack([l10, l11, zero]),
                    jnp.stack([l20, l21, l22])])


class Tridiagonal(NamedTuple):
  """Factor ``T = (I + L) S (I + L)ᵀ`` of a symmetric positive-definite block tridiagonal
  matrix: ``lower[i]`` the block (i, i − 1) of L (0 at i = 0), ``s_inv[i] = S_i⁻¹``."""

  lower: jax.Array  # f32[N, 3, 3]
  s_inv: jax.Array  # f32[N, 3, 3]


def tridiagonal_factor(diag, upper) -> Tridiagonal:
  """Block LDLᵀ (block Thomas) of the matrix with diagonal blocks ``diag[i]`` and super-diagonal
  blocks ``upper[i] = T[i − 1, i]`` (``upper[0]`` unused): ``S_i = D_i − C_iᵀ S_{i−1}⁻¹ C_i``,
  ``L_i = C_iᵀ S_{i−1}⁻¹``. Sequential in N, 3x3 arithmetic only."""
  def step(s_inv_prev, blocks):
    d, c = blocks
    low = c.T @ s_inv_prev
    s = d - low @ c
    s_inv = linalg.inv3(0.5 * (s + s.T))
    return s_inv, (low, 0.5 * (s_inv + s_inv.T))

  upper = upper.at[0].set(0.0)
  _, (lower, s_inv) = jax.lax.scan(step, jnp.zeros_like(diag[0]), (diag, upper))
  return Tridiagonal(lower, s_inv)


def _back_substitute(factor: Tridiagonal, y):
  """``x = (I + L)⁻ᵀ S⁻¹ y``: ``x_i = S_i⁻¹ y_i − L_{i+1}ᵀ x_{i+1}`` from the last row
  (y f32[N, 3, ...])."""
  low_next = jnp.concatenate([factor.lower[1:], jnp.zeros_like(factor.lower[:1])], axis=0)

  def step(x_next, row):
    y_i, s_inv, low = row
    x = jnp.tensordot(s_inv, y_i, 1) - jnp.tensordot(low.T, x_next, 1)
    return x, x

  _, x = jax.lax.scan(step, jnp.zeros_like(y[0]), (y, factor.s_inv, low_next), reverse=True)
  return x


def tridiagonal_solve(factor: Tridiagonal, b):
  """``T⁻¹ b`` (b f32[N, 3, ...]) from :func:`tridiagonal_factor`: ``(I + L) y = b`` by
  ``y_i = b_i − L_i y_{i−1}``, then :func:`_back_substitute`. Sequential scans: on CPU as fast
  here as a parallel prefix (``associative_scan``), in less memory."""
  def step(y_prev, row):
    low, b_i = row
    y = b_i - jnp.tensordot(low, y_prev, 1)
    return y, y

  _, y = jax.lax.scan(step, jnp.zeros_like(b[0]), (factor.lower, b))
  return _back_substitute(factor, y)


def _solve_loop_columns(factor: Tridiagonal, g, loop_src, loop_dst):
  """``T⁻¹ Gᵀ`` (f32[N, 3, 3K]). Row i of ``Gᵀ`` holds the blocks ``G_kᵀ`` of the loops k with
  an end at i; it is made inside the forward substitution, so ``Gᵀ`` itself is never stored."""
  n, k = factor.lower.shape[0], g.shape[0]
  g_src = jnp.swapaxes(g[:, :, :3], -1, -2)  # f32[K, 3 (node), 3 (row of G_k)]
  g_dst = jnp.swapaxes(g[:, :, 3:], -1, -2)

  def step(y_prev, row):
    i, low = row
    rhs = (jnp.where((loop_src == i)[:, None, None], g_src, 0.0)
           + jnp.where((loop_dst == i)[:, None, None], g_dst, 0.0))
    y = jnp.swapaxes(rhs, 0, 1).reshape(3, 3 * k) - low @ y_prev
    return y, y

  _, y = jax.lax.scan(step, jnp.zeros((3, 3 * k), g.dtype), (jnp.arange(n), factor.lower))
  return _back_substitute(factor, y)


# --- dense Cholesky in XLA ----------------------------------------------------------------------
# The capacitance is factorised here rather than by LAPACK: jaxlib's CPU LAPACK comes from
# SciPy's OpenBLAS, whose potrf goes multi-threaded from n = 256 and, with the other cores busy
# (XLA's own threads, other processes), stalled for hundreds of times its single-threaded time.
# This blocked version costs the same whatever the other cores do, and batches under ``vmap`` as
# matrix products (experiments/results/bench_slam_parts_cpu.md).

_BLOCK = 64


def _cholesky_unblocked(a):
  """Lower Cholesky factor of a small SPD matrix, column by column."""
  idx = jnp.arange(a.shape[0])

  def column(j, low):
    col = a[:, j] - low @ jnp.where(idx < j, low[j], 0.0)
    d = jnp.sqrt(col[j])
    return low.at[:, j].set(jnp.where(idx > j, col / d, jnp.where(idx == j, d, 0.0)))

  return jax.lax.fori_loop(0, a.shape[0], column, jnp.zeros_like(a))


def _lower_inverse(low):
  """Inverse of a small lower-triangular matrix, row by row."""
  idx = jnp.arange(low.shape[0])
  eye = jnp.eye(low.shape[0], dtype=low.dtype)

  def row(i, inv):
    return inv.at[i].set((eye[i] - jnp.where(idx < i, low[i], 0.0) @ inv) / low[i, i])

  return jax.lax.fori_loop(0, low.shape[0], row, jnp.zeros_like(low))


class _Cholesky(NamedTuple):
  """Blocked lower Cholesky factor of an n x n matrix, padded to m = ⌈n / b⌉·b rows with
  blocks of b = min(64, n)."""

  low: jax.Array  # f32[m, m]
  diag_inv: jax.Array  # f32[m / b, b, b] inverses of the diagonal blocks


def _cholesky(a) -> _Cholesky:
  """Right-looking blocked Cholesky (Golub & Van Loan, "Matrix computations", 4th ed., §4.2) of
  an SPD matrix; NaN where float32 finds it not positive definite."""
  n = a.shape[0]
  b = min(_BLOCK, n)
  nb = -(-n // b)
  m = nb * b
  pad = (jnp.arange(m) >= n).astype(a.dtype)
  trail = jnp.pad(a, ((0, m - n), (0, m - n))) + jnp.diag(pad)
  columns, diag_inv = [], []
  for j in range(nb):
    l11 = _cholesky_unblocked(trail[:b, :b])
    inv = _lower_inverse(l11)
    l21 = trail[b:, :b] @ inv.T
    trail = trail[b:, b:] - l21 @ l21.T
    columns.append(jnp.concatenate([jnp.zeros((j * b, b), a.dtype), l11, l21], axis=0))
    diag_inv.append(inv)
  return _Cholesky(jnp.concatenate(columns, axis=1), jnp.stack(diag_inv))


def _cholesky_solve(chol: _Cholesky, r):
  """``a⁻¹ r`` (r f32[n]) by block forward and back substitution."""
  nb, b = chol.diag_inv.shape[:2]
  n = r.shape[0]
  r = jnp.pad(r, (0, nb * b - n))
  ys: list[jax.Array] = []
  for j in range(nb):
    rhs = r[j * b:(j + 1) * b]
    if j:
      rhs = rhs - chol.low[j * b:(j + 1) * b, :j * b] @ jnp.concatenate(ys)
    ys.append(chol.diag_inv[j] @ rhs)
  xs: list[Any] = [None] * nb  # filled back to front: xs[j + 1:] are arrays when read
  for j in reversed(range(nb)):
    rhs = ys[j]
    if j < nb - 1:
      rhs = rhs - chol.low[(j + 1) * b:, j * b:(j + 1) * b].T @ jnp.concatenate(xs[j + 1:])
    xs[j] = chol.diag_inv[j].T @ rhs
  return jnp.concatenate(xs)[:n]


# --- preconditioner: chain exactly, loops by the Woodbury identity ------------------------------


class _Preconditioner(NamedTuple):
  """``P = T + Gᵀ G`` with T block tridiagonal and G the square-root-weighted Jacobians of up to
  K loop edges (``G_k = W_k J_k``, ``W_kᵀ W_k = Ω_k``)."""

  factor: Tridiagonal
  loop_src: jax.Array  # i32[K]
  loop_dst: jax.Array  # i32[K]
  g: jax.Array  # f32[K, 3, 6] (0 on unused slots)
  chol: _Cholesky | None  # of the capacitance I + G T⁻¹ Gᵀ (3K x 3K); None when K = 0


def _apply_g(pre: _Preconditioner, v):
  """``G v``: f32[N, 3] -> f32[3K]."""
  ve = jnp.concatenate([v[pre.loop_src], v[pre.loop_dst]], axis=-1)
  return jnp.einsum("kij,kj->ki", pre.g, ve).reshape(-1)


def _apply_gt(pre: _Preconditioner, w, n: int):
  """``Gᵀ w``: f32[3K] -> f32[N, 3]."""
  y = jnp.einsum("kji,kj->ki", pre.g, w.reshape(-1, 3))
  return jnp.zeros((n, 3), w.dtype).at[pre.loop_src].add(y[:, :3]).at[pre.loop_dst].add(y[:, 3:])


def _precondition(pre: _Preconditioner, r):
  """``P⁻¹ r = T⁻¹ (r − Gᵀ C⁻¹ G T⁻¹ r)``, ``C = I + G T⁻¹ Gᵀ`` (Woodbury)."""
  z = tridiagonal_solve(pre.factor, r)
  if pre.chol is None:
    return z
  w = _cholesky_solve(pre.chol, _apply_g(pre, z))
  # A Cholesky factorisation that failed in float32 (NaN) leaves P = T.
  w = jnp.where(jnp.all(jnp.isfinite(w)), w, 0.0)
  return tridiagonal_solve(pre.factor, r - _apply_gt(pre, w, r.shape[0]))


def _preconditioner(system: _System, src, dst, omega, live, damping, free,
                    loop_capacity: int) -> _Preconditioner:
  """T: the chain edges (|src − dst| = 1) in full and the damping; G: the first
  ``loop_capacity`` other edges, so that ``P = H`` when they all fit.

  A loop edge past the capacity, or one whose information is not positive definite, goes into T
  by its two diagonal blocks only: that keeps P positive definite and a fair approximation, and
  the conjugate gradients make up the rest. Fixed nodes: identity rows in T, zero columns in G."""
  n, e = free.shape[0], src.shape[0]
  dtype = system.diag.dtype
  eye = jnp.eye(3, dtype=dtype)
  chain = live & (jnp.abs(src - dst) == 1)
  hi = jnp.maximum(src, dst)
  link = jnp.zeros((n,), bool).at[hi].max(chain)  # an odometry edge (i − 1, i) at i
  anchored = jnp.cumprod((link | (jnp.arange(n) == 0)).astype(jnp.int32)) > 0
  root = jnp.swapaxes(jax.vmap(_chol3)(omega), -1, -2)  # W_e, W_eᵀ W_e = Ω_e
  definite = jnp.all(jnp.isfinite(root), axis=(-2, -1)) & jnp.all(
      jnp.diagonal(root, axis1=-2, axis2=-1) > 0, axis=-1)
  loop = live & ~chain
  rank = jnp.cumsum((loop & definite).astype(jnp.int32)) - 1
  woodbury = loop & definite & (rank < loop_capacity)
  blocks = jnp.where((chain | (loop & ~woodbury))[:, None, None], system.blocks, 0.0)
  diag = (jnp.zeros((n, 3, 3), dtype).at[src].add(blocks[:, :3, :3])
          .at[dst].add(blocks[:, 3:, 3:]))
  # Past a missing odometry edge the chain no longer ties T to node 0: a small share of H's
  # diagonal blocks there keeps T positive definite (P = H + that share).
  diag = diag + jnp.where(anchored, 0.0, _UNANCHORED)[:, None, None] * system.diag
  diag = jnp.where(free[:, None, None], diag + damping[:, :, None] * eye[None], eye[None])
  # T[hi − 1, hi]: the (src, dst) block if src is the lower index, else (dst, src).
  block = jnp.where((src < dst)[:, None, None], system.blocks[:, :3, 3:], system.blocks[:, 3:, :3])
  upper = jnp.zeros((n, 3, 3), dtype).at[hi].add(jnp.where(chain[:, None, None], block, 0.0))
  both = free & jnp.concatenate([jnp.zeros((1,), bool), free[:-1]])
  factor = tridiagonal_factor(diag, jnp.where(both[:, None, None], upper, 0.0))
  k = loop_capacity
  if k == 0:
    empty = jnp.zeros((0,), jnp.int32)
    return _Preconditioner(factor, empty, empty, jnp.zeros((0, 3, 6), dtype), None)
  slot = jnp.zeros((k,), jnp.int32).at[jnp.where(woodbury, rank, k)].set(
      jnp.arange(e, dtype=jnp.int32), mode="drop")
  used = jnp.arange(k) < jnp.sum(woodbury.astype(jnp.int32))
  g = jnp.where(used[:, None, None], root[slot] @ system.jac[slot], 0.0)
  loop_src, loop_dst = src[slot], dst[slot]
  # C = I + G U with U = T⁻¹ Gᵀ (f32[N, 3, 3K]) gathered at the loop ends.
  u = _solve_loop_columns(factor, g, loop_src, loop_dst)
  gu = g[:, :, :3] @ u[loop_src] + g[:, :, 3:] @ u[loop_dst]  # f32[K, 3, 3K]
  cap = gu.reshape(3 * k, 3 * k)
  cap = 0.5 * (cap + cap.T) + jnp.eye(3 * k, dtype=dtype)
  return _Preconditioner(factor, loop_src, loop_dst, g, _cholesky(cap))


# --- preconditioned conjugate gradients ----------------------------------------------------------


def pcg(matvec, precondition, b, tol, max_iterations: int):
  """Preconditioned conjugate gradients (Saad 2003 Alg. 9.1) for ``A x = b`` from x = 0, until
  ``‖r‖ ≤ tol ‖b‖`` or ``max_iterations``. Returns (x, iterations)."""
  def dot(u, v):
    return jnp.sum(u * v)

  def safe_div(num, den):
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)

  bound = (tol * tol) * dot(b, b)
  z = precondition(b)
  init = (jnp.zeros_like(b), b, z, dot(b, z), jnp.int32(0))

  def cond(state):
    _, r, _, _, k = state
    return (k < max_iterations) & (dot(r, r) > bound)

  def body(state):
    x, r, p, rz, k = state
    q = matvec(p)
    alpha = safe_div(rz, dot(p, q))
    x = x + alpha * p
    r = r - alpha * q
    z = precondition(r)
    rz_new = dot(r, z)
    p = z + safe_div(rz_new, rz) * p
    return x, r, p, rz_new, k + 1

  x, _, _, _, k = jax.lax.while_loop(cond, body, init)
  return x, k


# --- Levenberg–Marquardt -------------------------------------------------------------------------


def optimise(poses, node_valid, edges: Edges, *, max_iterations: int = 20, rtol: float = 2e-6,
             step_tol: float = 1e-5, lambda_init: float = 1e-5, cg_tol: float = 1e-3,
             cg_max_iterations: int = 10, loop_capacity: int | None = None) -> Result:
  """Minimises ``½ Σ r_eᵀ Ω_e r_e`` over the valid keyframes but node 0 (module docstring).

  Args:
    poses: f32[N, 3] initial keyframe poses (x, y m, θ rad).
    node_valid: bool[N] keyframes in use (conventionally a prefix; node 0 is the anchor).
    edges: :class:`Edges` (E slots); an edge counts when it is valid and both its ends are valid
      nodes.
    max_iterations: static cap on Levenberg–Marquardt iterations (rejected steps count).
    rtol: stop when a step changes the cost by at most ``rtol`` of it (such a step is taken,
      even a rise: float32 noise).
    step_tol: stop when a step moves no pose coordinate by more than this (m, rad).
    lambda_init: initial damping λ of ``H + λ diag H``.
    cg_tol: relative residual at which a linear solve stops.
    cg_max_iterations: static cap on conjugate-gradient iterations per solve.
    loop_capacity: static K, how many non-chain edges the preconditioner takes exactly (a
      ``3K x 3K`` Cholesky and ``T⁻¹`` of 3K columns per iteration); default ``E − (N − 1)``,
      the slots beyond a full chain. Further loop edges are left to the conjugate gradients
      (more iterations, or less accurate steps within ``cg_max_iterations``).
  Returns:
    :class:`Result`. Invalid nodes, node 0 and nodes without a counting edge keep their poses.
  """
  poses = jnp.asarray(poses, jnp.float32)
  n, e = poses.shape[0], edges.src.shape[0]
  k = max(e - (n - 1), 0) if loop_capacity is None else min(int(loop_capacity), e)
  src, dst, live = _live(node_valid, edges)
  measured = jnp.where(live[:, None], jnp.asarray(edges.measured, jnp.float32), 0.0)
  omega = jnp.where(live[:, None, None], jnp.asarray(edges.information, jnp.float32), 0.0)
  omega = 0.5 * (omega + jnp.swapaxes(omega, -1, -2))
  live_i = live.astype(jnp.int32)
  degree = jnp.zeros((n,), jnp.int32).at[src].add(live_i).at[dst].add(live_i)
  free = node_valid & (jnp.arange(n) > 0) & (degree > 0)
  work = jnp.where(node_valid[:, None], poses, 0.0)  # garbage in unused rows stays out

  def total(x):
    return _weighted_cost(_residuals(x, src, dst, measured, live), omega, live)

  def body(state):
    x, f, lam, it, _, _, cg_total = state
    system = _linearise(x, src, dst, measured, omega, live, free)
    h_diag = jnp.diagonal(system.diag, axis1=-2, axis2=-1)
    damping = jnp.where(free[:, None], lam * h_diag + _LAMBDA_MIN, 0.0)
    pre = _preconditioner(system, src, dst, omega, live, damping, free, k)
    delta, iters = pcg(lambda v: _matvec(system, src, dst, damping, v),
                       lambda v: jnp.where(free[:, None], _precondition(pre, v), 0.0),
                       -system.grad, cg_tol, cg_max_iterations)
    candidate = jnp.where(free[:, None], jax.vmap(retract)(x, delta), x)
    f_new = total(candidate)
    # A float32 cost carries noise of about 1e-6 of it (residuals of poses metres from the
    # origin): a change within rtol · f is taken as no change, and ends the run.
    flat = jnp.abs(f - f_new) <= rtol * f
    accept = (f_new <= f) | flat
    step = jnp.max(jnp.abs(delta))
    converged = (step <= step_tol) | flat
    stop = converged | (~accept & (lam >= _LAMBDA_MAX)) | ~jnp.isfinite(step)
    x = jnp.where(accept, candidate, x)
    f = jnp.where(accept, f_new, f)
    lam = jnp.where(accept, jnp.maximum(lam * 0.1, _LAMBDA_MIN), lam * 10.0)
    return x, f, lam, it + 1, stop, converged, cg_total + iters

  def cond(state):
    return (state[3] < max_iterations) & ~state[4]

  f0 = total(work)
  exact = f0 <= 0.0  # nothing to do
  init = (work, f0, jnp.float32(lambda_init), jnp.int32(0), exact, exact, jnp.int32(0))
  x, f, _, it, _, done, cg_total = jax.lax.while_loop(cond, body, init)
  out = jnp.where(free[:, None], x, poses)
  return Result(poses=out, initial_cost=f0, final_cost=f, iterations=it, converged=done,
                linear_iterations=cg_total)


__all__ = ["Edges", "Result", "Tridiagonal", "between", "between_error", "cost", "expmap",
           "logmap", "optimise", "pcg", "retract", "tridiagonal_factor", "tridiagonal_solve"]
