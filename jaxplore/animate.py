"""Animations of a saved run: belief map, trajectory and current path of chosen robots over time.

A results folder keeps only the final belief of a few robots, so :func:`animate` *re-simulates* the
chosen robots: it rebuilds the run specification from ``config.json`` (a sweep folder: the
specification of the robots' group, from its schedule) and resolves it as the run did
(:func:`jaxplore.resolve.resolve`), giving the same static config, parameter values and PRNG keys
(a run is reproducible); it refuses settings that resolve to another static config than the
recorded one, and checks that the replayed trajectory equals the ``x``, ``y`` columns of
``curves.parquet`` before drawing anything, so the animation shows the run that was recorded.

Frames are taken at planning rounds (every ``replan_every`` motion steps at the finest); each
shows, per robot, its log-odds belief over the truth, its trajectory so far (at step resolution),
and the rest of the path it is following at that moment (from its cell to its goal).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd

from jaxplore import results
from jaxplore.config import ConfigError
from jaxplore.errors import check_writable
from jaxplore.resolve import Batch, Resolved, config_difference, resolve
from jaxplore.runspec import SIM_PARAMS, RunSpec

MAX_FRAMES = 150  # default frame budget: --every is chosen so an animation has at most this many
TOLERANCE_M = 1e-4  # replayed and recorded positions must agree to this (metres)
WRITERS = {".gif": "pillow", ".mp4": "ffmpeg"}


@dataclasses.dataclass
class Replay:
  """The chosen robots re-simulated, with snapshots between planning rounds.

  Attributes:
    robots: indices of the robots in the run (panel order); a sweep's global row numbers.
    config: the folder's ``config.json``.
    planner, world: names, for titles.
    occupied, res, origin: the truth map.
    x, y: f64[T, R] replayed positions after every step (T = steps replayed).
    steps_recorded: int[R] steps of each robot in ``curves.parquet`` (its last is its done step).
    frames: snapshots at planning rounds, each a dict with ``step`` (int), ``logodds``
      f16[R, H, W], ``pose`` f32[R, 3], ``time``, ``coverage`` f32[R], ``done`` bool[R],
      ``reason`` i32[R], and the rest of the path being followed: ``waypoints`` i32[R, L + 1, 2]
      (the robot's cell, then the waypoints still ahead), ``path_len`` i32[R], ``goal`` i32[R, 2],
      ``planned`` bool[R] (False: done, or no waypoint ahead).
    max_deviation_m: largest |replayed − recorded| position over the recorded steps.
  """

  robots: tuple
  config: dict
  planner: str
  world: str
  occupied: np.ndarray
  res: float
  origin: np.ndarray
  x: np.ndarray
  y: np.ndarray
  steps_recorded: np.ndarray
  frames: list
  max_deviation_m: float


def load_run(run_dir) -> tuple[Path, dict, pd.DataFrame, pd.DataFrame]:
  """(run_dir, config, episodes, curves) of a results folder of ``jaxplore run`` or ``sweep``.

  Raises:
    ConfigError: the folder or one of its files is missing.
  """
  folder = results.load_folder(run_dir)
  return folder.path, folder.config, folder.episodes, folder.curves


def parse_robots(robots, n_robots: int) -> tuple[int, ...]:
  """Robot indices from ``"0,1,2"`` or a sequence of ints, checked against the run's batch size."""
  if isinstance(robots, (int, np.integer)):
    robots = (robots,)
  if isinstance(robots, str):
    try:
      robots = [int(r) for r in robots.split(",") if r.strip()]
    except ValueError:
      raise ConfigError(
          f"robots must be comma-separated integers like 0,1,2, got {robots!r}") from None
  robots = tuple(int(r) for r in robots)
  if not robots:
    raise ConfigError("choose at least one robot to animate")
  bad = [r for r in robots if not 0 <= r < n_robots]
  if bad:
    raise ConfigError(f"robot index {bad[0]} is out of range: the run has {n_robots} robots "
                      f"(0..{n_robots - 1})")
  if len(set(robots)) != len(robots):
    raise ConfigError(f"robot indices repeat: {list(robots)}")
  return robots


def _robot_seeds(config: dict, episodes: pd.DataFrame):
  """One integer seed per robot of a ``run(robot_seeds=...)`` call, else None (keys split from
  ``seed``). config.json records ``robot_seeds``; folders written before it did are read from
  the episodes' seed column, which holds either ``seed`` on every row or the robot seeds (a wrong
  guess cannot pass unnoticed: the replay would not match)."""
  if "robot_seeds" in config:
    seeds = config["robot_seeds"]
    return None if seeds is None else [int(v) for v in seeds]
  if "seed" not in episodes:
    return None
  seeds = episodes.sort_values("robot")["seed"].to_numpy()
  if np.all(seeds == int(config["seed"])):
    return None
  return [int(v) for v in seeds]


def _legacy_spec(config: dict, episodes: pd.DataFrame, grid) -> RunSpec:
  """The run spec of a folder written before config.json recorded one: every recorded parameter
  value (so none is derived again), the recorded static sizes, seeds and start."""
  sim_config = config["sim_config"]
  n_robots = int(config["robots"])
  values = lambda d: {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
  seeds = _robot_seeds(config, episodes)
  if seeds is not None and len(seeds) != n_robots:
    raise ConfigError(f"config.json records {len(seeds)} robot seeds for {n_robots} robots")
  return RunSpec(
      world=grid, planner=config.get("planner", sim_config["planner"]), robots=n_robots,
      seed=int(config["seed"]), robot_seeds=seeds, preset=config.get("preset"),
      start=config.get("start"), max_steps=sim_config["max_steps"],
      replan_every=sim_config["replan_every"], path_capacity=sim_config["path_capacity"],
      plan_window=sim_config.get("plan_window"), pose_noise=sim_config["pose_noise"],
      slam=sim_config.get("slam"),
      params={k: v for k, v in values(config["params"]).items() if k in SIM_PARAMS},
      planner_params=values(config["planner_params"]))


def _check_config(resolved, recorded: dict | None, where: Path | None, version: str):
  """Refuses to replay settings that resolve to another static config than the recorded one."""
  difference = config_difference(recorded, resolved.config)
  if difference is not None:
    raise ConfigError(
        f"{where} was written by jaxplore {version} and its settings resolve differently here "
        f"({difference}): an animation would not show the recorded run")


@dataclasses.dataclass
class _Setup:
  """What a replay needs: the chosen robots, the resolved batch and the planner's name."""

  robots: tuple
  resolved: Resolved
  batch: Batch  # of the chosen robots


def _run_setup(run_dir: Path, config: dict, episodes: pd.DataFrame, robots) -> _Setup:
  """A ``jaxplore run`` folder: its spec from config.json, the truth from maps.npz."""
  for key in ("sim_config", "params", "planner_params", "robots", "seed"):
    if key not in config:
      raise ConfigError(f"{run_dir / 'config.json'} has no {key!r}; it was not written by "
                        f"`jaxplore run` (nor is it a sweep folder with a schedule)")
  if not (run_dir / "maps.npz").is_file():
    raise ConfigError(f"{str(run_dir)!r} has no maps.npz (the truth map of the run)")
  robots = parse_robots(robots, int(config["robots"]))
  grid = results.read_maps_truth(run_dir / "maps.npz", config.get("world", {}).get("name", "map"))
  if "spec" in config:
    spec = RunSpec.from_json(config["spec"], world=grid)
  else:
    spec = _legacy_spec(config, episodes, grid)
  resolved = resolve(spec)
  _check_config(resolved, config["sim_config"], run_dir / "config.json",
                config.get("jaxplore_version", "?"))
  return _Setup(robots, resolved, resolved.batch(robots))


def _sweep_setup(run_dir: Path, robots) -> _Setup:
  """A ``jaxplore sweep`` folder: the robots (global row numbers) of one group, resolved from
  its schedule as the sweep ran them."""
  from jaxplore.sweeps import schedule as schedules
  made = schedules.read_schedule(run_dir, action="animate")
  robots = parse_robots(robots, made.rows)
  where = {row.row: (g, k)
           for g, group in enumerate(made.groups) for k, row in enumerate(group.rows)}
  chosen = {where[r][0] for r in robots}
  if len(chosen) > 1:
    def label(r):
      group = made.groups[where[r][0]]
      return f"robot {r}: {made.spec.worlds[group.world].label} / {group.planner}"
    labels = [label(r) for r in robots]
    raise ConfigError("the chosen robots ran in different world x planner groups (different "
                      f"programs); animate one group at a time: {'; '.join(labels)}")
  group = made.groups[chosen.pop()]
  resolved = schedules.resolve_group(made.spec, group, run_dir, {})
  _check_config(resolved, group.sim_config, schedules.schedule_path(run_dir),
                made.jaxplore_version)
  return _Setup(robots, resolved, resolved.batch([where[r][1] for r in robots]))


def resimulate(run_dir, robots=(0,), every=None, max_frames: int = MAX_FRAMES,
               progress: bool = True, check: bool = True) -> Replay:
  """Re-runs the chosen robots of a saved run and snapshots them at planning rounds.

  Args:
    run_dir: a results folder of ``jaxplore run --out`` or ``jaxplore sweep --out``.
    robots: robot indices (ints or ``"0,1,2"``); in a sweep, the ``robot`` column of its tables
      (all from one world × planner group).
    every: motion steps between frames, rounded up to a multiple of ``replan_every``; default:
      the smallest such multiple that keeps at most ``max_frames`` frames.
    progress: show a progress bar.
    check: raise if the replayed trajectory differs from ``curves.parquet``.
  Raises:
    ConfigError: bad folder or robot index, sweep robots of different groups; with ``check``, a
      replay that does not reproduce the recorded trajectory (e.g. a different JAX version
      changed the numbers).
  """
  run_dir, config, episodes, curves = load_run(run_dir)
  if every is not None and not (isinstance(every, (int, np.integer)) and every >= 1):
    raise ConfigError(f"every must be a positive number of steps, got {every!r}")
  if results.is_sweep_folder(run_dir):
    setup = _sweep_setup(run_dir, robots)
  else:
    setup = _run_setup(run_dir, config, episodes, robots)
  robots, resolved = setup.robots, setup.resolved
  sim_config, world = resolved.config, resolved.world
  params, keys, starts = setup.batch

  import jax

  from jaxplore import sim

  draw_memory = sim_config.planner.memory_graph

  recorded = curves.groupby("robot").step.max()
  steps_recorded = np.asarray([int(recorded.get(r, 0)) for r in robots])
  total_steps = int(steps_recorded.max())
  per_epoch = sim_config.replan_every
  n_epochs = max(1, -(-total_steps // per_epoch))
  if every is None:
    every_epochs = max(1, -(-n_epochs // max(1, max_frames - 1)))
  else:
    every_epochs = max(1, -(-int(every) // per_epoch))

  def snapshot(state, step):
    frame = {name: np.asarray(getattr(state, name)) for name in ("pose", "time", "done", "reason")}
    frame["logodds"] = np.asarray(state.logodds).astype(np.float16)
    frame["coverage"] = np.asarray(state.covered) / float(world.n_reachable)
    frame["step"] = step
    # The path still ahead: a robot plans when it needs to, at the start of a step, so the state
    # holds the path it is following; waypoints before path_idx are behind it.
    waypoints, path_idx = np.asarray(state.waypoints), np.asarray(state.path_idx)
    path_len = np.asarray(state.path_len)
    cells = np.floor((frame["pose"][:, [1, 0]] - np.asarray(world.origin)[[1, 0]]) / sim_config.res)
    ahead = np.full((len(robots), waypoints.shape[1] + 1, 2), -1, np.int32)
    lengths = np.zeros(len(robots), np.int32)
    for j in range(len(robots)):
      rest = waypoints[j, path_idx[j]: max(path_idx[j], path_len[j])]
      ahead[j, 0] = cells[j]
      ahead[j, 1: 1 + len(rest)] = rest
      lengths[j] = 1 + len(rest)
    frame.update(waypoints=ahead, path_len=lengths, goal=np.asarray(state.goal))
    frame["planned"] = ~frame["done"] & (lengths > 1)
    if draw_memory is not None:  # a graph the planner keeps (the REG family's), drawn too
      arrays = results.memory_arrays(state.memory, len(robots))
      frame["graph"] = [draw_memory({k: v[j] for k, v in arrays.items()}, sim_config.res,
                                    np.asarray(world.origin))
                        for j in range(len(robots))]
    return frame

  state = sim.reset_batch(sim_config, world, params, keys, starts)
  frames = [snapshot(state, 0)]
  xs, ys = [], []
  bar = None
  if progress:
    from tqdm.auto import tqdm
    bar = tqdm(total=n_epochs * per_epoch, unit="step",
               desc=f"replaying robots {','.join(map(str, robots))}")
  try:
    for k in range(1, n_epochs + 1):
      state, rec = sim.advance(sim_config, world, params, state, n_epochs=1)
      xs.append(np.asarray(rec.x, np.float64))
      ys.append(np.asarray(rec.y, np.float64))
      if k % every_epochs == 0 or k == n_epochs:
        frames.append(snapshot(state, min(k * per_epoch, sim_config.max_steps)))
      if bar is not None:
        bar.update(per_epoch)
  finally:
    if bar is not None:
      bar.close()
  x, y = np.concatenate(xs), np.concatenate(ys)

  deviation = 0.0
  for j, r in enumerate(robots):
    curve = curves[curves.robot == r].sort_values("step")
    n = len(curve)
    if n == 0:
      continue
    dev = np.hypot(x[:n, j] - curve.x.to_numpy(), y[:n, j] - curve.y.to_numpy())
    deviation = max(deviation, float(dev.max()))
    if check and dev.max() > TOLERANCE_M:
      first = int(np.argmax(dev > TOLERANCE_M))
      raise ConfigError(
          f"the replay of robot {r} leaves the recorded trajectory at step {first + 1} "
          f"(by {dev[first]:.3g} m, at most {dev.max():.3g} m); the run was made with JAX "
          f"{config.get('jax_version', '?')} and jaxplore {config.get('jaxplore_version', '?')}, "
          f"this is JAX {jax.__version__}: an animation would not show the recorded run")
  grid = resolved.grid
  return Replay(robots=robots, config=config, planner=sim_config.planner.name, world=grid.name,
                occupied=grid.occupied, res=grid.res,
                origin=np.asarray(grid.origin), x=x, y=y, steps_recorded=steps_recorded,
                frames=frames, max_deviation_m=deviation)


def _cells_to_xy(cells, res, origin):
  """i32[..., 2] (row, col) -> (x, y) arrays of cell centres in metres."""
  cells = np.asarray(cells)
  return origin[0] + (cells[..., 1] + 0.5) * res, origin[1] + (cells[..., 0] + 0.5) * res


def render(replay: Replay, out, fps: float = 8.0, dpi: int = 80, progress: bool = True) -> Path:
  """Draws ``replay`` to a GIF (Pillow) or MP4 (ffmpeg) at ``out``; written atomically."""
  out = Path(out)
  writer_name = _writer_name(out)
  import matplotlib.pyplot as plt
  from matplotlib import animation
  from matplotlib.collections import LineCollection, PolyCollection

  from jaxplore import plot, sim  # plot picks the Agg backend unless MPLBACKEND says otherwise

  robots, n = replay.robots, len(replay.robots)
  h, w = replay.occupied.shape
  extent = (replay.origin[0], replay.origin[0] + w * replay.res,
            replay.origin[1], replay.origin[1] + h * replay.res)
  ncols = min(n, 3)
  nrows = -(-n // ncols)
  panel_w = 4.0
  panel_h = max(1.5, min(6.0, panel_w * h / w)) + 0.5
  fig, axes = plt.subplots(nrows, ncols, figsize=(panel_w * ncols, panel_h * nrows), squeeze=False)
  colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
  artists = []
  for j, _r in enumerate(robots):
    ax = axes[j // ncols][j % ncols]
    colour = colours[j % len(colours)]
    image = ax.imshow(plot.belief_rgb(replay.occupied, replay.frames[0]["logodds"][j]),
                      origin="lower", extent=extent, interpolation="nearest")
    trail, = ax.plot([], [], lw=1.2, color=colour, label="trajectory")
    path, = ax.plot([], [], lw=1.0, ls="--", color="tab:red", label="planned path")
    goal, = ax.plot([], [], "x", ms=7, mew=2, color="tab:red", label="goal")
    robot, = ax.plot([], [], "o", ms=5, color=colour, mec="k")
    graph = None
    if "graph" in replay.frames[0]:
      graph = (ax.add_collection(PolyCollection([], facecolors=(0.2, 0.5, 0.9, 0.06),
                                                edgecolors=(0.2, 0.5, 0.9, 0.3), linewidths=0.4)),
               ax.add_collection(LineCollection([], colors="tab:green", linewidths=0.8)),
               ax.plot([], [], "o", ms=2.5, color="tab:green", label="exploration graph")[0])
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    if j == 0:
      ax.legend(loc="upper right", fontsize=6, framealpha=0.8)
    artists.append((ax, image, trail, path, goal, robot, graph))
  for j in range(n, nrows * ncols):
    axes[j // ncols][j % ncols].axis("off")
  title = fig.suptitle("")
  fig.tight_layout()

  def draw(frame):
    step = frame["step"]
    for j, r in enumerate(robots):
      ax, image, trail, path, goal, robot, graph = artists[j]
      image.set_data(plot.belief_rgb(replay.occupied, frame["logodds"][j]))
      shown = min(step, int(replay.steps_recorded[j]))
      trail.set_data(replay.x[:shown, j], replay.y[:shown, j])
      pose = frame["pose"][j]
      robot.set_data([pose[0]], [pose[1]])
      if frame["planned"][j]:
        px, py = _cells_to_xy(frame["waypoints"][j][: int(frame["path_len"][j])], replay.res,
                              replay.origin)
        path.set_data(np.concatenate([[pose[0]], px]), np.concatenate([[pose[1]], py]))
        gx, gy = _cells_to_xy(frame["goal"][j], replay.res, replay.origin)
        goal.set_data([gx], [gy])
      else:
        path.set_data([], [])
        goal.set_data([], [])
      if graph is not None:
        g = frame["graph"][j]
        graph[0].set_verts(list(g.lsr))
        graph[1].set_segments(list(g.nodes[g.edges]))
        graph[2].set_data(g.nodes[:, 0], g.nodes[:, 1])
      status = sim.REASONS[int(frame["reason"][j])] if frame["done"][j] else "exploring"
      ax.set_title(f"robot {r}: {float(frame['time'][j]):.0f} s, coverage "
                   f"{100 * float(frame['coverage'][j]):.0f} % ({status})", fontsize=8)
    title.set_text(f"{replay.planner} on {replay.world}"
                   f", step {step}")

  # matplotlib's stubs say fps is an int; the writers take any positive number (a frame's
  # duration is 1000 / fps ms for Pillow, ffmpeg gets -framerate str(fps)).
  writer: animation.AbstractMovieWriter
  if writer_name == "pillow":
    writer = animation.PillowWriter(fps=fps)  # type: ignore[arg-type]  # stub: fps int only
  else:
    writer = animation.FFMpegWriter(fps=fps,  # type: ignore[arg-type]  # stub: fps int only
                                    codec="h264", extra_args=["-pix_fmt", "yuv420p"])
  out.parent.mkdir(parents=True, exist_ok=True)
  tmp = out.with_name(out.stem + ".tmp" + out.suffix)
  bar = None
  if progress:
    from tqdm.auto import tqdm
    bar = tqdm(total=len(replay.frames), unit="frame", desc=f"rendering {out.name}")
  try:
    with writer.saving(fig, str(tmp), dpi):
      for frame in replay.frames:
        draw(frame)
        writer.grab_frame()
        if bar is not None:
          bar.update(1)
  except BaseException:
    tmp.unlink(missing_ok=True)
    raise
  finally:
    if bar is not None:
      bar.close()
    plt.close(fig)
  tmp.replace(out)
  return out


def _writer_name(out: Path) -> str:
  suffix = out.suffix.lower()
  if suffix not in WRITERS:
    raise ConfigError(f"cannot write {str(out)!r}: the animation file must end in "
                      f"{' or '.join(WRITERS)}")
  name = WRITERS[suffix]
  if name == "ffmpeg":
    from matplotlib import animation
    if not animation.FFMpegWriter.isAvailable():
      raise ConfigError(f"writing {str(out)!r} needs ffmpeg, which is not on PATH; install ffmpeg "
                        "or write a .gif instead")
  return name


def animate(run_dir, robots=(0,), out=None, every=None, fps: float = 8.0,
            progress: bool = True) -> Path:
  """Writes an animation of robots of a saved run and returns its path.

  Args:
    run_dir: a results folder of ``jaxplore run --out`` or ``jaxplore sweep --out``.
    robots: robot indices, e.g. ``(0, 1, 2)`` or ``"0,1,2"``; one panel each.
    out: ``.gif`` (Pillow) or ``.mp4`` (needs ffmpeg); default
      ``RUN_DIR/animation_<robots>.gif``.
    every: motion steps between frames (rounded up to whole planning rounds); default: at most
      :data:`MAX_FRAMES` frames.
    fps: frames per second.
  Raises:
    ConfigError: missing folder or file, robot index out of range, unknown file type, MP4 without
      ffmpeg, or a replay that does not reproduce the recorded trajectory.
  """
  run_dir = Path(run_dir)
  if out is not None:
    _writer_name(Path(out))  # refuse a bad file name before the replay
  # and a place it cannot be written (the replay takes seconds to minutes)
  check_writable(run_dir if out is None else out,
                 "the animation's folder" if out is None else "--out")
  if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
    raise ConfigError(f"fps must be a positive number, got {fps!r}")
  replay = resimulate(run_dir, robots, every=every, progress=progress)
  if out is None:
    out = run_dir / f"animation_{'-'.join(map(str, replay.robots))}.gif"
  return render(replay, out, fps=fps, progress=progress)


__all__ = ["Replay", "animate", "load_run", "parse_robots", "render", "resimulate"]
