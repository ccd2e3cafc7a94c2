"""li2020's visible_gains, the one-loop version (before db5f339) vs the depth-by-depth one.

Inputs are those of a li2020 planning round: the real config of each world (its grid, R_e in
cells, ``plan_chunk`` robots vmapped as the engine plans them), the belief states of
``--robots`` robots after ``--warm-steps`` steps of li2020, their per-cell gains
(``li2020.cell_gains``) and believed walls. Both versions run on the same inputs in one
process; compile time apart; the answers are compared (float sums may differ by their order).

Usage: taskset -c 1 python experiments/bench_visible_gains.py [--worlds lab,office]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def visible_gains_one_loop(gains, occupied, radius: float):
  """li2020.visible_gains as of 0c98c96: one loop over the disc offsets in depth-first order of
  the tree of sight lines, with a stack of one mask per depth (verbatim but for the comments)."""
  import jax
  import jax.numpy as jnp

  from jaxplore.planners.li2020 import ray_tree

  offsets, depth, member, sides = ray_tree(radius)
  c, h, w = gains.shape
  pad = int(math.floor(radius)) + 1
  framed_gain = jnp.pad(gains, [(0, 0), (pad, pad), (pad, pad)])
  framed_clear = jnp.pad(~occupied, [(pad, pad), (pad, pad)], constant_values=True)
  table = jnp.asarray(offsets) + pad
  sides = jnp.asarray(sides) + pad
  stack = jnp.zeros((int(depth.max()) + 1, h, w), bool).at[0].set(True)
  depth = jnp.asarray(depth)
  rim = jnp.asarray(member.any(axis=1))
  member = jnp.asarray(member, gains.dtype)

  def visit(i, carry):
    stack, full, crescent = carry
    clear_at = lambda at: jax.lax.dynamic_slice(framed_clear, (at[0], at[1]), (h, w))
    seen = stack[depth[i] - 1] & (clear_at(sides[i, 0]) | clear_at(sides[i, 1]))
    clear = clear_at(table[i])
    stack = stack.at[depth[i]].set(seen & clear)
    value = jnp.where(seen, jax.lax.dynamic_slice(framed_gain, (0, table[i, 0], table[i, 1]),
                                                  (c, h, w)), 0.0)
    crescent = jax.lax.cond(rim[i], lambda x: x + member[i][:, None, None, None] * value[None],
                            lambda x: x, crescent)
    return stack, full + value, crescent

  _, full, crescent = jax.lax.fori_loop(0, offsets.shape[0], visit,
                                        (stack, gains, jnp.zeros((8,) + gains.shape, gains.dtype)))
  return full, crescent


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", default="lab,office")
  parser.add_argument("--robots", type=int, default=8,
                      help="belief states per world (a multiple of plan_chunk)")
  parser.add_argument("--warm-steps", type=int, default=40)
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--memory", default="256,400,400",
                      help="robots,H,W of a lockstep round whose XLA temp memory is reported")
  args = parser.parse_args(argv)

  import jax
  import jax.numpy as jnp
  import numpy as np

  from jaxplore import planning, sim
  from jaxplore.planners import li2020
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec

  rows = []
  for world_name in args.worlds.split(","):
    resolved = resolve(RunSpec(world=world_name, planner="li2020", robots=args.robots,
                               max_steps=args.warm_steps + 8))
    config, params, world = resolved.config, resolved.params, resolved.world
    radius, chunk = li2020.r_e_cells(planning.planner_context(config)), config.plan_chunk
    settings = config.planner.settings
    params_b = sim.broadcast_params(params, args.robots)
    keys = jax.random.split(jax.random.PRNGKey(0), args.robots)
    states = sim.reset_batch(config, world, params_b, keys)
    states, _ = sim.advance(config, world, params_b, states, args.warm_steps // config.replan_every)

    def inputs(p, s):
      view = planning.belief_view(config, p, s, jnp.zeros(2, jnp.int32))
      return (li2020.cell_gains(view, s.memory["entropy_map"], p, p.planner["h0"], radius,
                                settings.eq21), view.occupied)

    gains, occupied = jax.jit(jax.vmap(inputs))(params_b, states)
    gains = gains.reshape((-1, chunk) + gains.shape[1:])  # rounds of plan_chunk robots
    occupied = occupied.reshape((-1, chunk) + occupied.shape[1:])
    results = {}
    for label, fn in (("one loop (old)", visible_gains_one_loop),
                      ("depth by depth (new)", li2020.visible_gains)):
      batched = jax.jit(jax.vmap(fn, (0, 0, None)), static_argnums=2)
      t0 = time.perf_counter()
      compiled = batched.lower(gains[0], occupied[0], radius).compile()
      compile_s = time.perf_counter() - t0
      results[label] = [jax.block_until_ready(compiled(g, o)) for g, o in zip(gains, occupied)]
      times = []
      for _ in range(args.repeats):
        for g, o in zip(gains, occupied):
          t0 = time.perf_counter()
          jax.block_until_ready(compiled(g, o))
          times.append(time.perf_counter() - t0)
      per_call = float(np.median(times))
      rows.append((world_name, config.height, config.width, radius, chunk, label, compile_s,
                   per_call))
      print(f"{world_name:8s} {label:22s} compile {compile_s:5.1f} s  {per_call * 1e3:8.1f} ms "
            f"per call of {chunk} robots", flush=True)
    old, new = (np.concatenate([np.concatenate([np.ravel(x) for x in out]) for out in results[k]])
                for k in results)
    rows[-1] += (float(np.max(np.abs(new - old) / np.maximum(np.abs(old), 1e-3))),)
  device = jax.devices()[0].device_kind
  table = ["| world | grid | R_e cells | robots per call | version | compile s | ms per call "
           "| ms per robot | speed-up | max rel. diff vs old |", "|---" * 10 + "|"]
  for i, row in enumerate(rows):
    world_name, h, w, radius, chunk, label, compile_s, per_call = row[:8]
    old_call = rows[i - 1][7] if i % 2 else per_call
    diff = f"{row[8]:.1e}" if len(row) > 8 else ""
    table.append(f"| {world_name} | {h}x{w} | {radius:.1f} | {chunk} | {label} | {compile_s:.1f} "
                 f"| {per_call * 1e3:.1f} | {per_call / chunk * 1e3:.1f} "
                 f"| {old_call / per_call:.1f}x | {diff} |")
  # XLA's temp memory (compiled, not run) for a whole batch vmapped, as the lockstep strategy
  # plans on an accelerator, at the last world's R_e.
  batch, h, w = (int(x) for x in args.memory.split(","))
  shapes = (jax.ShapeDtypeStruct((batch, 2, h, w), jnp.float32),
            jax.ShapeDtypeStruct((batch, h, w), bool))
  memory = []
  for label, fn in (("old", visible_gains_one_loop), ("new", li2020.visible_gains)):
    batched = jax.jit(jax.vmap(fn, (0, 0, None)), static_argnums=2)
    compiled = batched.lower(*shapes, radius).compile()
    memory.append(f"{label} {compiled.memory_analysis().temp_size_in_bytes / 1e9:.2f} GB")
  table.append(f"\nXLA temp memory, {batch} robots vmapped on {h}x{w} at R_e {radius:.1f} cells: "
               + ", ".join(memory) + " (outputs and inputs apart).")
  load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
  stamp = time.strftime("%Y-%m-%dT%H:%M:%S")
  text = (f"li2020 visible_gains, old vs new, on the inputs of li2020 planning rounds "
          f"({args.robots} belief states per world after {args.warm_steps} steps, vmapped in "
          f"rounds of the config's plan_chunk; median of {args.repeats} x {args.robots // chunk} "
          f"timed calls); device {device}, pinned to one core; {stamp}, load average at the end "
          f"{load}; command: taskset -c 1 python "
          f"experiments/bench_visible_gains.py "
          f"{' '.join(sys.argv[1:] if argv is None else argv)}\n\n" + "\n".join(table) + "\n")
  (HERE / "results").mkdir(exist_ok=True)
  (HERE / "results" / "bench_visible_gains.md").write_text(text)
  print(text)


if __name__ == "__main__":
  main()
