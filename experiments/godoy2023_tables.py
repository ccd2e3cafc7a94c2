"""Godoy-Calvo et al. 2023, Tables 3-4 and Figures 6/9: exploration time over 30 runs per method.

For every world and method, one batched ``jaxplore.run`` of 30 robots (robot ``i`` starts from
seed ``i`` in every method, so the methods are compared on the same starts). Exploration time is
the mission time of robots that finished (``complete``: 99 % of the reachable free area known;
or ``exhausted``: no reachable frontier left); the summary is the paper's Tables 3-4 layout
(mean, σ, min, max, Q1, Q3, by :func:`jaxplore.metrics.summarise`) with the paper's numbers
beside ours, and a box plot per world (the paper's Figures 6 and 9).

Worlds: ``open`` (built-in 20 x 20 m, ``godoy_open`` preset: 5.5 m / 270° lidar) and ``office``
(built-in 45 x 25 m, ``godoy_office``: 5 m / 360°) as in the paper, plus the real Gazebo maps
``husky_playpen`` (the paper's Table 3 arena, mapped with gmapping; ``godoy_open``, 0.1 m) and
``tb3_house`` (``godoy_office``, 0.1 m) from ``../shared/maps``. Loaded maps are cropped to their
largest free component plus a margin before resampling (the playpen's image is 99 x 99 m).
Methods: ``ig`` and ``frt`` (the paper's two rows, with Eq 3/12's Euclidean ``d``); ``ig_path``
and ``frt_path``, the same with ``d`` = path cost (``d_path = 1``: with Euclidean ``d`` and the
engine's ~1 s replanning, robots can oscillate between two far goals until the step budget, see
``jaxplore/planners/godoy2023.py``); ``nearest_frontier`` and ``fd`` as extra rows. The ``*_path``
rows reuse the compiled program of their planner (``d_path`` is a traced weight). These rows keep
every frontier cluster and measure ``d`` to the candidate, as the paper describes. Not run by
default: ``frt_released`` and ``ig_released_D{0.3,2,5.5}``, the authors' released code's reading
(clusters shorter than ``min_frontier_size`` = 0.5 m dropped, ``d`` to the nearest frontier
cell) with IG's ``D`` from their launch files (0.3, 2 m) and the Husky's lidar range (5.5 m).

Weights: the paper's Table 2 values were tuned on 0.05 m maps, and both utilities count cells
(Frt's A ~ 1/res, IG's I ~ 1/res²). ``--weights matched`` (default) scales C_i by
``(res / 0.05)`` for Frt and ``(res / 0.05)²`` for IG so that the distance and information terms
keep the paper's balance (Eq 10) at each world's resolution; ``--weights paper`` uses Table 2
literally.

Usage:
  python experiments/godoy2023_tables.py --quick   # 2 robots, 2 worlds, 300 steps: a smoke run
  python experiments/godoy2023_tables.py           # the full run (prints its expected duration)

Writes ``experiments/results/godoy2023_tables.md``, ``godoy2023_boxplot.png`` and
``godoy2023_episodes.csv`` (``godoy2023_quick_*`` with ``--quick``).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SHARED_MAPS = HERE.parent.parent / "shared" / "maps"
RESULTS = HERE / "results"

# label -> (world spec, preset, resolution or None for native)
WORLDS = {
    "open": ("open", "godoy_open", None),
    "office": ("office", "godoy_office", None),
    "husky_playpen": (SHARED_MAPS / "husky_playpen.yaml", "godoy_open", 0.1),
    "tb3_house": (SHARED_MAPS / "tb3_house.yaml", "godoy_office", 0.1),
}
# The paper keeps every frontier cluster and measures d to the candidate; the authors' released
# code drops clusters shorter than 0.5 m and measures d to the nearest frontier cell, and its
# launch files set D (expected_radius) to 0.3, 0.4 or 2 m.
PAPER_READING = {"min_frontier_size": 0.0, "d_nearest": 0.0}
RELEASED = {"min_frontier_size": 0.5, "d_nearest": 1.0}
# label -> (planner, distance of Eq 3/12: "euclidean" as in the paper, or "path"; weights)
METHODS = {
    "ig": ("ig", "euclidean", PAPER_READING),
    "frt": ("frt", "euclidean", PAPER_READING),
    "ig_path": ("ig", "path", PAPER_READING),
    "frt_path": ("frt", "path", PAPER_READING),
    "nearest_frontier": ("nearest_frontier", None, {}),
    "fd": ("fd", None, {}),
    "frt_released": ("frt", "euclidean", RELEASED),
    "ig_released_D0.3": ("ig", "euclidean", {**RELEASED, "D": 0.3}),
    "ig_released_D2": ("ig", "euclidean", {**RELEASED, "D": 2.0}),
    "ig_released_D5.5": ("ig", "euclidean", {**RELEASED, "D": 5.5}),
}
DEFAULT_METHODS = ("ig", "frt", "ig_path", "frt_path", "nearest_frontier", "fd")
QUICK_WORLDS = ("open", "tb3_house")
PAPER_RES = 0.05
STATS = ("mean", "std", "min", "max", "Q1", "Q3")
# Tables 3 (open: Clearpath playpen) and 4 (office_world): t̄, σ, t_min, t_max, Q1, Q3 in s.
PAPER = {
    "frt": {"open": (238.4, 25.8, 186.0, 305.0, 223.0, 258.7),
            "office": (331.0, 37.2, 278.0, 425.0, 302.8, 361.5)},
    "ig": {"open": (193.8, 18.8, 146.0, 227.0, 177.8, 210.3),
           "office": (294.6, 21.2, 262.0, 340.0, 271.5, 313.5)},
}
PAPER_TABLE_OF = {"open": "open", "husky_playpen": "open", "office": "office"}
# Cost model of the estimate, calibrated on this machine (2 shared cores) with --quick runs:
# seconds per robot-step per 10^4 cells, and seconds of compilation per (world, method).
SECONDS_PER_ROBOT_STEP_PER_10K_CELLS = 1.0e-3
COMPILE_SECONDS = 25.0


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--quick", action="store_true", help="smoke run: 2 robots, 2 worlds, 300 steps")
  parser.add_argument("--robots", type=int, default=None, help="robots (runs) per world and method (30)")
  parser.add_argument("--max-steps", type=int, default=None,
                      help="step budget per robot (default: jaxplore's, from the world's size)")
  parser.add_argument("--worlds", default=None, help=f"comma separated, from {', '.join(WORLDS)}")
  parser.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                      help=f"comma separated, from {', '.join(METHODS)}")
  parser.add_argument("--weights", choices=("matched", "paper"), default="matched")
  parser.add_argument("--devices", type=int, default=2, help="host devices to shard each batch over")
  parser.add_argument("--out", default=str(RESULTS))
  args = parser.parse_args(argv)
  if args.quick:
    args.robots = args.robots or 2
    args.max_steps = args.max_steps or 300
    args.worlds = args.worlds or ",".join(QUICK_WORLDS)
  args.robots = args.robots or 30
  args.worlds = [w for w in (args.worlds or ",".join(WORLDS)).split(",") if w]
  args.methods = [m for m in args.methods.split(",") if m]
  for w in args.worlds:
    if w not in WORLDS:
      parser.error(f"unknown world {w!r}; choose from {', '.join(WORLDS)}")
  for m in args.methods:
    if m not in METHODS:
      parser.error(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
  return args


def load_grid(label):
  """The world's truth; loaded maps cropped to their largest free component (+1 m) first."""
  import numpy as np
  from scipy import ndimage

  from jaxplore.maps import GridMap, load_world
  from jaxplore.maps.io import resample

  spec, _, res = WORLDS[label]
  if not isinstance(spec, Path):
    return load_world(spec, res)
  grid = load_world(str(spec))
  labelled, count = ndimage.label(grid.free)
  sizes = ndimage.sum_labels(grid.free, labelled, index=np.arange(1, count + 1))
  rows, cols = np.nonzero(labelled == 1 + int(np.argmax(sizes)))
  margin = int(math.ceil(1.0 / grid.res))
  r0, c0 = max(rows.min() - margin, 0), max(cols.min() - margin, 0)
  r1, c1 = min(rows.max() + margin + 1, grid.shape[0]), min(cols.max() + margin + 1, grid.shape[1])
  cropped = GridMap(grid.occupied[r0:r1, c0:c1], grid.res,
                    (grid.origin[0] + c0 * grid.res, grid.origin[1] + r0 * grid.res), label)
  return cropped if res is None else resample(cropped, res)


