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


def _results_folder(path, episodes, curves, sweep):
  """A results folder as run/sweep write it: the tables, maps.npz and config.json."""
  import json
  path.mkdir()
  episodes.assign(E_r=1.0, coverage=0.5).to_parquet(path / "episodes.parquet")
  curves.assign(distance=curves.time, entropy=1.0 - curves.coverage, x=1.0, y=1.0).to_parquet(
      path / "curves.parquet")
  np.savez(path / "maps.npz", occupied=np.zeros((8, 8), bool), logodds=np.zeros((1, 8, 8)),
           res=0.5, origin=np.zeros(2))
  (path / "config.json").write_text(json.dumps({} if sweep is None else {"sweep": sweep}))
  return path


def test_run_figures_label_a_sweeps_curves_and_read_older_folders(tmp_path, monkeypatch):
  """A sweep folder's curve figures draw one labelled curve per setting; a folder whose config
  predates ``figure_names`` (or a run's) draws the pooled curve instead of failing."""
  episodes, curves = _sweep_tables(2)
  drawn = []
  real = plot.spread
  monkeypatch.setattr(plot, "spread", lambda ax, part, x, y, label=None, **kw: (
      drawn.append((y, label, sorted(set(part.robot)))), real(ax, part, x, y, label=label)))
  sweep = _results_folder(tmp_path / "sweep", episodes, curves,
                          {"figure_names": ["planner", "region"]})
  names = {p.name for p in plot.run_figures(sweep)}
  assert names == {"map.png", "entropy_distance.png", "coverage_time.png", "sweep.png"}
  assert [d for d in drawn if d[0] == "coverage"] == [
      ("coverage", "planner=li2020, region=r1", [2, 3]),
      ("coverage", "planner=nearest_frontier, region=r0", [0, 1])]
  for config in ({"names": ["region"]}, None):  # an older sweep's config; a run's
    drawn.clear()
    older = _results_folder(tmp_path / f"older{len(list(tmp_path.iterdir()))}", episodes, curves,
                            config)
    assert "sweep.png" not in {p.name for p in plot.run_figures(older)}
    assert [d for d in drawn if d[0] == "coverage"] == [("coverage", None, [0, 1, 2, 3])]
