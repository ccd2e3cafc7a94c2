"""A robot's SLAM pose graph: keyframes, odometry and loop-closure edges, and its connectivity.

The engine's SLAM side (every planner may have one; Ahmed et al. 2024 and the AGS planner of
Placed & Castellanos 2021 reason about it). The authors ran Karto SLAM; this is a model of it
with Karto's settings from the authors' configuration:

* a keyframe when the odometry since the previous one (the increments compounded in its frame,
  as Karto's travel check) has moved ``kf_dist`` metres or turned ``kf_rot`` radians; the
  displacement is at most the distance and turn travelled, which gives a run's keyframe count an
  a-priori bound (:func:`keyframe_bound`);
* an odometry edge from the previous keyframe, of covariance ``σ_sm²·I`` (the scan matcher) plus
  the odometry covariance ``Σ V_n`` accumulated since that keyframe (Li Eq 16, scaled by the
  ``odom_noise_*`` settings: the one odometry noise model, also the simulated one); under the
  ``scan_matching`` model the edge carries the scan match's covariance instead
  (:mod:`jaxplore.slam.model`);
* a loop-closure edge when a new keyframe is within ``loop_radius`` of a keyframe at least
  ``loop_min_age`` keyframes older whose heading differs by at most ``loop_max_turn``, with a
  free line of sight between the two in the belief: the nearest such keyframe only (among the 4
  nearest candidates), of covariance ``σ_sm²·I``;
* every edge weighted by the D-optimality of its information matrix, ``exp(Σ log λ_i / 3)``
  (Placed & Castellanos 2021; Ahmed Eq 8's weighted Laplacian).

Connectivity (Khosoussi et al. 2019; Ahmed Table I): the weighted Laplacian ``L_w``, the
log-determinant of its reduced form ``L̃_w`` (one row and column removed; by the matrix-tree
theorem the log of the weighted number of spanning trees), the algebraic connectivity λ₂, the
average degree ``2m/n`` and the normalised tree connectivity ``logdet L̃_w / ((n − 2) ln n)``.

Dense kernels (:func:`laplacian`, :func:`reduced_logdet`, :func:`algebraic_connectivity`) cost
O(N³) in the node capacity. The planners use :func:`logdet_parts` instead: the graph is a chain
(the odometry edges) plus loop edges, and the chain's reduced Laplacian ``T`` (node 0 removed)
has the explicit inverse ``T⁻¹[x, y] = R(min(x, y))`` with ``R(x) = Σ_{k ≤ x} 1/w_k`` the chain's
resistance from node 0. By the matrix determinant lemma
``logdet L̃ = Σ log w_chain + logdet(I + W^½ S W^½)``, ``S = Uᵀ T⁻¹ U`` over the loop edges'
incidence vectors ``u_e``; ``S[e, f]`` is the chain resistance shared by the node intervals the
two loops span. That costs O(M³) in the loop capacity M, not O(N³).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import chex
import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import linalg, mapping, motion, pytrees
from jaxplore.errors import ConfigError

# Candidates whose line of sight is checked, nearest first, when a keyframe looks for a loop.
LOOP_CANDIDATES = 4


@pytrees.dataclass(frozen=True)
class PoseGraph:
  """One robot's pose graph, fixed capacity (N keyframes, M loop closures).

  Attributes:
    poses: f32[N, 3] keyframe poses (estimated x, y m, θ rad); rows at and past ``n_nodes`` unused.
    chain_w: f32[N] D-optimality weight of the odometry edge (i − 1, i) at ``i``; 0 at 0 and past
      the last keyframe.
    loops: i32[M, 2] loop-closure edges (older, newer keyframe); rows past ``n_loops`` unused.
    loop_w: f32[M] their weights (0 past ``n_loops``).
    n_nodes: i32 keyframes. n_loops: i32 loop closures.
    loops_dropped: i32 loop closures found with the loop list full (not added).
    acc_pose: f32[3] odometry since the last keyframe, in its frame (x, y m, θ rad).
    acc_cov: f32[3, 3] odometry covariance ``Σ V_n`` accumulated since the last keyframe.

  With the ``scan_matching`` SLAM model (:mod:`jaxplore.slam.model`; None otherwise):
    truth: f32[N, 3] the true pose at each keyframe (for the trajectory error, never read by
      the robot).
    chain_measured: f32[N, 3] the odometry edge (i − 1, i) at ``i``: keyframe i's pose in
      keyframe i − 1's frame, as the front end measured it. chain_info: f32[N, 3, 3] its
      information matrix.
    loop_measured: f32[M, 3], loop_info: f32[M, 3, 3]: the same for the loop closures.
    loop_false: bool[M] a closure whose measured relative pose is wrong (compared with the truth).
    loop_link: bool[M] an edge that is a near link, not a loop closure (Karto's
      ``LinkNearChains``: :func:`jaxplore.slam.model.close_loop`); it joins the graph without an
      optimisation.
    loop_revoked: bool[M] an edge the back end took out again: at the optimum it disagreed with
      the rest of the graph (:func:`jaxplore.slam.model.optimise`). It keeps its row (counted,
      weight 0) but no longer constrains the poses.
    loop_chi2: f32[M] each loop edge's ``rᵀ Ω r`` at the last optimisation (0 before it).
    ranges: f16[N, B] each keyframe's scan (cells; a beam with no hit holds ``-range``).
    search_cov: f32[3, 3] the keyframes' edge covariances compounded along the chain since the
      same closure or link as if independent: a bound of the drift that sizes the loop search
      (a window sized by the drift truncated the matches' score surfaces, and their
      covariances came out overconfident).
    keyframe_drift: f32[N, 3, 3] the estimate's uncertainty since the last loop closure or near
      link at each keyframe when it was added (:func:`jaxplore.slam.model.drift`); the newest
      keyframe's gates the closures (:func:`jaxplore.slam.model.current_drift`).
    drift_from: i32 the keyframe of the last loop closure or near link (0 before the first):
      the drift is counted from it.
    closed_at: f32[2] where (estimated x, y) the last loop closed; NaN before the first.
    linked_at: f32[2] where the last near link was made; NaN before the first.
    optimisations: i32 back-end runs. matches_rejected: i32 keyframes whose scan match was
      refused (the robot dead-reckoned). loops_rejected: i32 loop searches that found no match.
  """

  poses: chex.Array
  chain_w: chex.Array
  loops: chex.Array
  loop_w: chex.Array
  n_nodes: chex.Array
  n_loops: chex.Array
  loops_dropped: chex.Array
  acc_pose: chex.Array
  acc_cov: chex.Array
  truth: chex.Array | None = None
  chain_measured: chex.Array | None = None
  chain_info: chex.Array | None = None
  loop_measured: chex.Array | None = None
  loop_info: chex.Array | None = None
  loop_false: chex.Array | None = None
  loop_link: chex.Array | None = None
  loop_revoked: chex.Array | None = None
  loop_chi2: chex.Array | None = None
  ranges: chex.Array | None = None
  search_cov: chex.Array | None = None
  keyframe_drift: chex.Array | None = None
  drift_from: chex.Array | None = None
  closed_at: chex.Array | None = None
  linked_at: chex.Array | None = None
  optimisations: chex.Array | None = None
  matches_rejected: chex.Array | None = None
  loops_rejected: chex.Array | None = None

  if TYPE_CHECKING:  # chex.dataclass adds it at runtime
    def replace(self, **changes: Any) -> PoseGraph: ...


def init(pose, node_capacity: int, loop_capacity: int, beams: int = 0) -> PoseGraph:
  """A graph holding one keyframe at ``pose`` (f32[3]); with ``beams`` > 0, room for the
  ``scan_matching`` SLAM model's edges and keyframe scans of that many beams (the first
  keyframe's scan is stored by the caller)."""
  pose = jnp.asarray(pose, jnp.float32)
  slam = {}
  if beams:
    n, m = node_capacity, loop_capacity
    slam = dict(
        truth=jnp.zeros((n, 3), jnp.float32).at[0].set(pose),
        chain_measured=jnp.zeros((n, 3), jnp.float32),
        chain_info=jnp.broadcast_to(jnp.eye(3, dtype=jnp.float32), (n, 3, 3)),
        loop_measured=jnp.zeros((m, 3), jnp.float32),
        loop_info=jnp.broadcast_to(jnp.eye(3, dtype=jnp.float32), (m, 3, 3)),
        loop_false=jnp.zeros((m,), bool), loop_link=jnp.zeros((m,), bool),
        loop_revoked=jnp.zeros((m,), bool), loop_chi2=jnp.zeros((m,), jnp.float32),
        ranges=jnp.zeros((n, beams), jnp.float16),
        search_cov=jnp.zeros((3, 3), jnp.float32),
        keyframe_drift=jnp.zeros((n, 3, 3), jnp.float32), drift_from=jnp.int32(0),
        closed_at=jnp.full((2,), jnp.nan, jnp.float32),
        linked_at=jnp.full((2,), jnp.nan, jnp.float32),
        optimisations=jnp.int32(0),
        matches_rejected=jnp.int32(0), loops_rejected=jnp.int32(0))
  return PoseGraph(
      poses=jnp.zeros((node_capacity, 3), jnp.float32).at[0].set(pose),
      chain_w=jnp.zeros((node_capacity,), jnp.float32),
      loops=jnp.zeros((loop_capacity, 2), jnp.int32),
      loop_w=jnp.zeros((loop_capacity,), jnp.float32),
      n_nodes=jnp.int32(1), n_loops=jnp.int32(0), loops_dropped=jnp.int32(0),
      acc_pose=jnp.zeros((3,), jnp.float32), acc_cov=jnp.zeros((3, 3), jnp.float32), **slam)


