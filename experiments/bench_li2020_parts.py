"""Benchmark: where one li2020 plan's time goes, part by part, for a chunk of robots.

li2020 is the planner whose steps cost most under the lockstep strategy: it meets its GPU target
(10x the 2-core CPU) only from ~1,024 robots on, and after the first plans 4,096 robots run
9-10x (``experiments/results/bench_lab_li2020_gpu.md``). On one H100
(``lab``, 64 robots) a step with a robot or two planning costs 60-100 ms, nearly all of it in
the planning round (``experiments/results/bench_lockstep_variants_gpu.md``), while the CPU's
whole step costs ~2 ms per robot. A plan is a sequence of parts, each a loop whose trip count is
the latency a GPU pays (a chain of small kernels per trip), whatever the chunk's size. This
script times each part alone, vmapped over a chunk of robots of a mission under way, so a GPU
session can see which part to shorten:

- ``belief view``: the masks a round computes once (``planning.belief_view``: classification,
  wall distances, the escape route's widening loop, frontiers);
- ``shortest paths``: the edge weights (Eq 13-15 boundaries) and the solve, by the strategy's
  method (relaxation under lockstep, the sweeps under per_robot);
- ``path geometry``: Eq 16-17 along every path of the tree (``path_sums``, pointer jumping);
- ``candidates``: Eq 18-19's cut of each boundary path at its last waypoint within the
  covariance limit (``nearest_ancestor``, pointer jumping);
- ``cell gains``: Eq 20-21's per-cell gains;
- ``path gains``: one channel's Eq 20 sums over every path (the visible region: a loop over the
  disc's offsets in blocks, then ``path_sums``), what a plan runs once, or twice when it
  falls back to re-exploring;
- ``extract path``: the walk back from the goal (one cell per loop trip);
- ``whole plan``: the planner itself (``plan_li2020`` on the view), all of the above;
- ``planning round``: the engine's round for the chunk (``planning._plan_robots``: the gathers
  from the batch, the view, the plan, the write-back).

Every part is jitted alone on inputs computed before timing (the median of ``--repeats`` calls,
the first call and its compile apart); 'trips' gives the loop counts that the chunk's part ran
(its longest robot's, as a vmapped loop runs), where a part has one.

  python experiments/bench_li2020_parts.py                      # chunks of 1, 4, 16, 64
  python experiments/bench_li2020_parts.py --strategy per_robot --chunks 1,4

Rows are written as they finish to ``experiments/results/bench_li2020_parts_<backend>.md``
(``--out``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
from bench_accelerator import ResultsFile, _int_list  # noqa: E402
from stage_times import median_call_s  # noqa: E402

from jaxplore import driver, linalg, planning, sim  # noqa: E402
from jaxplore.graph.dijkstra import STRATEGY_BATCHING, extract_path  # noqa: E402
from jaxplore.graph.tree import nearest_ancestor  # noqa: E402
from jaxplore.maps import load_world  # noqa: E402
from jaxplore.planners import li2020  # noqa: E402
from jaxplore.resolve import resolve  # noqa: E402
from jaxplore.robot import planner_context, robot_view  # noqa: E402
from jaxplore.runspec import RunSpec  # noqa: E402


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  add = parser.add_argument
  add("--chunks", type=_int_list, default=[1, 4, 16, 64], help="robots planned together")
  add("--strategy", default="lockstep", choices=["lockstep", "per_robot"])
  add("--world", default="lab", help="a built-in world (li2020's preset runs on it)")
  add("--warmup", type=int, default=24, help="motion steps run before the parts are timed")
  add("--repeats", type=int, default=5, help="timed calls per part (the median is reported)")
  add("--seed", type=int, default=0)
  add("--out", default=None,
      help="markdown file (default results/bench_li2020_parts_<backend>.md)")
  return parser.parse_args(argv)


def parts(config, world):
  """The parts of one plan, each a function of one robot's inputs (vmapped by the caller)."""
  ctx = planner_context(config)
  spec = config.planner

  def view_of(params, state):
    return planning.belief_view(config, params, state, robot_view(config, world, state).cell)

  def solve(params, view, entropy, robot):
    weights = params.planner
    b_e, b_g = li2020.boundaries(view, entropy, weights["tau_e"])
    return ctx.shortest_paths(li2020.edge_weights(view, b_e, b_g, weights["k1"], weights["k2"]),
                              robot.cell)

  def geometry(params, robot, sp):
    return li2020.path_geometry(ctx, robot, params, sp.pred)

  def candidates(params, view, entropy, sp, cov):
    within = (linalg.det3(cov) <= params.planner["det_sigma_max"]) & jnp.isfinite(sp.dist).ravel()
    b_e, b_g = li2020.boundaries(view, entropy, params.planner["tau_e"])
    cut = nearest_ancestor(sp.pred.ravel(), within)
    return jnp.where((b_e | b_g).ravel(), cut, -1)

  def gains_of(params, view, entropy):
    return li2020.cell_gains(view, entropy, params, params.planner["h0"], li2020.r_e_cells(ctx),
                             ctx.settings.eq21)

  def path_gain(view, robot, sp, gains):
    return li2020.path_gains(ctx, view, robot, sp.pred, gains[:1])

  def extract(robot, sp, goal):
    return extract_path(sp.pred, goal, ctx.path_capacity, source=robot.cell)

  def whole_plan(params, view, robot, key, memory):
    return spec.propose(ctx, view, robot, params, key, memory)

  return dict(view_of=view_of, solve=solve, geometry=geometry, candidates=candidates,
              gains_of=gains_of, path_gain=path_gain, extract=extract, whole_plan=whole_plan)


