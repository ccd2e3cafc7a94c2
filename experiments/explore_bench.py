"""The six Explore-Bench blueprints with the ``explore_bench`` preset and nearest frontier.

Explore-Bench's grid simulator: 0.1 m cells, 3.5 m range, 360°, one cell per step, replanning
every step. Each blueprint starts at the Explore-Bench launch pose (world (8, 8), (6, 6) for
``corner``) plus a few random starts, and must run to completion.

Usage: python experiments/explore_bench.py [--robots 4] [--planner nearest_frontier]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BLUEPRINTS = HERE.parent.parent / "shared" / "maps" / "explore_bench"
NAMES = ("corner", "corridor", "loop", "loop_with_corridor", "room", "room_with_corner")


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--robots", type=int, default=4, help="random starts per map (plus the launch pose)")
  parser.add_argument("--planner", default="nearest_frontier")
  parser.add_argument("--max-steps", type=int, default=3000)
  parser.add_argument("--devices", type=int, default=1)
  args = parser.parse_args(argv)
  os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")
  import jaxplore

  rows = ["| blueprint | start | robots | complete | steps (mean) | distance m (mean) | coverage (mean) | wall s |",
          "|---|---|---|---|---|---|---|---|"]
  for name in NAMES:
    launch = "6,6,0" if name == "corner" else "8,8,0"
    for start, robots in ((launch, 1), (None, args.robots)):
      t0 = time.perf_counter()
      result = jaxplore.run(world=str(BLUEPRINTS / f"{name}.yaml"), planner=args.planner, preset="explore_bench",
                            robots=robots, start=start, max_steps=args.max_steps, progress=False, quiet=True,
                            devices=args.devices)
      e = result.episodes
      rows.append(f"| {name} | {start or 'random'} | {robots} | {int((e.reason == 'complete').sum())}/{robots} | "
                  f"{e.steps.mean():.0f} | {e.distance_m.mean():.1f} | {e.coverage.mean():.3f} | "
                  f"{time.perf_counter() - t0:.0f} |")
      print(rows[-1], flush=True)
  table = "\n".join(rows)
  (HERE / "results").mkdir(exist_ok=True)
  (HERE / "results" / "explore_bench.md").write_text(
      f"Explore-Bench blueprints, preset explore_bench, planner {args.planner}\n\n{table}\n")
  print(table)


if __name__ == "__main__":
  main()
