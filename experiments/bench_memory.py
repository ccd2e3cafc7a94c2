"""The memory guard's estimate (jaxplore.memory.estimate_bytes) against the measured peak RSS of
one ``jaxplore.run`` on big square maps, each in a fresh subprocess (``resource.getrusage`` of
the child: ru_maxrss), on this machine's CPU.

The baseline is the peak RSS of the same subprocess on a 64 x 64 map (Python, JAX, XLA and
the compiled programs), subtracted from every measurement: the estimate models the arrays of a
batch, not the runtime.

    python experiments/bench_memory.py --sizes 1000 2000 4000 --robots 1 4 \
        --out experiments/results/bench_memory.md
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys
import numpy as np
import jaxplore
from jaxplore import memory
from jaxplore.maps import GridMap
from jaxplore.resolve import resolve
from jaxplore.runspec import RunSpec
n, res, steps, robots = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
occ = np.zeros((n, n), bool)
occ[n // 3, : 2 * n // 3] = True  # one wall, so the map is not a single open room
spec = RunSpec.create(world=GridMap(occ, res, name=f"square{n}"), robots=robots, max_steps=steps,
                      start=(n * res / 2, n * res / 2 + 1.0))
estimate = memory.estimate_bytes(resolve(spec).config, robots)
r = jaxplore.run(spec, progress=False, quiet=True, devices=1)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
print(json.dumps({"estimate": estimate, "peak": peak, "steps": int(r.timing["sim_steps"])}))
"""


def measure(n: int, res: float, steps: int, robots: int) -> dict:
  t0 = time.perf_counter()
  proc = subprocess.run([sys.executable, "-c", CHILD, str(n), str(res), str(steps), str(robots)],
                        capture_output=True, text=True)
  wall = time.perf_counter() - t0
  if proc.returncode:
    raise RuntimeError(proc.stderr[-2000:])
  row = json.loads(proc.stdout.strip().splitlines()[-1])
  return dict(n=n, res=res, robots=robots, wall=wall, **row)


def main():
  parser = argparse.ArgumentParser()
  parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 2000, 4000])
  parser.add_argument("--res", type=float, default=0.05)
  parser.add_argument("--steps", type=int, default=16)
  parser.add_argument("--robots", type=int, nargs="+", default=[1])
  parser.add_argument("--out", default=None)
  args = parser.parse_args()
  rows = [measure(64, args.res, args.steps, 1)]
  base = rows[0]["peak"]
  for n in args.sizes:
    for robots in args.robots:
      rows.append(measure(n, args.res, args.steps, robots))
      print(rows[-1], flush=True)
  lines = ["| map (cells) | robots | estimate (MiB) | peak RSS (MiB) | peak - baseline (MiB) | "
           "estimate / (peak - baseline) | wall (s) |", "|---|---|---|---|---|---|---|"]
  for r in rows:
    net = r["peak"] - base
    ratio = r["estimate"] / net if net > 0 else float("nan")
    lines.append(f"| {r['n']} x {r['n']} | {r['robots']} | {r['estimate'] / 2**20:.0f} "
                 f"| {r['peak'] / 2**20:.0f} "
                 f"| {net / 2**20:.0f} | {ratio:.2f} | {r['wall']:.0f} |")
  text = "\n".join(lines)
  print(text)
  if args.out:
    Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
  main()