# --- edge weights --------------------------------------------------------------------------------


def d_optimality(info):
  """D-optimality of an information matrix, ``exp(Σ log λ_i / k)`` over its k eigenvalues
  (Placed & Castellanos 2021, the edge weight of Ahmed Eq 8). f32[..., k, k] -> f32[...]."""
  eig = linalg.eigvalsh(info)
  return jnp.exp(jnp.mean(jnp.log(eig), axis=-1))


def d_optimality_of_covariance(cov):
  """:func:`d_optimality` of ``cov⁻¹`` without inverting: ``exp(−Σ log λ_i(cov) / k)``."""
  eig = linalg.eigvalsh(cov)
  return jnp.exp(-jnp.mean(jnp.log(eig), axis=-1))


# --- capacity ------------------------------------------------------------------------------------


def keyframe_bound(max_steps: int, v_max, w_max, dt, kf_dist, kf_rot) -> int:
  """The most keyframes a run of ``max_steps`` steps can create (host side).

  A step drives at most ``v_max·dt`` and turns at most ``w_max·dt``; a keyframe is created when
  the displacement since the last one reaches ``kf_dist`` or its turn ``kf_rot``, and those are at
  most the distance and turn travelled, so each keyframe uses up at least one unit of
  ``distance / kf_dist + turn / kf_rot``; and at most one is created per step. Array arguments
  (a sweep) give the largest bound over their values.
  """
  per_step = float(np.max(np.asarray(v_max, np.float64) * np.asarray(dt, np.float64)
                          / np.asarray(kf_dist, np.float64)
                          + np.asarray(w_max, np.float64) * np.asarray(dt, np.float64)
                          / np.asarray(kf_rot, np.float64)))
  # Slack for float32 accumulation rounding a threshold crossing a little early.
  return 1 + min(int(max_steps), math.ceil(max_steps * per_step * (1 + 1e-4)))


