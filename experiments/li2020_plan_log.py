"""Logs every li2020 plan of a lab run (the robot's cell, the path's waypoints, gain and cost):
how many plans are one-cell steps under ``select=1`` (issue 41).

Usage: python experiments/li2020_plan_log.py [--select 1] [--seed 0] [--robots 4]
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import numpy as np

import jaxplore
from jaxplore.planners import li2020


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--select", type=float, default=1.0)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--robots", type=int, default=4)
  parser.add_argument("--world", default="lab")
  args = parser.parse_args(argv)
  log = []

  def record(cell, n, gain, cost, valid):
    log.append((tuple(np.asarray(cell).tolist()), int(n), float(gain), float(cost), bool(valid)))

  def plan(config, view, robot, params, key, memory, **kw):
    p, m = li2020.plan_li2020(config, view, robot, params, key, memory, **kw)
    jax.debug.callback(record, robot.cell, p.length, p.gain, p.cost, p.valid)
    return p, m

  spec = dataclasses.replace(li2020.LI2020, plan=plan)
  # per_robot on one device: one robot per plan call, so each callback is one plan.
  result = jaxplore.run(world=args.world, planner=spec, robots=args.robots, seed=args.seed,
                        preset="li2020", planner_params={"select": args.select}, progress=False,
                        quiet=True, strategy="per_robot", devices=1)
  print(result.episodes[["robot", "reason", "steps", "time_s", "distance_m",
                         "coverage"]].to_string())
  n = np.array([x[1] for x in log if x[4]])  # waypoints, the robot's own cell first
  print(f"plans logged {len(log)}, one-cell paths {(n <= 2).sum()}, at most 4 cells "
        f"{(n <= 5).sum()}, median {np.median(n):.0f} waypoints")


if __name__ == "__main__":
  main()
