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
  # distance is non-decreasing; np.interp needs increasing x, so keep the first sample of each value.
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
