"""Benchmark: candidate changes to the lockstep strategy, A/B against the engine as it is.

Each candidate is a setting of the code it measures, passed in for a run forced to the
``lockstep`` strategy, in a child process of its own: a field of
:class:`jaxplore.config.SimConfig` (the engine's tuning choices, ``lockstep_*`` and
``observation_dtype``), li2020's plan function given another ``visible_sums``
(``li2020.plan_li2020``), or XLA flags. No module of the package is patched. Two candidates won
on one H100 and are now the engine's defaults
(``experiments/results/bench_lockstep_variants_gpu.md``: ``tile_loop``, ``fixed_chunks``); two
more landed on a CPU's evidence alone (lockstep forced: they can only shrink what a round
computes, and are bit for bit: ``coarse_ladder``, ``fixed_leftovers``). Their variants here
undo them, so a GPU can check the win:

- ``tile_loop`` (``lockstep_whole_grid_update=False``): ``mapping.integrate_observation`` as a
  loop over the observed tiles (the ``per_robot`` update) instead of the whole grid at once. On
  a GPU a loop step is a chain of small kernels, batched over robots by gathers and scatters:
  the whole-grid update ran 1.4-2.2x the robot-steps/s on ``office`` (1,024-16,384 robots). The
  log-odds and coverage are the same bit for bit; the map-entropy change is summed in another
  order, so the ``entropy`` metric differs in its last bits (compared to 1e-5 relative).
- ``fixed_chunks`` (``lockstep_small_chunks=()``): a planning round without a window always in
  chunks of ``planning.lockstep_plan_chunk`` (at least ``lockstep_min_chunk``, 64), never the
  smaller chunk of 4 or 16 that holds every robot needing a plan. li2020 plans only when its
  path is done (1 robot of 64 at a typical step on ``lab``): chunks by need ran 1.5-1.6x the
  robot-steps/s on ``lab``, at twice the compile time. Bit for bit.
- ``coarse_ladder`` (``lockstep_small_chunks=(4, 16)``): the chunks by need only 4 and 16 below
  the round's own chunk (``planning.lockstep_plan_chunk``: 128 at 1,024 robots, 512 at 4,096),
  as before the ladder of factor 4 (4, 16, 64, 256, ...). li2020 on ``lab`` needs ~8-28 plans
  at a step of 1,024 robots, ~30-110 of 4,096: the coarse ladder plans them in the round's
  chunk. Forced lockstep on a 2-core CPU (one host device, 1,024 robots, steps 17-32): 358 ->
  471 robot-steps/s with the ladder, at 22.5 -> 28.6 s compile. On one H100 (1,024 robots) no
  gain: 5,151 coarse against 4,975 / 5,083 with the ladder, compile 42 s against 54-60 s; not
  timed at 4,096, where it may differ (``gpu_benchmarks.sh ladder``). Bit for bit.
- ``fixed_leftovers`` (``lockstep_leftovers_by_need=False``): the whole-grid round after a
  windowed one (the few plans the window could not certify: nearest frontier on ``office``)
  always in chunks of ``lockstep_min_chunk``, as before it took the smallest chunk by need as
  the planners without a window do. Lockstep forced on a 2-core CPU (office, 1,024 robots, 64
  steps, one device): 1,797 robot-steps/s by need against 1,247 and 1,276 (head before it,
  alternated), compile 13.6 s against 8.3-8.7. On one H100 (4,096 robots) 169,404 against
  179,293 / 165,256 for head: within the drift. Bit for bit.

Candidates still open or dropped:

- ``obs32`` (``observation_dtype="int32"``): the observation buffer
  (``sensor.empty_observation``) in int32 instead of int8 (a GPU scatters single bytes by a
  compare-and-swap loop, whole words natively). Bit for bit; 0.78-0.86x on an H100, and it took
  the whole-grid gain away.
- ``chunk16``, ``chunk4`` (``lockstep_min_chunk=16`` or 4): the lockstep planning chunk at least
  16 or 4 robots instead of 64 (windowed rounds included). Bit for bit (a chunk's size never
  changes a plan). ``chunk4`` on ``lab``: 0.99x (64 robots), 1.13x (256).
- ``visible_by_depth`` (li2020 only): li2020's ``"visible"`` region with its gains walked a
  whole depth of the sight-line tree at a time (``experiments/visible_by_depth.py``, passed as
  ``plan_li2020(..., visible_sums=...)``): 185 loop steps for ``lab``'s R_e of 57 cells instead
  of ~1,950, each a few gathers over [64, H, W]. The gains are the package's up to float
  summation order (relative 2e-6 on random grids), so a plan whose best candidates tie to the
  last bits may differ and the final state with it. On a CPU its gathers make it ~15x slower
  (4.4 s against 0.30 s for 4 robots); not yet timed on a GPU. A depth at once with the groups
  apart was slower on an H200 at 256 robots (its windows materialised); the chunks of 4 and 16
  that most li2020 rounds now take are where this one may win. Since 09638b5 li2020's default
  region is ``"beams"``, which these sums do not replace (the patch this variant was before
  changed nothing there), so it runs the ``"visible"`` region and its final state is compared
  with the ``visible`` variant's (the package's sums of that region), not head's: run the two
  together, ``--setting lab --variants visible,visible_by_depth``.
- CUDA graphs for loops (``--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL``) gave wrong
  results on an H100 with JAX 0.11.2 (every leaf of the final state differed; at 1,024 robots
  the loops did not run): not a variant any more, and not a flag to set for jaxplore.

Every (batch, variant) runs in its own process, alternated as head, the variants, head again,
so a drift of the machine shows; each times ``bench_accelerator.time_setting`` (the same steps
from the same reset, compile apart) and saves its final state, which the parent compares with
the first head run's.

  python experiments/bench_lockstep_variants.py                        # office, 1024 and 4096
  python experiments/bench_lockstep_variants.py --robots 8 --steps 32  # a quick CPU check
  # the smallest check that the script runs (office, 4 robots, 8 steps):
  python experiments/bench_lockstep_variants.py --robots 4 --steps 8 --chunk-steps 8 \
    --variants tile_loop,fixed_chunks,coarse_ladder,fixed_leftovers,obs32,chunk4 --out /tmp/v.md

Rows are written as they finish to ``experiments/results/bench_lockstep_variants_<backend>.md``
(``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
VARIANTS = {  # name: (SimConfig fields changed, li2020's region sums, XLA flags added)
    "head": ({}, None, ""),
    "tile_loop": ({"lockstep_whole_grid_update": False}, None, ""),
    "fixed_chunks": ({"lockstep_small_chunks": ()}, None, ""),
    "coarse_ladder": ({"lockstep_small_chunks": (4, 16)}, None, ""),
    "fixed_leftovers": ({"lockstep_leftovers_by_need": False}, None, ""),
    "obs32": ({"observation_dtype": "int32"}, None, ""),
    "chunk16": ({"lockstep_min_chunk": 16}, None, ""),
    "chunk4": ({"lockstep_min_chunk": 4}, None, ""),
    "visible": ({}, "visible", ""),
    "visible_by_depth": ({}, "visible_by_depth", ""),
}
# The variant whose final state a variant's is compared with, where it is not head's.
COMPARED_WITH = {"visible_by_depth": "visible"}
# Leaves that may differ by float summation order, with the relative tolerance they are held to.
TOLERANT = {".entropy": 1e-5}


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  add = parser.add_argument
  add("--setting", default="office", help="a setting of bench_accelerator.py")
  add("--robots", default="1024,4096", help="comma separated batch sizes")
  add("--variants", default="tile_loop,fixed_leftovers",
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


def _visible_by_depth(gains, occupied, radius, block=1):
  """``li2020.visible_gains``' signature, the sums of ``visible_by_depth.py`` (its own rows per
  loop step, whatever the strategy's ``block``)."""
  from visible_by_depth import visible_gains_by_depth
  return visible_gains_by_depth(gains, occupied, radius)


