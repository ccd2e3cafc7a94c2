"""Benchmark: candidate changes to the lockstep strategy, A/B against the engine as it is.

At 4,096 robots on ``office`` a lockstep step on one H200 took ~41 ms, 31 of them the motion
step, led by the belief update (a loop over the observed tiles, ~8 ms) and the marking of the
cells a scan saw (~8 ms) (README, "What is still slow on a GPU"). Each candidate below replaces
one engine function, in a child process of its own, for a run forced to the ``lockstep``
strategy (or adds XLA flags to it); nothing in the package changes until a candidate has won
on a GPU:

- ``whole_grid``: ``mapping.integrate_observation`` updates each robot's whole grid in one set
  of kernels instead of a loop over the observed tiles (on a GPU a loop step is a chain of small
  kernels, batched over robots by gathers and scatters). The log-odds and the coverage are the
  same bit for bit; the map-entropy change is summed over the whole grid instead of tile by
  tile, so the ``entropy`` metric differs in its last bits (compared to 1e-5 relative).
- ``obs32``: the observation buffer (``sensor.empty_observation``) in int32 instead of int8 (a
  GPU scatters single bytes by a compare-and-swap loop, whole words natively). Bit for bit.
- ``both``: the two together.
- ``graphs``: no code change; XLA:GPU records loops and conditionals into CUDA graphs
  (``--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL``), so a loop's predicate is read on
  the device instead of copied to the host every iteration: the hypothesis for li2020's visible
  gains, whose ~1,300 loop steps per call cost ~110 ms at 4 robots, far above their work.
- ``chunk16``, ``chunk4``: the lockstep planning chunk at least 16 or 4 robots instead of
  ``planning.LOCKSTEP_PLAN_CHUNK`` = 64. li2020 plans only when its path is done (1 robot of 64
  at a typical step on ``lab``) and pays for the whole chunk of 64 (copies of that robot);
  a smaller chunk costs less per call but needs more calls when many robots plan. Bit for bit
  (a chunk's size never changes a plan).
- ``by_need``: each planning round picks its chunk by how many robots need a plan: one chunk
  of 4 or 16 when that holds them all, else the engine's chunks (``lax.switch``; the planner is
  compiled once per size). Never more calls than the engine's, each no larger.

Every (batch, variant) runs in its own process, alternated as head, the variants, head again,
so a drift of the machine shows; each times ``bench_accelerator.time_setting`` (the same steps
from the same reset, compile apart) and saves its final state, which the parent compares with
the first head run's.

  python experiments/bench_lockstep_variants.py                        # office, 1024 and 4096
  python experiments/bench_lockstep_variants.py --robots 8 --steps 32  # a quick CPU check

Rows are written as they finish to ``experiments/results/bench_lockstep_variants_<backend>.md``
(``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
VARIANTS = {  # name: (engine functions replaced, XLA flags added)
    "head": ((), ""),
    "whole_grid": (("whole_grid",), ""),
    "obs32": (("obs32",), ""),
    "both": (("whole_grid", "obs32"), ""),
    "graphs": ((), "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL"),
    "chunk16": (("chunk16",), ""),
    "chunk4": (("chunk4",), ""),
    "by_need": (("by_need",), ""),
}
# Leaves that may differ by float summation order, with the relative tolerance they are held to.
TOLERANT = {".entropy": 1e-5}


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  add = parser.add_argument
  add("--setting", default="office", help="a setting of bench_accelerator.py")
  add("--robots", default="1024,4096", help="comma separated batch sizes")
  add("--variants", default="whole_grid,obs32,both,graphs",
      help=f"comma separated, of {', '.join(list(VARIANTS)[1:])}")
  add("--steps", type=int, default=96)
  add("--chunk-steps", type=int, default=32)
  add("--seed", type=int, default=0)
  add("--out", default=None)
  add("--devices", type=int, default=None, help="local devices to shard over (default: all)")
  add("--explore-bench", default=None, help="as bench_accelerator.py's")
  add("--child", default=None, help=argparse.SUPPRESS)
  add("--state-out", default=None, help=argparse.SUPPRESS)
  return parser.parse_args(argv)


def integrate_observation_whole_grid(logodds, robot, observed, reachable, params, after=0.0):
  """``mapping.integrate_observation`` on the robot's whole grid at once (no tile loop)."""
  import jax
  import jax.numpy as jnp

  from jaxplore import mapping, sensor

  grid = sensor.grid_of_tiles(observed, logodds.shape[1:])
  old = jax.lax.dynamic_index_in_dim(logodds, robot, 0, keepdims=False)
  new = mapping.update_logodds(old, grid, params)
  d_entropy = jnp.sum(mapping.entropy_of_logodds(new) - mapping.entropy_of_logodds(old))
  threshold = mapping.logit(params.p_free)
  d_covered = (jnp.sum(reachable & (new < threshold)).astype(jnp.int32)
               - jnp.sum(reachable & (old < threshold)).astype(jnp.int32))
  new = mapping._after(new, after, d_entropy, d_covered)
  return jax.lax.dynamic_update_index_in_dim(logodds, new, robot, 0), d_entropy, d_covered


def _patch(variant: str) -> None:
  import jax.numpy as jnp

  from jaxplore import mapping, planning, sensor

  patches = VARIANTS[variant][0]
  if "whole_grid" in patches:
    mapping.integrate_observation = integrate_observation_whole_grid
  if "obs32" in patches:
    empty = sensor.empty_observation
    sensor.empty_observation = lambda shape: empty(shape).astype(jnp.int32)
  for chunk in (16, 4):
    if f"chunk{chunk}" in patches:
      planning.LOCKSTEP_PLAN_CHUNK = chunk
  if "by_need" in patches:
    planning._plan_robots = _plan_robots_by_need(planning._plan_robots)


