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
# # jaxplore quickstart
#
# Run a batch of robots exploring a world, load the results folder with pandas, and plot coverage
# over time and a robot's belief map.
#
# This file is a [jupytext](https://jupytext.readthedocs.io) "percent" script: open it in Jupyter
# (`pip install jupytext`, then `jupytext --to notebook notebooks/quickstart.py`) or run it as
# plain Python (`python notebooks/quickstart.py`). With `JAXPLORE_NOTEBOOK_TINY=1` it uses tiny
# settings (a 8 × 6 m two-room floor, 2 robots, 40 steps) so the test suite can execute it in
# seconds; `JAXPLORE_NOTEBOOK_OUT` sets where the results and figures go.

# %%
import json
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import jaxplore
from jaxplore import plot
from jaxplore.maps import generate
from jaxplore.results import summary_table

TINY = os.environ.get("JAXPLORE_NOTEBOOK_TINY", "") not in ("", "0")
OUT = Path(os.environ.get("JAXPLORE_NOTEBOOK_OUT", "runs/notebooks")) / "quickstart"
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## Run a batch
#
# 16 robots with the nearest-frontier planner on the built-in `lab` world (17 × 13 m), each
# starting at its own random pose drawn from `seed`. Everything the run resolved is written to
# `OUT/run`: `config.json`, `episodes.parquet` (one row per robot), `curves.parquet` (one row per
# robot and step), `maps.npz` and figures.

# %%
if TINY:
  settings = dict(world=generate.office(8.0, 6.0, res=0.2, seed=0, name="tiny_office"), robots=2,
                  max_steps=40, replan_every=5, params={"r_max": 3.0}, progress=False)
else:
  settings = dict(world="lab", robots=16)
result = jaxplore.run(planner="nearest_frontier", seed=0, out=OUT / "run", quiet=True, **settings)
print(f"compile {result.timing['compile_s']:.1f} s, run {result.timing['run_s']:.1f} s, "
      f"{result.timing['robot_steps_per_s']:.0f} robot-steps/s")

# %% [markdown]
# ## Load the results folder
#
# The same tables are on `result.episodes` and `result.curves`; reading them back from the folder
# is how you would compare runs made earlier.

# %%
run_dir = result.out
config = json.loads((run_dir / "config.json").read_text())
episodes = pd.read_parquet(run_dir / "episodes.parquet")
curves = pd.read_parquet(run_dir / "curves.parquet")
print(f"{config['robots']} robots, planner {config['planner']}, world {config['world']['name']} "
      f"({config['world']['reachable_m2']:.0f} m² reachable), preset {config['preset']}")
episodes[["robot", "reason", "time_s", "distance_m", "coverage", "E_r"]]

# %% [markdown]
# ## Coverage over time
#
# Each thin line is one robot; the thick line and band are the mean and the 10–90 % range over
# robots (`jaxplore.plot.spread`, the same curve `coverage_time.png` shows).

# %%
fig, ax = plt.subplots(figsize=(6, 4))
for _, curve in curves.groupby("robot"):
  ax.plot(curve.time, curve.coverage, lw=0.5, color="grey", alpha=0.5)
plot.spread(ax, curves, "time", "coverage", label="mean over robots")
ax.set_xlabel("mission time (s)")
ax.set_ylabel("coverage of reachable free area")
ax.set_ylim(0, 1.02)
ax.legend(loc="lower right")
fig.tight_layout()
fig.savefig(OUT / "coverage_time.png", dpi=100)

# %% [markdown]
# ## A belief map
#
# `maps.npz` keeps the truth and the final log-odds belief of up to four robots. White is believed
# free, black believed occupied, light grey unknown; walls not yet seen are blue-grey.

# %%
maps = np.load(run_dir / "maps.npz")
shown = tuple(range(maps["logodds"].shape[0]))
fig, ax = plt.subplots(figsize=(7, 5))
plot.belief_map(ax, maps["occupied"], maps["logodds"][0], float(maps["res"]), maps["origin"],
                curves, shown)
ax.set_title("final belief of robot 0, trajectories of robots " + ", ".join(map(str, shown)))
fig.tight_layout()
fig.savefig(OUT / "belief_map.png", dpi=100)

# %% [markdown]
# ## Summary
#
# Termination reasons, and mean ± std of the headline metrics over robots (what `jaxplore run`
# prints). `E_r` is the entropy removed per metre travelled (nats/m).

# %%
print(summary_table(episodes))
episodes.describe()

# %% [markdown]
# To watch robots explore, `jaxplore animate RUN_DIR --robots 0,1,2` (or
# `jaxplore.animate.animate(run_dir, robots=(0, 1, 2))`) re-simulates them and writes a GIF.
