"""Every notebook in ``notebooks/`` executes on its tiny settings and writes what it promises."""

import runpy
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd
import pytest
from PIL import Image

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.fixture
def tiny(tmp_path, monkeypatch):
  """Runs a notebook script in this process (as ``python notebooks/X.py`` would) on tiny settings."""
  monkeypatch.setenv("JAXPLORE_NOTEBOOK_TINY", "1")
  monkeypatch.setenv("JAXPLORE_NOTEBOOK_OUT", str(tmp_path))
  monkeypatch.setenv("MPLBACKEND", "Agg")

  def run(name):
    try:
      return runpy.run_path(str(NOTEBOOKS / name), run_name="__main__")
    finally:
      plt.close("all")
  return run


def _png(path):
  assert path.is_file(), path
  with Image.open(path) as image:
    assert image.format == "PNG" and image.width > 200 and image.height > 150
    # not a blank canvas: a real figure has many colours
    assert len(image.convert("RGB").getcolors(maxcolors=1 << 20)) > 10


def test_every_notebook_is_tested():
  assert sorted(p.name for p in NOTEBOOKS.glob("*.py")) == ["quickstart.py", "sweep_analysis.py"]


def test_notebooks_are_percent_scripts():
  for path in NOTEBOOKS.glob("*.py"):
    text = path.read_text()
    assert "format_name: percent" in text and "# %% [markdown]" in text and "\n# %%\n" in text


def test_quickstart(tiny, tmp_path):
  ns = tiny("quickstart.py")
  out = tmp_path / "quickstart"
  _png(out / "coverage_time.png")
  _png(out / "belief_map.png")
  episodes = ns["episodes"]
  assert len(episodes) == 2 and episodes.distance_m.gt(0).all()
  pd.testing.assert_frame_equal(episodes, pd.read_parquet(out / "run" / "episodes.parquet"))
  assert ns["config"]["robots"] == 2 and ns["config"]["world"]["name"] == "tiny_office"


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
def test_sweep_analysis(tiny, tmp_path):
  ns = tiny("sweep_analysis.py")
  out = tmp_path / "sweep_analysis"
  _png(out / "E_r_heatmaps.png")
  summary = pd.read_csv(out / "summary.csv")
  # 2 alphas x 2 k1 x 2 k2 settings, 2 seeds each, every statistic filled in
  assert len(summary) == 8 and (summary.episodes == 2).all()
  assert set(zip(summary.alpha, summary.k1, summary.k2)) == {
      (a, k1, k2) for a in (1.0, 2.0) for k1 in (0.0, 0.3) for k2 in (0.6, 0.9)}
  for column in ("E_r_mean", "E_r_std", "distance_m_mean", "distance_m_std", "coverage_mean", "coverage_std"):
    assert summary[column].notna().all(), column
  assert (summary.coverage_mean > 0).all() and (summary.distance_m_mean > 0).all()
  # the summary is the per-setting mean of the episodes table
  episodes = ns["episodes"]
  first = episodes[(episodes.alpha == 1.0) & (episodes.k1 == 0.0) & (episodes.k2 == 0.6)]
  row = summary[(summary.alpha == 1.0) & (summary.k1 == 0.0) & (summary.k2 == 0.6)].iloc[0]
  assert row.E_r_mean == pytest.approx(first.E_r.mean())
  # the pick is the best E_r among settings within 5 % of the best coverage
  best = ns["best"]
  good = summary[summary.coverage_mean >= 0.95 * summary.coverage_mean.max()]
  assert best.E_r_mean == pytest.approx(good.E_r_mean.max())
  assert (out / "best.txt").read_text().strip() == (
      f"alpha={best.alpha:g}, k1={best.k1:g}, k2={best.k2:g}")
