"""``jaxplore.run``: one batch of robots on one world, from settings to tables, files and figures.

Host-side orchestration around the pure engine (:mod:`jaxplore.sim`): validates every input before
any compute, compiles once, advances the batch in chunks of planning epochs (progress bar, early
stop when every robot is done), shards the batch over local devices, and writes the results folder.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from jaxplore import __version__, metrics, posegraph, sim
from jaxplore.config import (PRESETS, ConfigError, Params, SimConfig, config_for, make_params,
                             validate_params)
from jaxplore.maps import GridMap, load_world
from jaxplore.planners import get_planner


@dataclasses.dataclass
class RunResult:
  """What a run produced (also written to ``out`` when given).

  Attributes:
    episodes: one row per robot (SPEC §5 episode metrics, termination reason).
    curves: one row per robot and step until the robot finished.
    config: the resolved settings (what ``config.json`` holds).
    timing: compile and run wall-clock seconds.
    grid: the truth map. state: the final engine state (NumPy leaves, batch first).
    out: the results folder, if any.
  """

  episodes: pd.DataFrame
  curves: pd.DataFrame
  config: dict
  timing: dict
  grid: GridMap
  state: sim.State
  out: Path | None = None


def default_max_steps(grid: GridMap, params: Params) -> int:
  """A step budget generous for frontier exploration of the reachable area: about three sweeps
  of the free area with a swath of twice the (capped) sensor range, plus turning time."""
  step_m = float(params.v_max) * float(params.dt)
  swath = 2.0 * min(float(params.r_max), 3.0)
  return int(3.0 * grid.free_area / swath / step_m) + 1000


def estimate_bytes(config: SimConfig, robots: int) -> int:
  """Rough peak memory of a run: per-robot state and planning masks, records, lidar buffers."""
  cells = config.height * config.width
  per_robot_state = cells * (4 + 4 + 1)  # log-odds, entropy map, blacklist
  per_robot_planning = cells * 4 * 8  # distances, predecessors, masks of one planning round
  records = config.max_steps * 10 * 4
  lidar = config.n_beams * (4 * config.max_range_cells + 2) * 4 * 6
  return robots * (per_robot_state + records + lidar) + min(robots, 64) * per_robot_planning


def available_bytes() -> int:
  try:
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
  except (ValueError, OSError, AttributeError):
    return 8 << 30


@functools.lru_cache(maxsize=32)
def _compiled_advance(config: SimConfig, n_epochs: int, n_devices: int):
  """The chunk function, jitted once per (config, chunk length, device count)."""
  fn = functools.partial(sim.advance_unjitted, config, n_epochs=n_epochs)
  if n_devices <= 1:
    return jax.jit(fn)
  from jax.sharding import Mesh, PartitionSpec as P
  mesh = Mesh(np.array(jax.local_devices()[:n_devices]), ("robots",))
  sharded = jax.shard_map(fn, mesh=mesh, in_specs=(P(), P("robots"), P("robots")),
                          out_specs=(P("robots"), P(None, "robots")), check_vma=False)
  return jax.jit(sharded)


def _to_float(leaf):
  arr = np.asarray(leaf, np.float64)
  return float(arr) if arr.ndim == 0 else arr.tolist()


def parse_start(start) -> tuple[float, float, float] | None:
  if start is None:
    return None
  values = [float(v) for v in (start.split(",") if isinstance(start, str) else start)]
  if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
    raise ConfigError(f"start must be 'x,y' or 'x,y,theta' in metres/radians, got {start!r}")
  return (values[0], values[1], values[2] if len(values) == 3 else 0.0)


# Settings a user gives like parameters (``--set r_e=1.0``) that fix a shape, so they are static
# (``SimConfig``), not traced: one value per batch.
STATIC_PARAMS = ("r_e",)


def split_static(params: dict | None) -> tuple[dict, dict]:
  """Splits parameter overrides into (traced, static): see :data:`STATIC_PARAMS`. A static value
  given per robot must be the same for all of them."""
  traced, static = {}, {}
  for name, value in (params or {}).items():
    if name not in STATIC_PARAMS:
      traced[name] = value
      continue
    values = np.unique(np.asarray(value, np.float64))
    if values.size != 1:
      raise ConfigError(f"{name} fixes a shape and must be one value per batch, got {values}")
    static[name] = float(values[0])
  return traced, static


def build_params(planner: str, preset, res: float, params=None, planner_params=None) -> Params:
  """The :class:`Params` of a run: preset, overrides, the planner's default weights and overrides.

  Leaves may be scalars or arrays with one value per robot (a sweep). No validation of values.
  Static settings among the overrides (:data:`STATIC_PARAMS`, the planner's settings) are left
  out: :func:`prepare` puts them into the ``SimConfig``.
  """
  spec = get_planner(planner)
  traced_weights, _ = spec.split_overrides(planner_params)
  weights = dict(spec.defaults)
  weights.update(traced_weights)
  return make_params(preset, res=res, planner=weights, **split_static(params)[0])


def robot_keys(seeds) -> jax.Array:
  """One PRNG key per robot, ``PRNGKey(s)`` for seed ``s`` (the same start in every setting)."""
  return jax.vmap(jax.random.PRNGKey)(jnp.asarray([int(s) for s in seeds], jnp.uint32))


def default_chunk_epochs(config: SimConfig) -> int:
  """Planning rounds per compiled call: about 500 steps, the granularity of progress and early stop."""
  return max(1, min(config.n_epochs, 2000 // config.replan_every // 4 or 1))


def prepare(world="office", planner="nearest_frontier", robots=16, seed=0, preset="li2020",
            res=None, start=None, max_steps=None, replan_every=None, params=None,
            planner_params=None, pose_noise=False, path_capacity=None, plan_window=None,
            pose_graph=None, graph_loops=None):
  """Resolves and validates every setting (no compute). Returns (grid, config, params, start).

  ``pose_graph``: keep each robot's SLAM pose graph (None: when the planner needs one); its
  keyframe capacity is the run's bound (:func:`jaxplore.posegraph.keyframe_bound`).
  """
  if not isinstance(robots, (int, np.integer)) or robots < 1:
    raise ConfigError(f"robots must be a positive integer, got {robots!r}")
  spec = get_planner(planner)
  if preset is not None and preset not in PRESETS:
    raise ConfigError(f"unknown preset {preset!r}; valid presets: {', '.join(sorted(PRESETS))}")
  grid = world if isinstance(world, GridMap) else load_world(world, res=res)
  start_pose = parse_start(start)
  p = build_params(planner, preset, grid.res, params, planner_params)
  _, static = split_static(params)
  _, settings = spec.split_overrides(planner_params)
  overrides = dict(planner=planner, pose_noise=bool(pose_noise),
                   planner_settings=spec.resolve_settings(settings), **static)
  if replan_every is not None:
    overrides["replan_every"] = int(replan_every)
  if path_capacity is not None:
    overrides["path_capacity"] = int(path_capacity)
  if plan_window is not None:
    overrides["plan_window"] = int(plan_window)
  steps = int(max_steps) if max_steps is not None else default_max_steps(grid, p)
  if pose_graph or (pose_graph is None and spec.needs_pose_graph):
    overrides["graph_nodes"] = posegraph.keyframe_bound(steps, p.v_max, p.w_max, p.dt, p.kf_dist, p.kf_rot)
    if graph_loops is not None:
      overrides["graph_loops"] = int(graph_loops)
  config = config_for(grid.shape, grid.res, p, preset=preset, max_steps=steps, **overrides)
  validate_params(p, config)
  if spec.validate is not None:
    spec.validate({k: np.asarray(v) for k, v in p.planner.items()}, p, sim.planner_context(config))
  return grid, config, p, start_pose


def run(world="office", planner="nearest_frontier", robots=16, seed=0, preset="li2020", res=None,
        start=None, max_steps=None, replan_every=None, params=None, planner_params=None,
        pose_noise=False, path_capacity=None, out=None, progress=True, devices=None,
        chunk_epochs=None, rate_interval=1.0, quiet=False, robot_seeds=None,
        plan_window=None, pose_graph=None, graph_loops=None) -> RunResult:
  """Runs ``robots`` robots exploring ``world`` with ``planner`` and returns/writes the results.

  Args:
    world: a built-in world name (``jaxplore maps``), a map_server YAML path, or a GridMap.
    planner: a registered planner name.
    robots: batch size; each robot gets its own PRNG key from ``seed``.
    preset: sensor/robot preset (``li2020``, ``godoy_open``, ``godoy_office``, ``toriz``,
      ``explore_bench``).
    res: resample the world to this resolution (m/cell); coarser only for loaded maps.
    start: (x, y[, θ]) start pose for every robot, or None to sample per robot.
    max_steps: step budget per robot (``timeout`` after it); default from the world's size.
    replan_every: a robot replans after this many steps even if its path is not done.
    params: overrides of :class:`jaxplore.config.Params` fields (e.g. ``{"r_max": 10}``).
    planner_params: overrides of the planner's weights.
    pose_noise: corrupt odometry and integrate scans at the dead-reckoned estimate.
    out: results folder (created); None writes nothing.
    devices: how many local devices to shard the batch over (default: all).
    chunk_epochs: planning rounds per compiled chunk (progress granularity).
    rate_interval: metres per interval for ``Std(E_r)``.
    robot_seeds: optional list of one integer seed per robot (its PRNG key is ``PRNGKey(s)``), so
      the same seed gives the same start in every setting of a sweep; default: ``robots`` keys
      split from ``seed``.
    plan_window: side in cells of the window nearest frontier plans on first (0 = whole grid
      always); default picked from the sensor range (``SimConfig.plan_window``).
    pose_graph, graph_loops: see :func:`prepare`.
  """
  grid, config, p, start_pose = prepare(world, planner, robots, seed, preset, res, start, max_steps,
                                        replan_every, params, planner_params, pose_noise,
                                        path_capacity, plan_window, pose_graph, graph_loops)
  need, have = estimate_bytes(config, robots), available_bytes()
  if need > 0.8 * have:
    raise ConfigError(f"{robots} robots on a {config.height}x{config.width} grid need about "
                      f"{need / 2**30:.1f} GiB, more than 80% of the {have / 2**30:.1f} GiB available; "
                      f"use fewer robots or a coarser --res")
  world_dev = sim.make_world(grid, float(np.max(np.asarray(p.r_robot))),
                             None if start_pose is None else start_pose[:2])

  n_local = len(jax.local_devices())
  n_dev = n_local if devices is None else max(1, min(int(devices), n_local))
  n_dev = math.gcd(n_dev, robots) if robots % n_dev else n_dev
  params_b = sim.broadcast_params(p, robots)
  if robot_seeds is None:
    keys = jax.random.split(jax.random.PRNGKey(seed), robots)
  else:
    robot_seeds = [int(s) for s in robot_seeds]
    if len(robot_seeds) != robots:
      raise ConfigError(f"robot_seeds has {len(robot_seeds)} seeds for {robots} robots")
    keys = robot_keys(robot_seeds)
  starts = None if start_pose is None else jnp.tile(jnp.asarray(start_pose, jnp.float32), (robots, 1))
  if chunk_epochs is None:
    chunk_epochs = default_chunk_epochs(config)
  advance = _compiled_advance(config, int(chunk_epochs), n_dev)

  t0 = time.perf_counter()
  state = sim.reset_batch(config, world_dev, params_b, keys, starts)
  jax.block_until_ready(state)
  t_reset = time.perf_counter() - t0
  t0 = time.perf_counter()
  compiled = advance.lower(world_dev, params_b, state).compile()
  t_compile = time.perf_counter() - t0

  chunks, interrupted = [], False
  bar = None
  if progress:
    from tqdm.auto import tqdm
    bar = tqdm(total=config.max_steps, unit="step", desc=f"{planner} x{robots} on {grid.name}",
               disable=quiet)
  t0 = time.perf_counter()
  steps_done = 0
  try:
    while steps_done < config.max_steps:
      state, rec = compiled(world_dev, params_b, state)
      rec = jax.tree.map(np.asarray, rec)
      chunks.append(rec)
      n = rec.done.shape[0]
      steps_done += n
      done = np.asarray(state.done)
      if bar is not None:
        bar.update(min(n, config.max_steps - bar.n))
        bar.set_postfix(done=f"{int(done.sum())}/{robots}", coverage=f"{float(rec.coverage[-1].mean()):.3f}")
      if done.all():
        break
  except KeyboardInterrupt:
    interrupted = True
  finally:
    if bar is not None:
      bar.close()
  t_run = time.perf_counter() - t0

  records = jax.tree.map(lambda *xs: np.concatenate(xs, axis=0)[: config.max_steps], *chunks) if chunks else None
  state_np = jax.tree.map(np.asarray, state)
  episodes, curves = tables(config, grid, world_dev, p, state_np, records, rate_interval)
  episodes.insert(0, "planner", planner)
  episodes.insert(0, "world", grid.name)
  episodes.insert(2, "seed", seed if robot_seeds is None else robot_seeds)
  resolved = {
      "jaxplore_version": __version__, "jax_version": jax.__version__, "numpy_version": np.__version__,
      "python": platform.python_version(), "devices": [str(d) for d in jax.devices()],
      "sharded_over": n_dev, "seed": seed, "robot_seeds": robot_seeds, "robots": robots, "planner": planner, "preset": preset,
      "start": start_pose, "interrupted": interrupted,
      "world": {"name": grid.name, "shape": list(grid.shape), "res": grid.res, "origin": list(grid.origin),
                "free_m2": grid.free_area,
                "reachable_m2": float(world_dev.n_reachable) * grid.res**2},
      "sim_config": dataclasses.asdict(config),
      "params": {k: _to_float(v) for k, v in dataclasses.asdict(p).items() if k != "planner"},
      "planner_params": {k: _to_float(v) for k, v in p.planner.items()},
      "planner_settings": (dataclasses.asdict(config.planner_settings)
                           if config.planner_settings is not None else {}),
      "rate_interval_m": rate_interval,
  }
  robot_steps = int(np.asarray(state_np.steps).sum())
  timing = {"reset_s": t_reset, "compile_s": t_compile, "run_s": t_run,
            "sim_steps": steps_done, "robot_steps": robot_steps,
            "robot_steps_per_s": robot_steps / t_run if t_run > 0 else float("nan")}
  result = RunResult(episodes, curves, resolved, timing, grid, state_np)
  if out is not None:
    result.out = write_results(result, Path(out))
  if not quiet:
    print(summary_table(episodes))
  if interrupted:
    raise KeyboardInterrupt(f"interrupted; partial results kept{' in ' + str(out) if out else ''}")
  return result


def tables(config: SimConfig, grid: GridMap, world: sim.World, params: Params, state, records,
           rate_interval: float):
  """(episodes, curves) DataFrames from the final state and the stacked records [T, B]."""
  robots = state.done.shape[0]
  n_reach = float(world.n_reachable)
  if records is None:
    curves = pd.DataFrame(columns=["robot", "step"])
  else:
    done = records.done
    ever = done.any(axis=0)
    last = np.where(ever, done.argmax(axis=0), done.shape[0] - 1)
    steps = np.arange(done.shape[0])
    keep = steps[:, None] <= last[None, :]
    t_idx, r_idx = np.nonzero(keep)
    order = np.lexsort((t_idx, r_idx))
    t_idx, r_idx = t_idx[order], r_idx[order]
    curves = pd.DataFrame({"robot": r_idx.astype(np.int32), "step": (t_idx + 1).astype(np.int32)})
    for name in ("time", "distance", "entropy", "coverage", "det_cov", "pose_error", "x", "y",
                 "graph_nodes", "graph_edges", "dopt_mean"):
      if getattr(records, name) is not None:
        curves[name] = getattr(records, name)[t_idx, r_idx].astype(np.float64)
  initial = float(config.height * config.width * math.log(2.0))
  rows = []
  groups = dict(tuple(curves.groupby("robot"))) if len(curves) else {}
  for b in range(robots):
    curve = groups.get(b)
    row = {"robot": b, "reason": sim.REASONS[int(state.reason[b])]}
    if curve is not None and len(curve):
      row.update(metrics.episode_row(curve, initial, grid.res, n_reach, rate_interval))
    row["idle_steps"] = int(state.idle_steps[b])
    graph = None if state.graph is None else jax.tree.map(lambda x: x[b], state.graph)
    row.update(metrics.map_and_graph_row(
        state.logodds[b], grid.occupied, graph,
        None if curve is None or "dopt_mean" not in curve else curve.dopt_mean.to_numpy()))
    rows.append(row)
  return pd.DataFrame(rows), curves


def _atomic_write(path: Path, write):
  tmp = path.with_name(path.name + ".tmp")
  write(tmp)
  os.replace(tmp, path)


def write_results(result: RunResult, out: Path) -> Path:
  """Writes config.json, timing.json, episodes.parquet, curves.parquet, maps.npz and figures."""
  from jaxplore import plot
  out.mkdir(parents=True, exist_ok=True)
  _atomic_write(out / "config.json", lambda p: p.write_text(json.dumps(result.config, indent=2)))
  _atomic_write(out / "timing.json", lambda p: p.write_text(json.dumps(result.timing, indent=2)))
  _atomic_write(out / "episodes.parquet", lambda p: result.episodes.to_parquet(p, index=False))
  _atomic_write(out / "curves.parquet", lambda p: result.curves.to_parquet(p, index=False))
  shown = min(4, result.state.logodds.shape[0])

  def save_maps(p):
    with open(p, "wb") as f:
      np.savez_compressed(f, occupied=result.grid.occupied, res=result.grid.res,
                          origin=np.asarray(result.grid.origin),
                          logodds=result.state.logodds[:shown].astype(np.float16))
  _atomic_write(out / "maps.npz", save_maps)
  plot.run_figures(out)
  return out


def summary_table(episodes: pd.DataFrame) -> str:
  """A short text table: reasons, and mean ± std of the headline metrics."""
  lines = []
  reasons = episodes["reason"].value_counts().to_dict()
  lines.append("termination: " + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())))
  for col, unit in (("time_s", "s"), ("distance_m", "m"), ("coverage", ""), ("coverage_m2", "m²"),
                    ("entropy_reduction", "nats"), ("E_r", "nats/m"), ("Std_E_r", "nats/m"),
                    ("t90_s", "s"), ("t99_s", "s")):
    if col in episodes:
      v = episodes[col].astype(float)
      lines.append(f"  {col:<18} {v.mean():12.4g} ± {v.std():<10.4g} {unit}  (min {v.min():.4g}, max {v.max():.4g})")
  return "\n".join(lines)


def sweep(*args, **kwargs):
  """A parameter sweep in chunks, resumable: see :func:`jaxplore.sweeps.sweep` (same arguments)."""
  from jaxplore import sweeps
  return sweeps.sweep(*args, **kwargs)
