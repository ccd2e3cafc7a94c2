"""Figures of a run, drawn from its saved results folder (so ``jaxplore plot DIR`` can redraw
them)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import matplotlib

# Figures go to files; an explicit MPLBACKEND (Jupyter's kernel sets its inline backend there)
# is kept so figures a notebook draws still show.
if not os.environ.get("MPLBACKEND"):
  matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from jaxplore.errors import ConfigError, check_writable  # noqa: E402


def _extent(shape, res, origin):
  h, w = shape
  return (origin[0], origin[0] + w * res, origin[1], origin[1] + h * res)


def belief_rgb(occupied, logodds) -> np.ndarray:
  """float[H, W, 3] image of a belief over the truth: believed-free cells white, believed-occupied
  black, unknown light grey, and truth walls not yet mapped blue-grey."""
  prob = 1.0 / (1.0 + np.exp(-np.asarray(logodds, np.float32)))
  shade = np.full(prob.shape, 0.82)
  shade[prob < 0.35] = 1.0
  shade[prob > 0.65] = 0.0
  rgb = np.repeat(shade[..., None], 3, axis=-1)
  unknown_wall = (np.abs(prob - 0.5) < 0.15) & occupied
  rgb[unknown_wall] = (0.55, 0.55, 0.6)
  return rgb


def belief_map(ax, occupied, logodds, res, origin, curves=None, robots=(0,)):
  """The belief of one robot over the truth, with the trajectories of ``robots``.

  Truth walls are drawn dark grey, believed-free cells white, believed-occupied black, unknown
  light grey.
  """
  ax.imshow(belief_rgb(occupied, logodds), origin="lower",
            extent=_extent(occupied.shape, res, origin), interpolation="nearest")
  if curves is not None and len(curves):
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, r in enumerate(robots):
      c = curves[curves.robot == r]
      if len(c):
        ax.plot(c.x, c.y, lw=1.0, color=colours[k % len(colours)], label=f"robot {r}")
        ax.plot(c.x.iloc[0], c.y.iloc[0], "o", ms=4, color=colours[k % len(colours)])
    ax.legend(loc="upper right", fontsize=7)
  ax.set_xlabel("x (m)")
  ax.set_ylabel("y (m)")
  ax.set_aspect("equal")


def exploration_graph(ax, nodes, edges, lsr=None, open_bins=None, current=None):
  """An exploration graph (Toriz & Sánchez's REG family) over a map already drawn on ``ax``.

  Args:
    nodes: float[n, 2] node positions (x, y), m; node 0 (the start) is drawn as a star.
    edges: int[E, 2] node pairs joined by an edge.
    lsr: optional float[n, B, 2] each node's local safe region, its bins' ray ends in order.
    open_bins: optional bool[n, B] bins still on a node's frontier (drawn as red dots at their
      ray ends).
    current: optional index of the node the robot is at (circled).
  """
  from matplotlib.collections import LineCollection, PolyCollection
  nodes = np.asarray(nodes, np.float64).reshape(-1, 2)
  edges = np.asarray(edges, np.int64).reshape(-1, 2)
  if lsr is not None and len(nodes):
    lsr = np.asarray(lsr, np.float64)
    ax.add_collection(PolyCollection(list(lsr), facecolors=(0.2, 0.5, 0.9, 0.06),
                                     edgecolors=(0.2, 0.5, 0.9, 0.35), linewidths=0.4))
    if open_bins is not None:
      ends = lsr[np.asarray(open_bins, bool)]
      ax.plot(ends[:, 0], ends[:, 1], ".", ms=2, color="tab:red", label="open arcs")
  if len(edges):
    ax.add_collection(LineCollection(nodes[edges], colors="tab:green", linewidths=1.0))
  if len(nodes):
    ax.plot(nodes[:, 0], nodes[:, 1], "o", ms=3, color="tab:green", label="graph nodes")
    ax.plot(nodes[0, 0], nodes[0, 1], "*", ms=10, color="tab:orange", label="node 0 (start)")
    if current is not None and 0 <= current < len(nodes):
      ax.plot(nodes[current, 0], nodes[current, 1], "o", ms=8, mfc="none", color="tab:purple")


def spread(ax, curves: pd.DataFrame, x: str, y: str, grid_points: int = 200, label=None,
           color=None):
  """Mean and 10–90 % band of ``y`` over robots, each robot's curve interpolated on a common ``x``
  grid (a finished robot holds its last value); ``color``: the axis's next colour if None."""
  if not len(curves):
    return
  xmax = curves.groupby("robot")[x].max().max()
  xs = np.linspace(0.0, max(xmax, 1e-9), grid_points)
  rows: list[np.ndarray] = []
  for _, c in curves.groupby("robot"):
    cx, cy = c[x].to_numpy(), c[y].to_numpy()
    keep = np.concatenate([[True], np.diff(cx) > 0])
    rows.append(np.interp(xs, cx[keep], cy[keep]))
  ys = np.asarray(rows)
  line, = ax.plot(xs, ys.mean(0), label=label, color=color)
  if len(ys) > 1:
    ax.fill_between(xs, np.quantile(ys, 0.1, axis=0), np.quantile(ys, 0.9, axis=0), alpha=0.25,
                    color=line.get_color(), lw=0)


