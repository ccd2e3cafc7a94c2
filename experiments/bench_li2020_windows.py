"""li2020 with its beams' sums on windows of the grid, against the grid alone, in whole runs.

``li2020.windowed_sums`` takes Eq 20's per-cell sums on a window of the grid when the plan's
tree (and the gains near it) fit: exact, so only the speed is in question, and it depends on how
much of an episode the tree spends inside the window. Each variant runs in its own process (the
windows are module constants read at trace time), one device, ``jaxplore.run`` from seed 0:

  off        the grid alone (``SUM_WINDOW_MIN_WORK`` = inf)
  0.5        a window of half the grid's sides (the default)
  0.5,0.75   and one of three quarters

Usage:
  python experiments/bench_li2020_windows.py --world lab --robots 64 --steps 300,1500
Prints a JSON line per run and a markdown table; ``--out FILE`` also writes the table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def one(world, robots, steps, windows, slam, planner):
  from jaxplore.cli import set_host_devices
  set_host_devices(1)
  import jaxplore
  from jaxplore.planners import li2020
  if windows == "off":
    li2020.SUM_WINDOW_MIN_WORK = float("inf")
  else:
    li2020.SUM_WINDOW_FRACTIONS = tuple(float(x) for x in windows.split(","))
  for n in steps:
    result = jaxplore.run(world=world, planner=planner, robots=robots, seed=0, max_steps=n,
                          slam=slam, progress=False, quiet=True)
    t = result.timing
    print(json.dumps(dict(windows=windows, planner=planner, steps=n,
                          compile_s=round(t["compile_s"], 1), run_s=round(t["run_s"], 1),
                          rate=round(t["robot_steps_per_s"]))), flush=True)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--world", default="lab")
  parser.add_argument("--robots", type=int, default=64)
  parser.add_argument("--steps", default="300,1500")
  parser.add_argument("--windows", default="off;0.5;0.5,0.75", help="variants, ';' separated")
  parser.add_argument("--slam", default="scan_matching")
  parser.add_argument("--baseline", default="nearest_frontier",
                      help="a planner run beside them (empty: none)")
  parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
  parser.add_argument("--planner", default="li2020", help=argparse.SUPPRESS)
  parser.add_argument("--out", default=None)
  args = parser.parse_args(argv)
  steps = [int(s) for s in args.steps.split(",")]
  if args.one is not None:
    return one(args.world, args.robots, steps, args.one, args.slam, args.planner)
  runs = [(w, "li2020") for w in args.windows.split(";")]
  if args.baseline:
    runs.append(("off", args.baseline))
  rows = []
  for windows, planner in runs:
    out = subprocess.run([sys.executable, __file__, "--one", windows, "--planner", planner,
                          "--world", args.world, "--robots", str(args.robots), "--steps",
                          args.steps, "--slam", args.slam], capture_output=True, text=True,
                         check=True).stdout
    for line in out.splitlines():
      if line.startswith("{"):
        print(line, flush=True)
        rows.append(json.loads(line))
  grid = {r["steps"]: r["rate"] for r in rows if r["windows"] == "off" and r["planner"] == "li2020"}
  lines = [f"# li2020's sums on windows of the grid: {args.world}, {args.robots} robots, "
           f"{args.slam}", "", f"Command: `python experiments/bench_li2020_windows.py "
           f"{' '.join(sys.argv[1:] if argv is None else argv)}`  ",
           f"{os.cpu_count()} cores, one device a process; "
           f"{time.strftime('%Y-%m-%d %H:%M')}; each variant its own process, one after the "
           "other.", "", "| planner | windows | steps | compile s | run s | robot-steps/s | "
           "vs the grid alone |", "|---|---|---|---|---|---|---|"]
  for r in rows:
    ratio = r["rate"] / grid[r["steps"]] if grid.get(r["steps"]) else float("nan")
    lines.append(f"| {r['planner']} | {r['windows']} | {r['steps']} | {r['compile_s']} | "
                 f"{r['run_s']} | {r['rate']:,} | {ratio:.2f}x |")
  text = "\n".join(lines) + "\n"
  print(text)
  if args.out:
    Path(args.out).write_text(text)


if __name__ == "__main__":
  main()
