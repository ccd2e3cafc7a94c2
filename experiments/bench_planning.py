"""Planning time per round for a batch of robots: li2020, gpbo and nearest frontier, side by side.

All planners plan for the same robots in the same belief states (taken after a few motion
steps on a ~200x200-cell world), in one process; compile time is reported separately. Nearest
frontier is timed with its planning window (the default) and on the whole grid, which is what
li2020 and gpbo (not windowed: their utilities weigh every candidate) always plan on. The
states carry Li's entropy map for the planners that read it; each planner gets its own fresh
per-robot memory (gpbo's GP hyper-parameters, li2020's progress timeout).

Usage: python experiments/bench_planning.py [--robots 256] [--world open] [--devices 2]
       [--planners nearest_frontier,li2020,gpbo] [--out results/bench_planning.md]
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
  parser.add_argument("--world", default="open")
  parser.add_argument("--warm-steps", type=int, default=40)
  parser.add_argument("--repeats", type=int, default=9)
  parser.add_argument("--devices", type=int, default=2)
  parser.add_argument("--planners", default="nearest_frontier,li2020,gpbo",
                      help="nearest_frontier is timed with its window and on the whole grid")
  parser.add_argument("--out", default=str(HERE / "results" / "bench_planning.md"),
                      help="where the table is written")
  args = parser.parse_args(argv)
  os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")

  import dataclasses

  import jax
  import jax.numpy as jnp
  import numpy as np
  from jax.sharding import Mesh, PartitionSpec as P

  from jaxplore import sim
  from jaxplore.planners import get_planner
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec

  rows = []
  states = None
  runs = []
  for planner in args.planners.split(","):
    runs += [(planner, False), (planner, True)] if planner == "nearest_frontier" else [(planner, False)]
  for planner, whole_grid in runs:
    resolved = resolve(RunSpec(world=args.world, planner=planner, robots=args.robots,
                               max_steps=args.warm_steps + 8,
                               plan_window=0 if whole_grid else None))
    config, params, world = resolved.config, resolved.params, resolved.world
    window = config.plan_window if sim.uses_window(config) else "off"
    params_b = sim.broadcast_params(params, args.robots)
    if states is None:  # the same belief states for every planner, with Li's entropy map
      warm = resolve(RunSpec(world=args.world, planner="li2020", robots=args.robots,
                             max_steps=args.warm_steps + 8)).config
      keys = jax.random.split(jax.random.PRNGKey(0), args.robots)
      states = sim.reset_batch(warm, world, params_b, keys)
      states, _ = sim.advance(warm, world, params_b, states, args.warm_steps // warm.replan_every)
    memory = get_planner(planner).initial_memory(sim.planner_context(config), params)
    memory = jax.tree.map(lambda x: jnp.broadcast_to(x, (args.robots,) + jnp.shape(x)), memory)
    if isinstance(memory, dict) and "entropy_map" in memory:  # li2020's, warmed up with them
      memory = dict(memory, entropy_map=states.memory["entropy_map"])
    planner_states = states.replace(memory=memory)
    n_dev = min(args.devices, len(jax.devices()))
    # Every robot plans (as when all arrive at once): the engine's per-robot planning loop.
    fn = lambda p, s: sim.plan_where_needed(config, world, p, s.replace(busy=jnp.zeros_like(s.busy)))
    if n_dev > 1:
      mesh = Mesh(np.array(jax.devices()[:n_dev]), ("robots",))
      fn = jax.shard_map(fn, mesh=mesh, in_specs=(P("robots"), P("robots")), out_specs=P("robots"),
                         check_vma=False)
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(params_b, planner_states).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(params_b, planner_states))
    times = []
    for _ in range(args.repeats):
      t0 = time.perf_counter()
      jax.block_until_ready(compiled(params_b, planner_states))
      times.append(time.perf_counter() - t0)
    per_round = float(np.median(times))
    rows.append((planner, window, compile_s, per_round, per_round / args.robots * 1e3))
    print(f"{planner:17s} window {window!s:4s} compile {compile_s:6.1f} s   {per_round * 1e3:8.1f} ms per round   "
          f"{per_round / args.robots * 1e3:6.2f} ms per robot", flush=True)
  # The ratios are to nearest frontier on the whole grid, or to the first planner without it.
  base_name, base = next(((f"{p} on the whole grid", r) for p, w, _, r, _ in rows
                          if p == "nearest_frontier" and w == "off"), (rows[0][0], rows[0][3]))
  table = [f"| planner | plan window | compile s | ms per planning round | ms per robot | vs {base_name} |",
           "|---|---|---|---|---|---|"]
  table += [f"| {p} | {w} | {c:.1f} | {r * 1e3:.1f} | {m:.2f} | {r / base:.2f}x |" for p, w, c, r, m in rows]
  load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
  text = (f"Planning time, {args.robots} robots on `{args.world}`, {n_dev} device(s), same belief states, "
          f"every robot planning (median of {args.repeats} timed rounds); {time.strftime('%Y-%m-%dT%H:%M:%S')}, "
          f"load average at the end {load}; command: python experiments/bench_planning.py "
          f"{' '.join(sys.argv[1:] if argv is None else argv)}\n\n" + "\n".join(table) + "\n")
  Path(args.out).parent.mkdir(parents=True, exist_ok=True)
  Path(args.out).write_text(text)
  print(text)


if __name__ == "__main__":
  main()
