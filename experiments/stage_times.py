"""Benchmark: where a step's time goes, by stage, batch size and execution strategy.

For each setting of ``bench_accelerator.py`` (``office`` nearest frontier, ``lab`` li2020, an
Explore-Bench blueprint), each strategy and each batch size, the script resolves the batch
(random starts, seed 0), resets it, runs ``--warmup`` motion steps (so the maps, the paths and
the robots that need a plan are those of a mission under way, not of the reset state), and then
times three jitted stages on that state, each called ``--repeats`` times on the same input
(median reported, compile apart):

- ``plan, all``: the planning round (``planning.plan_where_needed``) with every robot needing a
  plan (the reset state's load: what one plan costs per robot);
- ``plan, as needed``: the same round on the warm state, where only the robots whose path is
  done, blocked or ``replan_every`` steps old plan (the load of a step under way);
- ``motion``: the batch's motion step (``robot.step`` vmapped: drive, collisions, the lidar,
  the belief and entropy updates, localisation), no planning.

A step of the engine is one planning round as needed and one motion step, so the last two
columns add up to the time of a step (``bench_accelerator.py`` times whole chunks of steps).

  python experiments/stage_times.py --settings office --robots 64,256
  python experiments/stage_times.py --settings lab --robots 4,64 --strategies lockstep

Rows are printed and written as they finish to ``experiments/results/stage_times_<backend>.md``
(``--out``), with the device, JAX version and load.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
from bench_accelerator import (EXPLORE_BENCH, SETTINGS, ResultsFile, _int_list,  # noqa: E402
                               load_grid)

from jaxplore import driver, memory, sim  # noqa: E402
from jaxplore.resolve import resolve  # noqa: E402
from jaxplore.runspec import RunSpec  # noqa: E402


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  add = parser.add_argument
  add("--robots", type=_int_list, default=[4, 64, 1024], help="batch sizes")
  add("--settings", default=",".join(SETTINGS), help=f"comma separated, of {', '.join(SETTINGS)}")
  add("--strategies", default="per_robot,lockstep", help="comma separated: per_robot, lockstep")
  add("--warmup", type=int, default=32, help="motion steps run before the stages are timed")
  add("--repeats", type=int, default=5, help="timed calls per stage (the median is reported)")
  add("--seed", type=int, default=0)
  add("--out", default=None, help="markdown file (default results/stage_times_<backend>.md)")
  add("--explore-bench", default=str(EXPLORE_BENCH),
      help="folder of the Explore-Bench map files (default: ../shared/maps/explore_bench)")
  return parser.parse_args(argv)


def median_call_s(function, *args, repeats: int) -> tuple[float, float]:
  """(compile and first call s, median s of ``repeats`` further calls) of a jitted function."""
  t0 = time.perf_counter()
  jax.block_until_ready(function(*args))
  first = time.perf_counter() - t0
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    jax.block_until_ready(function(*args))
    times.append(time.perf_counter() - t0)
  return first, float(np.median(times))


def stage_row(grid, label: str, strategy: str, robots: int, args) -> dict:
  """Resolve, reset, warm up, then time the three stages of one (setting, strategy, batch)."""
  _, planner, preset = SETTINGS[label]
  spec = RunSpec(world=grid, planner=planner, robots=robots, seed=args.seed, preset=preset,
                 max_steps=args.warmup + 64, strategy=strategy)
  resolved = resolve(spec)
  config, world = resolved.config, resolved.world
  row = dict(setting=label, planner=planner, strategy=config.strategy, robots=robots)
  need, have = memory.estimate_bytes(config, robots), memory.available_bytes()
  if need > memory.MEMORY_FRACTION * have:
    return dict(row, note=f"skipped: needs ~{need / 2**30:.1f} GiB of {have / 2**30:.1f} GiB free")
  batch = resolved.batch()
  params = batch.params
  state = driver.reset(config, world, batch)
  epochs = -(-args.warmup // config.replan_every)
  if epochs:
    state, _ = sim.advance(config, world, params, state, epochs)
  plan = jax.jit(lambda p, s: sim.plan_where_needed(config, world, p, s))
  motion = jax.jit(jax.vmap(lambda p, s: sim.step(config, world, p, s)))
  everyone = state.replace(busy=jnp.zeros_like(state.busy), done=jnp.zeros_like(state.done))
  compile_s, plan_all = median_call_s(plan, params, everyone, repeats=args.repeats)
  _, plan_needed = median_call_s(plan, params, state, repeats=args.repeats)
  _, move = median_call_s(motion, params, state, repeats=args.repeats)
  return dict(row, warm_steps=epochs * config.replan_every, compile_s=compile_s,
              needing=int(np.asarray(sim.needs_plan(config, state)).sum()),
              running=int((~np.asarray(state.done)).sum()),
              plan_all=plan_all, plan_needed=plan_needed, motion=move)


HEADER = ("| setting | planner | strategy | robots | warm-up steps | robots needing a plan "
          "| plan, all: ms (us/robot) | plan, as needed: ms | motion: ms (us/robot) "
          "| step: robot-steps/s | plan's first call s | note |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")


def format_row(row: dict) -> str:
  head = f"| {row['setting']} | {row['planner']} | {row['strategy']} | {row['robots']} "
  if "motion" not in row:
    return head + f"| | | | | | | | {row['note']} |"
  n, step = row["robots"], row["plan_needed"] + row["motion"]
  return head + (
      f"| {row['warm_steps']} | {row['needing']} of {row['running']} running "
      f"| {row['plan_all'] * 1e3:,.1f} ({row['plan_all'] / n * 1e6:,.0f}) "
      f"| {row['plan_needed'] * 1e3:,.1f} "
      f"| {row['motion'] * 1e3:,.1f} ({row['motion'] / n * 1e6:,.1f}) "
      f"| {row['running'] / step:,.0f} | {row['compile_s']:.1f} | {row.get('note', '')} |")


def main(args):
  results = ResultsFile(
      Path(args.out or HERE / "results" / f"stage_times_{jax.default_backend()}.md"),
      "stage_times.py", "Where a step's time goes: planning round and motion step",
      f"each stage jitted alone on the state after the warm-up, the median of {args.repeats} "
      "calls (the first call, with its compile, apart). 'plan, all': every robot plans; 'plan, "
      "as needed': the robots that need to; 'step' = running robots / (plan as needed + "
      "motion).", HEADER)
  for label in args.settings.split(","):
    grid = load_grid(label, args.explore_bench)
    for strategy in args.strategies.split(","):
      for robots in args.robots:
        results.add(format_row(stage_row(grid, label, strategy, robots, args)))
  results.close()


if __name__ == "__main__":
  main(_parse_args())
