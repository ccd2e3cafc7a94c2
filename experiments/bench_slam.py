"""Benchmark: robot-steps per second with the ``scan_matching`` SLAM model against ``oracle``.

Side by side in one run, on one device: nearest frontier, the planner's default preset, the same
start poses and seeds for both models; each setting is compiled ahead of time (compile time
reported apart) and then timed over ``--steps`` motion steps from the reset state, ``--repeats``
times, alternating the two models (A B A B ...) so that a change of the machine's load falls on
both. Robot-steps count only steps in which a robot was still running.

  python experiments/bench_slam.py --quick                    # smoke run
  python experiments/bench_slam.py                            # office and lab, 64 and 256 robots
  python experiments/bench_slam.py --robots 1024,4096         # on a GPU

The table is printed and written to ``experiments/results/bench_slam_<device>.md`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import driver, sim
from jaxplore.resolve import resolve
from jaxplore.runspec import RunSpec

HERE = Path(__file__).resolve().parent
MODELS = ("oracle", "scan_matching")


def _ints(text: str) -> list[int]:
  return [int(v) for v in text.split(",") if v.strip()]


def parse_args(argv=None):
  p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--worlds", default="office,lab", help="built-in worlds, comma separated")
  p.add_argument("--robots", type=_ints, default=[64, 256], help="batch sizes (default 64,256)")
  p.add_argument("--steps", type=int, default=256, help="motion steps timed per repeat")
  p.add_argument("--chunk-steps", type=int, default=64, help="motion steps per compiled call")
  p.add_argument("--repeats", type=int, default=2, help="timed repeats per model (alternating)")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--quick", action="store_true", help="lab, 8 robots, 64 steps, 1 repeat")
  p.add_argument("--out", default=None, help="markdown file")
  args = p.parse_args(argv)
  if args.quick:
    args.worlds, args.robots, args.steps, args.repeats = "lab", [8], 64, 1
  return args


def prepare(world: str, model: str, robots: int, steps: int, seed: int):
  resolved = resolve(RunSpec.create(world=world, planner="nearest_frontier", robots=robots,
                                    seed=seed, slam=model, pose_noise=True, max_steps=steps + 64))
  return resolved


def time_model(cache, world_name, model, robots, args):
  resolved = prepare(world_name, model, robots, args.steps, args.seed)
  config, world = resolved.config, resolved.world
  params = sim.broadcast_params(resolved.params, robots)
  keys = jax.random.split(jax.random.PRNGKey(args.seed), robots)
  state = jax.block_until_ready(sim.reset_batch(config, world, params, keys, None))
  before = int(np.asarray(state.steps).sum())
  epochs = max(1, args.chunk_steps // config.replan_every)
  n_chunks = max(1, -(-args.steps // (epochs * config.replan_every)))
  key = (config, epochs, robots)
  compile_s = None
  if key not in cache:
    t0 = time.perf_counter()
    cache[key] = driver.compiled_advance(config, epochs, 1).lower(world, params, state).compile()
    compile_s = time.perf_counter() - t0
  compiled = cache[key]
  t0 = time.perf_counter()
  for _ in range(n_chunks):
    state, records = compiled(world, params, state)
    jax.block_until_ready((state, records))
  run_s = time.perf_counter() - t0
  robot_steps = int(np.asarray(state.steps).sum()) - before
  out = dict(world=world_name, model=model, robots=robots, compile_s=compile_s, run_s=run_s,
             rate=robot_steps / run_s,
             pose_error=float(np.mean(np.asarray(records.pose_error)[-1])))
  if model == "scan_matching":
    g = state.graph
    out["keyframes"] = float(np.mean(np.asarray(g.n_nodes)))
    loops = np.arange(np.asarray(g.loop_link).shape[-1]) < np.asarray(g.n_loops)[:, None]
    out["closures"] = float(np.mean(np.sum(loops & ~np.asarray(g.loop_link), axis=1)))
    out["near_links"] = float(np.mean(np.sum(np.asarray(g.loop_link), axis=1)))
    out["revoked"] = float(np.mean(np.sum(np.asarray(g.loop_revoked), axis=1)))
  return out


def main(argv=None):
  args = parse_args(argv)
  device = jax.devices()[0]
  cache: dict = {}
  rows = []
  started = time.time()
  for world in args.worlds.split(","):
    for robots in args.robots:
      runs = {m: [] for m in MODELS}
      for _ in range(args.repeats):
        for model in MODELS:
          r = time_model(cache, world, model, robots, args)
          runs[model].append(r)
          print(f"{world} {robots:5d} {model:14s} {r['rate']:9.1f} robot-steps/s "
                f"(compile {r['compile_s'] or 0:.1f} s, run {r['run_s']:.2f} s)", flush=True)
      best = {m: max(runs[m], key=lambda r: r["rate"]) for m in MODELS}
      compile_s = {m: next(r["compile_s"] for r in runs[m] if r["compile_s"] is not None)
                   for m in MODELS}
      rows.append(dict(world=world, robots=robots, oracle=best["oracle"]["rate"],
                       scan=best["scan_matching"]["rate"],
                       ratio=best["scan_matching"]["rate"] / best["oracle"]["rate"],
                       compile_oracle=compile_s["oracle"], compile_scan=compile_s["scan_matching"],
                       keyframes=best["scan_matching"]["keyframes"],
                       closures=best["scan_matching"]["closures"],
                       err_oracle=best["oracle"]["pose_error"],
                       err_scan=best["scan_matching"]["pose_error"]))
  kind = device.platform
  lines = [
      f"# SLAM model cost: scan_matching vs oracle ({device.device_kind}, {kind})", "",
      f"`python experiments/bench_slam.py {' '.join(argv or []) if argv else ''}`".replace(" `", "`"),
      "",
      f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
      f"jax {jax.__version__}; nearest frontier, {args.steps} motion steps from the reset state "
      f"in chunks of {args.chunk_steps}, best of {args.repeats} alternating repeats; "
      f"wall {time.time() - started:.0f} s.", "",
      "| world | robots | oracle robot-steps/s | scan_matching robot-steps/s | ratio | "
      "compile oracle / scan_matching (s) | keyframes | closures | pose error oracle / "
      "scan_matching (m) |",
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
  for r in rows:
    lines.append(f"| {r['world']} | {r['robots']} | {r['oracle']:.0f} | {r['scan']:.0f} | "
                 f"{r['ratio']:.2f} | {r['compile_oracle']:.1f} / {r['compile_scan']:.1f} | "
                 f"{r['keyframes']:.0f} | {r['closures']:.2f} | {r['err_oracle']:.4f} / "
                 f"{r['err_scan']:.4f} |")
  text = "\n".join(lines) + "\n"
  print(text)
  out = Path(args.out) if args.out else HERE / "results" / f"bench_slam_{kind}.md"
  if not args.quick or args.out:
    out.write_text(text)
    print(f"wrote {out}")


if __name__ == "__main__":
  main()