def adjust(variant: str):
  """The function of a resolved ``SimConfig`` that runs ``variant``: its fields replaced, and
  for the li2020 variants the planner's region (``"visible"``) and its sums."""
  fields, sums, _ = VARIANTS[variant]

  def adjusted(config):
    config = dataclasses.replace(config, **fields)
    if sums is None:
      return config
    from jaxplore.planners import li2020
    if config.planner.name != "li2020":
      raise SystemExit(f"variant {variant} is li2020's; this setting plans with "
                       f"{config.planner.name}")
    planner = config.planner.with_settings(region="visible")
    if sums == "visible_by_depth":
      planner = dataclasses.replace(planner, plan=functools.partial(
          li2020.plan_li2020, visible_sums=_visible_by_depth))
    return dataclasses.replace(config, planner=planner)

  return adjusted


def child(args) -> None:
  """One (variant, batch): time it, save the final state, print the row as JSON."""
  sys.path.insert(0, str(HERE.parent))
  sys.path.insert(0, str(HERE))
  import bench_accelerator
  import jax
  import numpy as np

  grid = bench_accelerator.load_grid(args.setting, args.explore_bench
                                     or bench_accelerator.EXPLORE_BENCH)
  keep = {}
  row = bench_accelerator.time_setting(grid, args.setting, "lockstep", int(args.robots), args,
                                       keep, adjust(args.child))
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
    references: dict[str, Path] = {}  # variant: its first final state
    for variant in ["head", *variants, "head"]:
      state_out = scratch / f"{robots}_{variant}_{1 if variant in references else 0}.npz"
      command = [sys.executable, __file__, "--child", variant, "--robots", robots,
                 "--setting", args.setting, "--steps", str(args.steps),
                 "--chunk-steps", str(args.chunk_steps), "--seed", str(args.seed),
                 *(["--devices", str(args.devices)] if args.devices else []),
                 "--state-out", str(state_out)]
      if args.explore_bench:
        command += ["--explore-bench", args.explore_bench]
      env = dict(os.environ)
      env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {VARIANTS[variant][2]}".strip()
      done = subprocess.run(command, capture_output=True, text=True, env=env)
      rows = [line[4:] for line in done.stdout.splitlines() if line.startswith("ROW ")]
      if done.returncode or not rows:
        line = f"| {robots} | {variant} | | | | failed: {done.stderr.strip()[-300:]!r} |"
      else:
        row = json.loads(rows[-1])
        if "rate" not in row:
          line = f"| {robots} | {variant} | | | | {row.get('note', '')} |"
        else:
          against = COMPARED_WITH.get(variant, "head")
          if "head" not in references:
            verdict = "(the reference)"
          elif against not in references:
            verdict = f"(no {against} run to compare with)"
          else:
            verdict = compare(references[against], state_out)
            verdict = verdict if against == "head" else f"against {against}: {verdict}"
          references.setdefault(variant, state_out)
          per_chunk = " / ".join(f"{r:,.0f}" for r in row["chunk_rates"])
          line = (f"| {robots} | {variant} | {row['compile_s']:.1f} | {row['rate']:,.0f} "
                  f"| {per_chunk} | {verdict} |")
      results.add(line)
  results.close()


if __name__ == "__main__":
  ARGS = _parse_args()
  child(ARGS) if ARGS.child else main(ARGS)
