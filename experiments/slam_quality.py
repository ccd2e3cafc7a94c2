"""What the SLAM model changes: ``oracle`` against ``scan_matching``, per world.

For each world: one batched ``jaxplore.run`` of N robots (nearest frontier, the li2020 preset,
seed 0: the same starts for both models) with each SLAM model; the ``oracle`` rows with
``pose_noise`` on (the same odometry error; relocalised by a measurement of the true pose). Per
model: the robots' final coverage and distance, how they ended, the keyframe trajectory error
(ATE, RMSE after alignment; scan_matching only, the oracle keeps no keyframes unless asked),
the mean and max distance between true and estimated position over the episode, map error
(SSIM and RMSE of P(occupied) against the truth, the fraction of walls misplaced by more than
a cell), loop closures (accepted, false). And a figure: one robot's keyframe trajectory and map
just before and just after its first loop closure, beside the truth.

Usage:
  python experiments/slam_quality.py                                  # office, willow, intel
  python experiments/slam_quality.py --worlds office --robots 4 --max-steps 400   # quick
  python experiments/slam_quality.py --worlds willow --models scan_matching \
      --set map_hole_cells=0 --out /tmp/no_holes                # what one default does

Writes ``experiments/results/slam_quality.md``, ``slam_quality_episodes.csv`` and
``slam_quality_closure.png``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
SHARED_MAPS = HERE.parent.parent / "shared" / "maps"
WORLDS = {"office": "office", "willow": str(SHARED_MAPS / "willow.yaml"),
          "intel": str(SHARED_MAPS / "intel.yaml")}
RES = {"willow": 0.2, "intel": 0.2}


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", default="office,willow,intel")
  parser.add_argument("--robots", type=int, default=16)
  parser.add_argument("--max-steps", type=int, default=None,
                      help="step budget (default: each world's own, from its free area)")
  parser.add_argument("--devices", type=int, default=2)
  parser.add_argument("--out", default=str(RESULTS / "slam_quality"))
  parser.add_argument("--figure-world", default="office")
  parser.add_argument("--models", default="oracle,scan_matching",
                      help="the SLAM models to compare, comma-separated")
  parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                      help="a setting for every run, as jaxplore run --set takes it (repeatable),"
                           " e.g. --set map_hole_cells=0 to measure what a default does")
  args = parser.parse_args(argv)
  flags = os.environ.get("XLA_FLAGS", "")
  if "xla_force_host_platform_device_count" not in flags and args.devices > 1:
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={args.devices}".strip()

  import pandas as pd

  import jaxplore

  out = Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)  # before the runs: their results are not lost
  settings = {}
  for item in args.set:
    name, _, value = item.partition("=")
    settings[name.strip()] = float(value)
  rows, episodes = [], []
  started = time.time()
  for name in args.worlds.split(","):
    for model in args.models.split(","):
      t0 = time.time()
      result = jaxplore.run(world=WORLDS.get(name, name), res=RES.get(name), robots=args.robots,
                            planner="nearest_frontier", seed=0, slam=model, pose_noise=True,
                            pose_graph=True, max_steps=args.max_steps, progress=True,
                            devices=args.devices, params=settings or None)
      ep = result.episodes.assign(world=name, model=model)
      episodes.append(ep)
      row = dict(world=name, model=model, robots=len(ep), steps=result.config["sim_config"]["max_steps"],
                 wall_s=time.time() - t0,
                 complete=int((ep.reason == "complete").sum()),
                 coverage=ep.coverage.mean(), distance=ep.distance_m.mean(),
                 pose_error_mean=ep.pose_error_mean.mean(), pose_error_max=ep.pose_error_max.max(),
                 ssim=ep.ssim.mean(), rmse=ep.rmse.mean(), misplaced=ep.misplaced_walls.mean())
      for col in ("ate_m", "rpe_m_per_m", "loop_closures", "false_closures", "near_links",
                  "false_links", "revoked", "false_revoked"):
        row[col] = ep[col].mean() if col in ep else float("nan")
      row["closing_robots"] = int((ep.loop_closures > 0).sum()) if "loop_closures" in ep else 0
      rows.append(row)
      print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
  table = pd.DataFrame(rows)
  pd.concat(episodes).to_csv(out.with_name(out.name + "_episodes.csv"), index=False)
  # The figure shows the default scan_matching model: not drawn for an ablation (--set).
  figure = (closure_figure(args.figure_world, out.with_name(out.name + "_closure.png"))
            if "scan_matching" in args.models.split(",") and not args.set else None)
  lines = [
      "# SLAM quality: oracle vs scan_matching", "",
      f"`python experiments/slam_quality.py --worlds {args.worlds} --robots {args.robots}"
      + (f" --max-steps {args.max_steps}" if args.max_steps else "")
      + (f" --models {args.models}" if args.models != "oracle,scan_matching" else "")
      + "".join(f" --set {item}" for item in args.set) + "`", "",
      f"Nearest frontier, li2020 preset (15 m, 190° lidar), seed 0 (both models start from the "
      f"same poses), odometry noise on in both (3 % per metre and per radian), two host devices "
      f"on a 2-core CPU; {time.time() - started:.0f} s in all. Means over the robots; "
      "`pose err` over every step of every robot (mean; max of the batch); ATE and RPE over "
      "the keyframes of the scan_matching robots (evo's definitions); map error of the final "
      "belief against the truth.", "",
      "| world | model | robots | complete | coverage | distance m | pose err mean / max m | "
      "ATE m | RPE m/m | SSIM | RMSE | misplaced walls | closures (false) | links (false) | "
      "revoked (false) | robots closing | wall s |",
      "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
  for r in rows:
    lines.append(
        f"| {r['world']} | {r['model']} | {r['robots']} | {r['complete']} | {r['coverage']:.3f} | "
        f"{r['distance']:.1f} | {r['pose_error_mean']:.3f} / {r['pose_error_max']:.3f} | "
        f"{r['ate_m']:.3f} | {r['rpe_m_per_m']:.4f} | {r['ssim']:.3f} | {r['rmse']:.3f} | "
        f"{r['misplaced']:.3f} | {r['loop_closures']:.2f} ({r['false_closures']:.2f}) | "
        f"{r['near_links']:.2f} ({r['false_links']:.2f}) | "
        f"{r['revoked']:.2f} ({r['false_revoked']:.2f}) | "
        f"{r['closing_robots']} | {r['wall_s']:.0f} |")
  if figure is not None:
    lines += ["", f"![a closure]({figure.name})", ""]
  text = "\n".join(lines) + "\n"
  out.with_suffix(".md").write_text(text)
  print(text)


def closure_figure(world: str, path: Path):
  """One robot on ``world`` with scan_matching, stepped a planning round at a time until its
  first loop closure: its keyframe trajectory and belief just before and just after, beside the
  truth. Returns the figure's path, or None when no robot closed a loop within the budget."""
  import jax
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  import numpy as np

  from jaxplore import driver, plot, sim
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec

  resolved = resolve(RunSpec.create(world=WORLDS.get(world, world), res=RES.get(world), robots=4,
                                    planner="nearest_frontier", seed=0, slam="scan_matching"))
  config, world_, grid = resolved.config, resolved.world, resolved.grid
  params = sim.broadcast_params(resolved.params, 4)
  keys = jax.random.split(jax.random.PRNGKey(0), 4)
  state = sim.reset_batch(config, world_, params, keys, None)
  advance = driver.compiled_advance(config, 1, 1)
  before = None
  for _ in range(config.n_epochs):
    previous = state
    state, _ = advance(world_, params, state)
    closed = np.asarray(state.graph.n_loops) > np.asarray(previous.graph.n_loops)
    if closed.any():
      robot = int(np.argmax(closed))
      before = previous
      break
  if before is None:
    return None
  fig, axes = plt.subplots(1, 2, figsize=(12, 5.5))
  for ax, (title, s) in zip(axes, (("just before the first closure", before),
                                   ("just after it (optimised, map rebuilt)", state))):
    g = jax.tree.map(lambda x: np.asarray(x[robot]), s.graph)
    n = int(g.n_nodes)
    plot.belief_map(ax, grid.occupied, np.asarray(s.logodds[robot]), grid.res, grid.origin)
    ax.plot(g.truth[:n, 0], g.truth[:n, 1], "-", color="tab:green", lw=1.5, label="true keyframes")
    ax.plot(g.poses[:n, 0], g.poses[:n, 1], "-", color="tab:red", lw=1.2,
            label="estimated keyframes")
    for a, b in g.loops[:int(g.n_loops)]:
      ax.plot(*np.stack([g.poses[a, :2], g.poses[b, :2]]).T, ":", color="tab:blue", lw=1.5)
    xy = np.concatenate([g.truth[:n, :2], g.poses[:n, :2]])
    lo, hi = xy.min(axis=0) - 3.0, xy.max(axis=0) + 3.0
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_title(f"robot {robot}, {title}\nkeyframes {n}, closures {int(g.n_loops)}")
    ax.legend(loc="lower right", fontsize=8)
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)
  return path


if __name__ == "__main__":
  main()
