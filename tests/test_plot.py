"""Figures of a results folder: which robots each curve of a sweep's figures is drawn from."""

import numpy as np
import pandas as pd

from jaxplore import plot


def _sweep_tables(n_settings: int, seeds: int = 2):
  """Episodes of a sweep (robot = row, one setting per ``seeds`` rows, a word axis and a number
  axis, NaN where a planner lacks the number) and each row's curve of 3 records."""
  rows = np.arange(n_settings * seeds)
  setting = rows // seeds
  episodes = pd.DataFrame({
      "robot": rows, "planner": np.where(setting % 2, "li2020", "nearest_frontier"),
      "region": np.asarray([f"r{s}" for s in setting], object),
      "alpha": np.where(setting % 2, setting.astype(float), np.nan)})
  curves = pd.DataFrame({"robot": np.repeat(rows, 3), "time": np.tile([0.0, 1.0, 2.0], len(rows)),
                         "coverage": np.linspace(0, 1, 3 * len(rows))})
  return episodes, curves


def test_a_sweep_draws_one_curve_per_setting_from_its_own_robots():
  episodes, curves = _sweep_tables(3)
  parts = plot._curves_by_setting(curves, episodes, ["planner", "region", "alpha"])
  assert [label for label, _ in parts] == ["planner=li2020, region=r1, alpha=1",
                                           "planner=nearest_frontier, region=r0, alpha=-",
                                           "planner=nearest_frontier, region=r2, alpha=-"]
  assert [sorted(set(part.robot)) for _, part in parts] == [[2, 3], [0, 1], [4, 5]]
  assert sum(len(part) for _, part in parts) == len(curves)


def test_a_run_or_a_wide_sweep_pools_its_robots_into_one_curve():
  episodes, curves = _sweep_tables(plot.MAX_CURVES + 1)
  for pooled in (plot._curves_by_setting(curves, episodes, ["region"]),
                 plot._curves_by_setting(curves, None, ()),
                 plot._curves_by_setting(curves, episodes.iloc[:2], ["region"])):  # one setting
    assert len(pooled) == 1 and pooled[0][0] is None and pooled[0][1] is curves
