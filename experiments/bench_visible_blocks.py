"""li2020's visible gains one sight offset at a time against blocks of offsets per loop step.

``li2020.visible_gains(..., block)`` takes the disc offsets of a depth (and its crescent
memberships) ``block`` at a time; the lockstep strategy uses ``li2020.VISIBLE_BLOCK``. This
times every block size on the same inputs (a lab-sized 130 x 170 grid with two walls and 1 %
scattered occupied cells, R_e = 57 cells as li2020's preset gives at 0.1 m, random gains in 30 %
of the cells, two channels), robots vmapped as a planning chunk is, compile apart, and checks
each result is the one-at-a-time result bit for bit. ``--by-depth N`` adds the GPU candidate of
``experiments/visible_by_depth.py`` (a whole depth of the sight-line tree per loop, N rows per
loop step), whose sums match to float summation order (its largest relative difference shown).

Usage: python experiments/bench_visible_blocks.py [--blocks 1 8] [--robots 4 64 256]
[--by-depth 64] (default robots: 4 on a CPU, the per_robot chunk; 4, 64 and 256 on an
accelerator).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--blocks", type=int, nargs="+", default=[1, 8])
  parser.add_argument("--robots", type=int, nargs="+", default=None)
  parser.add_argument("--by-depth", type=int, nargs="*", default=[],
                      help="rows per loop step of visible_by_depth candidates to time too")
  parser.add_argument("--repeats", type=int, default=3, help="timed calls (the best is kept)")
  parser.add_argument("--out", default=None,
                      help="markdown file (default results/bench_visible_blocks_<backend>.md)")
  args = parser.parse_args(argv)

  import jax
  import numpy as np

  from jaxplore.planners import li2020
  from visible_by_depth import visible_gains_by_depth

  backend = jax.default_backend()
  robots_list = args.robots or ([4] if backend == "cpu" else [4, 64, 256])
  rng = np.random.default_rng(0)
  h, w, radius = 130, 170, 57.0
  occupied = np.zeros((h, w), bool)
  occupied[[0, -1], :] = occupied[:, [0, -1]] = True
  occupied[60, 10:150] = True
  occupied[20:120, 90] = True
  occupied |= rng.random((h, w)) < 0.01
  rows = []
  for robots in robots_list:
    gains = (rng.random((robots, 2, h, w)) * (rng.random((robots, 1, h, w)) < 0.3)
             ).astype(np.float32)
    walls = np.broadcast_to(occupied, (robots, h, w))
    reference = None
    candidates = [(str(block), lambda g, o, block=block: li2020.visible_gains(g, o, radius, block))
                  for block in args.blocks]
    candidates += [(f"by depth, {rows}",
                    lambda g, o, rows=rows: visible_gains_by_depth(g, o, radius, rows))
                   for rows in args.by_depth]
    for label, function in candidates:
      fn = jax.jit(jax.vmap(function))
      start = time.perf_counter()
      compiled = fn.lower(gains, walls).compile()
      compile_s = time.perf_counter() - start
      out = jax.block_until_ready(compiled(gains, walls))
      times = []
      for _ in range(args.repeats):
        start = time.perf_counter()
        jax.block_until_ready(compiled(gains, walls))
        times.append(time.perf_counter() - start)
      if reference is None:
        reference, same = out, "(reference)"
      elif all(np.array_equal(a, b) for a, b in zip(reference, out)):
        same = "yes"
      else:
        worst = max(float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-6)))
                    for a, b in zip(reference, out))
        same = f"NO: max relative difference {worst:.1e}"
      best = min(times)
      rows.append(f"| {robots} | {label} | {compile_s:.1f} | {best * 1e3:.1f} "
                  f"| {best / robots * 1e3:.2f} | {same} |")
      print(rows[-1], flush=True)
  device = f"{jax.devices()[0].device_kind} ({backend})"
  text = (f"# li2020 visible gains by block size\n\nCommand: `python experiments/"
          f"bench_visible_blocks.py {' '.join(sys.argv[1:] if argv is None else argv)}`  \n"
          f"Device: {device}; jax {jax.__version__}; {time.strftime('%Y-%m-%d %H:%M')}; "
          f"1-minute load average at the end {os.getloadavg()[0]:.2f}.  \n"
          f"Inputs: 130 x 170 grid, R_e {radius:.0f} cells, 2 channels; best of "
          f"{args.repeats} calls after compiling.\n\n"
          "| robots | block | compile s | ms per call | ms per robot | same as block 1 |\n"
          "|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n")
  out_path = Path(args.out) if args.out else HERE / "results" / f"bench_visible_blocks_{backend}.md"
  out_path.parent.mkdir(exist_ok=True)
  out_path.write_text(text)
  print(f"wrote {out_path}")


if __name__ == "__main__":
  main()
