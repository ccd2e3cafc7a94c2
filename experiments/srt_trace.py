"""What an SRT robot does over a whole episode: one robot, the tree's state at every step.

For SRT's timeouts in ``toriz_tables.py`` on the Explore-Bench maps (do the robots cycle,
backtrack forever, or is the budget too small for the tree walk?). Per step: node count, current
node, mode (explore / travel / done), decisions, turns, coverage, time and distance. Per run:
how the steps split between driving to new nodes, turning and backtracking (driving to a
parent), how many times the robot arrived at a node by backtracking, the tree's depth, and what
the episode does after 99 % coverage. Pose noise on and robot seed ``i`` = ``toriz_tables.py``'s
robot ``i`` (same start, same episode).

Usage:
  python experiments/srt_trace.py --maps corridor,loop_with_corridor --seeds 0,1,2,3,4
  python experiments/srt_trace.py --maps corridor --seeds 0,1 --planner-set d_min=2.0
Appends one row per run to experiments/results/srt_trace.md (``--save-npz DIR`` also keeps the
per-step arrays; ``--no-record`` appends nothing).

Whether a change alters SRT's episodes, and from where: trace the same runs with the package
before and after it (``PYTHONPATH`` pointing at two checkouts, ``--save-npz`` to two folders,
``--no-record``), then ``--compare DIR_A DIR_B`` prints, per run, the first step at which the two
differ (pose, node count, current node, mode, decisions, turn) and what each did there.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "srt_trace.md"
HEADER = ("| map | seed | planner settings | ended | steps | time s | distance m | coverage % | "
          "nodes | new nodes / turns / backtracks | steps backtracking | most arrivals at a node | "
          "tree depth max / mean | t99 s | after t99: steps, new nodes |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def tracer(map_label: str, max_steps: int, planner: str = "srt", planner_params=None,
           pose_noise: bool = True, chunk: int = 500):
  """A function of the robot seed giving per-step arrays of its episode (numpy); compiled once."""
  import jax
  from toriz_tables import MAPS

  from jaxplore import runner, sim
  world_arg, _ = MAPS[map_label]
  grid, config, params, _ = runner.prepare(
      world=world_arg, planner=planner, robots=1, preset="toriz", pose_noise=pose_noise,
      max_steps=max_steps, params={"coverage_goal": 1.5, "slam": "oracle"},
      planner_params=planner_params or {})
  world = sim.make_world(grid, float(params.r_robot))

  @jax.jit
  def start(key):
    return sim.reset(config, world, params, key)

  @jax.jit
  def advance(state):
    def body(state, _):
      state = jax.lax.cond(sim.needs_plan(config, state),
                           lambda s: sim.plan(config, world, params, s), lambda s: s, state)
      state, _ = sim.step(config, world, params, state)
      m = state.memory
      row = (m.count, m.current, m.mode, m.decisions, m.turn, state.covered, state.time,
             state.distance, state.done, state.pose)
      return state, row
    return jax.lax.scan(body, state, None, length=chunk)

  def trace(seed: int):
    import numpy as np
    state = start(jax.random.PRNGKey(seed))
    rows = []
    while not bool(state.done) and len(rows) * chunk < max_steps:
      state, row = advance(state)
      rows.append(jax.tree.map(np.asarray, row))
    names = ("count", "current", "mode", "decisions", "turn", "covered", "time", "distance",
             "done", "pose")
    out = {k: np.concatenate([r[i] for r in rows]) for i, k in enumerate(names)}
    last = int(np.argmax(out["done"])) + 1 if out["done"].any() else max_steps
    out = {k: v[:last] for k, v in out.items()}
    out["coverage"] = out.pop("covered") / float(world.n_reachable)
    final = jax.tree.map(np.asarray, state)
    out["parent"] = final.memory.parent
    out["reason"] = np.int32(final.reason)
    return out
  return trace


def summary(t) -> dict:
  """One run's numbers (see the module docstring)."""
  import numpy as np

  from jaxplore import sim
  from jaxplore.planners import reg
  steps = len(t["mode"])
  d = t["decisions"]
  # The steps at which a decision was taken, and what it chose (the mode right after it).
  decided = np.concatenate([[d[0] > 0], d[1:] != d[:-1]])
  chose = t["mode"][decided]
  turns = int((t["turn"][decided] & (chose == reg.EXPLORE)).sum())
  backtracks = int((chose == reg.TRAVEL).sum())
  # Arrivals by backtracking: decisions taken right after a TRAVEL step.
  before = np.concatenate([[reg.START], t["mode"][:-1]])
  arrivals = t["current"][decided & (before == reg.TRAVEL)]
  most = int(np.bincount(arrivals[arrivals >= 0]).max()) if arrivals.size else 0
  count = int(t["count"][-1])
  parent = t["parent"]
  depth = np.zeros(count, int)
  for i in range(1, count):
    depth[i] = depth[parent[i]] + 1
  cov = t["coverage"]
  t99 = int(np.argmax(cov >= 0.99)) if (cov >= 0.99).any() else None
  return dict(
      ended=sim.REASONS[int(t["reason"])], steps=steps, time_s=float(t["time"][-1]),
      distance_m=float(t["distance"][-1]), coverage=float(cov[-1]), nodes=count,
      new_nodes=int((chose == reg.EXPLORE).sum()) - turns, turns=turns, backtracks=backtracks,
      backtracking=float(np.mean(t["mode"] == reg.TRAVEL)), most_arrivals=most,
      depth_max=int(depth.max()), depth_mean=float(depth.mean()),
      t99_s=float(t["time"][t99]) if t99 is not None else float("nan"),
      after_t99_steps=steps - t99 if t99 is not None else 0,
      after_t99_nodes=count - int(t["count"][t99]) if t99 is not None else 0)