def loop_bound(max_steps: int, params, keyframes: int) -> int:
  """Loop slots for a ``scan_matching`` run of ``max_steps`` steps (host side): its loop
  closures and near links as the model spaces them (:mod:`jaxplore.slam.model`). A robot looks
  for the next closure only once it is ``loop_radius`` from where it closed the last, and makes
  at most one near link per ``link_spacing`` driven (per keyframe at 0, none at
  ``link_radius`` 0), so a run that drives ``d`` metres makes about ``d / loop_radius`` closures
  and ``d / link_spacing`` links; 10 % more for the closures the back end revokes (they keep
  their slots). A sizing, not a proof: a closure found with the list full is counted
  (``loops_dropped``) and the run's summary says so. Array arguments (a sweep) give the largest
  over their values."""
  distance = max_steps * float(np.max(np.asarray(params.v_max, np.float64)
                                      * np.asarray(params.dt, np.float64)))
  closures = distance / float(np.min(params.loop_radius))
  spacing = float(np.min(params.link_spacing))
  links = (0.0 if float(np.max(params.link_radius)) <= 0
           else keyframes if spacing <= 0 else distance / spacing)
  return max(8, math.ceil(1.1 * (closures + links)))


def check_capacity(node_capacity: int, max_steps: int, params) -> None:
  """Raises :class:`ConfigError` when a run could create more keyframes than the graph holds."""
  bound = keyframe_bound(max_steps, params.v_max, params.w_max, params.dt, params.kf_dist,
                         params.kf_rot)
  if bound > node_capacity:
    raise ConfigError(
        f"the pose graph holds {node_capacity} keyframes, but {max_steps} steps of up to "
        f"{float(np.max(params.v_max)) * float(np.max(params.dt)):.3g} m and "
        f"{float(np.max(params.w_max)) * float(np.max(params.dt)):.3g} rad with a keyframe every "
        f"{float(np.min(params.kf_dist)):.3g} m or {float(np.min(params.kf_rot)):.3g} rad can "
        f"create {bound}; raise graph_nodes to {bound} or shorten the run")