def _plan_robots_by_need(plan_robots, smaller=(4, 16)):
  """``planning._plan_robots`` planning in the smallest of ``smaller`` + (chunk,) chunks that
  holds every robot that needs a plan in one, else in ``chunk``-sized chunks as before."""
  import jax
  import jax.numpy as jnp

  def by_need(config, world, params, state, need, window, chunk):
    sizes = sorted({size for size in smaller if size < min(chunk, need.shape[0])} | {chunk})
    if len(sizes) == 1:
      return plan_robots(config, world, params, state, need, window, chunk)
    n_need = jnp.sum(need.astype(jnp.int32))
    branch = sum((n_need > size).astype(jnp.int32) for size in sizes[:-1])
    rounds = [lambda s, size=size: plan_robots(config, world, params, s, need, window, size)
              for size in sizes]
    return jax.lax.switch(branch, rounds, state)

  return by_need


def child(args) -> None:
  """One (variant, batch): patch, time, save the final state, print the row as JSON."""
  sys.path.insert(0, str(HERE.parent))
  sys.path.insert(0, str(HERE))
  _patch(args.child)
  import bench_accelerator
  import jax
  import numpy as np

  grid = bench_accelerator.load_grid(args.setting, args.explore_bench
                                     or bench_accelerator.EXPLORE_BENCH)
  keep = {}
  row = bench_accelerator.time_setting(grid, args.setting, "lockstep", int(args.robots), args,
                                       keep)
  if "state" in keep:
    leaves = jax.tree_util.tree_flatten_with_path(keep["state"])[0]
    np.savez(args.state_out, **{jax.tree_util.keystr(path): np.asarray(leaf)
                                for path, leaf in leaves})
  print("ROW " + json.dumps({k: v for k, v in row.items()}), flush=True)


def compare(reference: str, other: str) -> str:
  """'bit for bit', or what differs between two saved final states."""
  import numpy as np

  a, b = np.load(reference), np.load(other)
  differ = []
  for name in a.files:
    x, y = a[name], b[name]
    if name in TOLERANT:
      if not np.allclose(x, y, rtol=TOLERANT[name], atol=0):
        differ.append(f"{name} beyond {TOLERANT[name]:g}")
      elif not np.array_equal(x, y):
        differ.append(f"{name} within {TOLERANT[name]:g} (max rel "
                      f"{np.max(np.abs(x - y) / np.maximum(np.abs(x), 1e-30)):.1e})")
    elif not np.array_equal(x, y, equal_nan=True):
      differ.append(f"{name} DIFFERS")
  return "bit for bit" if not differ else "; ".join(differ)


def main(args) -> None:
  sys.path.insert(0, str(HERE.parent))
  sys.path.insert(0, str(HERE))
  import jax

  from bench_accelerator import ResultsFile

  variants = [v for v in args.variants.split(",") if v]
  unknown = set(variants) - set(VARIANTS)
  if unknown:
    raise SystemExit(f"unknown variants {sorted(unknown)}; known: {', '.join(VARIANTS)}")
  results = ResultsFile(
      Path(args.out or HERE / "results" / f"bench_lockstep_variants_{jax.default_backend()}.md"),
      "bench_lockstep_variants.py", "Lockstep candidates against the engine as it is",
      f"{args.steps} motion steps from the reset state in chunks of {args.chunk_steps}, "
      "lockstep, each row its own process (compile apart).",
      "| robots | variant | compile s | robot-steps/s | per chunk | final state against head |\n"
      "|---|---|---|---|---|---|")
  scratch = Path(tempfile.mkdtemp(prefix="lockstep_variants_"))
  for robots in args.robots.split(","):
    reference = None
    for variant in ["head", *variants, "head"]:
      state_out = scratch / f"{robots}_{variant}_{0 if reference is None else 1}.npz"
      command = [sys.executable, __file__, "--child", variant, "--robots", robots,
                 "--setting", args.setting, "--steps", str(args.steps),
                 "--chunk-steps", str(args.chunk_steps), "--seed", str(args.seed),
                 *(["--devices", str(args.devices)] if args.devices else []),
                 "--state-out", str(state_out)]
      if args.explore_bench:
        command += ["--explore-bench", args.explore_bench]
      env = dict(os.environ)
      env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {VARIANTS[variant][1]}".strip()
      done = subprocess.run(command, capture_output=True, text=True, env=env)
      rows = [line[4:] for line in done.stdout.splitlines() if line.startswith("ROW ")]
      if done.returncode or not rows:
        line = f"| {robots} | {variant} | | | | failed: {done.stderr.strip()[-300:]!r} |"
      else:
        row = json.loads(rows[-1])
        if "rate" not in row:
          line = f"| {robots} | {variant} | | | | {row.get('note', '')} |"
        else:
          if reference is None:
            reference, verdict = state_out, "(the reference)"
          else:
            verdict = compare(reference, state_out)
          per_chunk = " / ".join(f"{r:,.0f}" for r in row["chunk_rates"])
          line = (f"| {robots} | {variant} | {row['compile_s']:.1f} | {row['rate']:,.0f} "
                  f"| {per_chunk} | {verdict} |")
      results.add(line)
  results.close()


if __name__ == "__main__":
  ARGS = _parse_args()
  child(ARGS) if ARGS.child else main(ARGS)