def row(map_label: str, seed: int, settings: str, s: dict) -> str:
  return (f"| {map_label} | {seed} | {settings or 'defaults'} | {s['ended']} | {s['steps']} | "
          f"{s['time_s']:.0f} | {s['distance_m']:.0f} | {100 * s['coverage']:.1f} | "
          f"{s['nodes']} | {s['new_nodes']} / "
          f"{s['turns']} / {s['backtracks']} | {100 * s['backtracking']:.0f} % | "
          f"{s['most_arrivals']} | {s['depth_max']} / {s['depth_mean']:.1f} | "
          f"{s['t99_s']:.0f} | {s['after_t99_steps']} "
          f"({100 * s['after_t99_steps'] / s['steps']:.0f} %), {s['after_t99_nodes']} |")


def compare(dir_a: str, dir_b: str) -> list[str]:
  """Per run saved in both folders: the first step at which the two episodes differ."""
  import numpy as np

  from jaxplore.planners import reg
  keys = ("pose", "count", "current", "mode", "decisions", "turn")
  lines = []
  for path_a in sorted(Path(dir_a).glob("*.npz")):
    path_b = Path(dir_b) / path_a.name
    if not path_b.exists():
      continue
    a, b = np.load(path_a), np.load(path_b)
    n = min(len(a["mode"]), len(b["mode"]))
    differs = np.zeros(n, bool)
    for k in keys:
      differs |= np.any((a[k][:n] != b[k][:n]).reshape(n, -1), axis=1)
    what = lambda t, i: (f"{reg.MODES[int(t['mode'][i])]}{' (turn)' if t['turn'][i] else ''}, "
                         f"node {int(t['current'][i])} of {int(t['count'][i])}")
    if differs.any():
      i = int(np.argmax(differs))
      where = (f"first differs at step {i} (coverage {100 * a['coverage'][i]:.1f} %): "
               f"A {what(a, i)}; B {what(b, i)}")
    else:
      where = f"identical over {n} steps"
    lines.append(f"{path_a.stem}: A {len(a['mode'])} steps, B {len(b['mode'])} steps; {where}")
  return lines


def main(argv=None):
  import numpy as np
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--maps", default="corridor")
  parser.add_argument("--seeds", default="0", help="robot seeds, e.g. 0,1,2")
  parser.add_argument("--max-steps", type=int, default=20000)
  parser.add_argument("--planner", default="srt")
  parser.add_argument("--planner-set", action="append", default=[], metavar="NAME=VALUE")
  parser.add_argument("--save-npz", default=None, metavar="DIR")
  parser.add_argument("--no-record", action="store_true",
                      help="append nothing to results/srt_trace.md")
  parser.add_argument("--compare", nargs=2, default=None, metavar=("DIR_A", "DIR_B"),
                      help="compare the runs saved (--save-npz) in two folders and exit")
  args = parser.parse_args(argv)
  if args.compare:
    print("\n".join(compare(*args.compare)))
    return
  planner_params = {k: float(v) for k, v in (s.split("=") for s in args.planner_set)}
  settings = ", ".join(args.planner_set)
  if not RESULTS.exists() and not args.no_record:
    RESULTS.write_text("SRT episodes step by step (experiments/srt_trace.py; pose noise on, "
                       "`toriz` preset, robot seed i as in toriz_tables.py)\n\n" + HEADER + "\n")
  for map_label in args.maps.split(","):
    t0 = time.perf_counter()
    trace = tracer(map_label, args.max_steps, args.planner, planner_params)
    for seed in (int(x) for x in args.seeds.split(",")):
      t = trace(seed)
      if args.save_npz:
        Path(args.save_npz).mkdir(parents=True, exist_ok=True)
        np.savez_compressed(Path(args.save_npz) / f"{map_label}_{args.planner}_s{seed}.npz", **t)
      line = row(map_label, seed, settings, summary(t))
      if not args.no_record:
        with RESULTS.open("a") as f:
          f.write(line + "\n")
      print(line, f"({time.perf_counter() - t0:.0f} s wall)", flush=True)


if __name__ == "__main__":
  main()