def planner_weights(method, res, mode):
  """The planner and its weights for a method label: Table 2's, C_i matched to the resolution
  (see the module docstring), ``d_path`` and the paper's or the released frontier reading
  (``min_frontier_size``, ``d_nearest``, ``D``) from the method."""
  from jaxplore.planners import get_planner
  planner, distance, overrides = METHODS[method]
  weights = {**get_planner(planner).defaults, **overrides}
  if distance is not None:
    weights["d_path"] = float(distance == "path")
  if mode == "matched" and planner == "frt":
    weights["C_i"] *= res / PAPER_RES
  if mode == "matched" and planner == "ig":
    weights["C_i"] *= (res / PAPER_RES) ** 2
  return planner, weights


def expected_seconds(grids, args):
  """(expected, upper bound) wall-clock seconds of the run, from the cost model above.

  A batch runs until its slowest robot is done: in trial runs that was ~3/4 of jaxplore's
  default step budget for the Godoy presets, and the whole budget for ``ig``/``frt`` with
  Euclidean ``d`` (some robots oscillate until timeout). The upper bound runs every batch to its
  budget. Compilation is paid once per (world, planner): the ``*_path`` rows reuse it.
  """
  from jaxplore.config import make_params
  from jaxplore.resolve import default_max_steps
  expected = upper = 0.0
  for label, grid in grids.items():
    params = make_params(WORLDS[label][1], res=grid.res)
    budget = args.max_steps or default_max_steps(grid, params)
    per_step = args.robots * SECONDS_PER_ROBOT_STEP_PER_10K_CELLS * grid.occupied.size / 1e4
    planners = {METHODS[m][0] for m in args.methods}
    expected += COMPILE_SECONDS * len(planners)
    upper += COMPILE_SECONDS * len(planners)
    for method in args.methods:
      slowest = budget if METHODS[method][1] == "euclidean" else min(budget, 0.75 * budget)
      expected += slowest * per_step
      upper += budget * per_step
  return expected, upper