# --- growing the graph ---------------------------------------------------------------------------


def line_free(logodds, a_xy, b_xy, origin, res: float, free_logit, samples: int):
  """Whether every cell on the segment a → b (metres) is believed free.

  ``samples`` points evenly spaced from a to b (a static count, at most half a cell apart for
  the segments it is used on) are looked up; cells off the grid count as not free.
  """
  t = jnp.linspace(0.0, 1.0, samples, dtype=jnp.float32)[:, None]
  pts = a_xy[None, :] + t * (b_xy - a_xy)[None, :]
  rows = jnp.floor((pts[:, 1] - origin[1]) / res).astype(jnp.int32)
  cols = jnp.floor((pts[:, 0] - origin[0]) / res).astype(jnp.int32)
  values = logodds.at[rows, cols].get(mode="fill", fill_value=jnp.inf, wrap_negative_indices=False)
  return jnp.all(values < free_logit)


def observe(graph: PoseGraph, pose, v_n, increment, active, logodds, origin, res: float, params,
            los_samples: int) -> PoseGraph:
  """One motion step: accumulate odometry; add a keyframe, its odometry edge and at most one
  loop closure when the odometry since the last keyframe moved or turned far enough.

  Args:
    graph: the robot's graph.
    pose: f32[3] the robot's estimated pose after the step.
    v_n: f32[3, 3] the step's odometry covariance: the simulated odometry error's (Li Eq 16's
      form, ``odom_noise_*``), which the engine passes.
    increment: f32[3] the step's odometry (x, y, θ in the frame before the step; Li Eq 9).
    active: bool; the robot moved or turned (an inactive step changes nothing).
    logodds: f32[H, W] the belief (loop-closure line of sight).
    origin: f32[2] metres of cell (0, 0)'s corner. res: metres per cell.
    params: ``Params`` with ``kf_dist``, ``kf_rot``, ``scan_match_sigma``, ``loop_radius``,
      ``loop_min_age``, ``loop_max_turn``, ``p_free``.
    los_samples: static number of points on a line-of-sight test.
  """
  n_cap = graph.poses.shape[0]
  m_cap = graph.loops.shape[0]
  acc_pose = jnp.where(active, motion.compound(graph.acc_pose, increment), graph.acc_pose)
  acc_cov = graph.acc_cov + jnp.where(active, v_n, 0.0)
  i = graph.n_nodes
  moved = jnp.sqrt(acc_pose[0] ** 2 + acc_pose[1] ** 2)
  new = active & ((moved >= params.kf_dist) | (jnp.abs(acc_pose[2]) >= params.kf_rot)) & (i < n_cap)
  sm_var = params.scan_match_sigma ** 2
  edge_cov = acc_cov + sm_var * jnp.eye(3, dtype=jnp.float32)
  w_odometry = jnp.cbrt(1.0 / linalg.det3(edge_cov))
  slot = jnp.where(new, i, n_cap)
  poses = graph.poses.at[slot].set(pose.astype(jnp.float32), mode="drop")
  chain_w = graph.chain_w.at[slot].set(w_odometry, mode="drop")

  # Loop closure: the nearest old-enough keyframe in range, heading and line of sight.
  index = jnp.arange(n_cap)
  offset = graph.poses[:, :2] - pose[None, :2]
  dist = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
  turn = jnp.abs(motion.wrap_angle(graph.poses[:, 2] - pose[2]))
  eligible = ((index.astype(jnp.float32) <= i.astype(jnp.float32) - params.loop_min_age)
              & (dist <= params.loop_radius) & (turn <= params.loop_max_turn))
  score, nearest = jax.lax.top_k(jnp.where(eligible, -dist, -jnp.inf), min(LOOP_CANDIDATES, n_cap))
  free_logit = mapping.logit(params.p_free)
  sight = jax.vmap(lambda j: line_free(logodds, graph.poses[j, :2], pose[:2], origin, res,
                                       free_logit, los_samples))(nearest)
  ok = jnp.isfinite(score) & sight
  j = nearest[jnp.argmax(ok)]
  closes = new & jnp.any(ok)
  room = graph.n_loops < m_cap
  write = closes & room
  loop_slot = jnp.where(write, graph.n_loops, m_cap)
  loops = graph.loops.at[loop_slot].set(jnp.stack([j, i]).astype(jnp.int32), mode="drop")
  loop_w = graph.loop_w.at[loop_slot].set(1.0 / sm_var, mode="drop")

  keep = ~new
  return graph.replace(poses=poses, chain_w=chain_w, loops=loops, loop_w=loop_w,
                       n_nodes=i + new.astype(jnp.int32),
                       n_loops=graph.n_loops + write.astype(jnp.int32),
                       loops_dropped=graph.loops_dropped + (closes & ~room).astype(jnp.int32),
                       acc_pose=jnp.where(keep, acc_pose, 0.0),
                       acc_cov=jnp.where(keep, acc_cov, 0.0))


