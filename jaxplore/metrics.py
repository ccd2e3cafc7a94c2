"""Per-episode summaries and summaries over seeds, host side (NumPy/pandas): Li et al. 2020's
E_r and Std(E_r), times to coverage, Godoy-Calvo et al.'s Tables 3-4 layout.

Curves come from the engine's per-step :class:`jaxplore.sim.Record` (one row per robot and step);
episodes are one row per robot.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

COVERAGE_LEVELS = (0.90, 0.95, 0.99)


def reduction_rate_std(distance, entropy, interval: float) -> float:
  """``Std(E_r)``: the standard deviation of the entropy reduction per metre over successive
  ``interval``-metre stretches of the path (entropy interpolated at every ``k·interval`` m)."""
  distance = np.asarray(distance, np.float64)
  entropy = np.asarray(entropy, np.float64)
  if distance.size < 2 or distance[-1] < 2 * interval:
    return float("nan")
  marks = np.arange(0.0, distance[-1] + 1e-9, interval)
  # distance is non-decreasing; np.interp needs increasing x, so keep the first sample of each
  # value.
  keep = np.concatenate([[True], np.diff(distance) > 0])
  at = np.interp(marks, distance[keep], entropy[keep])
  rates = -np.diff(at) / interval
  return float(np.std(rates))


def first_time_reaching(time, coverage, level: float) -> float:
  """Mission time at which coverage first reaches ``level`` (NaN if never)."""
  hit = np.nonzero(np.asarray(coverage) >= level - 1e-9)[0]
  return float(np.asarray(time)[hit[0]]) if hit.size else float("nan")


def episode_row(curve: pd.DataFrame, initial_entropy: float, res: float, n_reachable: float,
                interval: float) -> dict:
  """One robot's episode summary from its curve (rows ordered by step, up to its last step)."""
  last = curve.iloc[-1]
  reduction = initial_entropy - float(last.entropy)
  distance = float(last.distance)
  row = {
      "steps": int(len(curve)),
      "time_s": float(last.time),
      "distance_m": distance,
      "entropy_initial": initial_entropy,
      "entropy_final": float(last.entropy),
      "entropy_reduction": reduction,
      "E_r": reduction / distance if distance > 0 else float("nan"),
      "Std_E_r": reduction_rate_std(np.concatenate([[0.0], curve.distance.to_numpy()]),
                                    np.concatenate([[initial_entropy], curve.entropy.to_numpy()]),
                                    interval),
      "coverage": float(last.coverage),
      "coverage_m2": float(last.coverage) * n_reachable * res**2,
      "det_cov_final": float(last.det_cov),
      "pose_error_mean": float(curve.pose_error.mean()),
      "pose_error_max": float(curve.pose_error.max()),
  }
  for level in COVERAGE_LEVELS:
    row[f"t{int(level * 100)}_s"] = first_time_reaching(curve.time, curve.coverage, level)
  return row


def summarise(episodes: pd.DataFrame, by, columns) -> pd.DataFrame:
  """mean, std, min, max, Q1, Q3 of ``columns`` per group (Godoy-Calvo Tables 3–4 layout)."""
  stats = {
      "mean": "mean", "std": "std", "min": "min", "max": "max",
      "Q1": lambda s: s.quantile(0.25), "Q3": lambda s: s.quantile(0.75),
  }
  grouped = episodes.groupby(list(by), sort=False)[list(columns)]
  parts = {name: grouped.agg(fn) for name, fn in stats.items()}
  out = pd.concat(parts, axis=1)
  out.columns = [f"{col}_{stat}" for stat, col in out.columns]
  return out.reset_index()


def map_quality(logodds, truth_occupied) -> dict:
  """SSIM and RMSE of the belief's P(occupied) against the truth (0 free, 1 occupied), over the
  whole grid (Ahmed et al. Table I's map-quality columns; SSIM by scikit-image, data range 1)."""
  from skimage.metrics import structural_similarity
  p = 1.0 / (1.0 + np.exp(-np.asarray(logodds, np.float64)))
  truth = np.asarray(truth_occupied, np.float64)
  side = min(p.shape)  # scikit-image's 7-cell window, narrowed (odd) on maps under 7 cells
  window = min(7, side if side % 2 else side - 1)
  return {"ssim": float(structural_similarity(p, truth, data_range=1.0, win_size=window)),
          "rmse": float(np.sqrt(np.mean((p - truth) ** 2)))}


def graph_laplacian_sparse(chain_w, loops, loop_w, n_nodes: int, n_loops: int):
  """The weighted Laplacian (SciPy CSR, float64) of a pose graph's first ``n_nodes`` keyframes."""
  from scipy import sparse
  k = np.arange(1, n_nodes)
  src = np.concatenate([k - 1, np.asarray(loops)[:n_loops, 0]])
  dst = np.concatenate([k, np.asarray(loops)[:n_loops, 1]])
  w = np.concatenate([np.asarray(chain_w, np.float64)[1:n_nodes],
                      np.asarray(loop_w, np.float64)[:n_loops]])
  adj = sparse.coo_matrix((w, (src, dst)), shape=(n_nodes, n_nodes)).tocsr()
  adj = adj + adj.T
  return sparse.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj


# Above this many keyframes, λ₂ comes from a sparse shift-invert eigensolver instead of a dense one.
DENSE_EIG_NODES = 600


