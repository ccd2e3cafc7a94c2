"""Toriz & Sánchez, Tables 1-3: time, distance and coverage of Extended REG, REG, SRG and SRT.

For every map and method, one batched ``jaxplore.run`` of N robots (30 by default) with pose
noise on; robot ``i`` uses seed ``i`` in every method, so it starts from the same pose (drawn
uniformly over the map's free space, ``--start random``, default; or the map's launch pose for
every robot, ``--start fixed``, as the paper's runs from one start). Coverage never ends an
episode (``coverage_goal`` above 1): the REG family ends when it is back at its start node with
nothing left to explore (``exhausted``) and its time includes the return, as the paper's;
nearest frontier (an extra row) ends when no reachable frontier is left.

Maps: the built-in ``corridors`` world (a LIRMM-like corridor loop with side rooms; the paper's
LIRMM map is not public) and the Explore-Bench ``corridor`` and ``loop_with_corridor``
blueprints, with the ``toriz`` preset (4 m, 240° lidar at 0.36°). Columns per method: mission
time (s, including the return home), distance (m) and coverage (%), each as mean, sample std,
min and max over the runs (the paper's Tables 1-3), the paper's LIRMM numbers beside them, the
time to 99 % coverage, and how many runs ended back at node 0. Coverage is the engine's (reachable
cells the belief holds free); ``explored`` also counts reachable cells the belief holds occupied
(with pose noise, smeared walls cover free cells near them, which no method can see free).

Usage:
  python experiments/toriz_tables.py --quick    # 2 robots, one map: a smoke run
  python experiments/toriz_tables.py --no-noise # the same without pose noise
  python experiments/toriz_tables.py            # 30 robots, 3 maps, 5 methods (hours: background)
  python experiments/toriz_tables.py --seeds 10 --maps corridors

Per (map, method) episodes are cached in ``experiments/results/toriz_tables/`` (delete a file to
rerun it); the tables go to ``experiments/results/toriz_tables.md`` and the box plots to
``toriz_boxplot.png`` (``toriz_quick_*`` with ``--quick``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BLUEPRINTS = HERE.parent.parent / "shared" / "maps" / "explore_bench"
RESULTS = HERE / "results"

# label -> (world argument of jaxplore.run, launch pose for --start fixed)
MAPS = {
    "corridors": ("corridors", "4.5,4.5,0"),
    "corridor": (str(BLUEPRINTS / "corridor.yaml"), "8,8,0"),
    "loop_with_corridor": (str(BLUEPRINTS / "loop_with_corridor.yaml"), "8,8,0"),
}
METHODS = ("ereg", "reg", "srg", "srt", "nearest_frontier", "ereg_lsr", "reg_lsr")
LABELS = {"ereg": "Extended REG", "reg": "REG", "srg": "SRG", "srt": "SRT",
          "nearest_frontier": "nearest frontier", "ereg_lsr": "Extended REG, LSR arcs only",
          "reg_lsr": "REG, LSR arcs only"}
# Ablations (not run unless named in --methods): a method's planner with settings of its own.
# ``*_lsr``: the free arcs of the paper, closed by the local safe regions alone (no belief
# arcs, no shadow edges).
VARIANTS = {"ereg_lsr": ("ereg", {"belief_arcs": False, "shadow_arcs": False}),
            "reg_lsr": ("reg", {"belief_arcs": False, "shadow_arcs": False})}
DEFAULT_METHODS = METHODS[:5]

# The paper's Tables 1-3 (LIRMM, 30 runs): mean, sample std, min, max, recomputed from its
# per-run columns.
PAPER = {
    "ereg": {"time": (261.40, 14.23, 242.59, 284.90), "distance": (93.79, 3.41, 88.18, 98.46),
             "coverage": (100.0, 0.0, 100.0, 100.0)},
    "reg": {"time": (350.55, 37.91, 294.31, 417.52), "distance": (111.38, 12.98, 90.23, 130.70),
            "coverage": (100.0, 0.0, 100.0, 100.0)},
    "srg": {"time": (513.19, 59.30, 401.00, 619.70), "distance": (139.86, 23.84, 99.98, 176.50),
            "coverage": (95.76, 2.71, 91.09, 99.96)},
    "srt": {"time": (569.32, 84.92, 420.15, 688.01), "distance": (159.57, 33.47, 115.63, 207.75),
            "coverage": (91.39, 3.96, 84.67, 98.99)},
}


def explored_fraction(grid, logodds, params):
  """Per robot: reachable cells whose belief is free or occupied (not unknown)."""
  import numpy as np

  from jaxplore import sim
  world = sim.make_world(grid, float(params["r_robot"]))
  reachable = np.asarray(world.reachable)
  prob = 1.0 / (1.0 + np.exp(-np.asarray(logodds, np.float32)))
  known = (prob < params["p_free"]) | (prob > params["p_occ"])
  return (known & reachable[None]).sum(axis=(1, 2)) / reachable.sum()


def run_one(map_label: str, method: str, seeds, start: str, max_steps: int, path: Path,
            pose_noise: bool = True, slam: str = "oracle"):
  """Runs one (map, method) batch, or reads it back from ``path``."""
  import numpy as np
  import pandas as pd

  import jaxplore
  if path.exists():
    return pd.read_parquet(path)
  world, launch = MAPS[map_label]
  planner, settings = VARIANTS.get(method, (method, {}))
  t0 = time.perf_counter()
  result = jaxplore.run(world=world, planner=planner, robots=len(seeds), robot_seeds=list(seeds),
                        preset="toriz", pose_noise=pose_noise,
                        params={"coverage_goal": 1.5, **settings},
                        start=launch if start == "fixed" else None, max_steps=max_steps,
                        slam=slam, progress=False, quiet=True)
  episodes = result.episodes.copy()
  episodes["map"] = map_label
  episodes["method"] = method
  episodes["explored"] = explored_fraction(result.grid, result.state.logodds,
                                           result.config["params"])
  from jaxplore.planners import reg
  memory = result.state.memory
  if not isinstance(memory, reg.Memory):
    episodes["home"] = np.nan
    episodes["nodes"] = np.nan
    episodes["overflow"] = False
  else:
    episodes["home"] = (np.asarray(memory.current) == 0) & (np.asarray(memory.mode) == reg.DONE)
    episodes["nodes"] = np.asarray(memory.count)
    episodes["overflow"] = np.asarray(memory.overflow)
  episodes["wall_s"] = time.perf_counter() - t0
  episodes["compile_s"] = result.timing["compile_s"]
  path.parent.mkdir(parents=True, exist_ok=True)
  episodes.to_parquet(path, index=False)
  return episodes


def stats(values) -> tuple[float, float, float, float]:
  import numpy as np
  v = np.asarray(values, np.float64)
  return (float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else float("nan"), float(v.min()),
          float(v.max()))


def fmt(s) -> str:
  return f"{s[0]:.1f} ± {s[1]:.1f} [{s[2]:.1f}, {s[3]:.1f}]"


def tables(episodes) -> str:
  lines = []
  for map_label, group in episodes.groupby("map", sort=False):
    lines += [f"### {map_label}", "",
              "| method | runs | time s | distance m | coverage % | explored % "
              "| t99 s (runs reaching 99 %) | back at node 0 | ended |",
              "|---|---|---|---|---|---|---|---|---|"]
    for method in METHODS:
      e = group[group.method == method]
      if not len(e):
        continue
      t99 = e.t99_s.dropna()
      t99_text = f"{t99.mean():.1f} ({len(t99)}/{len(e)})" if len(t99) else f"- (0/{len(e)})"
      home = "-" if e.home.isna().all() else f"{int(e.home.astype(bool).sum())}/{len(e)}"
      ended = ", ".join(f"{k} {v}" for k, v in sorted(e.reason.value_counts().items()))
      cells = (fmt(stats(e.time_s)), fmt(stats(e.distance_m)), fmt(stats(100 * e.coverage)),
               fmt(stats(100 * e.explored)), t99_text, home, ended)
      lines.append(f"| {LABELS[method]} | {len(e)} | " + " | ".join(cells) + " |")
      if method in PAPER:
        p = PAPER[method]
        lines.append(f"| *paper (LIRMM)* | 30 | *{fmt(p['time'])}* | *{fmt(p['distance'])}* | "
                     f"*{fmt(p['coverage'])}* | | | | |")
    for suffix, what in (("", ""), ("_lsr", ", LSR arcs only")):
      e, r = group[group.method == "ereg" + suffix], group[group.method == "reg" + suffix]
      if len(e) and len(r):
        time_change = 100 * (e.time_s.mean() / r.time_s.mean() - 1)
        distance_change = 100 * (e.distance_m.mean() / r.distance_m.mean() - 1)
        lines += ["", f"Extended REG vs REG{what}: time {time_change:+.0f} %, "
                  f"distance {distance_change:+.0f} %, "
                  f"std of time {e.time_s.std():.1f} vs {r.time_s.std():.1f} s "
                  f"(paper: -25 %, -16 %, 14.2 vs 37.9 s)."]
    lines.append("")
  return "\n".join(lines)


def boxplot(episodes, path: Path):
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  maps = list(dict.fromkeys(episodes["map"]))
  columns = (("time_s", "time (s)"), ("distance_m", "distance (m)"), ("coverage", "coverage (%)"))
  fig, axes = plt.subplots(len(maps), 3, figsize=(13, 3.3 * len(maps)), squeeze=False)
  for i, map_label in enumerate(maps):
    group = episodes[episodes["map"] == map_label]
    methods = [m for m in METHODS if (group.method == m).any()]
    for j, (column, title) in enumerate(columns):
      scale = 100.0 if column == "coverage" else 1.0
      data = [scale * group[group.method == m][column].to_numpy() for m in methods]
      ax = axes[i, j]
      ax.boxplot(data, showmeans=True)
      ax.set_xticks(range(1, len(methods) + 1))
      ax.set_xticklabels([LABELS[m].replace(" ", "\n") for m in methods], fontsize=8)
      paper = [PAPER[m][column.split("_")[0]][0] if m in PAPER else None for m in methods]
      marks = [(k + 1, v) for k, v in enumerate(paper) if v is not None]
      ax.plot([k for k, _ in marks], [v for _, v in marks], "x", color="tab:red",
              label="paper (LIRMM) mean")
      ax.set_title(f"{map_label}: {title}", fontsize=9)
      if i == 0 and j == 0:
        ax.legend(fontsize=7)
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--seeds", type=int, default=30, help="runs per method (seeds 0..N-1)")
  parser.add_argument("--chunk", type=int, default=10,
                      help="robots per batched run; seeds run (and are cached) in such chunks")
  parser.add_argument("--maps", default=",".join(MAPS))
  parser.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                      help=f"of {', '.join(METHODS)} (the *_lsr ablations only when named)")
  parser.add_argument("--start", choices=("random", "fixed"), default="random")
  parser.add_argument("--max-steps", type=int, default=6000)
  parser.add_argument("--srt-max-steps", type=int, default=16000,
                      help="SRT's budget: its depth-first walk of the tree (one backtrack per "
                           "node, 120-164 nodes on the Explore-Bench maps) ends at its root "
                           "after 7,845-10,524 steps there (experiments/srt_trace.py)")
  parser.add_argument("--no-noise", action="store_true",
                      help="pose noise off (the estimate is the truth)")
  parser.add_argument("--quick", action="store_true", help="2 robots on corridors, 2500 steps")
  parser.add_argument("--slam", choices=("oracle", "scan_matching"), default="oracle",
                      help="the SLAM model of every method's runs (the REG family's own is "
                           "scan_matching, nearest frontier's the oracle: one model for all "
                           "compares them on equal terms); the tables here were made on oracle")
  args = parser.parse_args(argv)
  import pandas as pd
  if args.quick:
    args.seeds, args.chunk, args.maps, args.max_steps = 2, 2, "corridors", 2500
    args.srt_max_steps = 2500
  tag = "toriz_quick" if args.quick else "toriz"
  if args.start == "fixed":
    tag += "_fixed"
  if args.no_noise:
    tag += "_no_noise"
  if args.slam != "oracle":
    tag += f"_{args.slam}"
  cache = RESULTS / f"{tag}_tables"
  parts = []
  # Seed chunks outermost: a partial run still gives every map and method its first chunks.
  for first in range(0, args.seeds, args.chunk):
    seeds = range(first, min(first + args.chunk, args.seeds))
    for map_label in args.maps.split(","):
      for method in args.methods.split(","):
        span = f"{seeds.start}-{seeds.stop - 1}"
        max_steps = args.srt_max_steps if method == "srt" else args.max_steps
        path = cache / f"{map_label}_{method}_seeds{span}_m{max_steps}.parquet"
        t0 = time.perf_counter()
        part = run_one(map_label, method, seeds, args.start, max_steps, path,
                       not args.no_noise, args.slam)
        parts.append(part)
        print(f"{map_label:20s} {method:17s} seeds {span}: time {part.time_s.mean():7.1f} s  "
              f"distance {part.distance_m.mean():6.1f} m  "
              f"coverage {100 * part.coverage.mean():5.1f} %  "
              f"explored {100 * part.explored.mean():5.1f} %  "
              f"({', '.join(f'{k} {v}' for k, v in part.reason.value_counts().items())})  "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
  episodes = pd.concat(parts, ignore_index=True)
  RESULTS.mkdir(exist_ok=True)
  text = (f"Toriz & Sánchez Tables 1-3 on jaxplore: {args.seeds} runs per method, "
          f"pose noise {'off' if args.no_noise else 'on'}, "
          f"{args.start} starts (seed i = the same start for every method), `toriz` preset, "
          f"step budget {args.max_steps} ({args.srt_max_steps} for SRT); "
          f"mean ± sample std [min, max]. "
          f"Command: python experiments/toriz_tables.py {' '.join(sys.argv[1:] if argv is None else argv)}\n\n"
          + tables(episodes))
  (RESULTS / f"{tag}_tables.md").write_text(text)
  boxplot(episodes, RESULTS / f"{tag}_boxplot.png")
  print(text)


if __name__ == "__main__":
  main()