# --- dense kernels -------------------------------------------------------------------------------


def edges(graph: PoseGraph):
  """(src i32[E], dst i32[E], weight f32[E], valid bool[E]) over the N − 1 chain slots and the
  M loop slots, E = N − 1 + M."""
  n_cap = graph.poses.shape[0]
  k = jnp.arange(1, n_cap)
  chain_valid = k < graph.n_nodes
  loop_valid = jnp.arange(graph.loops.shape[0]) < graph.n_loops
  src = jnp.concatenate([k - 1, graph.loops[:, 0]])
  dst = jnp.concatenate([k, graph.loops[:, 1]])
  valid = jnp.concatenate([chain_valid, loop_valid])
  weight = jnp.where(valid, jnp.concatenate([graph.chain_w[1:], graph.loop_w]), 0.0)
  return src, dst, weight, valid


def laplacian(n_cap: int, src, dst, weight):
  """Dense weighted Laplacian f32[n_cap, n_cap] of an edge list (weight 0 = no edge)."""
  lap = jnp.zeros((n_cap, n_cap), jnp.float32)
  lap = lap.at[src, dst].add(-weight).at[dst, src].add(-weight)
  degree = jnp.zeros((n_cap,), jnp.float32).at[src].add(weight).at[dst].add(weight)
  return lap + jnp.diag(degree)


