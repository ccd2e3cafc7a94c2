"""Planning time per plan for a batch of robots: Extended REG vs nearest frontier, side by side.

The robots first explore ``--world`` with ``ereg`` for ``--warm-steps`` steps (so that each has
an exploration graph of a few dozen nodes and a partly known map), then every robot plans at
once from those states with each planner, in one process: ``ereg`` (which plans on the whole
grid: its nodes, arcs and hops span the map) and nearest frontier with its planning window (the
default) and on the whole grid. Compile time is reported separately; the planning round is
timed as the median of ``--repeats`` rounds.

Usage: python experiments/bench_reg_planning.py [--robots 256] [--world corridors] [--devices 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--robots", type=int, default=256)
  parser.add_argument("--world", default="corridors")
  parser.add_argument("--warm-steps", type=int, default=400)
  parser.add_argument("--repeats", type=int, default=5)
  parser.add_argument("--devices", type=int, default=1)
  args = parser.parse_args(argv)
  os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")
  import dataclasses

  import jax
  import jax.numpy as jnp
  import numpy as np
  from jax.sharding import Mesh, PartitionSpec as P

  from jaxplore import runner, sim
  from jaxplore.planners import get_planner

  def setup(planner):
    grid, config, params, _ = runner.prepare(world=args.world, planner=planner, robots=args.robots,
                                             preset="toriz", max_steps=args.warm_steps + 8,
                                             params={"coverage_goal": 1.5, "slam": "oracle"})
    return grid, config, params

  grid, config, params = setup("ereg")
  world = sim.make_world(grid, float(params.r_robot))
  params_b = sim.broadcast_params(params, args.robots)
  keys = jax.vmap(jax.random.PRNGKey)(jnp.arange(args.robots, dtype=jnp.uint32))
  t0 = time.perf_counter()
  states = sim.reset_batch(config, world, params_b, keys)
  states, _ = sim.advance(config, world, params_b, states, args.warm_steps // config.replan_every)
  jax.block_until_ready(states)
  warm_s = time.perf_counter() - t0
  nodes = np.asarray(states.memory.count)
  coverage = np.asarray(states.covered) / float(world.n_reachable)
  print(f"warm-up {args.warm_steps} steps of ereg: {warm_s:.0f} s; nodes per robot "
        f"{nodes.mean():.1f} (min {nodes.min()}, max {nodes.max()}); "
        f"coverage {coverage.mean():.2f}", flush=True)

  n_dev = min(args.devices, len(jax.devices()))
  rows = []
  cases = (("ereg", True), ("nearest_frontier", False), ("nearest_frontier", True))
  for planner, whole_grid in cases:
    _, config_p, params_p = setup(planner)
    if whole_grid:
      config_p = dataclasses.replace(config_p, plan_window=0)
    window = config_p.plan_window if sim.uses_window(config_p) else "off"
    params_pb = sim.broadcast_params(params_p, args.robots)
    memory = states.memory if get_planner(planner).init_memory is not None else ()
    # Every robot plans (as when all arrive at once): the engine's per-robot planning loop.
    planning_states = states.replace(busy=jnp.zeros_like(states.busy), memory=memory)
    fn = lambda p, s, c=config_p: sim.plan_where_needed(c, world, p, s)
    if n_dev > 1:
      mesh = Mesh(np.array(jax.devices()[:n_dev]), ("robots",))
      fn = jax.shard_map(fn, mesh=mesh, in_specs=(P("robots"), P("robots")), out_specs=P("robots"),
                         check_vma=False)
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(params_pb, planning_states).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(params_pb, planning_states))
    times = []
    for _ in range(args.repeats):
      t0 = time.perf_counter()
      jax.block_until_ready(compiled(params_pb, planning_states))
      times.append(time.perf_counter() - t0)
    per_round = float(np.median(times))
    rows.append((planner, window, compile_s, per_round, per_round / args.robots * 1e3))
    print(f"{planner:17s} window {window!s:4s} compile {compile_s:6.1f} s   "
          f"{per_round * 1e3:9.1f} ms per round   {per_round / args.robots * 1e3:7.2f} ms per plan",
          flush=True)
  base = next(r for p, w, _, r, _ in rows if p == "nearest_frontier" and w == "off")
  table = ["| planner | plan window | compile s | ms per planning round | ms per plan "
           "| vs nearest frontier on the whole grid |", "|---|---|---|---|---|---|"]
  table += [f"| {p} | {w} | {c:.1f} | {r * 1e3:.1f} | {m:.2f} | {r / base:.2f}x |"
            for p, w, c, r, m in rows]
  load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
  text = (f"Planning time, {args.robots} robots on `{args.world}` (`toriz` preset), {n_dev} "
          f"device(s), the same belief states for every planner (after {args.warm_steps} steps of "
          f"`ereg`: {nodes.mean():.1f} graph nodes per robot on average, coverage "
          f"{coverage.mean():.2f}), every robot planning (median of {args.repeats} timed rounds); "
          f"{time.strftime('%Y-%m-%dT%H:%M:%S')}, load average at the end {load}; command: "
          f"python experiments/bench_reg_planning.py {' '.join(sys.argv[1:] if argv is None else argv)}\n\n"
          + "\n".join(table) + "\n")
  (HERE / "results").mkdir(exist_ok=True)
  (HERE / "results" / "bench_reg_planning.md").write_text(text)
  print(text)


if __name__ == "__main__":
  main()