def graph_metrics(chain_w, loops, loop_w, n_nodes: int, n_loops: int,
                  loops_dropped: int = 0) -> dict:
  """Ahmed et al. Table I's graph connectivity of one pose graph (host side, float64).

  Returns keyframes, edges, ``lambda2`` (algebraic connectivity of the D-optimality-weighted
  Laplacian), ``avg_degree`` (2m/n), ``logdet`` (log weighted spanning-tree count, the reduced
  Laplacian's log-determinant), ``tau_hat`` (``logdet / ((n − 2) ln n)``), ``dopt_mean`` (mean
  edge D-optimality) and ``loops_dropped``.
  """
  from scipy import sparse
  from scipy.sparse import linalg as splinalg
  n, m = int(n_nodes), int(n_loops)
  edges = n - 1 + m
  lap = graph_laplacian_sparse(chain_w, loops, loop_w, n, m)
  weights = np.concatenate([np.asarray(chain_w, np.float64)[1:n],
                            np.asarray(loop_w, np.float64)[:m]])
  out = {"graph_nodes": n, "graph_edges": edges, "loops_dropped": int(loops_dropped),
         "avg_degree": 2.0 * edges / n,
         "dopt_mean": float(weights.mean()) if edges else float("nan")}
  if n >= 2:
    lu = splinalg.splu(sparse.csc_matrix(lap[1:, 1:]))
    out["logdet"] = float(np.sum(np.log(np.abs(lu.U.diagonal()))))
  else:
    out["logdet"] = 0.0
  out["tau_hat"] = out["logdet"] / ((n - 2) * np.log(n)) if n >= 3 else float("nan")
  if n < 2:
    out["lambda2"] = float("nan")
  elif n <= DENSE_EIG_NODES:
    out["lambda2"] = float(np.linalg.eigvalsh(lap.toarray())[1])
  else:
    scale = float(lap.diagonal().max())
    vals = splinalg.eigsh(sparse.csc_matrix(lap), k=2, sigma=-1e-6 * scale, which="LM",
                          return_eigenvectors=False)
    out["lambda2"] = float(np.sort(vals)[1])
  return out


def dopt_range(dopt_mean_curve) -> dict:
  """Ahmed et al. Table II from one episode's mean edge D-optimality over time: its max, min and
  ``%R = 100·(max − min)/max`` (steps before the first edge, NaN, are skipped)."""
  values = np.asarray(dopt_mean_curve, np.float64)
  values = values[np.isfinite(values)]
  if values.size == 0:
    return {"dopt_max": float("nan"), "dopt_min": float("nan"), "dopt_R": float("nan")}
  hi, lo = float(values.max()), float(values.min())
  return {"dopt_max": hi, "dopt_min": lo, "dopt_R": 100.0 * (hi - lo) / hi}


def slam_accuracy(graph) -> dict:
  """A ``scan_matching`` robot's SLAM columns from its final pose graph: ``ate_m`` (absolute
  trajectory error of its keyframes, RMSE after rigid alignment, as ``evo_ape --align``),
  ``rpe_m_per_m`` (relative pose error over 1 m stretches, as ``evo_rpe --delta 1 --delta_unit
  m``, divided by the metre), ``loop_closures`` and ``false_closures``, ``near_links`` and
  ``false_links`` (:func:`jaxplore.slam.model.close_loop`; the edges in the final graph),
  ``revoked`` and ``false_revoked`` (loop edges the back end took out again, and how many of
  them were false: :func:`jaxplore.slam.model.optimise`), ``matches_rejected`` (keyframes
  dead-reckoned), ``optimisations``."""
  from jaxplore.slam import accuracy
  n = int(graph.n_nodes)
  valid = np.arange(np.asarray(graph.poses).shape[0]) < n
  estimated = np.asarray(graph.poses, np.float32)
  truth = np.asarray(graph.truth, np.float32)
  loops = int(graph.n_loops)
  link = np.asarray(graph.loop_link)[:loops]
  false = np.asarray(graph.loop_false)[:loops]
  revoked = np.asarray(graph.loop_revoked)[:loops]
  return {
      "ate_m": float(accuracy.absolute_trajectory_error(estimated, truth, valid)),
      "rpe_m_per_m": float(accuracy.relative_pose_error(estimated, truth, valid, delta=1.0)),
      "loop_closures": int(np.sum(~link & ~revoked)),
      "false_closures": int(np.sum(false & ~link & ~revoked)),
      "near_links": int(np.sum(link & ~revoked)),
      "false_links": int(np.sum(false & link & ~revoked)),
      "revoked": int(np.sum(revoked)),
      "false_revoked": int(np.sum(false & revoked)),
      "matches_rejected": int(graph.matches_rejected),
      "optimisations": int(graph.optimisations),
  }


def map_and_graph_row(logodds, truth_occupied, graph=None, dopt_curve=None) -> dict:
  """One robot's map-quality columns (with ``misplaced_walls``: the fraction of the cells its
  belief holds occupied, P > 0.5, that lie more than one cell from every true wall) and, with its
  final pose graph (NumPy leaves of a :class:`jaxplore.posegraph.PoseGraph`), its connectivity and
  Table II columns, and with the ``scan_matching`` model its :func:`slam_accuracy`."""
  from jaxplore.slam import accuracy
  row = map_quality(logodds, truth_occupied)
  row["misplaced_walls"] = float(accuracy.misplaced_walls(np.asarray(logodds) > 0.0,
                                                          np.asarray(truth_occupied)))
  if graph is not None:
    m = int(graph.n_loops)
    kept = np.ones(m, bool)
    if getattr(graph, "loop_revoked", None) is not None:  # revoked edges are out of the graph
      kept = ~np.asarray(graph.loop_revoked)[:m]
    row.update(graph_metrics(graph.chain_w, np.asarray(graph.loops)[:m][kept],
                             np.asarray(graph.loop_w)[:m][kept], int(graph.n_nodes),
                             int(kept.sum()), int(graph.loops_dropped)))
    row.update(dopt_range([] if dopt_curve is None else dopt_curve))
    if getattr(graph, "truth", None) is not None:
      row.update(slam_accuracy(graph))
  return row