def visible_loop_steps(config) -> int:
  """The loop steps of ``li2020.visible_gains`` at the strategy's block (blocks of offsets and
  of crescent memberships, and the outer loop's steps over two depths each)."""
  ctx = planner_context(config)
  _, counts, _, rim_counts = li2020.sight_levels(li2020.r_e_cells(ctx))
  block = li2020.VISIBLE_BLOCK[config.strategy]
  blocks = lambda n: int(np.sum(-(-n // block)))
  return blocks(counts) + blocks(rim_counts) + counts.size // 2


def _farthest_goal(sp):
  """Per robot, its farthest reachable cell: the longest walk back the tree offers."""
  dist = jnp.where(jnp.isfinite(sp.dist), sp.dist, -1.0)
  flat = jnp.argmax(dist.reshape(dist.shape[0], -1), axis=1)
  width = sp.dist.shape[-1]
  return jnp.stack([flat // width, flat % width], -1).astype(jnp.int32)


def parts_rows(config, world, params, state, chunk: int, repeats: int) -> list[dict]:
  """Times every part for robots 0..chunk-1 of the warm ``state``."""
  robots = jnp.arange(chunk)
  p = jax.tree.map(lambda x: x[robots], params)
  s = jax.tree.map(lambda x: x[robots], state)
  fn = parts(config, world)
  method = STRATEGY_BATCHING[config.strategy][1]  # the planners' contexts batch so
  rows = []

  def timed(name, function, *args, trips=None):
    jitted = jax.jit(jax.vmap(function))
    first, median = median_call_s(jitted, *args, repeats=repeats)
    out = jitted(*args)
    rows.append(dict(part=name, chunk=chunk, first_s=first, ms=median * 1e3,
                     trips=trips(out) if trips else ""))
    return out

  views = timed("belief view", fn["view_of"], p, s)
  robot = jax.vmap(lambda st: robot_view(config, world, st))(s)
  entropy = s.memory["entropy_map"]  # li2020's I_e, in its memory
  sp = timed("shortest paths", fn["solve"], p, views, entropy, robot,
             trips=lambda out: f"{int(out.sweeps.max())} {method} rounds")
  _, cov, _ = timed("path geometry", fn["geometry"], p, robot, sp)
  timed("candidates", fn["candidates"], p, views, entropy, sp, cov)
  gains = timed("cell gains", fn["gains_of"], p, views, entropy)
  timed("path gains (one channel)", fn["path_gain"], views, robot, sp, gains,
        trips=lambda _: f"{visible_loop_steps(config)} visible-gain loop steps")
  goal = _farthest_goal(sp)
  timed("extract path (farthest goal)", fn["extract"], robot, sp, goal,
        trips=lambda out: f"{int(out[1].max())} cells")
  keys = jax.random.split(jax.random.PRNGKey(0), chunk)
  timed("whole plan", fn["whole_plan"], p, views, robot, keys, s.memory)
  need = jnp.zeros(state.busy.shape, bool).at[robots].set(True)
  round_ = jax.jit(lambda prm, st: planning._plan_robots(config, world, prm, st, need, 0,
                                                         chunk)[0])
  first, median = median_call_s(round_, params, state, repeats=repeats)
  rows.append(dict(part="planning round", chunk=chunk, first_s=first, ms=median * 1e3, trips=""))
  return rows


HEADER = ("| chunk | part | ms per call | ms per robot | share of the whole plan | loop trips "
          "| first call s |\n|---|---|---|---|---|---|---|")


def format_rows(rows: list[dict]) -> list[str]:
  whole = next(r["ms"] for r in rows if r["part"] == "whole plan")
  return [f"| {r['chunk']} | {r['part']} | {r['ms']:,.2f} | {r['ms'] / r['chunk']:,.2f} "
          f"| {r['ms'] / whole:.0%} | {r['trips']} | {r['first_s']:.1f} |" for r in rows]


def main(args):
  grid = load_world(args.world)
  results = ResultsFile(
      Path(args.out or HERE / "results" / f"bench_li2020_parts_{jax.default_backend()}.md"),
      "bench_li2020_parts.py", f"Where a li2020 plan's time goes ({args.world}, {args.strategy})",
      f"robots 0..chunk-1 of a batch of {max(args.chunks)} after {args.warmup} motion steps "
      f"(seed {args.seed}); each part jitted alone and vmapped over the chunk, the median of "
      f"{args.repeats} calls (the first, with its compile, apart). The parts run in sequence "
      "in a plan; 'whole plan' is the planner, 'planning round' the engine's round around it.",
      HEADER)
  robots = max(args.chunks)
  spec = RunSpec(world=grid, planner="li2020", robots=robots, seed=args.seed, preset="li2020",
                 max_steps=args.warmup + 64, strategy=args.strategy)
  resolved = resolve(spec)
  config, world = resolved.config, resolved.world
  batch = resolved.batch()
  state = driver.reset(config, world, batch)
  epochs = -(-args.warmup // config.replan_every)
  if epochs:
    state, _ = sim.advance(config, world, batch.params, state, epochs)
  for chunk in args.chunks:
    for line in format_rows(parts_rows(config, world, batch.params, state, chunk, args.repeats)):
      results.add(line)
  results.close()


if __name__ == "__main__":
  main(_parse_args())
