"""Benchmark: robot-steps per second of the batched engine versus a sequential NumPy/SciPy loop.

Measured side by side in one run, on the built-in worlds ``open`` (200 x 200 cells at 0.1 m) and
``lab`` with the ``li2020`` preset, and on the six Explore-Bench blueprints
(``../shared/maps/explore_bench/*.yaml``) with the ``explore_bench`` preset (one planning round
per step):

* the engine (nearest-frontier planner, ``pose_noise=False``): robot-steps per second for each
  batch size, from the reset state, in chunks of planning epochs compiled ahead of time with
  ``driver.compiled_advance`` (compile time reported on its own; every chunk is timed up to
  ``block_until_ready``); the batch is sharded over ``--devices`` host devices;
* the sequential reference (``experiments/reference_numpy.py``: one robot at a time, SciPy's
  Dijkstra for paths) from the same start poses for the same number of steps: its robot-steps
  per second do not depend on the batch, so the engine/reference ratio is given per batch size;
* the lidar alone: microseconds per 360-beam 15 m scan per robot, ``sensor.measure`` +
  ``sensor.mark_observed`` jitted over B poses versus the reference's scan function called B times.

Robot-steps count only steps in which a robot was still running (neither finished nor timed
out); the engine still pays for finished robots of a batch, so a batch that finishes early looks
slower. Starts are drawn uniformly from each world's start area with ``--seed``.

  python experiments/bench_engine.py --quick              # smoke run, < 1 minute
  python experiments/bench_engine.py                      # full run (~15 minutes on 2 idle cores)
  python experiments/bench_engine.py --devices 2          # shard the batch over 2 host devices

The table is printed and written to ``experiments/results/bench_engine.md`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
EXPLORE_BENCH = HERE.parent.parent / "shared" / "maps" / "explore_bench"
EXPLORE_BENCH_MAPS = ("corner", "corridor", "loop", "loop_with_corridor", "room", "room_with_corner")
DEFAULT_WORLDS = ("open", "lab") + tuple(f"eb:{name}" for name in EXPLORE_BENCH_MAPS)
QUICK_WORLDS = ("lab", "eb:room")


def _int_list(text: str) -> list[int]:
  return [int(v) for v in text.split(",") if v.strip()]


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--robots", type=_int_list, default=None,
                      help="batch sizes, comma separated (default 1,16,64,256; --quick: 1,4)")
  parser.add_argument("--devices", type=int, default=1, help="host devices to shard the batch over")
  parser.add_argument("--worlds", default=None,
                      help="comma separated: built-in names and eb:<blueprint> (default: open, lab and "
                           "the six Explore-Bench blueprints; --quick: lab, eb:room)")
  parser.add_argument("--steps", type=int, default=None,
                      help="motion steps timed per setting on open/lab (li2020: a planning round every "
                           "8 steps), for the engine and the reference (default 128)")
  parser.add_argument("--eb-steps", type=int, default=None,
                      help="motion steps timed per setting on the Explore-Bench blueprints (a planning "
                           "round every step) (default 64)")
  parser.add_argument("--chunk-steps", type=int, default=None,
                      help="motion steps per compiled chunk (default 32)")
  parser.add_argument("--ref-robots", type=int, default=None,
                      help="robots timed with the sequential reference per world (default 2)")
  parser.add_argument("--lidar-batches", type=_int_list, default=None, help="default 1,64,256")
  parser.add_argument("--lidar-ref-scans", type=int, default=None,
                      help="scans timed with the reference per lidar batch (default 64)")
  parser.add_argument("--compare-window", action="store_true",
                      help="where the engine plans on a window around each robot (SimConfig.plan_window), "
                           "also time it planning on the whole grid, side by side")
  parser.add_argument("--repeats", type=int, default=None,
                      help="times each world's reference and engine settings are timed, interleaved "
                           "(reference, then every engine setting, again); rates are the medians "
                           "(default 2; --quick: 1). This machine's speed drifts by up to ~30 %% "
                           "between minutes, so a single pair of timings can mislead")
  parser.add_argument("--quick", action="store_true", help="tiny smoke version (< 1 minute)")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--out", default=str(HERE / "results" / "bench_engine.md"), help="markdown file")
  args = parser.parse_args(argv)
  quick = args.quick
  defaults = dict(robots=[1, 4] if quick else [1, 16, 64, 256],
                  worlds=",".join(QUICK_WORLDS if quick else DEFAULT_WORLDS),
                  steps=16 if quick else 128, eb_steps=8 if quick else 64,
                  chunk_steps=8 if quick else 32,
                  ref_robots=1 if quick else 2, repeats=1 if quick else 2,
                  lidar_batches=[1, 4] if quick else [1, 64, 256],
                  lidar_ref_scans=4 if quick else 64)
  for name, value in defaults.items():
    if getattr(args, name) is None:
      setattr(args, name, value)
  args.worlds = [w.strip() for w in args.worlds.split(",") if w.strip()]
  return args


ARGS = _parse_args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.devices > 1:
  # Must be set before JAX starts: XLA:CPU runs a while loop on one thread, so a second core
  # is only used through a second host device.
  os.environ["XLA_FLAGS"] = (
      os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices}"
  )

import dataclasses  # noqa: E402
import datetime  # noqa: E402
import platform  # noqa: E402
import shlex  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
import reference_numpy  # noqa: E402
from jaxplore import driver, sensor, sim  # noqa: E402
from jaxplore.config import PARAM_FIELDS  # noqa: E402
from jaxplore.maps import load_map, load_world  # noqa: E402
from jaxplore.resolve import resolve  # noqa: E402
from jaxplore.runspec import RunSpec  # noqa: E402

LIDAR_BEAMS = 360
LIDAR_RANGE_M = 15.0
# Batches up to this size run one untimed chunk first (first-call costs are a visible share of
# their short timed window; for larger batches they are not, and a warm-up chunk costs minutes).
WARMUP_MAX_ROBOTS = 16


# --- settings --------------------------------------------------------------------------------


def load_bench_world(name: str):
  """(grid, preset) of a world label: a built-in name (li2020) or ``eb:<blueprint>`` (explore_bench)."""
  if name.startswith("eb:"):
    path = EXPLORE_BENCH / f"{name[3:]}.yaml"
    if not path.exists():
      raise SystemExit(f"no Explore-Bench blueprint {path}; valid: {', '.join(EXPLORE_BENCH_MAPS)}")
    grid = load_map(path)
    return grid, "explore_bench"
  return load_world(name), "li2020"


def sample_starts(world: sim.World, grid, count: int, seed: int) -> np.ndarray:
  """``count`` start poses (x, y, θ): centres of random start-area cells, random headings."""
  rng = np.random.default_rng(seed)
  cells = np.argwhere(np.asarray(world.start_ok))
  chosen = cells[rng.integers(len(cells), size=count)]
  x, y = grid.cell_to_world(chosen[:, 0], chosen[:, 1])
  theta = rng.uniform(-math.pi, math.pi, size=count)
  return np.stack([x, y, theta], axis=1).astype(np.float32)


def setting(grid, preset: str, robots: int, steps: int):
  """(config, params) of the benchmark: nearest frontier, no pose noise, no timeout in the window."""
  resolved = resolve(RunSpec(world=grid, planner="nearest_frontier", robots=robots, preset=preset,
                             max_steps=steps + 64))
  return resolved.config, resolved.params


# --- engine ----------------------------------------------------------------------------------


def time_engine(compiled_cache: dict, config, params, world, starts, steps: int, chunk_steps: int,
                devices: int, seed: int, compared: int) -> dict:
  """Compiles (once per config, batch and device count) and times the engine from the reset state.

  The timed window starts at the reset state (the same window the reference is timed on); small
  batches first run one untimed chunk from it (``WARMUP_MAX_ROBOTS``).

  ``compared``: how many of the first robots the reference also ran (their mean final coverage
  is reported next to the reference's as a check that both did the same job).
  """
  robots = len(starts)
  n_dev = driver.shard_count(robots, devices)
  chunk_epochs = max(1, chunk_steps // config.replan_every)
  n_chunks = max(1, -(-steps // (chunk_epochs * config.replan_every)))
  params_b = sim.broadcast_params(params, robots)
  keys = jax.random.split(jax.random.PRNGKey(seed), robots)
  state = jax.block_until_ready(
      sim.reset_batch(config, world, params_b, keys, jnp.asarray(starts, jnp.float32)))
  steps_before = int(np.asarray(state.steps).sum())

  key = (config, chunk_epochs, n_dev, robots)
  compile_s = None
  if key not in compiled_cache:
    advance = driver.compiled_advance(config, chunk_epochs, n_dev)
    t0 = time.perf_counter()
    compiled_cache[key] = advance.lower(world, params_b, state).compile()
    compile_s = time.perf_counter() - t0
  compiled = compiled_cache[key]
  # Place the inputs where the executable wants them (sharded over devices) before timing.
  world, params_b, state = jax.device_put((world, params_b, state), compiled.input_shardings[0])
  if robots <= WARMUP_MAX_ROBOTS:
    jax.block_until_ready(compiled(world, params_b, state))

  t0 = time.perf_counter()
  for _ in range(n_chunks):
    state, records = compiled(world, params_b, state)
    jax.block_until_ready((state, records))
  run_s = time.perf_counter() - t0
  robot_steps = int(np.asarray(state.steps).sum()) - steps_before
  return dict(robots=robots, devices=n_dev, compile_s=compile_s, run_s=run_s,
              lockstep_steps=n_chunks * chunk_epochs * config.replan_every, robot_steps=robot_steps,
              engine_rate=robot_steps / run_s, done=int(np.asarray(state.done).sum()),
              coverage=float(np.asarray(records.coverage)[-1, :compared].mean()))


# --- reference -------------------------------------------------------------------------------


def time_reference(grid, config, params, starts, steps: int) -> dict:
  """The sequential reference from the first starts, one robot after the other."""
  params_dict = {name: float(np.asarray(getattr(params, name))) for name in PARAM_FIELDS}
  total_steps, total_s, coverage = 0, 0.0, []
  phases = {"scan": 0.0, "belief": 0.0, "plan": 0.0, "motion": 0.0}
  for start in starts:
    result = reference_numpy.run_reference(grid, params_dict, config, tuple(map(float, start)), steps)
    total_steps += result["steps"]
    total_s += result["wall_s"]
    coverage.append(result["coverage"])
    for name in phases:
      phases[name] += result["timing"][name]
  return dict(ref_robots=len(starts), ref_steps=total_steps, ref_s=total_s,
              ref_rate=total_steps / total_s, ref_coverage=float(np.mean(coverage)),
              ref_phases={k: v / total_s for k, v in phases.items()})


# --- lidar -----------------------------------------------------------------------------------


def lidar_bench(batches, ref_scans: int, seed: int) -> list[dict]:
  """µs per 360-beam 15 m scan per robot on ``open``: engine cast (jit + vmap) vs the reference."""
  grid = load_world("open")
  occupied = grid.occupied
  h, w = occupied.shape
  r_max_cells = LIDAR_RANGE_M / grid.res
  n_cross = math.ceil(r_max_cells) + 1
  truth_framed = sensor.frame_truth(jnp.asarray(occupied))
  rng = np.random.default_rng(seed)
  free = np.argwhere(~occupied)

  def engine_scan(u0, v0, theta):
    # What the engine's step runs: the early-stopping walk to the first hit (sensor.measure) and
    # the free/occupied marking of every cell seen (sensor.mark_observed).
    angles = sensor.beam_angles(theta, jnp.float32(2 * math.pi), LIDAR_BEAMS)
    scan = sensor.measure(truth_framed, (h, w), u0, v0, angles, jnp.float32(r_max_cells), n_cross)
    end_rows, end_cols = sensor.end_cells(scan, u0, v0, jnp.bool_(True))
    observed = sensor.mark_observed(sensor.empty_observation((h, w)), (h, w), scan, u0, v0, end_rows,
                                    end_cols, n_cross)
    return scan.ranges, scan.hit_rows, scan.hit_cols, jnp.sum(observed.astype(jnp.int32))

  # One pose after the other, as the engine's step processes robots (mapping.per_robot).
  batched = jax.jit(lambda u0, v0, theta: jax.lax.map(lambda a: engine_scan(*a), (u0, v0, theta)))
  rows = []
  for batch in batches:
    cells = free[rng.integers(len(free), size=batch)]
    v0 = (cells[:, 0] + rng.uniform(size=batch)).astype(np.float32)
    u0 = (cells[:, 1] + rng.uniform(size=batch)).astype(np.float32)
    theta = rng.uniform(-math.pi, math.pi, size=batch).astype(np.float32)
    args = tuple(jnp.asarray(a) for a in (u0, v0, theta))
    t0 = time.perf_counter()
    compiled = batched.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))  # warm-up
    repeats = max(3, 2048 // batch)
    t0 = time.perf_counter()
    for _ in range(repeats):
      jax.block_until_ready(compiled(*args))
    engine_us = 1e6 * (time.perf_counter() - t0) / (repeats * batch)

    def reference_scan(i):
      angles = reference_numpy.beam_angles(float(theta[i]), 2 * math.pi, LIDAR_BEAMS)
      reference_numpy.scan(occupied, float(u0[i]), float(v0[i]), angles, r_max_cells, n_cross)

    reference_scan(0)  # warm-up
    t0 = time.perf_counter()
    for i in range(ref_scans):  # one robot at a time: the batch size does not matter
      reference_scan(i % batch)
    ref_us = 1e6 * (time.perf_counter() - t0) / ref_scans
    rows.append(dict(batch=batch, compile_s=compile_s, engine_us=engine_us, ref_us=ref_us,
                     ref_scans=ref_scans, ratio=ref_us / engine_us))
    print(f"  lidar B={batch}: engine {engine_us:.1f} µs/scan, reference {ref_us:.1f} µs/scan "
          f"({ref_us / engine_us:.1f}x)", flush=True)
  return rows


# --- report ----------------------------------------------------------------------------------


def load_average() -> str:
  try:
    return " / ".join(f"{v:.2f}" for v in os.getloadavg())
  except OSError:
    return "unknown"


def machine_lines(args, load_at_start: str) -> list[str]:
  cpu = "unknown"
  try:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
      if line.startswith("model name"):
        cpu = line.split(":", 1)[1].strip()
        break
  except OSError:
    pass
  return [
      f"- date: {datetime.datetime.now().isoformat(timespec='seconds')}",
      f"- command: `{shlex.join([sys.executable.split('/')[-1]] + sys.argv)}`",
      f"- machine: nproc {os.cpu_count()}, {cpu}, {platform.system()} {platform.machine()}, "
      f"Python {platform.python_version()}",
      f"- load average (1/5/15 min) at start: {load_at_start} (above ~0: other processes shared the CPU)",
      f"- jax {jax.__version__}, numpy {np.__version__}, scipy {scipy.__version__}",
      f"- devices: {', '.join(str(d) for d in jax.devices())}; batch sharded over up to {args.devices}",
      f"- XLA_FLAGS: `{os.environ.get('XLA_FLAGS', '')}`",
  ]


def report(args, rows, lidar_rows, load_at_start: str, wall_s: float) -> str:
  lines = ["# Engine vs sequential NumPy/SciPy reference: robot-steps per second", ""]
  lines += machine_lines(args, load_at_start)
  lines += [
      f"- motion steps timed per setting: {args.steps} on open/lab, {args.eb_steps} on Explore-Bench "
      f"(engine chunks of {args.chunk_steps} steps); reference: the first {args.ref_robots} robot(s) "
      f"of each world, same starts and step count; seed {args.seed}",
      f"- repeats: {args.repeats}, interleaved (each world: the reference, then every engine setting, "
      "again); rates are medians, `engine / reference` is their ratio and the range is that of the "
      "per-repeat ratios (each engine timing over the reference timed just before it)",
      f"- total wall time of the benchmark: {wall_s:.0f} s",
      "",
      "Planner: nearest frontier, `pose_noise=False`. `open`, `lab`: `li2020` preset (15 m, 190°, "
      "190 beams, replanning every 8 steps); `eb:*`: Explore-Bench blueprints with the `explore_bench` "
      "preset (3.5 m, 360 beams, replanning every step). Robot-steps count running robots only; "
      "`done` = robots finished at the end of the window. Compile time is apart from run time "
      "(`-` = executable reused from an earlier world of the same shape). Plan window: the side "
      "of the window around each robot that nearest frontier plans on first (`SimConfig.plan_window`, "
      "picked from the sensor range capped at 3.5 m; the whole grid is planned only when the window "
      "cannot certify the nearest frontier); `off` = whole grid every time"
      + (" (rows in italics: the same setting with the window off, for comparison; the summaries "
         "below use the default rows only)." if any(not r["main"] for r in rows) else "."),
      "",
      "| world | preset | H x W | plan window | robots | devices | compile s | run s | engine robot-steps/s "
      "| reference robot-steps/s | engine / reference | range over repeats | done "
      "| coverage engine / ref (same robots) |",
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
  ]
  for r in rows:
    compile_s = "-" if r["compile_s"] is None else f"{r['compile_s']:.1f}"
    window = r["window"] or "off"
    if not r["main"]:
      window = f"*{window}*"
    lines.append(
        f"| {r['world']} | {r['preset']} | {r['shape'][0]} x {r['shape'][1]} | {window} | {r['robots']} "
        f"| {r['devices']} | {compile_s} | {r['run_s']:.2f} | {r['engine_rate']:.0f} "
        f"| {r['ref_rate']:.0f} | **{r['engine_rate'] / r['ref_rate']:.1f}x** "
        f"| {r['ratio_min']:.1f}-{r['ratio_max']:.1f}x | {r['done']}/{r['robots']} "
        f"| {r['coverage']:.3f} / {r['ref_coverage']:.3f} |")

  compared = [r for r in rows if not r["main"]]
  if compared:
    lines += ["", "Planning window on / off, same setting (engine robot-steps/s):", "",
              "| world | robots | window | on | off | on / off |", "|---|---|---|---|---|---|"]
    for off in compared:
      on = next(r for r in rows if r["main"] and r["world"] == off["world"] and r["robots"] == off["robots"])
      lines.append(f"| {off['world']} | {off['robots']} | {on['window']} | {on['engine_rate']:.0f} "
                   f"| {off['engine_rate']:.0f} | {on['engine_rate'] / off['engine_rate']:.2f}x |")
  rows = [r for r in rows if r["main"]]
  lines += ["", "Engine / reference by batch size (geometric mean over worlds):", "",
            "| robots | geometric mean | min | max |", "|---|---|---|---|"]
  for robots in sorted({r["robots"] for r in rows}):
    ratios = np.array([r["engine_rate"] / r["ref_rate"] for r in rows if r["robots"] == robots])
    geometric_mean = np.exp(np.log(ratios).mean())
    lines.append(f"| {robots} | {geometric_mean:.1f}x | {ratios.min():.1f}x | {ratios.max():.1f}x |")
  if any(r["robots"] == 256 for r in rows):
    at_256 = [r["engine_rate"] / r["ref_rate"] for r in rows if r["robots"] == 256]
    verdict = "met" if min(at_256) >= 20 else "NOT met"
    worst = min(r["ratio_min"] for r in rows if r["robots"] == 256)
    lines.append(f"\nTarget (engine >= 20x the reference at 256 robots, every world): {verdict} "
                 f"(lowest median ratio {min(at_256):.1f}x; lowest single repeat {worst:.1f}x).")

  lines += ["", "Where the sequential reference spends its time (fraction of its wall time):", "",
            "| world | robots x steps | robot-steps/s | scan | belief + entropy map | plan | motion |",
            "|---|---|---|---|---|---|---|"]
  seen = set()
  for r in rows:
    if r["world"] in seen:
      continue
    seen.add(r["world"])
    p = r["ref_phases"]
    lines.append(f"| {r['world']} | {r['ref_robots']} x {r['ref_steps'] // max(1, r['ref_robots'])} "
                 f"| {r['ref_rate']:.0f} | {p['scan']:.0%} | {p['belief']:.0%} | {p['plan']:.0%} "
                 f"| {p['motion']:.0%} |")

  lines += ["", f"Lidar alone: {LIDAR_BEAMS}-beam {LIDAR_RANGE_M:.0f} m scans (full circle) on `open` "
            "(0.1 m cells), µs per scan per robot. Engine: `sensor.measure` + `sensor.mark_observed` (what a step runs), "
            "B poses one after the other in one jitted call on one device; reference: `reference_numpy.scan` called once per pose.", "",
            "| B | engine µs/scan | reference µs/scan | reference / engine | engine compile s |",
            "|---|---|---|---|---|"]
  for r in lidar_rows:
    lines.append(f"| {r['batch']} | {r['engine_us']:.1f} | {r['ref_us']:.1f} ({r['ref_scans']} scans) "
                 f"| {r['ratio']:.1f}x | {r['compile_s']:.1f} |")
  return "\n".join(lines) + "\n"


def combine_repeats(name, preset, shape, window, main, refs, engines) -> dict:
  """One table row from interleaved repeats: median rates, and the range of the per-repeat ratios
  (each engine timing over the reference timed just before it)."""
  median = lambda values: float(np.median(values))
  ratios = [e["engine_rate"] / r["ref_rate"] for e, r in zip(engines, refs)]
  first = engines[0]
  compile_s = next((e["compile_s"] for e in engines if e["compile_s"] is not None), None)
  ref_rate = median([r["ref_rate"] for r in refs])
  # Phases and coverage of the reference come from its repeat nearest the median.
  ref = min(refs, key=lambda r: abs(r["ref_rate"] - ref_rate))
  return dict(world=name, preset=preset, shape=shape, window=window, main=main,
              robots=first["robots"], devices=first["devices"], compile_s=compile_s,
              run_s=median([e["run_s"] for e in engines]),
              engine_rate=median([e["engine_rate"] for e in engines]), done=first["done"],
              coverage=first["coverage"], ratio_min=min(ratios), ratio_max=max(ratios),
              **{**ref, "ref_rate": ref_rate})


def main(args):
  if args.devices > len(jax.devices()):
    raise SystemExit(f"asked for {args.devices} devices, JAX sees {jax.devices()}")
  load_at_start = load_average()
  t_start = time.perf_counter()
  print("\n".join(machine_lines(args, load_at_start)), flush=True)
  rows, compiled_cache = [], {}
  for name in args.worlds:
    grid, preset = load_bench_world(name)
    steps = args.eb_steps if preset == "explore_bench" else args.steps
    config, params = setting(grid, preset, max(args.robots), steps)
    world = sim.make_world(grid, float(np.asarray(params.r_robot)))
    starts = sample_starts(world, grid, max(args.robots + [args.ref_robots]), args.seed)
    windows = [config.plan_window] + ([0] if args.compare_window and sim.uses_window(config) else [])
    settings = [(robots, window) for robots in args.robots for window in windows]
    refs, engines = [], {setting: [] for setting in settings}
    for repeat in range(args.repeats):
      refs.append(time_reference(grid, config, params, starts[: args.ref_robots], steps))
      print(f"{name}: reference {refs[-1]['ref_rate']:.1f} robot-steps/s over {refs[-1]['ref_steps']} steps "
            f"(repeat {repeat + 1}/{args.repeats})", flush=True)
      for robots, window in settings:
        engine = time_engine(compiled_cache, dataclasses.replace(config, plan_window=window), params,
                             world, starts[:robots], steps, args.chunk_steps, args.devices, args.seed,
                             min(robots, args.ref_robots))
        engines[robots, window].append(engine)
        compile_text = "cached" if engine["compile_s"] is None else f"{engine['compile_s']:.1f} s"
        print(f"  {robots:>4} robots, plan window {window or 'off'}: compile {compile_text}, engine "
              f"{engine['engine_rate']:.0f} robot-steps/s "
              f"({engine['engine_rate'] / refs[-1]['ref_rate']:.1f}x the reference of this repeat), "
              f"done {engine['done']}/{robots}", flush=True)
    for robots, window in settings:
      rows.append(combine_repeats(name, preset, grid.shape, window, window == config.plan_window,
                                  refs, engines[robots, window]))
  print("lidar:", flush=True)
  lidar_rows = lidar_bench(args.lidar_batches, args.lidar_ref_scans, args.seed)
  text = report(args, rows, lidar_rows, load_at_start, time.perf_counter() - t_start)
  out = Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(text)
  print()
  print(text)
  print(f"written to {out}")


if __name__ == "__main__":
  main(ARGS)
