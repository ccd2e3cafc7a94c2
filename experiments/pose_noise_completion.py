"""Does exploration finish with pose noise on? Completion, coverage and map error per world.

For each (world, planner): one batched ``jaxplore.run`` of N robots (seed i for robot i) with
``pose_noise`` on (the simulated odometry error, ``odom_noise_d``/``odom_noise_phi``, with the
engine's relocalisation), the world's default step budget, and the same without pose noise
for comparison. Reported per row: robots that ended ``complete`` (99 % of the reachable free
area believed free), coverage, distance, the mean and max distance between the true and the
estimated position, and the map error (RMSE of P(occupied) against the truth, SSIM).

Usage:
  python experiments/pose_noise_completion.py                        # lab, office, building; nf
  python experiments/pose_noise_completion.py --planners nearest_frontier,li2020 --robots 16
  python experiments/pose_noise_completion.py --planners nearest_frontier,li2020 --cached-only
  python experiments/pose_noise_completion.py --planners li2020_no_timeout   # a variant row
  python experiments/pose_noise_completion.py --planners li2020_no_timeout --budget-scale 2

``--planners`` takes planner names and the variant rows of ``li2020_table1.py`` (a planner with
some weights set, e.g. ``li2020_no_timeout``: li2020 without its progress timeout).
``--budget-scale`` multiplies each world's default step budget (for a planner that explores
more slowly than the budget's frontier-sweep estimate allows); its rows say so.

Writes ``experiments/results/pose_noise_completion.md`` (and the episodes beside it).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", default="lab,office,building")
  parser.add_argument("--planners", default="nearest_frontier")
  parser.add_argument("--robots", type=int, default=16)
  parser.add_argument("--preset", default="li2020")
  parser.add_argument("--devices", type=int, default=2)
  parser.add_argument("--budget-scale", type=float, default=1.0,
                      help="multiply each world's default step budget (the rows say so)")
  parser.add_argument("--out", default=str(RESULTS / "pose_noise_completion"))
  parser.add_argument("--cached-only", action="store_true",
                      help="build the table from the rows already computed; run nothing")
  args = parser.parse_args(argv)
  if not args.budget_scale > 0:
    parser.error(f"--budget-scale must be > 0, got {args.budget_scale}")
  flags = os.environ.get("XLA_FLAGS", "")
  if "xla_force_host_platform_device_count" not in flags and args.devices > 1:
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={args.devices}".strip()

  import pandas as pd

  import jaxplore
  from li2020_table1 import VARIANTS
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec

  out = Path(args.out)
  out.mkdir(parents=True, exist_ok=True)
  rows = []
  scaled = "" if args.budget_scale == 1 else f"_x{args.budget_scale:g}"
  for world in args.worlds.split(","):
    budget = resolve(RunSpec.create(world=world, robots=1, preset=args.preset)).config.max_steps
    max_steps = int(round(budget * args.budget_scale))
    for planner in args.planners.split(","):
      for noise in (True, False):
        part = out / f"{world}_{planner}_{'noise' if noise else 'exact'}_r{args.robots}{scaled}.parquet"
        if part.exists():
          episodes = pd.read_parquet(part)
        elif args.cached_only:
          continue
        else:
          t0 = time.perf_counter()
          name, weights = VARIANTS.get(planner, (planner, None))
          result = jaxplore.run(world=world, planner=name, robots=args.robots, seed=0,
                                preset=args.preset, pose_noise=noise, progress=False, quiet=True,
                                robot_seeds=list(range(args.robots)), devices=args.devices,
                                planner_params=weights, max_steps=max_steps,
                                slam="oracle")  # the oracle's pose noise is what it measures
          episodes = result.episodes
          episodes.to_parquet(part.with_name(part.name + ".tmp"), index=False)
          os.replace(part.with_name(part.name + ".tmp"), part)
          print(f"{world:9s} {planner:17s} noise={noise!s:5s} {time.perf_counter() - t0:6.0f} s "
                f"{episodes.reason.value_counts().to_dict()}", flush=True)
        rows.append(dict(world=world, planner=planner, pose_noise=noise,
                         step_budget=f"{max_steps}" + (f" ({args.budget_scale:g}x)" if scaled else ""),
                         complete=f"{int((episodes.reason == 'complete').sum())}/{len(episodes)}",
                         ended=", ".join(f"{k} {v}" for k, v in
                                         episodes.reason.value_counts().items()),
                         coverage=f"{episodes.coverage.mean():.3f} (min {episodes.coverage.min():.3f})",
                         distance_m=f"{episodes.distance_m.mean():.0f} ± {episodes.distance_m.std():.0f}",
                         pose_error_m=f"{episodes.pose_error_mean.mean():.3f} "
                                      f"(max {episodes.pose_error_max.max():.3f})",
                         rmse=f"{episodes.rmse.mean():.4f}", ssim=f"{episodes.ssim.mean():.3f}",
                         collisions=f"{episodes.collisions.mean():.1f}"))
  table = pd.DataFrame(rows)
  lines = ["# Exploration with pose noise: completion and map error", "",
           f"{args.robots} robots per row (seed i for robot i), preset `{args.preset}`, the world's "
           "default step budget" + (f" times {args.budget_scale:g}" if scaled else "")
           + "; `pose_noise` on: odometry error 3 % per metre and per radian "
           "(`odom_noise_d`, `odom_noise_phi`) with the engine's relocalisation. `rmse`: RMSE of "
           "P(occupied) of the final belief against the truth; `pose_error_m`: mean (and max) "
           "distance between the true and the estimated position.", "",
           f"Command: `python experiments/pose_noise_completion.py --worlds {args.worlds} "
           f"--planners {args.planners} --robots {args.robots}"
           + (f" --budget-scale {args.budget_scale:g}" if scaled else "") + "`"
           + (" (rows already computed only)" if args.cached_only else ""), "",
           "| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
  lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in table.itertuples(index=False)]
  path = RESULTS / f"pose_noise_completion{scaled}.md"
  path.write_text("\n".join(lines) + "\n")
  print(path.read_text())


if __name__ == "__main__":
  main()
