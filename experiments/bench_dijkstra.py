"""Benchmark: batched grid shortest paths (cone sweeping, relaxation) versus SciPy's Dijkstra.

Measures milliseconds per map for ``jaxplore.graph.shortest_paths_batched`` on seeded 256 x 256
room-like worlds and mazes, for several batch sizes, next to ``scipy.sparse.csgraph.dijkstra``
(with predecessors) on the same graphs, timed in the same process. JAX compile time
(``.lower().compile()``) is reported apart from run time, and every JAX timing is taken after
``block_until_ready()``; each row keeps the best of ``--repeats`` runs.

  python experiments/bench_dijkstra.py                   # 1 and 2 host devices, full table
  python experiments/bench_dijkstra.py --devices 2       # only the batch sharded over 2 devices
  python experiments/bench_dijkstra.py --chunks 2 4 8    # compare chunk sizes
  python experiments/bench_dijkstra.py --methods sweeps relaxation   # the GPU's method too

``sweeps-only`` is ``sweeps`` without the tile-by-tile finish (``tiles_after_rounds=0``), timed
beside it to show what the finish buys on mazes.

Each device count runs in its own subprocess, because the host device count is fixed when JAX
starts (``XLA_FLAGS=--xla_force_host_platform_device_count=N``). With N > 1 the batch axis is
sharded over a ``Mesh`` with ``jax.shard_map``, and each device runs the chunked solver on its
half. The table is printed and written to ``experiments/results/bench_dijkstra.md`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile


RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "bench_dijkstra.md")


def _parse_args(argv=None):
  parser = argparse.ArgumentParser(
      description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
  )
  add = parser.add_argument
  add("--devices", type=int, nargs="+", default=[1, 2], help="host device counts to run")
  add("--size", type=int, default=256, help="grid side in cells")
  add("--batches", type=int, nargs="+", default=[1, 16, 64, 256])
  add("--maps", nargs="+", default=["rooms", "maze"], choices=["rooms", "maze"])
  add("--chunks", type=int, nargs="+", default=[4], help="grids solved together per lax.map step")
  add("--methods", nargs="+", default=["sweeps", "sweeps-only"],
      choices=["sweeps", "sweeps-only", "relaxation"],
      help="solver methods (jaxplore.graph.dijkstra.METHODS; 'sweeps' is the CPU's, which "
           "finishes unsettled grids tile by tile; 'sweeps-only' never does)")
  add("--tiles-after-rounds", type=int, nargs="+", default=None,
      help="for 'sweeps': whole-grid rounds before the tile-by-tile finish, one row each "
           "(default: the solver's TILES_AFTER_ROUNDS)")
  add("--repeats", type=int, default=3, help="timed runs per setting (the best is kept)")
  add("--scipy-maps", type=int, default=32, help="maps timed with SciPy per map type")
  add("--max-batch-maze", type=int, default=256, help="largest maze batch timed")
  add("--seed", type=int, default=0)
  add("--out", default=RESULTS, help="markdown file for the table")
  add("--worker-json", default=None, help=argparse.SUPPRESS)
  return parser.parse_args(argv)


ARGS = _parse_args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.worker_json and ARGS.devices[0] > 1:
  # Must be set before JAX starts: XLA:CPU runs a while loop on one thread, so a second core
  # is only used through a second host device.
  os.environ["XLA_FLAGS"] = (
      os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices[0]}"
  )

import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse  # noqa: E402
from scipy.sparse.csgraph import dijkstra  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from jax.sharding import Mesh, NamedSharding, PartitionSpec  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from jaxplore.graph import shortest_paths_batched  # noqa: E402


# --- worlds ----------------------------------------------------------------------------------


def room_world(rng: np.random.Generator, size: int) -> np.ndarray:
  """A room-like world: bool[size, size], True = wall.

  Recursively splits the floor into rooms with 1-2 cell walls, leaves a door of 4-10 cells in
  every split, and scatters a few box obstacles (furniture).
  """
  occupied = np.zeros((size, size), bool)
  occupied[[0, -1], :] = True
  occupied[:, [0, -1]] = True

  def split(r0, r1, c0, c1, depth):
    height, width = r1 - r0, c1 - c0
    if depth == 0 or max(height, width) < 40:
      return
    thickness = int(rng.integers(1, 3))
    door = int(rng.integers(4, 11))
    if height >= width:
      wall = int(rng.integers(r0 + height // 3, r1 - height // 3))
      occupied[wall : wall + thickness, c0:c1] = True
      opening = int(rng.integers(c0 + 1, c1 - door - 1))
      occupied[wall : wall + thickness, opening : opening + door] = False
      split(r0, wall, c0, c1, depth - 1)
      split(wall + thickness, r1, c0, c1, depth - 1)
    else:
      wall = int(rng.integers(c0 + width // 3, c1 - width // 3))
      occupied[r0:r1, wall : wall + thickness] = True
      opening = int(rng.integers(r0 + 1, r1 - door - 1))
      occupied[opening : opening + door, wall : wall + thickness] = False
      split(r0, r1, c0, wall, depth - 1)
      split(r0, r1, wall + thickness, c1, depth - 1)

  split(1, size - 1, 1, size - 1, depth=4)
  for _ in range(size // 16):
    r, c = rng.integers(4, size - 12, 2)
    h, w = rng.integers(2, 8, 2)
    occupied[r : r + h, c : c + w] = True
  return occupied


def maze_world(rng: np.random.Generator, size: int, corridor: int = 3, wall: int = 1) -> np.ndarray:
  """A perfect maze (recursive backtracker): bool[size, size], True = wall.

  Corridors are ``corridor`` cells wide, walls ``wall`` cells thick.
  """
  pitch = corridor + wall
  cells = (size - wall) // pitch
  occupied = np.ones((size, size), bool)
  visited = np.zeros((cells, cells), bool)

  def carve(r, c):
    top, left = wall + r * pitch, wall + c * pitch
    occupied[top : top + corridor, left : left + corridor] = False

  stack = [(0, 0)]
  visited[0, 0] = True
  carve(0, 0)
  while stack:
    r, c = stack[-1]
    options = [
        (r + dr, c + dc)
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))
        if 0 <= r + dr < cells and 0 <= c + dc < cells and not visited[r + dr, c + dc]
    ]
    if not options:
      stack.pop()
      continue
    nr, nc = options[int(rng.integers(len(options)))]
    visited[nr, nc] = True
    carve(nr, nc)
    # Knock out the wall between the two maze cells.
    top = wall + min(r, nr) * pitch
    left = wall + min(c, nc) * pitch
    if nr != r:
      occupied[top + corridor : top + pitch, left : left + corridor] = False
    else:
      occupied[top : top + corridor, left + corridor : left + pitch] = False
    stack.append((nr, nc))
  return occupied


def make_batch(kind: str, batch: int, size: int, seed: int):
  """Seeded worlds as node costs f32[B, size, size] (1 = free, inf = wall) and free sources."""
  rng = np.random.default_rng(seed)
  costs, sources = [], []
  for _ in range(batch):
    occupied = room_world(rng, size) if kind == "rooms" else maze_world(rng, size)
    free = np.argwhere(~occupied)
    sources.append(free[rng.integers(len(free))])
    costs.append(np.where(occupied, np.inf, 1.0).astype(np.float32))
  return np.stack(costs), np.stack(sources).astype(np.int32)


def grid_graph(node_cost: np.ndarray) -> scipy.sparse.csr_matrix:
  """The 8-connected grid graph with edge u -> v weighing step * node_cost[v]."""
  height, width = node_cost.shape
  index = np.arange(height * width).reshape(height, width)
  flat_cost = node_cost.astype(np.float64).ravel()
  tails, heads, weights = [], [], []
  for dr in (-1, 0, 1):
    for dc in (-1, 0, 1):
      if dr == dc == 0:
        continue
      tail = index[max(0, -dr) : height - max(0, dr), max(0, -dc) : width - max(0, dc)].ravel()
      head = tail + dr * width + dc
      weight = np.hypot(dr, dc) * flat_cost[head]
      keep = np.isfinite(weight)
      tails.append(tail[keep])
      heads.append(head[keep])
      weights.append(weight[keep])
  n = height * width
  return scipy.sparse.csr_matrix(
      (np.concatenate(weights), (np.concatenate(tails), np.concatenate(heads))), shape=(n, n)
  )


# --- timing ----------------------------------------------------------------------------------


def time_scipy(costs, sources, repeats):
  """Best-of-``repeats`` ms per map of SciPy Dijkstra with predecessors (graph build excluded)."""
  graphs = [grid_graph(c) for c in costs]
  width = costs.shape[2]
  best = np.inf
  for _ in range(repeats):
    start = time.perf_counter()
    for graph, (r, c) in zip(graphs, sources):
      dijkstra(graph, indices=int(r * width + c), return_predecessors=True)
    best = min(best, time.perf_counter() - start)
  return 1e3 * best / len(costs), graphs


def build_solver(devices: int, chunk: int, method: str = "sweeps",
                 tiles_after_rounds: int | None = None):
  """A jitted batched solver; with devices > 1, the batch axis is sharded over a 1-D mesh."""
  options = dict(method="sweeps", tiles_after_rounds=0) if method == "sweeps-only" else (
      dict(method=method))
  if method == "sweeps" and tiles_after_rounds is not None:
    options["tiles_after_rounds"] = tiles_after_rounds
  solve = lambda costs, sources: shortest_paths_batched(costs, sources, chunk=chunk, **options)
  if devices == 1:
    return jax.jit(solve), None
  mesh = Mesh(np.array(jax.devices()[:devices]), ("batch",))
  spec = PartitionSpec("batch")
  sharded = jax.shard_map(solve, mesh=mesh, in_specs=(spec, spec), out_specs=spec)
  return jax.jit(sharded), NamedSharding(mesh, spec)


def time_jax(solver, sharding, costs, sources, repeats):
  """(compile s, best ms per map, result) for one batch."""
  costs, sources = jnp.asarray(costs), jnp.asarray(sources)
  if sharding is not None:
    costs, sources = jax.device_put(costs, sharding), jax.device_put(sources, sharding)
  start = time.perf_counter()
  compiled = solver.lower(costs, sources).compile()
  compile_s = time.perf_counter() - start
  result = jax.block_until_ready(compiled(costs, sources))  # warm-up
  best = np.inf
  for _ in range(repeats):
    start = time.perf_counter()
    result = jax.block_until_ready(compiled(costs, sources))
    best = min(best, time.perf_counter() - start)
  return compile_s, 1e3 * best / costs.shape[0], result


def check_against_scipy(result, graphs, sources, width, count=4):
  """Max relative distance error on the first ``count`` maps (a guard, not a test)."""
  worst = 0.0
  for i in range(min(count, len(sources))):
    r, c = sources[i]
    expected = dijkstra(graphs[i], indices=int(r * width + c))
    got = np.asarray(result.dist[i]).ravel()
    finite = np.isfinite(expected)
    if not np.array_equal(finite, np.isfinite(got)):
      return np.inf
    error = np.abs(got[finite] - expected[finite]) / np.maximum(expected[finite], 1)
    worst = max(worst, float(error.max()))
  return worst


def run_worker(args):
  """Time every (map kind, batch, chunk) on ``args.devices[0]`` devices; rows to a JSON file."""
  devices = args.devices[0]
  if devices > len(jax.devices()):
    raise SystemExit(f"asked for {devices} devices, JAX sees {jax.devices()}")
  rows = []
  for kind in args.maps:
    batches = [b for b in args.batches if kind == "rooms" or b <= args.max_batch_maze]
    count = max(batches + [args.scipy_maps])
    all_costs, all_sources = make_batch(kind, count, args.size, args.seed)
    scipy_ms, graphs = time_scipy(
        all_costs[: args.scipy_maps], all_sources[: args.scipy_maps], args.repeats
    )
    variants = [(m, n) for m in args.methods
                for n in (args.tiles_after_rounds or [None] if m == "sweeps" else [None])]
    for (method, tiles_after), chunk, batch in ((v, c, b) for v in variants
                                                for c in args.chunks for b in batches):
      if batch % devices:
        continue  # B = 1 is timed by the 1-device worker
      solver, sharding = build_solver(devices, chunk, method, tiles_after)
      label = method if tiles_after is None else f"sweeps, tiles after {tiles_after}"
      costs, sources = all_costs[:batch], all_sources[:batch]
      compile_s, jax_ms, result = time_jax(solver, sharding, costs, sources, args.repeats)
      sweeps = np.asarray(result.sweeps)
      rows.append(dict(
          kind=kind, method=label, batch=batch, devices=devices,
          chunk=min(chunk, batch // devices),
          compile_s=compile_s, jax_ms=jax_ms, scipy_ms=scipy_ms, speedup=scipy_ms / jax_ms,
          sweeps_mean=float(sweeps.mean()), sweeps_max=int(sweeps.max()),
          converged=bool(np.all(np.asarray(result.converged))),
          max_rel_err=check_against_scipy(result, graphs, sources, args.size),
      ))
      print(_format_row(rows[-1]), flush=True)
  with open(args.worker_json, "w") as f:
    json.dump(rows, f)


HEADER = (
    "| map | method | B | devices | chunk | compile s | JAX ms/map | SciPy ms/map | SciPy/JAX "
    "| mean rounds | max rounds | converged | max rel err |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def _format_row(row):
  return (
      f"| {row['kind']} | {row.get('method', 'sweeps')} | {row['batch']} | {row['devices']} "
      f"| {row['chunk']} "
      f"| {row['compile_s']:.2f} | {row['jax_ms']:.2f} | {row['scipy_ms']:.2f} "
      f"| {row['speedup']:.2f} | {row['sweeps_mean']:.1f} | {row['sweeps_max']} "
      f"| {row['converged']} | {row['max_rel_err']:.1e} |"
  )


def _load_average() -> str:
  try:
    with open("/proc/loadavg") as f:
      return f.read().split()[0]
  except OSError:
    return "?"


def _cpu_name() -> str:
  try:
    with open("/proc/cpuinfo") as f:
      return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
  except (OSError, StopIteration):
    return platform.processor() or "unknown CPU"


def main(args):
  """Run one worker subprocess per device count, then print and save the combined table."""
  rows = []
  load_before = _load_average()
  print(HEADER, flush=True)
  for devices in args.devices:
    with tempfile.TemporaryDirectory() as tmp:
      out = os.path.join(tmp, "rows.json")
      worker = ["--devices", str(devices), "--worker-json", out]
      this_script = os.path.abspath(__file__)
      subprocess.run([sys.executable, this_script, *sys.argv[1:], *worker], check=True)
      with open(out) as f:
        rows += json.load(f)
  command = " ".join(["python experiments/bench_dijkstra.py", *sys.argv[1:]])
  lines = [
      "# Grid shortest paths: cone sweeping or relaxation (JAX) vs SciPy Dijkstra",
      "",
      f"Command: `{command}`  ",
      f"Machine: {_cpu_name()}, {os.cpu_count()} cores; jax {jax.__version__}, "
      f"Python {platform.python_version()}; 1-minute load average {load_before} before the run, "
      f"{_load_average()} after (other processes share the cores).  ",
      f"Worlds: {args.size} x {args.size}, seed {args.seed}; node cost 1 per free cell, walls "
      "blocked. SciPy time excludes building the sparse graph and is the same for every batch size "
      f"(first {args.scipy_maps} maps, `dijkstra(..., return_predecessors=True)`), timed in the "
      "same process as the JAX rows next to it.  ",
      "JAX ms/map = best of the timed runs after compilation, / B. 'max rel err' compares `dist` "
      "with SciPy (float64) on the first 4 maps. Rounds: of the 4 sweeps for `sweeps-only`; for "
      "`sweeps`, with the tile-by-tile finish counted in whole-grid rounds (a round's worth of "
      "tile visits = 1); relaxation passes for `relaxation`.",
      "",
      HEADER,
      *[_format_row(row) for row in rows],
      "",
  ]
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  with open(args.out, "w") as f:
    f.write("\n".join(lines))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  if ARGS.worker_json:
    print(f"# worker: jax {jax.__version__}, devices {jax.devices()}", flush=True)
    run_worker(ARGS)
  else:
    main(ARGS)