def saved_memory_graph(run_dir, res: float, origin, robot: int = 0):
  """Robot ``robot``'s memory graph (:attr:`jaxplore.planners.base.PlannerSpec.memory_graph`,
  e.g. the REG family's exploration graph) from a run folder's ``memory.npz``, or None where the
  run's planner draws none (or the folder holds no memory of it)."""
  path, config = Path(run_dir) / "memory.npz", Path(run_dir) / "config.json"
  if not (path.is_file() and config.is_file()):
    return None
  recorded = json.loads(config.read_text())
  planner = (recorded.get("sim_config") or {}).get("planner", recorded.get("planner"))
  from jaxplore.planners import planner_names
  if not isinstance(planner, str) or planner not in planner_names():
    return None
  from jaxplore.planners import get_planner
  draw = get_planner(planner).memory_graph
  if draw is None:
    return None
  with np.load(path) as saved:
    arrays = {name: saved[name][robot] for name in saved.files}
  try:
    return draw(arrays, res, origin)
  except (KeyError, AttributeError, IndexError):  # a memory of another version's layout
    return None


def run_figures(run_dir) -> list[Path]:
  """Writes ``map.png``, ``entropy_distance.png`` and ``coverage_time.png`` into ``run_dir``."""
  run_dir = Path(run_dir)
  if not run_dir.is_dir():
    raise ConfigError(f"{str(run_dir)!r} is not a folder (give a jaxplore run or sweep --out)")
  check_writable(run_dir, "the results folder")
  missing = [n for n in ("curves.parquet", "maps.npz") if not (run_dir / n).is_file()]
  if missing:
    unfinished = " (an unfinished sweep: jaxplore sweep --resume it)" if any(
        run_dir.glob("sweep_*.json")) else ""
    raise ConfigError(f"{str(run_dir)!r} holds no finished jaxplore results: "
                      f"{' and '.join(missing)} missing{unfinished}")
  try:
    curves = pd.read_parquet(run_dir / "curves.parquet")
    maps = np.load(run_dir / "maps.npz")
  except Exception as err:  # a torn file: pyarrow's and NumPy's errors vary
    raise ConfigError(f"{str(run_dir)!r}: unreadable results "
                      f"({type(err).__name__}: {err})") from None
  written = []

  fig, ax = plt.subplots(figsize=(7, 6))
  shown = tuple(range(min(4, maps["logodds"].shape[0])))
  belief_map(ax, maps["occupied"], maps["logodds"][0], float(maps["res"]), maps["origin"], curves,
             shown)
  graph = saved_memory_graph(run_dir, float(maps["res"]), maps["origin"])
  if graph is not None:
    exploration_graph(ax, graph.nodes, graph.edges, graph.lsr, graph.open, graph.current)
    ax.set_title(f"belief of robot 0, trajectories, and robot 0's planner's graph "
                 f"({len(graph.nodes)} nodes{', capacity reached' if graph.overflow else ''})",
                 fontsize=9)
  else:
    ax.set_title("belief of robot 0 and trajectories")
  written.append(_save(fig, run_dir / "map.png"))

  sweep = (json.loads((run_dir / "config.json").read_text()).get("sweep")
           if (run_dir / "config.json").exists() else None)
  names = (sweep or {}).get("figure_names") or ()  # none in a run's (or an older sweep's) config
  episodes = pd.read_parquet(run_dir / "episodes.parquet") if names else None
  settings = _curves_by_setting(curves, episodes, names)
  band = "mean per setting" if len(settings) > 1 else "mean"
  for x, y, name, xlabel, ylabel, title in (
      ("distance", "entropy", "entropy_distance.png", "distance travelled (m)",
       "map entropy (nats)", "map entropy vs distance"),
      ("time", "coverage", "coverage_time.png", "mission time (s)",
       "coverage of reachable free area", "coverage vs time")):
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, part in settings:
      spread(ax, part, x, y, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if y == "coverage":
      ax.set_ylim(0, 1.02)
    if len(settings) > 1:
      ax.legend(fontsize=6)
    ax.set_title(f"{title} ({band}, 10–90 % band)")
    written.append(_save(fig, run_dir / name))

  if episodes is not None:
    written.append(sweep_figure(episodes, names, run_dir / "sweep.png"))
  return written


# A sweep's curve figures draw one curve per setting up to this many settings, else all pooled.
MAX_CURVES = 8


def _setting_label(names, key) -> str:
  """``name=value, ...`` of one setting (``-`` for NaN: a name its planner does not have)."""
  show = lambda v: v if isinstance(v, str) else ("-" if v != v else f"{v:g}")
  values = key if isinstance(key, tuple) else (key,)
  return ", ".join(f"{n}={show(v)}" for n, v in zip(names, values))


def _curves_by_setting(curves: pd.DataFrame, episodes,
                       names) -> list[tuple[str | None, pd.DataFrame]]:
  """``[(label, curves of its robots)]`` per setting of a sweep (``names`` its figure names), or
  ``[(None, curves)]`` for a run or a sweep of more than :data:`MAX_CURVES` settings."""
  if episodes is None or not names:
    return [(None, curves)]
  grouped = episodes.groupby(list(names), sort=True, dropna=False)
  if not 1 < grouped.ngroups <= MAX_CURVES:
    return [(None, curves)]
  return [(_setting_label(names, key), curves[curves.robot.isin(part.robot)])
          for key, part in grouped]


def _save(fig, path: Path) -> Path:
  fig.tight_layout()
  tmp = path.with_name(path.stem + ".tmp.png")
  fig.savefig(tmp, dpi=120)
  plt.close(fig)
  tmp.replace(path)
  return path


def sweep_figure(episodes: pd.DataFrame, names, path) -> Path:
  """E_r and coverage per sweep setting: mean ± std over seeds, one bar per setting.

  ``names`` may include ``world`` and ``planner``; a NaN value (a weight the planner lacks) is a
  setting of its own, shown as ``-``.
  """
  grouped = episodes.groupby(list(names), sort=True, dropna=False)
  labels = [_setting_label(names, key) for key, _ in grouped]
  fig, axes = plt.subplots(2, 1, figsize=(max(6, 0.45 * len(labels) + 2), 7), sharex=True)
  # Two-line labels: on one line they ran past the axes' height and were clipped.
  for ax, column, title in ((axes[0], "E_r", "entropy reduced per metre\nE_r (nats/m)"),
                            (axes[1], "coverage", "coverage of\nreachable free area")):
    mean, std = grouped[column].mean(), grouped[column].std().fillna(0.0)
    ax.bar(range(len(labels)), mean.to_numpy(), yerr=std.to_numpy(), capsize=2, color="tab:blue",
           alpha=0.8)
    ax.set_ylabel(title)
  axes[1].set_xticks(range(len(labels)))
  axes[1].set_xticklabels(labels, rotation=70, ha="right", fontsize=7)
  axes[0].set_title("sweep: mean ± std over seeds")
  return _save(fig, Path(path))