def format_row(name, values, extra=""):
  return f"| {name} | " + " | ".join(f"{v:.1f}" for v in values) + f" | {extra} |"


def write_table(summary, episodes, grids, args, path):
  """The Tables 3-4 layout per world, ours beside the paper's."""
  lines = ["# Godoy-Calvo et al. 2023, Tables 3-4: exploration time (s)", "",
           f"{args.robots} runs per method and world (robot i starts from seed i in every method); "
           f"weights: {args.weights} (see `experiments/godoy2023_tables.py`). Time counts only steps in "
           "which the robot moved or turned. Statistics over robots that finished (complete or "
           "exhausted); `done` = finished / runs, `cov` = mean final coverage of the reachable free area.",
           "",
           "Methods: `ig`, `frt` = Eq 3 / Eq 12 with the paper's Euclidean d; `ig_path`, `frt_path` = the "
           "same with d = path cost (`d_path = 1`), which removes the oscillation between far goals that "
           "Euclidean d allows under the engine's ~1 s replanning (the authors' launch files replan at 0.33 Hz, and on arrival); "
           "`nearest_frontier`, `fd` = extra rows. The paper's rows are Gazebo runs (Husky on the "
           "Clearpath playpen, Table 3; TurtleBot3 on office_world with its central rooms closed off, "
           "Table 4): compare shapes (IG faster than Frt, smaller spread), not absolute times.",
           ""]
  if args.quick:
    lines += ["**Smoke run (`--quick`): few robots and a short step budget; the numbers mean nothing.**", ""]
  for label, grid in grids.items():
    spec, preset, _ = WORLDS[label]
    lines += [f"## {label} ({grid.shape[1]} x {grid.shape[0]} cells at {grid.res} m, "
              f"{grid.free_area:.0f} m² free, preset `{preset}`)", "",
              "| method | t̄ | σ | t_min | t_max | Q1 | Q3 | done, cov |",
              "|---|---|---|---|---|---|---|---|"]
    for method in args.methods:
      rows = summary[(summary.world == label) & (summary.planner == method)]
      mine = episodes[(episodes.world == label) & (episodes.planner == method)]
      done = int(mine.reason.isin(["complete", "exhausted"]).sum())
      extra = f"{done}/{len(mine)}, {mine.coverage.mean():.3f}"
      if len(rows):
        values = [float(rows.iloc[0][f"time_s_{s}"]) for s in STATS]
        lines.append(format_row(method, values, extra).replace("nan", "–"))
      else:
        lines.append(f"| {method} | – | – | – | – | – | – | {extra} |")
    table = PAPER_TABLE_OF.get(label)
    if table is not None:
      for method in ("frt", "ig"):
        lines.append(format_row(f"*paper {method.upper() if method == 'ig' else 'Frt'}*",
                                PAPER[method][table], f"Table {3 if table == 'open' else 4}"))
    lines.append("")
  path.write_text("\n".join(lines) + "\n")


