"""Does throughput hold as the batch grows? Robot-steps per second for 64 to 1,024 robots.

Explore-Bench ``room`` with the ``explore_bench`` preset and nearest frontier, every robot
starting at the Explore-Bench launch pose (world (8, 8)), as ``jaxplore.run`` runs it (the
engine's scan, state donated, per-robot planning). Two measurements per batch size, each its
own compiled program, compile time apart:

- *window*: the first ``--window`` steps (every robot still running), robot-steps per second;
- *whole episode*: to the end (every robot complete or out of budget). Robot-steps count only
  the steps robots were running; ``slot-steps/s`` counts every robot slot of every engine step
  (a finished robot's slot still rides along until the whole batch is done).

Usage: python experiments/bench_batch_scaling.py [--robots 64,256,1024] [--devices 1]
       [--out results/bench_batch_scaling.md]
Pin the process to the cores it may use (``taskset -c 0``) and keep them otherwise idle.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOM = HERE.parent.parent / "shared" / "maps" / "explore_bench" / "room.yaml"


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--robots", default="64,256,1024")
  parser.add_argument("--window", type=int, default=200)
  parser.add_argument("--max-steps", type=int, default=3000, help="budget of a whole episode")
  parser.add_argument("--devices", type=int, default=1)
  parser.add_argument("--out", default=str(HERE / "results" / "bench_batch_scaling.md"))
  args = parser.parse_args(argv)
  if not ROOM.exists():
    parser.error(f"the Explore-Bench blueprints are not at {ROOM.parent} (../shared/maps beside "
                 "the checkout)")
  os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")
  import jax

  import jaxplore

  rows = []
  for robots in (int(n) for n in args.robots.split(",")):
    for label, steps in (("window", args.window), ("whole episode", args.max_steps)):
      result = jaxplore.run(world=str(ROOM), planner="nearest_frontier", preset="explore_bench",
                            robots=robots, start=(8, 8, 0), max_steps=steps, progress=False,
                            quiet=True, devices=args.devices)
      t = result.timing
      complete = int((result.episodes.reason == "complete").sum())
      rows.append((robots, label, t["sim_steps"], complete, t["compile_s"], t["run_s"],
                   t["robot_steps_per_s"], robots * t["sim_steps"] / t["run_s"]))
      print(f"{robots:5d} robots  {label:13s} {t['sim_steps']:5d} steps  compile {t['compile_s']:5.1f} s  "
            f"run {t['run_s']:6.1f} s  {t['robot_steps_per_s']:8.0f} robot-steps/s  "
            f"{rows[-1][7]:8.0f} slot-steps/s  complete {complete}/{robots}", flush=True)
  device = f"{args.devices} x {jax.devices()[0].device_kind}"
  load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
  lines = [
      "# Throughput against batch size (Explore-Bench room, nearest frontier)", "",
      f"Command: `python experiments/bench_batch_scaling.py {' '.join(sys.argv[1:] if argv is None else argv)}`; "
      f"device {device}; {time.strftime('%Y-%m-%dT%H:%M:%S')}; load average at the end {load}. "
      "All robots start at world (8, 8); compile time apart from run time.", "",
      "| robots | run | engine steps | complete | compile s | run s | robot-steps/s | slot-steps/s |",
      "|---|---|---|---|---|---|---|---|"]
  lines += [f"| {r} | {label} | {n} | {c}/{r} | {comp:.1f} | {run:.1f} | {rate:,.0f} | {slots:,.0f} |"
            for r, label, n, c, comp, run, rate, slots in rows]
  Path(args.out).parent.mkdir(parents=True, exist_ok=True)
  Path(args.out).write_text("\n".join(lines) + "\n")
  print("\n".join(lines))


if __name__ == "__main__":
  main()
