"""Planning time per plan for a batch of robots: ahmed (and AGS) vs nearest frontier, side by side.

All planners plan for the same robots in the same belief states and pose graphs (taken after
``--warm-steps`` motion steps of nearest frontier with every robot's pose graph kept), in one
process; compile time is reported separately. Nearest frontier is timed with its planning window
(the default) and on the whole grid, which is what ahmed and AGS (their utility weighs every
candidate) always plan on. ahmed's cost grows with the pose graph's loop-closure capacity
(``--graph-loops``: the capacitance's Cholesky is cubic in it, whatever the graph holds).

Usage: python experiments/bench_ahmed_planning.py [--robots 256] [--world office] [--devices 2]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
PARAMS = dict(r_max=6.0, fov=math.pi, v_max=0.3, w_max=0.8, range_noise=0.01)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--robots", type=int, default=256)
  parser.add_argument("--world", default="office")
  parser.add_argument("--res", type=float, default=0.1)
  parser.add_argument("--warm-steps", type=int, default=400)
  parser.add_argument("--graph-loops", type=int, default=1024)
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--planners", default="nearest_frontier,nearest_frontier/whole,ahmed,ags")
  parser.add_argument("--devices", type=int, default=2)
  args = parser.parse_args(argv)
  os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")
  import jax
  import jax.numpy as jnp
  import numpy as np
  from jax.sharding import Mesh, PartitionSpec as P

  from jaxplore import sim
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec

  rows = []
  states = None
  n_dev = min(args.devices, len(jax.devices()))
  for label in args.planners.split(","):
    planner, _, variant = label.partition("/")
    resolved = resolve(RunSpec(world=args.world, res=args.res, planner=planner, robots=args.robots,
                               preset=None, params=PARAMS, max_steps=args.warm_steps + 8,
                               pose_graph=True, graph_loops=args.graph_loops,
                               plan_window=0 if variant == "whole" else None))
    grid, config, params, world = resolved.grid, resolved.config, resolved.params, resolved.world
    window = config.plan_window if sim.uses_window(config) else "off"
    params_b = sim.broadcast_params(params, args.robots)
    if states is None:  # the same belief states and graphs for every planner
      keys = jax.random.split(jax.random.PRNGKey(0), args.robots)
      states = sim.reset_batch(config, world, params_b, keys)
      states, _ = sim.advance(config, world, params_b, states,
                              args.warm_steps // config.replan_every)
      graph_nodes = np.asarray(states.graph.n_nodes)
      graph_loops = np.asarray(states.graph.n_loops)
    # Every robot plans (as when all arrive at once): the engine's per-robot planning loop.
    fn = lambda p, s: sim.plan_where_needed(config, world, p,
                                            s.replace(busy=jnp.zeros_like(s.busy)))
    if n_dev > 1:
      mesh = Mesh(np.array(jax.devices()[:n_dev]), ("robots",))
      fn = jax.shard_map(fn, mesh=mesh, in_specs=(P("robots"), P("robots")), out_specs=P("robots"),
                         check_vma=False)
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(params_b, states).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(params_b, states))
    times = []
    for _ in range(args.repeats):
      t0 = time.perf_counter()
      jax.block_until_ready(compiled(params_b, states))
      times.append(time.perf_counter() - t0)
    per_round = float(np.median(times))
    rows.append((label, window, compile_s, per_round, per_round / args.robots * 1e3))
    print(f"{label:24s} window {window!s:4s} compile {compile_s:6.1f} s   "
          f"{per_round * 1e3:9.1f} ms per round   "
          f"{per_round / args.robots * 1e3:8.2f} ms per robot", flush=True)
  base = next((r for p, w, _, r, _ in rows if p.startswith("nearest_frontier") and w == "off"),
              rows[0][3])
  table = ["| planner | plan window | compile s | ms per planning round | ms per plan (per robot) "
           "| vs nearest frontier on the whole grid |", "|---|---|---|---|---|---|"]
  table += [f"| {p} | {w} | {c:.1f} | {r * 1e3:.1f} | {m:.2f} | {r / base:.1f}x |"
            for p, w, c, r, m in rows]
  load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
  text = (f"Planning time, {args.robots} robots on `{args.world}` ({grid.shape[0]}x{grid.shape[1]} "
          f"cells), {n_dev} device(s), the same belief states and pose graphs (after "
          f"{args.warm_steps} steps: {graph_nodes.mean():.0f} keyframes and "
          f"{graph_loops.mean():.0f} loop closures on average; loop capacity {args.graph_loops}), "
          f"every robot planning (median of {args.repeats} timed rounds); "
          f"{time.strftime('%Y-%m-%dT%H:%M:%S')}, load average at the end {load}; command: "
          f"python experiments/bench_ahmed_planning.py {' '.join(sys.argv[1:] if argv is None else argv)}\n\n"
          + "\n".join(table) + "\n")
  (HERE / "results").mkdir(exist_ok=True)
  (HERE / "results" / "bench_ahmed_planning.md").write_text(text)
  print(text)


if __name__ == "__main__":
  main()