def box_plot(episodes, grids, args, path):
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt

  fig, axes = plt.subplots(1, len(grids), figsize=(4.2 * len(grids), 4.2), squeeze=False)
  for ax, label in zip(axes[0], grids):
    data, names = [], []
    for method in args.methods:
      mine = episodes[(episodes.world == label) & (episodes.planner == method)
                      & episodes.reason.isin(["complete", "exhausted"])]
      data.append(mine.time_s.to_numpy())
      names.append(method.replace("nearest_frontier", "nearest"))
    ax.boxplot(data, tick_labels=names, showmeans=True)
    table = PAPER_TABLE_OF.get(label)
    if table is not None:
      # The paper gives mean, Q1, Q3, min and max (no median): drawn with the mean as centre line.
      stats = [dict(med=v[0], q1=v[4], q3=v[5], whislo=v[2], whishi=v[3], label=f"paper {m}")
               for m, v in (("Frt", PAPER["frt"][table]), ("IG", PAPER["ig"][table]))]
      ax.bxp(stats, positions=[len(data) + 1, len(data) + 2], showfliers=False,
             boxprops=dict(color="grey", linestyle="--"), medianprops=dict(color="grey"))
      ax.set_xlim(0.4, len(data) + 2.6)
    ax.set_title(label)
    ax.set_ylabel("exploration time (s)")
    ax.tick_params(axis="x", labelrotation=30)
  fig.suptitle("Godoy-Calvo 2023 Figures 6/9: exploration time per method"
               + (" (smoke run)" if args.quick else ""))
  fig.tight_layout()
  fig.savefig(path, dpi=120)
  plt.close(fig)


