"""Robot-steps per second of whole runs, planner against planner, on one SLAM model or each.

Issue 41 asks li2020 (and Ahmed's planners) to cost within a few times nearest frontier per
robot-step. A plan's cost alone (``bench_planning.py``, ``bench_ahmed_planning.py``) does not
say that: planners plan at different rates (li2020 follows a whole path, nearest frontier
replans every few steps) and every step also pays the motion, the lidar and the SLAM model. This
runs each (planner, SLAM model, batch) as a user would, ``jaxplore.run`` on the default devices
for the first ``--steps`` steps from the same seed (0: the run's own budget, every episode to
its end), one after the other in one process, and reports robot-steps per second with compile
time apart (the steps of robots still exploring: a robot whose episode ended counts no more).

Usage:
  python experiments/bench_planner_cost.py --world lab --robots 64,256 --steps 300 \\
      --planners nearest_frontier,li2020 --slams oracle,scan_matching
Prints markdown; ``--out FILE`` also writes it.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--world", default="lab")
  parser.add_argument("--robots", default="64,256")
  parser.add_argument("--steps", type=int, default=300)
  parser.add_argument("--planners", default="nearest_frontier,li2020")
  parser.add_argument("--slams", default="oracle,scan_matching")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--out", default=None)
  args = parser.parse_args(argv)

  import os

  from jaxplore.cli import set_host_devices
  set_host_devices()  # the CLI's default devices, before JAX starts
  import jax

  import jaxplore
  rows = []
  for robots in [int(r) for r in args.robots.split(",")]:
    for slam in args.slams.split(","):
      for planner in args.planners.split(","):
        t0 = time.perf_counter()
        result = jaxplore.run(world=args.world, planner=planner, robots=robots, seed=args.seed,
                              max_steps=args.steps or None, slam=slam, progress=False,
                              quiet=True)
        t = result.timing
        rows.append((robots, slam, planner, t["compile_s"], t["run_s"], t["robot_steps"],
                     t["robot_steps_per_s"], time.perf_counter() - t0))
        print(f"{robots:4d} {slam:14s} {planner:17s} compile {t['compile_s']:6.1f} s  run "
              f"{t['run_s']:6.1f} s  {t['robot_steps_per_s']:8.0f} robot-steps/s", flush=True)
  first = args.planners.split(",")[0]
  base = {(r[0], r[1]): r[6] for r in rows if r[2] == first}
  devices = jax.devices()
  command = sys.argv[1:] if argv is None else argv
  span = f"first {args.steps} steps" if args.steps else "whole episodes"
  lines = [f"# Robot-steps per second by planner: {args.world}, {span}",
           "", f"Command: `python experiments/bench_planner_cost.py {' '.join(command)}`  ",
           f"Devices: {len(devices)} x {devices[0].platform} "
           f"({platform.processor() or platform.machine()}, {os.cpu_count()} cores); "
           f"{time.strftime('%Y-%m-%d %H:%M')}. One process, the runs one after the other.", "",
           "| robots | SLAM | planner | compile s | run s | robot-steps | robot-steps/s | "
           f"time per robot-step vs {first} (same SLAM) |",
           "|---|---|---|---|---|---|---|---|"]
  for robots, slam, planner, compile_s, run_s, steps, rate, _ in rows:
    ratio = base.get((robots, slam))
    lines.append(f"| {robots} | {slam} | {planner} | {compile_s:.1f} | {run_s:.1f} | {steps} | "
                 f"{rate:,.0f} | {ratio / rate if ratio else float('nan'):.2f}x |")
  text = "\n".join(lines) + "\n"
  print(text)
  if args.out:
    Path(args.out).write_text(text)


if __name__ == "__main__":
  main()