def graph_laplacian(graph: PoseGraph):
  src, dst, weight, _ = edges(graph)
  return laplacian(graph.poses.shape[0], src, dst, weight)


def reduced_logdet(lap, valid, anchor=0):
  """``log det L̃``: the Laplacian over the ``valid`` nodes with node ``anchor`` removed, by
  Cholesky (``2 Σ log diag``). Removed and invalid rows/columns are replaced by the identity, so
  the shape stays fixed; the matrix-tree theorem makes the result the log of the weighted number
  of spanning trees whatever the anchor."""
  keep = valid & (jnp.arange(lap.shape[0]) != anchor)
  both = keep[:, None] & keep[None, :]
  eye = jnp.eye(lap.shape[0], dtype=lap.dtype)
  chol = linalg.cholesky(jnp.where(both, lap, eye))
  return 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol)))


def algebraic_connectivity(lap, valid):
  """λ₂: the second smallest eigenvalue of the Laplacian over the ``valid`` nodes (Fiedler).

  Invalid nodes get a diagonal above every valid eigenvalue (the largest is at most twice the
  largest weighted degree), so the valid spectrum comes first after sorting.
  """
  both = valid[:, None] & valid[None, :]
  top = 2.0 * jnp.max(jnp.where(valid, jnp.diagonal(lap), 0.0)) + 1.0
  masked = jnp.where(both, lap, jnp.where(jnp.eye(lap.shape[0], dtype=bool), top, 0.0))
  return linalg.eigvalsh(masked)[1]


def average_degree(n_nodes, n_edges):
  """``2m / n`` (Ahmed §III)."""
  return 2.0 * n_edges / jnp.maximum(n_nodes, 1)


def tree_connectivity(logdet, n_nodes):
  """Normalised tree connectivity ``logdet L̃_w / ((n − 2) ln n)`` (Khosoussi et al. 2019: the
  weighted tree count relative to that of the complete graph, ``n^(n−2)``)."""
  n = jnp.asarray(n_nodes, jnp.float32)
  return logdet / ((n - 2.0) * jnp.log(n))


# --- structured log-determinant (chain + loops) --------------------------------------------------


def chain_resistance(chain_w, n_nodes):
  """``R[x] = Σ_{1 ≤ k ≤ x} 1/w_k``: the chain's resistance from node 0 to node x (f32[N]); flat
  past the last keyframe."""
  k = jnp.arange(chain_w.shape[0])
  inv = jnp.where((k >= 1) & (k < n_nodes), 1.0 / jnp.where(chain_w > 0, chain_w, 1.0), 0.0)
  return jnp.cumsum(inv)


def shared_resistance(r_hi_a, r_lo_a, r_hi_b, r_lo_b):
  """Chain resistance shared by two intervals given by their end resistances:
  ``max(0, min(hi_a, hi_b) − max(lo_a, lo_b))`` (broadcasts)."""
  return jnp.maximum(jnp.minimum(r_hi_a, r_hi_b) - jnp.maximum(r_lo_a, r_lo_b), 0.0)