def main(argv=None):
  args = _parse_args(argv)
  # Before JAX starts: XLA:CPU runs a while loop on one thread, so each core needs its own device.
  flags = os.environ.get("XLA_FLAGS", "")
  if "xla_force_host_platform_device_count" not in flags and args.devices > 1:
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={args.devices}".strip()

  import pandas as pd

  import jaxplore
  from jaxplore import metrics

  out = Path(args.out)
  out.mkdir(parents=True, exist_ok=True)
  prefix = "godoy2023_quick" if args.quick else "godoy2023"
  parts = out / f"{prefix}_parts"
  parts.mkdir(exist_ok=True)
  grids = {label: load_grid(label) for label in args.worlds}
  expected, upper = expected_seconds(grids, args)
  print(f"{len(grids)} worlds x {len(args.methods)} methods x {args.robots} robots; expected duration "
        f"~{expected / 60:.0f} min (at most ~{upper / 60:.0f} min if every batch runs to its step budget)",
        flush=True)

  episodes, timings = [], []
  started = time.perf_counter()
  for label, grid in grids.items():
    _, preset, _ = WORLDS[label]
    for method in args.methods:
      # Each (world, method) batch is saved when done and reused by a later invocation with the
      # same settings: the full table can be built in several sittings.
      part = parts / f"{label}_{method}_r{args.robots}_m{args.max_steps or 'auto'}_{args.weights}.parquet"
      if part.exists():
        episodes.append(pd.read_parquet(part))
        print(f"{label:14s} {method:17s} reused {part.name}", flush=True)
        continue
      t0 = time.perf_counter()
      planner, weights = planner_weights(method, grid.res, args.weights)
      result = jaxplore.run(world=grid, planner=planner, robots=args.robots, seed=0, preset=preset,
                            max_steps=args.max_steps, progress=False, quiet=True, planner_params=weights,
                            robot_seeds=list(range(args.robots)), devices=args.devices)
      mine = result.episodes.assign(world=label, planner=method)
      mine.to_parquet(part.with_name(part.name + ".tmp"), index=False)
      os.replace(part.with_name(part.name + ".tmp"), part)
      episodes.append(mine)
      timing = dict(world=label, planner=method, wall_s=time.perf_counter() - t0, **result.timing)
      timings.append(timing)
      reasons = result.episodes.reason.value_counts().to_dict()
      print(f"{label:14s} {method:17s} {timing['wall_s']:7.1f} s (compile {timing['compile_s']:.0f} s, "
            f"{timing['robot_steps_per_s']:.0f} robot-steps/s)  {reasons}", flush=True)
  episodes = pd.concat(episodes, ignore_index=True)
  episodes.to_csv(out / f"{prefix}_episodes.csv", index=False)

  finished = episodes[episodes.reason.isin(["complete", "exhausted"])]
  summary = metrics.summarise(finished, by=["world", "planner"], columns=["time_s"])
  write_table(summary, episodes, grids, args, out / f"{prefix}_tables.md")
  box_plot(episodes, grids, args, out / f"{prefix}_boxplot.png")
  print((out / f"{prefix}_tables.md").read_text())
  total = time.perf_counter() - started
  print(f"done in {total / 60:.1f} min; wrote {out / (prefix + '_tables.md')}, "
        f"{out / (prefix + '_boxplot.png')}, {out / (prefix + '_episodes.csv')}")
  if args.quick:
    # Calibrates the cost model: the full run's estimate from this run's measured throughput.
    t = pd.DataFrame(timings)
    seconds_per = (t.run_s / t.robot_steps.clip(lower=1)).mean()
    cells = sum(g.occupied.size for g in grids.values()) / len(grids)
    print(f"measured here: {seconds_per * 1e4 / cells:.2e} s per robot-step per 10^4 cells, "
          f"{t.compile_s.mean() + t.reset_s.mean():.0f} s compile per (world, method)")
    full = _parse_args([])
    full_grids = {label: load_grid(label) for label in full.worlds}
    expected, upper = expected_seconds(full_grids, full)
    print(f"the full run (python experiments/godoy2023_tables.py): expected ~{expected / 60:.0f} min, "
          f"at most ~{upper / 60:.0f} min")


if __name__ == "__main__":
  main()
