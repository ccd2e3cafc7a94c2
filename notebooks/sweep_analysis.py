# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # An α × k1 × k2 sweep of Li et al. 2020's planner
#
# Li et al.'s entropy-boundary planner (`li2020`) has three numbers worth tuning: α sets the radius
# `R_u = α·R_e` within which the entropy map is updated, and k1, k2 weight the Dijkstra edges into
# entropy boundaries and grid-map boundaries (Eq 8, `0 <= k1 < k2 < 1`). `jaxplore.sweep` runs every
# combination × seeds as one compiled batch; this notebook summarises the results per setting with
# pandas, draws E_r (entropy removed per metre travelled) over k1 × k2 for each α, and picks a
# setting.
#
# A jupytext "percent" script: `pip install jupytext`, `jupytext --to notebook
# notebooks/sweep_analysis.py` to open it in Jupyter, or run it as plain Python. The default
# settings (27 settings × 4 seeds = 108 robots on the `lab` world) take a while on a laptop CPU;
# `JAXPLORE_NOTEBOOK_TINY=1` runs 8 settings × 2 seeds on a tiny floor for a few dozen steps (what
# the test suite does). `JAXPLORE_NOTEBOOK_OUT` sets where results and figures go.

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import jaxplore
from jaxplore.maps import generate

TINY = os.environ.get("JAXPLORE_NOTEBOOK_TINY", "") not in ("", "0")
OUT = Path(os.environ.get("JAXPLORE_NOTEBOOK_OUT", "runs/notebooks")) / "sweep_analysis"
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## Run the sweep
#
# Seed `s` starts at the same pose in every setting, so settings are compared on the same starts.

# %%
if TINY:
  grid = {"alpha": [1.0, 2.0], "k1": [0.0, 0.3], "k2": [0.6, 0.9]}
  seeds = 2
  run_settings = dict(world=generate.office(8.0, 6.0, res=0.2, seed=0, name="tiny_office"),
                      max_steps=30, replan_every=5, params={"r_max": 3.0}, progress=False)
else:
  grid = {"alpha": [1.0, 1.5, 2.0], "k1": [0.0, 0.2, 0.4], "k2": [0.6, 0.75, 0.9]}
  seeds = 4
  run_settings = dict(world="lab")
result = jaxplore.sweep(grid, seeds=seeds, planner="li2020", out=OUT / "sweep", quiet=True,
                        **run_settings)
episodes = result.episodes
print(f"{len(episodes)} robot-episodes ({len(episodes) // seeds} settings x {seeds} seeds); "
      f"compile {result.timing['compile_s']:.1f} s, run {result.timing['run_s']:.1f} s")
episodes[["robot", "seed", *grid, "reason", "E_r", "distance_m", "coverage"]].head()

# %% [markdown]
# The table on disk is the same: `pd.read_parquet(OUT / "sweep" / "episodes.parquet")` has one
# row per robot-episode with one column per swept parameter.

# %%
on_disk = pd.read_parquet(OUT / "sweep" / "episodes.parquet")
assert len(on_disk) == len(episodes) and set(grid) <= set(on_disk.columns)

# %% [markdown]
# ## Mean and std per setting
#
# `E_r` (nats/m): entropy removed per metre; `distance_m`: path length; `coverage`: fraction of the
# reachable free area known free at the end.

# %%
names = list(grid)
summary = episodes.groupby(names)[["E_r", "distance_m", "coverage"]].agg(["mean", "std"])
summary.columns = [f"{column}_{stat}" for column, stat in summary.columns]
summary = summary.reset_index()
summary["episodes"] = episodes.groupby(names).size().to_numpy()
summary.to_csv(OUT / "summary.csv", index=False)
summary.round(4)

# %% [markdown]
# ## E_r over k1 × k2, one panel per α
#
# Mean over seeds; every panel shares one colour scale.

# %%
alphas = sorted(episodes.alpha.unique())
k1s, k2s = sorted(episodes.k1.unique()), sorted(episodes.k2.unique())
tables = {a: summary[summary.alpha == a].pivot(index="k1", columns="k2", values="E_r_mean")
          .reindex(index=k1s, columns=k2s) for a in alphas}
values = np.concatenate([t.to_numpy().ravel() for t in tables.values()])
vmin, vmax = np.nanmin(values), np.nanmax(values)
fig, axes = plt.subplots(1, len(alphas), figsize=(3.6 * len(alphas) + 1, 3.4), squeeze=False)
for ax, a in zip(axes[0], alphas):
  table = tables[a]
  image = ax.imshow(table.to_numpy(), origin="lower", cmap="viridis", vmin=vmin, vmax=vmax,
                    aspect="auto")
  ax.set_xticks(range(len(k2s)), [f"{v:g}" for v in k2s])
  ax.set_yticks(range(len(k1s)), [f"{v:g}" for v in k1s])
  ax.set_xlabel("k2")
  ax.set_ylabel("k1")
  ax.set_title(f"α = {a:g}")
  for i in range(len(k1s)):
    for j in range(len(k2s)):
      v = table.to_numpy()[i, j]
      ax.text(j, i, "–" if np.isnan(v) else f"{v:.3g}", ha="center", va="center", fontsize=8,
              color="white" if np.isnan(v) or v < (vmin + vmax) / 2 else "black")
fig.colorbar(image, ax=axes[0].tolist(), label="E_r (nats/m), mean over seeds")
fig.savefig(OUT / "E_r_heatmaps.png", dpi=100, bbox_inches="tight")

# %% [markdown]
# ## The best setting
#
# A setting that stops early can have a high rate on a short path, so E_r alone is not the whole
# story: among the settings whose mean coverage is within 5 % of the best mean coverage, take the
# one with the highest mean E_r.

# %%
good = summary[summary.coverage_mean >= 0.95 * summary.coverage_mean.max()]
best = good.loc[good.E_r_mean.idxmax()]
print("best setting: " + ", ".join(f"{n} = {best[n]:g}" for n in names))
print(f"  E_r {best.E_r_mean:.4g} ± {best.E_r_std:.3g} nats/m, distance {best.distance_m_mean:.3g} m, "
      f"coverage {best.coverage_mean:.3f}")
(OUT / "best.txt").write_text(", ".join(f"{n}={best[n]:g}" for n in names) + "\n")
best
