"""Benchmark: robot-steps per second and compile time by batch size, on whatever devices JAX has.

For each setting (``office`` with nearest frontier and the ``li2020`` preset, the main job's;
``lab`` with ``li2020``; an Explore-Bench blueprint with nearest frontier and the
``explore_bench`` preset, one planning round per step), each execution strategy
(``SimConfig.strategy``: ``per_robot``, ``lockstep``) and each batch size, the script resolves
the batch (random starts from the world's start area), resets it, compiles one chunk of
``--chunk-steps`` motion steps ahead of time (``driver.compile_advance``, sharded over
``--devices`` local devices), and times ``--steps`` motion steps from the reset state, every
chunk up to ``block_until_ready``. Robot-steps count only robots still running.

A batch is skipped when the memory guard says it does not fit (``jaxplore.memory``: 80 % of the
free memory of one device on a GPU or TPU, of the host on a CPU), or when the same strategy's
smaller batch projects a run longer than ``--budget-s`` seconds.

  python experiments/bench_accelerator.py                          # 64, 1024, 4096, 16384 robots
  python experiments/bench_accelerator.py --robots 64,256 --steps 64   # a quick CPU run

Rows are printed and written as they finish to ``experiments/results/bench_accelerator_<backend>.md``
(``--out``), with the device, JAX version and load, so a run cut short keeps what it measured.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
EXPLORE_BENCH = HERE.parent.parent / "shared" / "maps" / "explore_bench"
SETTINGS = {  # label: (world, planner, preset)
    "office": ("office", "nearest_frontier", "li2020"),
    "lab": ("lab", "li2020", "li2020"),
    "eb:room": ("eb:room", "nearest_frontier", "explore_bench"),
}


def _int_list(text: str) -> list[int]:
  return [int(v) for v in text.split(",") if v.strip()]


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  add = parser.add_argument
  add("--robots", type=_int_list, default=[64, 1024, 4096, 16384], help="batch sizes")
  add("--settings", default=",".join(SETTINGS), help=f"comma separated, of {', '.join(SETTINGS)}")
  add("--strategies", default="per_robot,lockstep", help="comma separated: per_robot, lockstep")
  add("--steps", type=int, default=96, help="motion steps timed from the reset state")
  add("--chunk-steps", type=int, default=32, help="motion steps per compiled chunk")
  add("--devices", type=int, default=None, help="local devices to shard over (default: all)")
  add("--host-devices", type=int, default=None,
      help="on a CPU, expose this many host devices (XLA:CPU runs a loop on one core per device)")
  add("--budget-s", type=float, default=300.0,
      help="skip a batch whose run the same strategy's smaller batch projects longer than this")
  add("--seed", type=int, default=0)
  add("--out", default=None, help="markdown file (default results/bench_accelerator_<backend>.md)")
  add("--explore-bench", default=str(EXPLORE_BENCH),
      help="folder of the Explore-Bench map files (default: ../shared/maps/explore_bench)")
  return parser.parse_args(argv)


ARGS = _parse_args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.host_devices:
  # Before JAX starts: the host device count is fixed when the CPU backend is created.
  os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                             + f" --xla_force_host_platform_device_count={ARGS.host_devices}")

import jax  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(HERE.parent))
from jaxplore import driver, memory  # noqa: E402
from jaxplore.maps import load_world  # noqa: E402
from jaxplore.maps.io import load_map  # noqa: E402
from jaxplore.resolve import resolve  # noqa: E402
from jaxplore.runspec import RunSpec  # noqa: E402


def load_grid(label: str, explore_bench=EXPLORE_BENCH):
  world = SETTINGS[label][0]
  if world.startswith("eb:"):
    return load_map(Path(explore_bench) / f"{world[3:]}.yaml")
  return load_world(world)


def device_description() -> str:
  devices = jax.local_devices()
  kinds = sorted({d.device_kind for d in devices})
  return f"{len(devices)} x {', '.join(kinds)} ({jax.default_backend()})"


def _cpu_name() -> str:
  try:
    with open("/proc/cpuinfo") as f:
      return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
  except (OSError, StopIteration):
    return platform.processor() or "unknown CPU"


def _load() -> str:
  try:
    with open("/proc/loadavg") as f:
      return f.read().split()[0]
  except OSError:
    return "?"


class ResultsFile:
  """A markdown results file written as rows finish (a run cut short keeps what it measured):
  a heading naming the command, the devices, the host and its load, then one table."""

  def __init__(self, out: Path, script: str, title: str, timed: str, header: str):
    self.out = out
    out.parent.mkdir(parents=True, exist_ok=True)
    command = " ".join([f"python experiments/{script}", *sys.argv[1:]])
    lines = [f"# {title}", "", f"Command: `{command}`  ",
             f"Devices: {device_description()}; host: {_cpu_name()}, {os.cpu_count()} cores; "
             f"jax {jax.__version__}, Python {platform.python_version()}; 1-minute load average "
             f"{_load()} at the start.  ", f"Timed: {timed}", "", header]
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)

  def add(self, line: str) -> None:
    print(line, flush=True)
    with self.out.open("a") as f:
      f.write(line + "\n")

  def close(self) -> None:
    with self.out.open("a") as f:
      f.write(f"\n1-minute load average at the end: {_load()}.\n")
    print(f"wrote {self.out}")


def peak_device_bytes() -> int | None:
  stats = jax.local_devices()[0].memory_stats() or {}
  return stats.get("peak_bytes_in_use")


def time_setting(grid, label: str, strategy: str, robots: int, args, keep: dict | None = None,
                 adjust=None) -> dict:
  """Resolve, reset, compile and time one (setting, strategy, batch); one result row (and the
  final state in ``keep["state"]``, when ``keep`` is given). ``adjust``: a function of the
  resolved :class:`jaxplore.config.SimConfig` returning the one to run (a variant of the engine's
  settings, ``bench_lockstep_variants.py``), or None."""
  _, planner, preset = SETTINGS[label]
  steps = args.steps
  spec = RunSpec(world=grid, planner=planner, robots=robots, seed=args.seed, preset=preset,
                 max_steps=steps + 4 * args.chunk_steps, strategy=strategy)
  resolved = resolve(spec)
  config = resolved.config if adjust is None else adjust(resolved.config)
  n_dev = driver.shard_count(robots, driver.local_devices(args.devices))
  row = dict(setting=label, planner=planner, grid=f"{config.height}x{config.width}",
             strategy=config.strategy, robots=robots, devices=n_dev)
  per_device = -(-robots // n_dev) if jax.default_backend() != "cpu" else robots
  need, have = memory.estimate_bytes(config, per_device), memory.available_bytes()
  if need > memory.MEMORY_FRACTION * have:
    return dict(row, note=f"skipped: needs ~{need / 2**30:.1f} GiB of {have / 2**30:.1f} GiB free")
  batch = resolved.batch()
  t0 = time.perf_counter()
  state = driver.reset(config, resolved.world, batch)
  reset_s = time.perf_counter() - t0
  chunk_epochs = max(1, args.chunk_steps // config.replan_every)
  t0 = time.perf_counter()
  compiled = driver.compile_advance(config, chunk_epochs, n_dev, resolved.world, batch.params,
                                    state)
  compile_s = time.perf_counter() - t0
  world, params, state = jax.device_put((resolved.world, batch.params, state),
                                        compiled.input_shardings[0])
  steps_before = int(np.asarray(state.steps).sum())
  chunk_rates, t_all, done_steps = [], 0.0, 0
  while done_steps < steps:
    before = int(np.asarray(state.steps).sum())
    t0 = time.perf_counter()
    state, records = compiled(world, params, state)
    jax.block_until_ready((state, records))
    dt = time.perf_counter() - t0
    t_all += dt
    done_steps += chunk_epochs * config.replan_every
    chunk_rates.append((int(np.asarray(state.steps).sum()) - before) / dt)
  robot_steps = int(np.asarray(state.steps).sum()) - steps_before
  if keep is not None:
    keep["state"] = state
  return dict(row, reset_s=reset_s, compile_s=compile_s, run_s=t_all, steps=done_steps,
              robot_steps=robot_steps, rate=robot_steps / t_all,
              chunk_rates=chunk_rates, done=int(np.asarray(state.done).sum()),
              coverage=float(np.asarray(records.coverage)[-1].mean()),
              peak_gib=(peak_device_bytes() or 0) / 2**30, estimate_gib=need / 2**30)


HEADER = ("| setting | planner | grid | strategy | robots | devices | reset s | compile s | run s "
          "| steps | robot-steps/s | per chunk | done | coverage | peak GiB (guard's estimate) | note |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def format_row(row: dict) -> str:
  if "rate" not in row:
    return (f"| {row['setting']} | {row['planner']} | {row['grid']} | {row['strategy']} "
            f"| {row['robots']} | {row['devices']} | | | | | | | | | | {row['note']} |")
  per_chunk = " / ".join(f"{r:,.0f}" for r in row["chunk_rates"])
  return (f"| {row['setting']} | {row['planner']} | {row['grid']} | {row['strategy']} "
          f"| {row['robots']} | {row['devices']} | {row['reset_s']:.1f} | {row['compile_s']:.1f} "
          f"| {row['run_s']:.1f} | {row['steps']} | {row['rate']:,.0f} | {per_chunk} "
          f"| {row['done']} | {row['coverage']:.3f} | {_peak(row)} | {row.get('note', '')} |")


def _peak(row: dict) -> str:
  """The device's peak memory (none on a CPU) and the memory guard's estimate, in GiB."""
  peak = f"{row['peak_gib']:.1f}" if row.get("peak_gib") else "n/a"
  return f"{peak} ({row['estimate_gib']:.1f})"


def main(args):
  backend = jax.default_backend()
  results = ResultsFile(
      Path(args.out or HERE / "results" / f"bench_accelerator_{backend}.md"),
      "bench_accelerator.py",
      "Robot-steps per second and compile time by batch size and execution strategy",
      f"{args.steps} motion steps from the reset state in chunks of {args.chunk_steps} "
      "(compiled ahead of time; compile and reset reported apart); robot-steps/s counts running "
      "robots only; 'per chunk' gives each chunk's rate in order. Random starts from each "
      f"world's start area (seed {args.seed}).", HEADER)
  for label in args.settings.split(","):
    grid = load_grid(label, args.explore_bench)
    for strategy in args.strategies.split(","):
      last = None
      for robots in args.robots:
        if last is not None and "run_s" in last:
          projected = last["run_s"] * robots / last["robots"]
          if projected > args.budget_s:
            results.add(format_row(dict(
                setting=label, planner=SETTINGS[label][1], grid="x".join(map(str, grid.shape)),
                strategy=strategy, robots=robots, devices="",
                note=f"skipped: projected {projected:.0f} s > --budget-s {args.budget_s:g}")))
            continue
        last = time_setting(grid, label, strategy, robots, args)
        results.add(format_row(last))
  results.close()


if __name__ == "__main__":
  main(ARGS)
