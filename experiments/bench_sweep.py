"""Benchmark: robot-episodes per hour of a 256-setting α × k1 × k2 sweep run as one ``jaxplore.sweep``
versus the same settings run one at a time through ``jaxplore.run``, side by side in one process.

* **sweep**: ``jaxplore.sweep`` over alpha (4 values) × k1 (8) × k2 (8) = 256 settings × 1 seed,
  ``li2020`` planner, on a small world (``lab`` at 0.2 m/cell: 85 × 65 cells), every episode to
  completion or a budget of 400 steps (``--max-steps``). Measured whole, twice: cold (trace,
  compile, run) and warm (every program cached), so first-call costs and run time come apart.
* **one at a time**: ``--singles`` settings spread over the grid (default 4; different alpha values,
  so different static configs) each run as ``jaxplore.run(robots=1)``, cold then warm; the other
  settings are **extrapolated** from them: in one Python process a static config compiles once and is then
  cached (alpha fixes a static bound, so the 256 settings need one compile per distinct config:
  counted exactly with ``resolve``), while separate ``jaxplore run`` commands compile every
  time (process start-up not counted).

Compiles are counted, and their seconds summed, with a ``jax.monitoring`` listener on XLA backend
compiles (every compiled function, the engine's and the small helpers'); "engine compiles" are the
``advance`` program's. Robot-episodes per hour are given with and without compile time.

  python experiments/bench_sweep.py --quick     # smoke run on a 40 x 40 world (~2 minutes)
  python experiments/bench_sweep.py             # full run (a few minutes on 2 idle cores)
  python experiments/bench_sweep.py --devices 2 # the sweep's chunks sharded over 2 host devices

Writes ``experiments/results/bench_sweep.md`` (``--quick``: ``bench_sweep_quick.md``) or ``--out``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true", help="2 x 2 x 2 settings on a 40 x 40 world")
  parser.add_argument("--world", default=None, help="default lab (--quick: open)")
  parser.add_argument("--res", type=float, default=None, help="m/cell (default 0.2; --quick: 0.5)")
  parser.add_argument("--max-steps", type=int, default=None,
                      help="step budget per episode (default 400; --quick: 40)")
  parser.add_argument("--singles", type=int, default=None,
                      help="settings run one at a time (default 4; --quick: 2)")
  parser.add_argument("--devices", type=int, default=1,
                      help="host devices the sweep shards its chunks over (single runs use 1)")
  parser.add_argument("--chunk-size", type=int, default=None, help="default: the sweep's own choice")
  parser.add_argument("--out", default=None, help="markdown file")
  args = parser.parse_args(argv)
  quick = args.quick
  defaults = dict(world="open" if quick else "lab", res=0.5 if quick else 0.2,
                  max_steps=40 if quick else 400, singles=2 if quick else 4,
                  out=str(HERE / "results" / ("bench_sweep_quick.md" if quick else "bench_sweep.md")))
  for name, value in defaults.items():
    if getattr(args, name) is None:
      setattr(args, name, value)
  return args


ARGS = _parse_args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.devices > 1:
  # Before JAX starts: XLA:CPU runs a loop on one thread; a second core needs a second device.
  os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                             + f" --xla_force_host_platform_device_count={ARGS.devices}")

import datetime  # noqa: E402
import itertools  # noqa: E402
import platform  # noqa: E402
import shlex  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import jax  # noqa: E402
import jax.monitoring  # noqa: E402

sys.path.insert(0, str(HERE.parent))
import jaxplore  # noqa: E402
from jaxplore.driver import COMPILE_EVENT  # noqa: E402
from jaxplore.resolve import resolve  # noqa: E402
from jaxplore.runspec import RunSpec  # noqa: E402

COMPILES: list[tuple[str, float]] = []


def _on_event(event, duration, **kwargs):
  if event == COMPILE_EVENT:
    COMPILES.append((str(kwargs.get("fun_name", "?")), float(duration)))


def grid_of(quick: bool) -> dict:
  """alpha × k1 × k2; every k1 < every k2 (li2020 needs 0 <= k1 < k2 < 1)."""
  if quick:
    return {"alpha": [1.0, 2.0], "k1": [0.0, 0.2], "k2": [0.6, 0.9]}
  return {"alpha": [1.0, 1.5, 2.0, 2.5],
          "k1": [round(0.05 * i, 2) for i in range(8)],  # 0 .. 0.35
          "k2": [round(0.4 + 0.08 * i, 2) for i in range(8)]}  # 0.4 .. 0.96


def compile_window(start: int) -> tuple[int, int, float]:
  """(all compiles, engine compiles, compile seconds) since ``start``."""
  events = COMPILES[start:]
  return len(events), sum("advance" in name for name, _ in events), sum(d for _, d in events)


def load_average() -> str:
  try:
    return f"{os.getloadavg()[0]:.2f}"
  except OSError:
    return "n/a"


def timed(fn):
  """(result, wall seconds, XLA compiles, engine compiles, XLA compile seconds) of ``fn()``."""
  mark = len(COMPILES)
  t0 = time.perf_counter()
  result = fn()
  wall = time.perf_counter() - t0
  return (result, wall, *compile_window(mark))


def main(args) -> int:
  jax.monitoring.register_event_duration_secs_listener(_on_event)
  grid = grid_of(args.quick)
  names = list(grid)
  settings = [dict(zip(names, combo)) for combo in itertools.product(*grid.values())]
  n = len(settings)
  # the oracle, as bench_sweep.md's earlier rows (li2020's own model is now scan_matching)
  common = dict(world=args.world, res=args.res, planner="li2020", max_steps=args.max_steps,
                slam="oracle")
  load_before = load_average()
  print(f"{n} settings ({' x '.join(f'{k}:{len(v)}' for k, v in grid.items())}) on {args.world} "
        f"at {args.res} m; load average {load_before}", flush=True)

  # --- the sweep, twice: cold (trace + compile + run), then warm (everything cached: the run)
  def do_sweep():
    return jaxplore.sweep(grid, seeds=1, progress=True, quiet=True, devices=args.devices,
                          chunk_size=args.chunk_size, **common)
  cold = timed(do_sweep)
  warm = timed(do_sweep)
  result = cold[0]
  episodes = result.episodes
  deterministic = episodes.equals(warm[0].episodes)
  print(f"sweep: cold {cold[1]:.1f} s ({cold[3]} engine compile(s), {cold[4]:.1f} s XLA compile), "
        f"warm {warm[1]:.1f} s ({warm[3]} engine compiles); same table twice: {deterministic}", flush=True)

  # --- one at a time: a handful of settings spread over the grid, each cold then warm
  picks = sorted({int(round(i)) for i in np.linspace(0, n - 1, args.singles)})
  singles = []
  for i in picks:
    s = settings[i]

    def do_run():
      return jaxplore.run(robots=1, robot_seeds=[0], params={"alpha": s["alpha"]},
                          planner_params={"k1": s["k1"], "k2": s["k2"]}, progress=False, quiet=True,
                          devices=1, **common)
    first, again = timed(do_run), timed(do_run)
    row = episodes[np.isclose(episodes.alpha, s["alpha"]) & np.isclose(episodes.k1, s["k1"])
                   & np.isclose(episodes.k2, s["k2"])].iloc[0]
    mine = first[0].episodes.iloc[0]
    same = mine.reason == row.reason and all(
        float(mine[c]) == float(row[c]) or (np.isnan(float(mine[c])) and np.isnan(float(row[c])))
        for c in ("distance_m", "coverage", "entropy_reduction", "time_s", "E_r"))
    singles.append(dict(setting=s, cold=first[1], warm=again[1], compiles=first[2], engine=first[3],
                        compile_s=first[4], warm_engine=again[3], reason=mine.reason, same=same,
                        steps=int(first[0].timing["robot_steps"])))
    print(f"single {s}: cold {first[1]:.1f} s ({first[3]} engine compile, {first[4]:.1f} s XLA compile), "
          f"warm {again[1]:.2f} s; same metrics as the sweep row: {same}", flush=True)

  # --- extrapolation of the one-at-a-time mode to every setting
  configs = set()
  for s in settings:
    configs.add(resolve(RunSpec(world=args.world, planner="li2020", robots=1, res=args.res,
                                max_steps=args.max_steps, params={"alpha": s["alpha"]},
                                planner_params={"k1": s["k1"], "k2": s["k2"]})).config)
  overhead = float(np.mean([r["cold"] - r["warm"] for r in singles]))  # trace + compile per config
  warm_run = float(np.mean([r["warm"] for r in singles]))
  cold_run = float(np.mean([r["cold"] for r in singles]))
  seq_process = len(configs) * overhead + n * warm_run
  seq_commands = n * cold_run
  load_after = load_average()

  # --- report
  per_hour = lambda seconds: n / seconds * 3600 if seconds > 0 else float("nan")
  sweep_overhead = cold[1] - warm[1]
  rows = [
      ("one `jaxplore.sweep` (measured)", f"{cold[2]} ({cold[3]})", f"{cold[4]:.1f}", sweep_overhead,
       warm[1], cold[1]),
      (f"`jaxplore.run` one setting at a time, one process (extrapolated from {len(singles)} settings)",
       f"{len(configs)} static configs", "", len(configs) * overhead, n * warm_run, seq_process),
      (f"`jaxplore.run` one setting at a time, separate processes (extrapolated from {len(singles)} settings)",
       f"{n} x", "", n * overhead, n * warm_run, seq_commands),
  ]
  command = "python experiments/bench_sweep.py " + shlex.join(sys.argv[1:])
  reasons = episodes.reason.value_counts().to_dict()
  g = result.config["groups"][0]
  lines = [
      "# Sweep throughput: one `jaxplore.sweep` vs `jaxplore.run` one setting at a time",
      "",
      f"Command: `{command.strip()}`  ",
      f"Date: {datetime.datetime.now().isoformat(timespec='minutes')}; machine: "
      f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; jax {jax.__version__}, "
      f"Python {platform.python_version()}; 1-minute load average {load_before} before, {load_after} "
      "after (other processes share the cores).  ",
      f"Settings: {' x '.join(f'{k} {v}' for k, v in grid.items())} = {n}, 1 seed (PRNGKey(0)), "
      f"li2020 planner and preset, world `{args.world}` at {args.res} m/cell "
      f"({g['world']['shape'][1]} x {g['world']['shape'][0]} cells), step budget "
      f"{g['sim_config']['max_steps']}; sweep chunks of {g['chunk_size']} robots over "
      f"{cold[0].timing['sharded_over']} device(s); single runs on 1 device.  ",
      f"Episodes of the sweep: {', '.join(f'{k} {v}' for k, v in sorted(reasons.items()))}; the "
      f"second (warm) sweep gave the same table: {deterministic}.",
      "",
      "Each mode was run cold (trace + compile + run) and then again warm (every program cached): "
      "first-call overhead = cold - warm, run = warm.",
      "",
      "| mode | XLA compiles (engine) | XLA compile s | first-call overhead s | run s | total s | robot-episodes/hour | excl. overhead |",
      "|---|---|---|---|---|---|---|---|",
  ]
  for mode, compiles, xla_s, over, run_s, total in rows:
    lines.append(f"| {mode} | {compiles} | {xla_s} | {over:.1f} | {run_s:.1f} | {total:.1f} | "
                 f"{per_hour(total):,.0f} | {per_hour(run_s):,.0f} |")
  lines += [
      "",
      f"Sweep vs one setting at a time in one process: {seq_process / cold[1]:.1f}x the robot-episodes "
      f"per hour with first-call costs, {(n * warm_run) / max(warm[1], 1e-9):.1f}x without; vs "
      f"separate processes: {seq_commands / cold[1]:.1f}x.",
      "",
      "Settings run one at a time (each `jaxplore.run(robots=1)`, measured cold then warm):",
      "",
      "| alpha | k1 | k2 | cold s | XLA compiles (engine) | XLA compile s | warm s | robot-steps | reason | same metrics as the sweep's row |",
      "|---|---|---|---|---|---|---|---|---|---|",
  ]
  for r in singles:
    s = r["setting"]
    lines.append(f"| {s['alpha']:g} | {s['k1']:g} | {s['k2']:g} | {r['cold']:.1f} | {r['compiles']} "
                 f"({r['engine']}) | {r['compile_s']:.1f} | {r['warm']:.2f} | {r['steps']} | {r['reason']} | "
                 f"{r['same']} |")
  lines += [
      "",
      f"Extrapolation (not measured): one process = {len(configs)} distinct static configs (alpha sets "
      f"the static entropy-update window, so each alpha compiles its own program) x {overhead:.1f} s "
      f"mean first-call overhead + {n} x {warm_run:.2f} s mean warm run; separate processes = {n} x "
      f"{cold_run:.1f} s mean cold run (Python and JAX start-up not counted). A single robot's run "
      "stops when it finishes; a sweep chunk runs until its last robot finishes.",
  ]
  text = "\n".join(lines) + "\n"
  out = Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(text)
  print(text)
  print(f"wrote {out}")
  return 0


if __name__ == "__main__":
  sys.exit(main(ARGS))