def loop_capacitance(graph: PoseGraph, resistance):
  """``C = I + W^½ S W^½`` over the M loop slots (unused slots give identity rows)."""
  lo = resistance[graph.loops[:, 0]]
  hi = resistance[graph.loops[:, 1]]
  w = jnp.where(jnp.arange(graph.loops.shape[0]) < graph.n_loops, graph.loop_w, 0.0)
  s = shared_resistance(hi[:, None], lo[:, None], hi[None, :], lo[None, :])
  root = jnp.sqrt(w)
  return jnp.eye(w.shape[0], dtype=jnp.float32) + root[:, None] * s * root[None, :]


def logdet_parts(graph: PoseGraph):
  """The pieces of ``log det L̃_w`` by the determinant lemma (module docstring).

  Returns (logdet, resistance f32[N], chol f32[M, M] the Cholesky factor of the loop
  capacitance, root_w f32[M] square roots of the loop weights).
  """
  resistance = chain_resistance(graph.chain_w, graph.n_nodes)
  k = jnp.arange(graph.chain_w.shape[0])
  chain_term = jnp.sum(jnp.where((k >= 1) & (k < graph.n_nodes),
                                 jnp.log(jnp.where(graph.chain_w > 0, graph.chain_w, 1.0)), 0.0))
  chol = linalg.cholesky(loop_capacitance(graph, resistance))
  root_w = jnp.sqrt(jnp.where(jnp.arange(graph.loops.shape[0]) < graph.n_loops, graph.loop_w, 0.0))
  logdet = chain_term + 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol)))
  return logdet, resistance, chol, root_w


def extended_logdet(graph: PoseGraph, parts, new_w, new_valid, loop_to, loop_w):
  """``log det L̃`` of the graph extended by a pendant chain of new nodes with loop closures.

  The new nodes hang off the last keyframe, one after another, so without loops they add
  exactly ``Σ log w`` (a pendant path). Each new node p may close one loop to an existing
  keyframe ``loop_to[p]``: these are rank-one updates, taken together by the Schur complement
  of the loop capacitance (determinant lemma over the touched nodes only).

  Args:
    graph: the real graph. parts: :func:`logdet_parts` of it.
    new_w: f32[P] weights of the pendant chain's edges (node p − 1 → p; node −1 = last keyframe).
    new_valid: bool[P] which new nodes exist (a prefix).
    loop_to: i32[P] keyframe each new node closes a loop to. loop_w: f32[P] its weight (0 = none).
  Returns:
    f32 log det of the extended reduced Laplacian.
  """
  logdet, resistance, chol, root_w = parts
  last = graph.n_nodes - 1
  w = jnp.where(new_valid, new_w, 1.0)
  pendant = jnp.cumsum(jnp.where(new_valid, 1.0 / w, 0.0))
  r_new = resistance[last] + pendant  # resistance from node 0 to each new node
  lw = jnp.where(new_valid, loop_w, 0.0)
  root_h = jnp.sqrt(lw)
  r_to = resistance[jnp.clip(loop_to, 0, graph.poses.shape[0] - 1)]
  # Interval of a new loop: [loop_to, new node]; of an old loop: [loops[e, 0], loops[e, 1]].
  lo = resistance[graph.loops[:, 0]]
  hi = resistance[graph.loops[:, 1]]
  b = shared_resistance(hi[:, None], lo[:, None], r_new[None, :], r_to[None, :])
  b = root_w[:, None] * b * root_h[None, :]
  d = shared_resistance(r_new[:, None], r_to[:, None], r_new[None, :], r_to[None, :])
  d = jnp.eye(lw.shape[0], dtype=jnp.float32) + root_h[:, None] * d * root_h[None, :]
  y = linalg.solve_triangular(chol, b, lower=True)
  schur = d - y.T @ y
  schur_chol = linalg.cholesky(schur)
  return (logdet + jnp.sum(jnp.where(new_valid, jnp.log(w), 0.0))
          + 2.0 * jnp.sum(jnp.log(jnp.diagonal(schur_chol))))
