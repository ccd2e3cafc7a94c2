"""The entropy-boundary planner of Li, Yang, Wang and Wang 2020, "A high-efficiency,
information-based exploration path planning method for active simultaneous localization and
mapping" (Algorithm 1).

The planner keeps Li's smoothed entropy map ``I_e`` (Eq 1-3) in each robot's memory: after each
scan the robot integrates, its step hook (:func:`update_entropy_map`) blends the cells within
``R_u = α·R_e`` of the robot (Eq 7) toward their entropy in the belief (Eq 3).

One planning round for one robot:

1. Boundary features by a 3x3 box sum (Eq 4): ``B_e`` = traversable cells whose smoothed entropy
   ``I_e`` exceeds ``τ_e`` next to a cell that does not; ``B_g`` = traversable cells next to the
   inflated obstacles.
2. One weighted Dijkstra from the robot (Eq 8): entering a ``B_e`` cell costs ``k1`` times the
   step length, a ``B_g`` cell ``k2`` times (``0 ≤ k1 < k2 < 1``; ``k1 = 0`` is allowed). Its
   shortest-path tree holds every candidate path (to every reachable boundary cell).
3. For every tree node at once, by pointer jumping over the tree (:mod:`jaxplore.graph.tree`):
   - the dead-reckoning covariance Σ at the end of the path (Eq 16–17; the compounding
     Jacobians of a path multiply to ``I + N(total displacement)``, so Σ reduces to a few running
     sums along the path, see :func:`_covariance_from_sums`). ``δd`` is each grid step's length;
     ``δφ`` the turn between the chords of consecutive road-mark points ``Settings.road_mark_m``
     apart (Eq 16 takes it between road-mark points: per grid cell, a staircase that
     approximates a straight line would turn by 45° at every other cell);
   - the information gain of the path (Eq 20–21; Eq 21's garbled sign read as a decrease, in
     either of two readings, ``Settings.eq21``): the expected decrease of ``I_e`` over the union
     of cells within ``R_e`` of its waypoints, each cell once. A waypoint adds the cells of its
     ``R_e`` disc that are not in its parent's disc (a "crescent"); this counts every cell once
     unless a path leaves a cell's disc and later comes back into it (only around obstacles
     thinner than ``2 R_e`` or at zig-zags of weighted paths), where that cell is counted again.
     :func:`path_gain` computes the exact union for one path;
   - the path length, and the re-explore metric ``E_r`` (Eq 22) as the gain is (computed only
     when no path gains: it decides only then).
4. Correction (Eq 18–19): det Σ never decreases along a path (Eq 14), so a candidate path is cut
   at its last waypoint with ``det Σ ≤ det Σ_max``: its nearest such ancestor in the tree.
5. Selection: the corrected path with the largest gain (``select = 0``) or gain per metre
   driven (``select = 1``), where a path's gain is what its road-mark points p_1 ... p_m add to
   the region of P_0, the robot's own position (Li's Figure 5; its scan is in the maps already,
   Algorithm 1 line 2): entropy that no scan from where the robot stands removed is no path's
   gain. If no path has a positive gain, the path with the largest re-explore metric (uncut:
   relocalising is its purpose) is taken while frontiers remain or Σ is above its limit;
   otherwise nothing is left (the episode ends).
6. Stop (Algorithm 1, line 23) when the average entropy of the observable belief falls below
   ``E_min`` (0 disables it; the engine's coverage goal usually ends the episode first).
7. The robot follows the chosen path to its end (Algorithm 1 sends a whole path; the planner
   registers ``commits``), or until it is blocked, then plans again.

Not Li's: a progress timeout (as explore_lite's ``progress_timeout``). A robot that drives
``progress_m`` metres (straight lines between its plans) without one more cell of its belief
becoming known ends its episode as exhausted, with ``stuck`` set in its memory. Without it a
robot can drive back and forth for ever between two places whose regions still hold entropy
that no scan can remove (unknown cells behind a wall within ``R_e`` of a waypoint, with the
``disc`` region; cells a sight chain of the ``visible`` region reaches round a wall corner).
With the ``beams`` region and a path's gain taken beyond the robot's own region, what it
ended was mostly the Eq 22 fallback's trips where Eq 18–19 cut every candidate short of the
unexplored space (the robot drives to the best re-explore path's end, in mapped space by design,
and back): with this project's earlier Σ_max and unscaled V_n, winding paths were cut within
metres. With Σ_max derived from the SLAM model (``DET_SIGMA_MAX``) that is rare
(docs/papers/li2020.md).

Cells counted in the gain: known cells, and unknown cells within ``R_e`` of a free cell through
unknown cells (:func:`observable_cells`). Unknown cells inside walls or outside the building can
never be observed; counting them would pull the robot along walls forever.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import frontiers, linalg, mapping, reductions
from jaxplore.errors import ConfigError, shown
from jaxplore.graph.dijkstra import extract_path
from jaxplore.graph.tree import nearest_ancestor, path_sums
from jaxplore.planners import base
from jaxplore.settings import LENGTH_LIMIT_M, check_length, setting

# Eq 18-19's Σ_max, which Li et al. do not give, in the units and noise model of the SLAM model:
# the uncertainty at which the robot could still find its place again. Σ (Eq 17) is what dead
# reckoning along a path would reach with V_n of the odometry noise (``odom_noise_*``) if no scan
# matched on the way; the scan_matching model's loop closure searches 3σ of such drift, at most
# ``loop_search_m`` = 2 m and ``slam_max_angle`` = 0.349 rad (Karto's coarse angle offset). So
# Σ_max = diag(σ², σ², σ_θ²) with σ = 2/3 m, σ_θ = 0.349/3 rad: det Σ_max = 2.67e-3. With
# the default 3 % noise and Σ_0 = 1e-4·I (a NumPy loop of Eq 17 as :func:`path_geometry` takes
# it: δd per 0.1 m cell, δφ at road-mark points 0.5 m apart), a straight path never reaches it;
# one turning by 90° every 1 m does after 35 m, every 4 m after 48 m, every 8 m after 56 m; from
# Σ_0 = 1e-2·I (a robot whose scans did not match for a while) after 26, 32 and 34 m. When the
# robot's own Σ is past it, Eq 22 sends it back to mapped space.
SIGMA_MAX_XY, SIGMA_MAX_THETA = 2.0 / 3.0, 0.349 / 3.0
DET_SIGMA_MAX = SIGMA_MAX_XY ** 4 * SIGMA_MAX_THETA ** 2


@dataclasses.dataclass(frozen=True)
class Weights:
  """Traced weights of ``li2020`` (``params.planner[name]``; sweeping them never recompiles)."""

  entropy_k: float = setting(0.5, "Li et al. Eq 3: the smoothing k of the entropy map", ge=0,
                             lt=1)
  alpha: float = setting(1.5, "Li et al. Eq 7: the entropy map is updated within R_u = alpha * "
                         "R_e of the robot", gt=0)
  k1: float = setting(0.2, "Eq 8: weight of edges into entropy boundaries B_e (k1 < k2)", ge=0,
                      lt=1)
  k2: float = setting(0.6, "Eq 8: weight of edges into grid-map boundaries B_g", gt=0, lt=1)
  tau_e: float = setting(0.6, "Eq 4: entropy threshold of the entropy boundaries B_e",
                         unit="nats", ge=0)
  det_sigma_max: float = setting(
      DET_SIGMA_MAX, "Eq 19: det Σ_max, a path is cut where det Σ exceeds it (default: "
      "Σ_max = diag(σ², σ², σ_θ²), σ a third of loop_search_m's 2 m and σ_θ of slam_max_angle's "
      "0.349 rad: a drift a loop closure's search still covers at 3σ)", unit="m²·m²·rad²", gt=0)
  select: float = setting(0.0, "0: the candidate of largest gain; 1: of largest gain per metre",
                          ge=0, le=1, integer=True)
  e_min: float = setting(0.0, "stop when the average observable entropy falls below this "
                         "(0: never)", unit="nats", ge=0)
  h0: float = setting(math.log(2.0), "Eq 22: H_0 of the re-explore metric", unit="nats", ge=0)
  # Not Li's: explore_lite's progress_timeout.
  progress_m: float = setting(20.0, "a robot that drives this far (straight lines between its "
                              "plans) without one more cell becoming known ends exhausted "
                              "(0: never)", unit="m", ge=0)


DEFAULTS = {f.name: f.default for f in dataclasses.fields(Weights)}

# Disc offsets per loop step of visible_gains, by execution strategy. On a GPU a block is one
# fused kernel instead of a chain of small ones per offset, and 8 was the best of 4, 8 and 16;
# on a CPU blocks of 2 were the fastest, for the sums alone and for a whole run. The numbers:
# experiments/results/bench_visible_blocks_cpu.md (experiments/bench_visible_blocks.py) and
# bench_accelerator_gpu.md ("visible gains in blocks of 8").
VISIBLE_BLOCK = {"per_robot": 2, "lockstep": 8}


@dataclasses.dataclass(frozen=True)
class Settings:
  """Static settings of ``li2020``.

  Attributes:
    r_e: Li's effective radius ``R_e`` (Eq 5-6), m: the radius of the gain regions, and
      ``α·R_e`` the entropy map's update radius. With a preset and unset, derived from the
      lidar (:func:`effective_radius`, at most its range; :func:`size_settings`).
    dpi_min: Eq 6's beam density ``R_e`` is derived at, beams per metre (0: one per cell).
    max_update_radius_cells: static bound of the update radius ``R_u = α·R_e`` in cells (the
      side of the window the step hook updates); unless given, sized from the largest ``α`` of
      the batch (:func:`size_settings`).
    eq21: Eq 21's reading of the entropy a cell will have once observed, ``H'(c)`` (the gain of a
      cell is ``H(c) − H'(c)`` where positive, ``H`` = the entropy map ``I_e``): ``"sensor"``,
      ``H' = k·H(c) + (1−k)·H_obs`` with ``H_obs`` the entropy after one free observation (Eq 3
      applied once); ``"cell"``, ``H' = Ĥ(P(c))``, the cell's entropy in the occupancy belief now
      (Eq 21 as printed is a function of the cell's ``P(c)``; its sign is garbled).
    road_mark_m: spacing of the road-mark points ``p_m`` along a candidate path at which Eq 16's
      heading change ``δφ`` is taken (the direction between consecutive road-mark points), m.
      Per grid cell (0) a staircase path that approximates a straight line turns by 45° at
      every other cell and its Σ explodes while a grid-aligned path's does not.
    region: ``Region(p_i)`` of Eq 20 and 22. ``"beams"`` (default): the cells within ``R_e``
      of ``p_i`` that a scan from ``p_i`` could see, no cell the belief holds occupied on the
      beam to it (:func:`beam_gains`: the exact traversal of a straight line, as the lidar's
      beams cross the grid); a cell is counted where it enters a waypoint's region if seen from
      there, or where it leaves one if seen from there, whichever of the two path sums is
      larger (each is at most the exact union; a cell seen only while the path passes by,
      inside every region on the way, is missed). ``"visible"``: the same along the chains of
      a tree of sight lines (:func:`visible_gains`, the default before the beams), which stray
      up to 1.5 cells from their segments and see round wall corners that every beam hits:
      the unknown cells behind such a corner hold gain that no scan from there removes, and
      robots drove back and forth for it (intel, willow). ``"disc"``: the whole disc,
      walls ignored; unknown cells behind a known wall then hold gain that no scan can remove,
      and robots drive back and forth between two places that both count them. ``"disc"``
      costs one shifted sum per crescent offset (about 20 R_e), ``"visible"`` about three per
      disc offset (π R_e²), ``"beams"`` about as much as ``"visible"`` on a CPU (2.6 beam steps
      per disc offset, :data:`BEAM_GROUP` beams a loop step; timed in docs/papers/li2020.md; not
      measured on a GPU).
  """

  r_e: float = setting(0.75, "Li et al. Eq 5-6: the effective radius R_e (the entropy map's "
                       "update radius is alpha * R_e, li2020's gain disc R_e); with a preset "
                       "and unset: derived from the lidar", unit="m", static=True, gt=0)
  dpi_min: float = setting(0.0, "Li et al. Eq 6: the beam density R_e is derived at (0: one "
                           "beam per cell)", unit="beams/m", static=True, ge=0)
  max_update_radius_cells: int = setting(30, "static bound of the entropy map's update radius "
                                         "R_u = alpha * R_e in cells (a run sizes it from the "
                                         "largest alpha unless given)", static=True, ge=1,
                                         integer=True)
  eq21: str = setting("sensor", "Eq 21's reading of H'(c), the entropy of a cell once observed: "
                      "sensor (one observation's) or cell (its belief's now)", static=True,
                      choices=("sensor", "cell"))
  road_mark_m: float = setting(0.5, "spacing of the road-mark points of Eq 16 along a path",
                               unit="m", static=True, ge=0)
  region: str = setting("beams", "Region(p_i) of Eq 20 and 22: the cells within R_e a scan "
                        "could see, along beams (beams) or along a tree of sight lines "
                        "(visible), or the whole disc", static=True,
                        choices=("beams", "visible", "disc"))


def init_memory(ctx, params):
  """A robot's memory: the entropy map ``I_e`` (f32[H, W], every cell unknown: ln 2), and the
  progress timeout's unknown cells at the last progress, metres driven since, where the robot
  planned last (once it has), and whether the timeout ended the episode; and counts of its
  plans: all, those whose path Eq 18-19 cut short, and Eq 22's re-explore plans."""
  return {"entropy_map": jnp.full((ctx.height, ctx.width), mapping.LN2, jnp.float32),
          "unknown": jnp.int32(ctx.height * ctx.width), "driven": jnp.float32(0.0),
          "xy": jnp.zeros((2,), jnp.float32), "planned": jnp.bool_(False),
          "stuck": jnp.bool_(False), "plans": jnp.int32(0), "cut_plans": jnp.int32(0),
          "reexplore_plans": jnp.int32(0)}


def r_e_cells(ctx) -> float:
  """R_e in cells (static)."""
  return ctx.settings.r_e / ctx.res


def update_entropy_map(ctx, params, memory, robot: base.RobotView, logodds, moved):
  """The step hook: Eq 3 within ``R_u = α·R_e`` of the robot after the scan just integrated
  (:func:`jaxplore.mapping.update_entropy_map`); a robot that did not move updates no cell but,
  at most, the one whose centre it stands on."""
  weights = params.planner
  settings = ctx.settings
  radius = jnp.where(moved, weights["alpha"] * settings.r_e / ctx.res, 0.0)
  entropy_map = mapping.update_entropy_map(memory["entropy_map"], logodds, robot.position,
                                           radius, weights["entropy_k"],
                                           2 * settings.max_update_radius_cells + 3)
  return dict(memory, entropy_map=entropy_map)


def effective_radius(res: float, fov: float, n_beams: int, dpi_min: float | None = None) -> float:
  """Li et al.'s effective radius R_e (Eq 5-6), m: the largest distance D at which the scanner
  density ``S_dpi = 1 / (D·tan θ)`` stays above ``dpi_min``, i.e. ``1 / (dpi_min·tan θ)``.

  Args:
    res: metres per cell; ``dpi_min`` defaults to one beam per cell, ``1 / res``.
    fov, n_beams: the lidar's field of view (rad) and beam count; θ is the angle between two
      adjacent beams (:func:`jaxplore.sensor.beam_angles`' spacing).
    dpi_min: Eq 6's minimum density, beams per metre.
  """
  if n_beams < 2 or not fov > 0:
    raise ConfigError(f"R_e needs at least 2 beams over a positive field of view, got {n_beams}, "
                      f"{fov}")
  step = fov / n_beams if fov >= 2 * math.pi - 1e-6 else fov / (n_beams - 1)
  spacing = res if dpi_min is None else 1.0 / dpi_min
  if not spacing > 0:
    raise ConfigError(f"dpi_min must be > 0 beams per metre, got {dpi_min}")
  return spacing / math.tan(step)


def size_settings(settings: Settings, given, config, params, preset) -> Settings:
  """R_e and the bound of the update radius for a run (``PlannerSpec.size_settings``), but for
  those the user gave.

  With a ``preset`` and ``r_e`` not given, R_e is derived from the lidar by Eq 5-6
  (:func:`effective_radius`, one beam per cell unless ``dpi_min`` is given; the widest ``fov``
  of ``params``), at most the lidar's range ``r_max`` (a scan sees nothing beyond it, however
  dense its beams would be there, as on coarse grids). ``max_update_radius_cells`` is sized
  from the largest ``alpha`` of the batch.
  """
  limit = max(math.hypot(config.height, config.width) * config.res, LENGTH_LIMIT_M)
  alpha = params.planner.get("alpha", DEFAULTS["alpha"])
  check_length("alpha", alpha, math.inf, "")
  r_e = settings.r_e
  if preset is not None and "r_e" not in given:
    r_e = min(effective_radius(config.res, float(np.max(np.asarray(params.fov))), config.n_beams,
                               settings.dpi_min or None),
              float(np.max(np.asarray(params.r_max))))
    check_length("r_e", r_e, limit, "the gain kernels",
                 "R_e derived from fov, the beam count and dpi_min by Eq 5-6,")
  else:
    check_length("r_e", r_e, limit, "the gain kernels (R_e)")
  r_u = float(np.max(np.asarray(alpha))) * r_e
  check_length("alpha", r_u, limit, "the entropy-map update", "R_u = alpha * r_e")
  bound = settings.max_update_radius_cells
  if "max_update_radius_cells" not in given:
    bound = max(1, math.ceil(r_u / config.res - 1e-6))
  return dataclasses.replace(settings, r_e=r_e, max_update_radius_cells=bound)

GEOMETRY = ("length", "a", "b", "bx", "by", "bxx", "byy", "bxy")
CHANNELS = ("gain", "reexplore") + GEOMETRY


def validate(weights, params, ctx):
  k1, k2 = np.broadcast_arrays(np.asarray(weights["k1"]), np.asarray(weights["k2"]))
  bad = (k1 < 0) | (k2 >= 1) | (k1 >= k2)
  if np.any(bad):
    pairs = [f"({a:g}, {b:g})" for a, b in zip(k1[bad].tolist(), k2[bad].tolist())]
    raise ConfigError(f"li2020 needs 0 <= k1 < k2 < 1 (Eq 8), got (k1, k2) = {shown(pairs)}")
  settings = ctx.settings
  max_ru = settings.max_update_radius_cells * ctx.res
  r_u = np.asarray(weights["alpha"], np.float64) * settings.r_e
  if np.any(r_u > max_ru + 1e-6):
    raise ConfigError(f"planner 'li2020': weight alpha must be such that alpha * r_e <= "
                      f"max_update_radius_cells * res = {max_ru:.3g} m, got "
                      f"{shown(np.asarray(weights['alpha']), r_u > max_ru + 1e-6)}")


def boundaries(view: base.BeliefView, entropy_map, tau_e):
  """(B_e, B_g) of Eq 4 with a 3x3 kernel of ones (n = 3); ``entropy_map``: I_e, f32[H, W]."""
  high = entropy_map > tau_e
  b_e = view.traversable & high & (mapping.neighbour_count(high, border=True) < 9)
  b_g = view.traversable & mapping.any_neighbour(view.inflated & ~view.traversable, border=True)
  return b_e, b_g


def edge_weights(view: base.BeliefView, b_e, b_g, k1, k2):
  """Node cost of Eq 8: edges into B_e scaled by k1, into B_g by k2, blocked off the traversable
  set."""
  weight = jnp.where(b_e, k1, jnp.where(b_g, k2, 1.0))
  return jnp.where(view.traversable, weight, jnp.inf).astype(jnp.float32)


def disc_offsets(radius: float):
  r = int(math.floor(radius))
  return [(di, dj) for di in range(-r, r + 1) for dj in range(-r, r + 1)
          if di * di + dj * dj <= radius * radius + 1e-9]


def crescents(radius: float):
  """For each parent direction d (parent = v + d): the disc offsets of v outside the parent's
  disc."""
  disc = disc_offsets(radius)
  return {d: [o for o in disc if (o[0] - d[0]) ** 2 + (o[1] - d[1]) ** 2 > radius * radius + 1e-9]
          for d in mapping.NEIGHBOURS_8}


def _shift_sum(field, offsets, pad):
  """Σ_o field[i + o] for every cell (zero outside the grid); field [..., H, W].

  A loop over the offsets (an R_e of tens of cells has a thousand crescent offsets: unrolled,
  they would each be compiled).
  """
  h, w = field.shape[-2:]
  lead = field.ndim - 2
  framed = jnp.pad(field, [(0, 0)] * lead + [(pad, pad), (pad, pad)])
  table = jnp.asarray(offsets, jnp.int32).reshape(-1, 2) + pad

  def add(i, out):
    start = (0,) * lead + (table[i, 0], table[i, 1])
    return out + jax.lax.dynamic_slice(framed, start, field.shape[:lead] + (h, w))

  return jax.lax.fori_loop(0, table.shape[0], add, jnp.zeros(field.shape, field.dtype))


def observable_cells(view: base.BeliefView, radius: float):
  """Known cells, and unknown cells reachable from a free cell through unknown cells (4-neighbour
  steps, at most ``radius`` of them): what a robot passing by could observe. Unknown cells behind
  observed walls (wall interiors, outside the building) are never reached."""
  def grow(_, reach):
    framed = mapping.frame(reach, False)
    grown = reach
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
      grown = grown | mapping.shifted(framed, di, dj)
    return reach | (grown & view.unknown)

  reach = jax.lax.fori_loop(0, int(math.ceil(radius)), grow, view.free)
  return ~view.unknown | reach


def cell_gains(view: base.BeliefView, entropy_map, params, h0, radius: float,
               eq21: str = "sensor"):
  """Per-cell expected entropy decrease (Eq 20–21, read as a decrease) and re-explore term (Eq 22).

  The gain of a cell is ``H(c) − H'(c)`` where positive, ``H`` the entropy map ``I_e``
  (``entropy_map``, f32[H, W]), with
  Eq 21's ``H'`` read as ``k·H(c) + (1−k)·H_obs`` (``eq21="sensor"``; ``H_obs`` the entropy of a
  cell after one free observation), or as ``Ĥ(P(c))``, the cell's entropy in the belief
  (``eq21="cell"``); see :class:`Settings`.
  """
  h = entropy_map
  if eq21 == "sensor":
    h_obs = mapping.entropy_of_logodds(params.l_free)
    k = params.planner["entropy_k"]
    after = k * h + (1.0 - k) * h_obs
  elif eq21 == "cell":
    after = mapping.entropy_of_logodds(view.logodds)
  else:
    raise ValueError(f"eq21 must be 'sensor' or 'cell', got {eq21!r}")
  observable = observable_cells(view, radius)
  gain = jnp.where(observable, jnp.maximum(h - after, 0.0), 0.0)
  reexplore = jnp.where(observable, jnp.maximum(h0 - h, 0.0), 0.0)
  return jnp.stack([gain, reexplore])


@functools.cache
def ray_tree(radius: float):
  """The disc offsets as a tree of sight lines, in depth-first pre-order.

  Each offset's parent is one of its 8-neighbours nearer the centre, chosen (offsets taken by
  increasing distance) so that the chain of cells from the centre through the parent's chain
  stays closest to the straight segment (least sum of the chain cells' distances to its line).
  A chain is an 8-connected digital line. It cannot follow every segment exactly (sight lines to
  neighbouring offsets share their chains near the centre): for R_e = 57 cells, chain cells lie
  at most 1.47 cells (0.81 on average) from their segment, where the cells a segment crosses
  lie within 0.71. Returns (offsets i32[N, 2], depth i32[N] (1 for the 8 neighbours of the
  centre), crescent membership bool[N, 8] (offset in ``crescents(radius)[d]`` for the d-th of
  ``mapping.NEIGHBOURS_8``), sides i32[N, 2, 2] (the two cells beside the step from the parent:
  a diagonal step between two occupied cells is blocked, as the segment would be)).
  """
  disc = sorted((o for o in disc_offsets(radius) if o != (0, 0)),
                key=lambda o: (o[0] * o[0] + o[1] * o[1], o))
  chains = {(0, 0): np.zeros((0, 2))}
  children: dict[tuple[int, int], list[tuple[int, int]]] = {(0, 0): []}
  parent_of = {}
  for o in disc:
    normal = np.array([o[1], -o[0]], np.float64) / math.hypot(*o)
    best, best_cost = None, math.inf
    for di, dj in mapping.NEIGHBOURS_8:
      q = (o[0] + di, o[1] + dj)
      if q not in chains or q[0] ** 2 + q[1] ** 2 >= o[0] ** 2 + o[1] ** 2:
        continue
      cells = chains[q] if q == (0, 0) else np.vstack([chains[q], q])
      cost = float(np.abs(cells @ normal).sum())
      if cost < best_cost - 1e-9:
        best, best_cost = q, cost
    assert best is not None  # a nearer 8-neighbour of a disc offset is in the disc, seen before
    chains[o] = chains[best] if best == (0, 0) else np.vstack([chains[best], best])
    children[best].append(o)
    children[o] = []
    parent_of[o] = best
  order, depth, stack = [], [], [((0, 0), 0)]
  while stack:
    node, d = stack.pop()
    if node != (0, 0):
      order.append(node)
      depth.append(d)
    stack.extend((c, d + 1) for c in sorted(children[node], reverse=True))
  rim = [set(crescents(radius)[d]) for d in mapping.NEIGHBOURS_8]
  member = np.array([[o in r for r in rim] for o in order], bool)
  # The two cells beside a diagonal step of the chain (the step itself where it is straight).
  sides = np.array([[(o[0], parent_of[o][1]), (parent_of[o][0], o[1])] for o in order], np.int32)
  return np.asarray(order, np.int32), np.asarray(depth, np.int32), member, sides


@functools.cache
def sight_levels(radius: float):
  """:func:`ray_tree` regrouped for :func:`visible_gains`: in groups of subtrees, each group by
  depth, so that the masks of one depth of a group are all that its next depth reads.

  A group is the subtree of one of the centre's 8 neighbours or, where that subtree is wider
  (has more offsets at one depth) than the others, a part of it: the neighbour and some of its
  children's subtrees (the neighbour's own gain counted in its first part only). The widest
  depth sets the size of visible_gains' mask buffers: for R_e = 57 cells, 40 instead of 79.

  Returns (steps i32[S, D, M, 7]: for the m-th offset of group s at depth d + 1, its (row,
  col), its parent's (row, col), the parent's index among the offsets of depth d (M for the
  centre), the step's index in ``mapping.NEIGHBOURS_8`` and 1 if its gain is counted here (0:
  counted in another group); counts i32[S, D]; rim i32[S, D, K, 2]: the crescent memberships of
  the counted offsets of each depth, (n, the offset's index among those of its depth) for an
  offset in ``crescents(radius)[n]``, n indexing ``mapping.NEIGHBOURS_8``; rim_counts
  i32[S, D]). Rows past a count are zero. D is even (an empty depth last where needed).
  """
  offsets, depth, member, sides = ray_tree(radius)
  parents = np.stack([sides[:, 1, 0], sides[:, 0, 1]], -1)
  n_depth = int(depth.max() + 1) // 2 * 2
  # Depth-first order: a new subtree at each depth 1, a new child's subtree at each depth 2.
  subtree, child = np.cumsum(depth == 1) - 1, np.cumsum(depth <= 2) - 1
  widths = lambda unit: np.bincount(depth[unit], minlength=n_depth + 1)
  subtrees = [np.flatnonzero(subtree == s) for s in range(subtree.max() + 1)]
  children = {s: [np.flatnonzero((child == c) & (depth >= 2)) for c in np.unique(child[nodes])
                  if depth[child == c].min() == 2] for s, nodes in enumerate(subtrees)}
  limit = max([sorted(widths(nodes).max() for nodes in subtrees)[-min(2, len(subtrees))]]
              + [widths(unit).max() for units in children.values() for unit in units])
  groups = []  # (offset indices in depth-first order, counted flags)
  for s, nodes in enumerate(subtrees):
    if widths(nodes).max() <= limit:
      groups.append((nodes, np.ones(len(nodes), bool)))
      continue
    bins: list[np.ndarray] = []
    for unit in children[s]:
      if not bins or (widths(np.concatenate([bins[-1], unit])) > limit).any():
        bins.append(unit)
      else:
        bins[-1] = np.concatenate([bins[-1], unit])
    groups += [(np.concatenate([nodes[:1], unit]), np.arange(len(unit) + 1) > 0 if b else
                np.ones(len(unit) + 1, bool)) for b, unit in enumerate(bins)]
  width = max(widths(nodes).max() for nodes, _ in groups)
  steps = np.zeros((len(groups), n_depth, width, 7), np.int32)
  counts = np.zeros((len(groups), n_depth), np.int32)
  levels: list[list[list[tuple[Any, Any]]]] = [[[] for _ in range(n_depth)] for _ in groups]
  for g, (nodes, counted) in enumerate(groups):
    where = {}
    for i, count_here in zip(nodes, counted):
      o, p, d = offsets[i], parents[i], depth[i]
      where[tuple(o)] = m = counts[g, d - 1]
      direction = mapping.NEIGHBOURS_8.index((int(o[0] - p[0]), int(o[1] - p[1])))
      parent = width if d == 1 else where[tuple(p)]
      steps[g, d - 1, m] = (o[0], o[1], p[0], p[1], parent, direction, count_here)
      counts[g, d - 1] += 1
      if count_here:
        levels[g][d - 1] += [(n, m) for n in np.flatnonzero(member[i])]
  rim_counts = np.array([[len(r) for r in by_d] for by_d in levels], np.int32)
  rim = np.zeros(rim_counts.shape + (max(1, int(rim_counts.max())), 2), np.int32)
  for (g, d), count in np.ndenumerate(rim_counts):
    rim[g, d, :count] = np.reshape(levels[g][d], (count, 2))
  return steps, counts, rim, rim_counts


def sight_fields(gains, occupied, radius: float):
  """What :func:`visible_gains` reads, framed by ``pad`` cells so that every disc offset's window
  lies inside: (pad, framed gains f32[C, H + 2 pad, W + 2 pad], clear bool[H + 2 pad,
  W + 2 pad] (not occupied; the frame is clear), corners bool[8, H + 2 pad, W + 2 pad]).

  ``corners[k][x]``: the two cells beside the k-th step of ``mapping.NEIGHBOURS_8`` from ``x``
  are not both occupied (for a straight step: ``x`` and the cell it steps to; see
  :func:`ray_tree`'s sides).
  """
  _, h, w = gains.shape
  pad = int(math.floor(radius)) + 1
  framed_gain = jnp.pad(gains, [(0, 0), (pad, pad), (pad, pad)])
  # Clear cells framed by pad + 1 (a corner map reads one cell beyond the frame).
  clear = jnp.pad(~occupied, pad + 1, constant_values=True)
  inner = lambda di, dj: jax.lax.slice(clear, (1 + di, 1 + dj),
                                       (1 + di + h + 2 * pad, 1 + dj + w + 2 * pad))
  corners = jnp.stack([inner(di, 0) | inner(0, dj) for di, dj in mapping.NEIGHBOURS_8])
  return pad, framed_gain, inner(0, 0), corners


def visible_gains(gains, occupied, radius: float, block: int = 1):
  """Per-cell sums of ``gains`` over what a sensor at each cell sees within ``radius``.

  A cell ``c`` within ``radius`` of ``v`` is seen from ``v`` when no cell the belief holds
  occupied lies on the chain of cells from ``v`` to ``c`` (:func:`ray_tree`: an 8-connected
  approximation of the cells the straight segment crosses; unknown and free cells are
  transparent, an occupied ``c`` is seen). This is Li Eq 20's ``Region(p_i)`` restricted to the
  cells a scan from ``p_i`` can reach: unknown cells behind a known wall are not in it.

  The tree of sight lines is walked group by group of subtrees, depth by depth
  (:func:`sight_levels`).
  An offset's mask (the cells ``v`` that see ``v + offset``) is its parent's mask, cut where the
  chain steps diagonally between two occupied cells; the masks of one depth are kept, without
  the cells whose offset cell is occupied, for the next. The cost is two shifted reads of
  booleans, a few ANDs and one masked add per disc offset, then one more masked add per
  crescent membership. The masks live in two buffers of one depth's ([M + 1, H, W], M ~ 0.7
  radius), not in a stack over depths: XLA:CPU copied that stack twice per offset (~85 % of
  the time of the one-loop version this replaces).

  The offsets of a depth, and its crescent memberships, are taken ``block`` at a time, one
  loop step each block (the last block's extra rows add nothing): on a GPU a block is one fused
  kernel instead of ``block`` chains of small ones, and there are ``block`` times fewer loop
  steps. The sums are added in the same order, so the result does not depend on ``block``.

  Args:
    gains: f32[C, H, W] per-cell values.
    occupied: bool[H, W] cells that block the view.
    radius: R_e in cells (static).
    block: offsets per loop step (static, >= 1; :data:`VISIBLE_BLOCK` by strategy).
  Returns:
    (full f32[C, H, W]: the sum over the whole visible disc of every cell; crescent
    f32[8, C, H, W]: the sum over the visible part of the crescent of ``crescents(radius)[d]``
    for the d-th of ``mapping.NEIGHBOURS_8``).
  """
  if block < 1:
    raise ValueError(f"block must be >= 1, got {block}")
  pad, framed_gain, clear, corners = sight_fields(gains, occupied, radius)
  return _visible_sums(pad, framed_gain, clear, corners, radius, block)


def _visible_sums(pad, framed_gain, clear, corners, radius: float, block: int):
  """:func:`visible_gains` from :func:`sight_fields`' framed fields, for the viewpoints ``pad``
  cells inside their frame (a crop of the framed fields gives a window of viewpoints:
  :func:`windowed_sums`)."""
  steps, counts, rim, rim_counts = sight_levels(radius)
  n_groups, n_depth, width = steps.shape[:3]
  slots = -(-width // block) * block
  if slots > width:  # room for whole blocks: a last block's extra rows write spare slots
    steps = np.pad(steps, [(0, 0), (0, 0), (0, slots - width), (0, 0)])
    steps[..., 4] = np.where(steps[..., 4] == width, slots, steps[..., 4])
  if rim.shape[2] % block:
    rim = np.pad(rim, [(0, 0), (0, 0), (0, -rim.shape[2] % block), (0, 0)])
  steps, counts, rim, rim_counts = (jnp.asarray(a) for a in (steps, counts, rim, rim_counts))
  h, w = framed_gain.shape[1] - 2 * pad, framed_gain.shape[2] - 2 * pad
  gains = framed_gain[:, pad:pad + h, pad:pad + w]

  def seen_at(parent_masks, step):
    """The mask of the offset of ``step``: its parent's, unless the step squeezes diagonally
    between two occupied cells (or is straight from and to occupied cells, at the centre)."""
    corner = jax.lax.dynamic_slice(corners, (step[5], step[2] + pad, step[3] + pad), (1, h, w))
    return parent_masks[step[4]] & corner[0]

  def window(field, at):
    return jax.lax.dynamic_slice(field, (0, at[0] + pad, at[1] + pad), field.shape[:1] + (h, w))

  def in_blocks(count, body, carry):
    """``fori_loop(0, count, body, carry)``, ``block`` indices per loop step."""

    def step(b, carry):
      for u in range(block):
        carry = body(b * block + u, carry)
      return carry

    return jax.lax.fori_loop(0, (count + block - 1) // block, step, carry)

  def level(k, parent_masks, masks, full, crescent):
    group, d = k // n_depth, k % n_depth  # depth d + 1 of the group
    table = steps[group, d]

    def visit(m, carry):
      masks, full = carry
      seen = seen_at(parent_masks, table[m])
      at = table[m, :2]
      sight = seen & jax.lax.dynamic_slice(clear, (at[0] + pad, at[1] + pad), (h, w))
      masks = jax.lax.dynamic_update_index_in_dim(masks, sight, m, 0)
      counted = seen & (table[m, 6] > 0)  # 0 in the rows past the count
      return masks, full + jnp.where(counted, window(framed_gain, at), 0.0)

    def add(j, crescent):
      n, m = rim[group, d, j]
      # A last block's rows past the count point at offset 0.
      seen = seen_at(parent_masks, table[m]) & (j < rim_counts[group, d])
      return crescent.at[n].add(jnp.where(seen, window(framed_gain, table[m, :2]), 0.0))

    masks, full = in_blocks(counts[group, d], visit, (masks, full))
    return masks, full, in_blocks(rim_counts[group, d], add, crescent)

  def two_levels(k, carry):
    # Two depths per iteration, each buffer in its place: swapping them in the carry of a
    # loop over single depths made XLA copy both at every depth.
    even, odd, full, crescent = carry
    odd, full, crescent = level(2 * k, even, odd, full, crescent)
    even, full, crescent = level(2 * k + 1, odd, even, full, crescent)
    return even, odd, full, crescent

  # The last slot of both buffers is the centre's mask (every cell sees itself), never
  # overwritten.
  masks = jnp.zeros((slots + 1, h, w), bool).at[slots].set(True)
  crescent = jnp.zeros((8,) + gains.shape, gains.dtype)
  _, _, full, crescent = jax.lax.fori_loop(0, n_groups * n_depth // 2, two_levels,
                                           (masks, masks, gains, crescent))
  return full, crescent


def beam_cells(angle: float, radius: float) -> list[tuple[int, int]]:
  """The cells (row, column offsets) that a beam from the centre of cell (0, 0) at ``angle``
  (radians from the column axis toward the row axis) crosses, in order, up to the last one whose
  centre lies within ``radius`` of the origin: the Amanatides–Woo traversal of
  :mod:`jaxplore.sensor` (at an exact corner, the cell beside it on the old row, then the one
  across). Cells past the disc between two in it are kept: they block the beam as well."""
  du, dv = math.cos(angle), math.sin(angle)
  step_u = 1 if du > 0 else -1
  step_v = 1 if dv > 0 else -1
  dt_u = abs(1.0 / du) if abs(du) > 1e-12 else math.inf
  dt_v = abs(1.0 / dv) if abs(dv) > 1e-12 else math.inf
  t_u, t_v = 0.5 * dt_u, 0.5 * dt_v  # the first grid line crossed from the cell's centre
  row = col = 0
  cells: list[tuple[int, int]] = []
  last_inside = 0
  while min(t_u, t_v) <= radius + 1.0:
    if abs(t_u - t_v) < 1e-9:
      col += step_u
      cells.append((row, col))
      row += step_v
      t_u += dt_u
      t_v += dt_v
    elif t_u < t_v:
      col += step_u
      t_u += dt_u
    else:
      row += step_v
      t_v += dt_v
    cells.append((row, col))
    if row * row + col * col <= radius * radius + 1e-9:
      last_inside = len(cells)
  return cells[:last_inside]


# Beams walked together by beam_gains (its masks' buffer): fixed, so that the sums do not depend
# on the execution strategy's block.
BEAM_GROUP = 8


@functools.cache
def beam_table(radius: float):
  """The beams of :func:`beam_gains`, :data:`BEAM_GROUP` to a group: beams from the centre of a
  cell at evenly spaced angles, as many as it takes for every disc offset to be crossed by one
  (about ``2π R_e``: neighbouring beams are about a cell apart at ``R_e``, as Eq 5–6 space the
  lidar's). Each disc offset is owned by one beam that crosses it, the one whose direction is
  nearest the offset's centre: it is seen from a cell when that beam meets no occupied cell
  before it.

  Returns (offsets i32[G, L, BEAM_GROUP, 2]: the cell each beam of group g crosses at its step
  s ((0, 0) past its end); lengths i32[G]: the steps of the group's longest beam; owned
  i32[G, L, BEAM_GROUP]: the beams of the group that own their step's cell, first
  ``own_counts`` i32[G, L] of them; rim i32[G, L, K, 2]: (beam, n) for an owned cell in
  ``crescents(radius)[n]``, n indexing ``mapping.NEIGHBOURS_8``, first ``rim_counts``
  i32[G, L]). Rows past a count are zero.
  """
  disc = [o for o in disc_offsets(radius) if o != (0, 0)]
  n_beams = BEAM_GROUP * -(-(int(math.ceil(2 * math.pi * radius)) + 8) // BEAM_GROUP)
  while True:
    angles = [2 * math.pi * (k + 0.5) / n_beams for k in range(n_beams)]
    beams = [beam_cells(a, radius) for a in angles]
    owner: dict[tuple[int, int], tuple[float, int]] = {}
    for k, (angle, cells) in enumerate(zip(angles, beams)):
      for o in cells:
        off = abs(math.remainder(math.atan2(o[0], o[1]) - angle, 2 * math.pi))
        if o != (0, 0) and (o not in owner or off < owner[o][0]):
          owner[o] = (off, k)
    if all(o in owner for o in disc):
      break
    n_beams += BEAM_GROUP
  rim = [set(crescents(radius)[d]) for d in mapping.NEIGHBOURS_8]
  groups, length = n_beams // BEAM_GROUP, max(len(cells) for cells in beams)
  offsets = np.zeros((groups, length, BEAM_GROUP, 2), np.int32)
  lengths = np.zeros(groups, np.int32)
  owned = np.zeros((groups, length, BEAM_GROUP), np.int32)
  own_counts = np.zeros((groups, length), np.int32)
  rims: list[list[list[tuple[int, int]]]] = [[[] for _ in range(length)] for _ in range(groups)]
  in_disc = set(disc)
  for k, cells in enumerate(beams):
    g, u = divmod(k, BEAM_GROUP)
    lengths[g] = max(lengths[g], len(cells))
    for s, o in enumerate(cells):
      offsets[g, s, u] = o
      if o in in_disc and owner[o][1] == k:
        owned[g, s, own_counts[g, s]] = u
        own_counts[g, s] += 1
        rims[g][s] += [(u, n) for n in range(8) if o in rim[n]]
  rim_counts = np.array([[len(r) for r in by_step] for by_step in rims], np.int32)
  rim_table = np.zeros(rim_counts.shape + (max(1, int(rim_counts.max())), 2), np.int32)
  for (g, s), count in np.ndenumerate(rim_counts):
    rim_table[g, s, :count] = np.reshape(rims[g][s], (count, 2))
  return offsets, lengths, owned, own_counts, rim_table, rim_counts


def beam_gains(gains, occupied, radius: float, block: int = 1):
  """Per-cell sums of ``gains`` over the cells that beams from each cell reach within
  ``radius``: what :func:`visible_gains` sums, with each disc offset seen along a beam
  (:func:`beam_table`: the exact traversal of a straight line, as the lidar's beams cross the
  grid) instead of along a chain of a tree of sight lines. A tree's chains share their first
  cells, so a chain strays up to 1.5 cells from its segment and slips round wall corners that
  the segment (and every beam) hits; the unknown cells behind such a corner then hold gain that
  no scan from there removes. Here a beam's cells are those its line crosses: an offset counts
  when no occupied cell lies on its beam before it (an occupied offset is seen).

  The beams are walked :data:`BEAM_GROUP` at a time, step by step: per step a shifted read of
  the clear cells for each beam, one masked add per owned cell and one per crescent membership
  (about 2.6 steps per disc offset: beams cross more cells than their offsets, and overlap near
  the centre). The adds of a step are taken ``block`` at a time, one loop step each block, in
  the same order whatever ``block`` is, so the result does not depend on it.

  Args, returns: as :func:`visible_gains`.
  """
  if block < 1:
    raise ValueError(f"block must be >= 1, got {block}")
  pad, framed_gain, clear, corners = sight_fields(gains, occupied, radius)
  return _beam_sums(pad, framed_gain, clear, corners, radius, block)


def _beam_sums(pad, framed_gain, clear, corners, radius: float, block: int):
  """:func:`beam_gains` from :func:`sight_fields`' framed fields (``corners`` unused), for the
  viewpoints ``pad`` cells inside their frame (:func:`windowed_sums`)."""
  del corners
  offsets, lengths, owned, own_counts, rim, rim_counts = beam_table(radius)
  pad_to = lambda a: np.pad(a, [(0, 0), (0, 0), (0, -a.shape[2] % block)] + [(0, 0)] * (a.ndim - 3))
  offsets, lengths, owned, own_counts, rim, rim_counts = (
      jnp.asarray(a) for a in (offsets, lengths, pad_to(owned), own_counts, pad_to(rim),
                               rim_counts))
  h, w = framed_gain.shape[1] - 2 * pad, framed_gain.shape[2] - 2 * pad
  gains = framed_gain[:, pad:pad + h, pad:pad + w]

  def window(field, at):
    return jax.lax.dynamic_slice(field, (0, at[0] + pad, at[1] + pad), field.shape[:1] + (h, w))

  def in_blocks(count, body, carry):
    """``fori_loop(0, count, body, carry)``, ``block`` indices per loop step (the last block's
    indices past ``count`` are for ``body`` to ignore)."""

    def step(b, carry):
      for u in range(block):
        carry = body(b * block + u, carry)
      return carry

    return jax.lax.fori_loop(0, (count + block - 1) // block, step, carry)

  def group(g, carry):
    full, crescent = carry

    def step(s, carry):
      masks, full, crescent = carry
      at = offsets[g, s]

      def add(j, full):
        u = owned[g, s, j]
        seen = jax.lax.dynamic_index_in_dim(masks, u, keepdims=False) & (j < own_counts[g, s])
        return full + jnp.where(seen, window(framed_gain, at[u]), 0.0)

      def add_rim(j, crescent):
        u, n = rim[g, s, j]
        seen = jax.lax.dynamic_index_in_dim(masks, u, keepdims=False) & (j < rim_counts[g, s])
        return crescent.at[n].add(jnp.where(seen, window(framed_gain, at[u]), 0.0))

      full = in_blocks(own_counts[g, s], add, full)
      crescent = in_blocks(rim_counts[g, s], add_rim, crescent)
      ahead = jnp.stack([window(clear[None], at[u])[0] for u in range(BEAM_GROUP)])
      return masks & ahead, full, crescent

    masks = jnp.ones((BEAM_GROUP, h, w), bool)
    _, full, crescent = jax.lax.fori_loop(0, lengths[g], step, (masks, full, crescent))
    return full, crescent

  crescent = jnp.zeros((8,) + gains.shape, gains.dtype)
  # Every cell sees itself (as visible_gains' centre).
  return jax.lax.fori_loop(0, offsets.shape[0], group, (gains, crescent))


# The viewpoint windows of windowed_sums, as fractions of each side of the grid (the grid itself
# is the last), and the work (viewpoints x disc offsets) below which the grid alone is used:
# each window is one more compiled copy of the sums' loop. Half of each side ran li2020 1.35x
# faster over the first 300 steps on lab (64 robots) and 1.06-1.08x over 1,500-2,000 steps (lab,
# building); a second window at three quarters added 1-2 % (experiments/results/
# bench_li2020_windows_cpu.md).
SUM_WINDOW_FRACTIONS = (0.5,)
SUM_WINDOW_MIN_WORK = 5e7


def sum_windows(height: int, width: int, radius: float) -> tuple[tuple[int, int], ...]:
  """The viewpoint windows :func:`windowed_sums` chooses from, smallest first, the grid last:
  :data:`SUM_WINDOW_FRACTIONS` of each side, rounded up to 8 cells; the grid alone where the sums
  are cheap (below :data:`SUM_WINDOW_MIN_WORK`)."""
  if height * width * len(disc_offsets(radius)) < SUM_WINDOW_MIN_WORK:
    return ((height, width),)
  side = lambda f, n: min(n, 8 * math.ceil(f * n / 8))
  sizes = {(side(f, height), side(f, width)) for f in SUM_WINDOW_FRACTIONS}
  return tuple(sorted(sizes - {(height, width)})) + ((height, width),)


def sum_window(gains, needed, radius: float, windows):
  """Which of ``windows`` :func:`windowed_sums` computes on, and where: (its index, its first
  row, its first column before it is moved inside the grid).

  The window must hold the rows (and columns) that hold a needed viewpoint (``needed``,
  bool[H, W]) and lie within the sums' frame (``pad`` = ⌊R_e⌋ + 1 cells) of a row (column) with
  a gain (``gains`` f32[C, H, W] not 0); other viewpoints' sums are 0 or not read. With none, the
  smallest window at the corner."""
  _, h, w = gains.shape
  pad = int(math.floor(radius)) + 1

  def span(rows, gain_rows, n):
    near = jnp.convolve(gain_rows.astype(jnp.float32), jnp.ones(2 * pad + 1), mode="same") > 0
    keep = rows & near
    first, last = jnp.argmax(keep), n - 1 - jnp.argmax(keep[::-1])
    return jnp.where(jnp.any(keep), first, 0), jnp.where(jnp.any(keep), last, 0)

  has_gain = jnp.any(gains != 0, axis=0)
  r0, r1 = span(jnp.any(needed, 1), jnp.any(has_gain, 1), h)
  c0, c1 = span(jnp.any(needed, 0), jnp.any(has_gain, 0), w)
  level = sum(((r1 - r0 + 1 > wh) | (c1 - c0 + 1 > ww)).astype(jnp.int32)
              for wh, ww in windows[:-1])
  return jnp.int32(level), r0, c0


def windowed_sums(sums, gains, occupied, needed, radius: float, block: int, windows=None):
  """:func:`beam_gains` (``sums=_beam_sums``) or :func:`visible_gains` (``_visible_sums``),
  exact at the viewpoints ``needed`` (bool[H, W]), computed on the smallest of ``windows``
  (:func:`sum_windows` unless given) that holds every needed viewpoint whose disc holds a gain.
  Elsewhere the result is 0.

  The sums cost the same per viewpoint wherever it is, and a plan reads them only at the nodes
  of its shortest-path tree: early in an episode, when the known free space is a corner of the
  grid, and wherever the gains lie in a corner, most of the grid's sums are never read. A
  needed viewpoint outside the window has no gain within ``R_e`` rows or columns: its sums are 0.
  Inside, the window's sums read the same cells in the same order as the grid's: the same
  numbers, bit for bit.

  The window is chosen by a ``lax.switch``; under ``vmap`` (a chunk of robots planned together)
  the chunk takes the window of the robot that needs the largest (a custom batching rule: a
  batched switch would run every window), each robot its own corner of it.
  """
  c, h, w = gains.shape
  windows = sum_windows(h, w, radius) if windows is None else tuple(windows)
  fields = sight_fields(gains, occupied, radius)
  pad = fields[0]
  if len(windows) == 1:
    return sums(pad, fields[1], fields[2], fields[3], radius, block)
  level, r0, c0 = sum_window(gains, needed, radius, windows)

  def in_window(size, framed, r0, c0):
    wh, ww = size
    top, left = jnp.minimum(r0, h - wh), jnp.minimum(c0, w - ww)
    crop = lambda a: jax.lax.dynamic_slice(
        a, (0,) * (a.ndim - 2) + (top, left), a.shape[:-2] + (wh + 2 * pad, ww + 2 * pad))
    full, crescent = sums(pad, *(crop(a) for a in framed), radius, block)
    place = lambda a, shape: jax.lax.dynamic_update_slice(
        jnp.zeros(shape, a.dtype), a, (0,) * (a.ndim - 2) + (top, left))
    return place(full, (c, h, w)), place(crescent, (8, c, h, w))

  branches = [functools.partial(in_window, size) for size in windows]

  @jax.custom_batching.custom_vmap
  def chosen(level, framed, r0, c0):
    return jax.lax.switch(level, branches, framed, r0, c0)

  @chosen.def_vmap
  def chosen_batched(axis_size, in_batched, level, framed, r0, c0):
    level_batched, framed_batched, r0_batched, c0_batched = in_batched
    largest = jnp.max(level) if level_batched else level
    axes = (jax.tree.map(lambda b: 0 if b else None, framed_batched),
            0 if r0_batched else None, 0 if c0_batched else None)
    batched = [jax.vmap(branch, in_axes=axes, axis_size=axis_size) for branch in branches]
    out = jax.lax.switch(largest, batched, framed, r0, c0)
    return out, jax.tree.map(lambda _: True, out)

  return chosen(level, fields[1:], r0, c0)


def path_gain(gain_grid, cells, length, radius: float):
  """Exact Eq 20 gain of one path: Σ of ``gain_grid`` over the union of R_e-discs of its waypoints.

  Args:
    gain_grid: f32[H, W] per-cell gain.
    cells: i32[L, 2] waypoints; only the first ``length`` count.
    radius: R_e in cells (static).
  """
  h, w = gain_grid.shape
  covered = jnp.zeros((h, w), bool)
  valid = jnp.arange(cells.shape[0]) < length
  for di, dj in disc_offsets(radius):
    r, c = cells[:, 0] + di, cells[:, 1] + dj
    keep = valid & (r >= 0) & (r < h) & (c >= 0) & (c < w)
    covered = covered.at[jnp.where(keep, r, h), jnp.where(keep, c, w)].set(True, mode="drop")
  return jnp.sum(jnp.where(covered, gain_grid, 0.0))


def _covariance_from_sums(sums, xy, xy_root, cov0):
  """Σ at every node from the running sums of Eq 16–17 along its path.

  Eq 17 unrolled: ``Σ_n = A_n Σ_0 A_nᵀ + Σ_m A_{n←m} V_m A_{n←m}ᵀ`` with ``A = Π J1 = I + N(Δ)``
  (``N`` has ``−Δy, Δx`` in its last column, and ``N N' = 0``), and ``J2 V_m J2ᵀ = V_m`` because
  V_m's x and y variances are equal. With ``a = (σ_d δd)²``, ``b = (σ_φ δφ)²`` and ``(dx, dy)``
  the displacement from waypoint m to node n, the sum needs only Σa, Σb, Σbx, Σby, Σbx², Σby²,
  Σbxy along the path (``sums`` in the order of :data:`GEOMETRY`). Returns f32[N, 3, 3].
  """
  s = {name: sums[:, i] for i, name in enumerate(GEOMETRY)}
  x, y = xy[:, 0], xy[:, 1]
  sum_b_dx = x * s["b"] - s["bx"]
  sum_b_dy = y * s["b"] - s["by"]
  sum_b_dx2 = x * x * s["b"] - 2 * x * s["bx"] + s["bxx"]
  sum_b_dy2 = y * y * s["b"] - 2 * y * s["by"] + s["byy"]
  sum_b_dxdy = x * y * s["b"] - x * s["by"] - y * s["bx"] + s["bxy"]
  q = jnp.stack([
      jnp.stack([s["a"] + sum_b_dy2, -sum_b_dxdy, -sum_b_dy], -1),
      jnp.stack([-sum_b_dxdy, s["a"] + sum_b_dx2, sum_b_dx], -1),
      jnp.stack([-sum_b_dy, sum_b_dx, s["b"]], -1)], -2)
  # A Σ_0 Aᵀ entry by entry: XLA:CPU runs a batched ``dot_general`` of 3x3 matrices as a
  # library call that was the slowest operation of a planning round (docs/performance.md).
  dx, dy = x - xy_root[0], y - xy_root[1]
  c = cov0
  m = [[c[0, k] - dy * c[2, k] for k in range(3)], [c[1, k] + dx * c[2, k] for k in range(3)],
       [jnp.broadcast_to(c[2, k], dx.shape) for k in range(3)]]  # A Σ_0
  a_cov_at = jnp.stack([jnp.stack([m[i][0] - dy * m[i][2], m[i][1] + dx * m[i][2], m[i][2]], -1)
                        for i in range(3)], -2)
  return a_cov_at + q


def road_mark_cells(ctx) -> int:
  """Cells between road-mark points (:class:`Settings` ``road_mark_m``); 1 = every cell."""
  settings = ctx.settings
  if settings.road_mark_m <= 0:
    return 1
  return max(1, int(round(settings.road_mark_m / ctx.res)))


def _ancestor(parent, k: int):
  """The k-th ancestor of every node (``parent`` maps the root and outside nodes to themselves),
  by binary lifting: one gather per bit of ``k``."""
  result = jnp.arange(parent.shape[0], dtype=parent.dtype)
  power = parent
  while k:
    if k & 1:
      result = power[result]
    power = power[power]
    k >>= 1
  return result


def _tree_steps(config, robot, pred):
  """Per node of the Dijkstra tree: (its parent (itself at the root and outside the tree),
  whether it has one, the step toward the parent in rows and columns, the root's index)."""
  w = config.width
  pred_flat = pred.ravel()
  idx = jnp.arange(pred_flat.shape[0], dtype=jnp.int32)
  has_parent = pred_flat >= 0
  parent = jnp.where(has_parent, pred_flat, idx)
  d_row, d_col = parent // w - idx // w, parent % w - idx % w  # in {-1, 0, 1}
  return parent, has_parent, d_row, d_col, robot.cell[0] * w + robot.cell[1]


def path_geometry(config, robot, params, pred):
  """Per-node path length and the Eq 16-17 covariance at the end of every path in the tree.

  Returns (sums f32[H*W, 8]: the running sums of :data:`GEOMETRY` along each path, covariance
  f32[H*W, 3, 3], xy f32[H*W, 2] in metres relative to the robot cell).
  """
  h, w = config.height, config.width
  res = config.res
  pred_flat = pred.ravel()
  idx = jnp.arange(h * w, dtype=jnp.int32)
  rows, cols = idx // w, idx % w
  parent, has_parent, d_row, d_col, _ = _tree_steps(config, robot, pred)

  xy = jnp.stack([(cols - robot.cell[1]) * res, (rows - robot.cell[0]) * res],
                 -1).astype(jnp.float32)
  spacing = road_mark_cells(config)
  if spacing <= 1:
    # Per grid cell: the heading of the move into each node is one of 8 directions (a node
    # without a parent, such as the root, has the robot's heading), and the turn from the
    # parent's heading is tabulated (9 headings, 9 x 9 wrapped turns).
    code = (d_row + 1) * 3 + (d_col + 1)  # 4: no parent
    moves = jnp.arange(9)
    headings = jnp.where(moves == 4, robot.pose[2], jnp.arctan2(
        -(moves // 3 - 1).astype(jnp.float32), -(moves % 3 - 1).astype(jnp.float32)))
    turn = headings[:, None] - headings[None, :]
    turns = jnp.arctan2(jnp.sin(turn), jnp.cos(turn))
    delta_phi = jnp.where(has_parent, turns[code, code[parent]], 0.0)
  else:
    # Road-mark points every ``spacing`` cells from the root: δφ at each is the turn between the
    # chords to it and to the previous one (the first chord turns from the robot's heading).
    depth = path_sums(pred_flat, jnp.ones((h * w, 1), jnp.float32))[:, 0] - 1.0
    back = _ancestor(parent, spacing)
    back2 = back[back]
    chord = lambda a, b: jnp.arctan2(xy[b, 1] - xy[a, 1], xy[b, 0] - xy[a, 0])
    heading = chord(back, idx)
    previous = jnp.where(depth >= 2 * spacing, chord(back2, back), robot.pose[2])
    turn = heading - previous
    road_mark = (depth >= spacing) & (jnp.mod(depth, spacing) == 0)
    delta_phi = jnp.where(road_mark, jnp.arctan2(jnp.sin(turn), jnp.cos(turn)), 0.0)
  delta_d = jnp.where(has_parent,
                      res * jnp.sqrt((d_row * d_row + d_col * d_col).astype(jnp.float32)), 0.0)

  a = (params.odom_noise_d * delta_d) ** 2
  b = (params.odom_noise_phi * delta_phi) ** 2
  x, y = xy[:, 0], xy[:, 1]
  sums = path_sums(pred_flat, jnp.stack([delta_d, a, b, b * x, b * y, b * x * x, b * y * y,
                                         b * x * y], -1))
  cov = _covariance_from_sums(sums, xy, jnp.zeros(2), robot.cov)
  return sums, cov, xy


def path_gains(config, view, robot, pred, gains, visible_sums=None):
  """Per-node Eq 20 sums of each channel of ``gains`` (f32[C, H, W]) over the regions of every
  path's waypoints (``Settings.region``), each cell once per path. Returns f32[H*W, C].

  The channels are independent: a channel's sums do not depend on the others passed with it.
  ``visible_sums``: the ``"visible"`` region's sums, a function of :func:`visible_gains`'
  signature (None: :func:`visible_gains`), for a candidate to be compared against it
  (``experiments/bench_lockstep_variants.py``'s ``visible_by_depth``).
  """
  h, w = config.height, config.width
  n_channels = gains.shape[0]
  pred_flat = pred.ravel()
  idx = jnp.arange(h * w, dtype=jnp.int32)
  parent, has_parent, d_row, d_col, root = _tree_steps(config, robot, pred)
  radius = r_e_cells(config)
  settings = config.settings
  if settings.region in ("visible", "beams"):
    # Each cell once per path, counted where it enters the region of a waypoint (seen from that
    # waypoint), or where it leaves it (seen from the waypoint it leaves), whichever sum is
    # larger; see visible_gains and Settings.region.
    code = (d_row + 1) * 3 + (d_col + 1)  # index into NEIGHBOURS_8 after removing (0, 0)
    toward, away = jnp.where(code > 4, code - 1, code), jnp.where(code < 4, 7 - code, 8 - code)
    in_tree = has_parent & (idx != root)
    block = VISIBLE_BLOCK[config.strategy]
    if visible_sums is not None and settings.region == "visible":
      full, crescent = visible_sums(gains, view.occupied, radius, block)
    else:
      # Read at the tree's nodes only (the root's and each node's parent's are nodes too).
      needed = (in_tree | (idx == root)).reshape(h, w)
      sums_of = _visible_sums if settings.region == "visible" else _beam_sums
      full, crescent = windowed_sums(sums_of, gains, view.occupied, needed, radius, block)
    full, crescent = full.reshape(n_channels, -1), crescent.reshape(8, n_channels, -1)
    enter = jnp.where(in_tree, crescent[toward, :, idx].T, 0.0)
    enter = jnp.where(idx == root, full[:, root][:, None], enter)
    leave = jnp.where(in_tree, crescent[away, :, parent].T, 0.0)
    sums = path_sums(pred_flat, jnp.concatenate([enter, leave]).T)
    return jnp.maximum(sums[:, :n_channels], sums[:, n_channels:] + full.T)
  # Crescent of new cells per parent direction (the root gets its whole disc).
  pad = int(math.floor(radius)) + 1
  new_cells = jnp.zeros((n_channels, h * w), jnp.float32)
  for (di, dj), offsets in crescents(radius).items():
    field = _shift_sum(gains, offsets, pad).reshape(n_channels, -1)
    new_cells = jnp.where((d_row == di) & (d_col == dj), field, new_cells)
  disc = jnp.asarray(disc_offsets(radius), jnp.int32)
  # wrap_negative_indices=False: a disc over the top or left border must read 0 there, not the
  # last row or column.
  disc_at_root = jnp.sum(gains.at[:, robot.cell[0] + disc[:, 0], robot.cell[1] + disc[:, 1]].get(
      mode="fill", fill_value=0.0, wrap_negative_indices=False), axis=1)
  new_cells = jnp.where(idx == root, disc_at_root[:, None], new_cells)
  return path_sums(pred_flat, new_cells.T)


def tree_quantities(config, view, robot, params, pred, gains):
  """Per-node path sums (gain, re-explore, length, covariance terms) over the Dijkstra tree:
  :func:`path_gains` of both channels of ``gains`` beside :func:`path_geometry`.

  Returns (sums f32[H*W, 10] in the order of :data:`CHANNELS`, covariance f32[H*W, 3, 3], xy
  f32[H*W, 2] in metres relative to the robot cell).
  """
  geometry, cov, xy = path_geometry(config, robot, params, pred)
  return jnp.concatenate([path_gains(config, view, robot, pred, gains), geometry], -1), cov, xy


def average_observable_entropy(view: base.BeliefView, radius: float):
  observable = observable_cells(view, radius)
  entropy = mapping.entropy_of_logodds(view.logodds)
  return jnp.sum(jnp.where(observable, entropy, 0.0)) / jnp.maximum(jnp.sum(observable), 1)


def plan_li2020(config, view: base.BeliefView, robot: base.RobotView, params, key, memory, *,
                visible_sums=None):
  """One planning round of Algorithm 1 (see the module docstring). Returns (Plan, memory).
  ``visible_sums``: as :func:`path_gains`' (None: :func:`visible_gains`)."""
  weights = params.planner
  settings = config.settings
  h, w = config.height, config.width
  entropy_map = memory["entropy_map"]
  b_e, b_g = boundaries(view, entropy_map, weights["tau_e"])
  sp = config.shortest_paths(edge_weights(view, b_e, b_g, weights["k1"], weights["k2"]),
                             robot.cell)
  reachable = jnp.isfinite(sp.dist).ravel()
  geometry, cov, _ = path_geometry(config, robot, params, sp.pred)
  root = robot.cell[0] * w + robot.cell[1]
  idx = jnp.arange(h * w, dtype=jnp.int32)

  # Eq 18-19: cut every candidate at its last waypoint within the covariance limit.
  within = (linalg.det3(cov) <= weights["det_sigma_max"]) & reachable
  boundary = (b_e | b_g).ravel() & reachable & (idx != root)
  cut = nearest_ancestor(sp.pred.ravel(), within)
  cut = jnp.where(boundary, cut, -1)
  candidates = jnp.zeros((h * w,), bool).at[jnp.where(cut >= 0, cut, h * w)].set(True, mode="drop")
  candidates = candidates & (idx != root)
  # The candidates that are the corrected end of a longer path (Eq 18's m* < m).
  cut_short = jnp.zeros((h * w,), bool).at[jnp.where((cut >= 0) & (cut != idx), cut, h * w)].set(
      True, mode="drop")

  # The Eq 20 gain of every path, then, only where no candidate gains (Eq 22's fallback), the
  # re-explore metric: one channel of cell gains per pass of the same loop. The second pass, a
  # large share of a plan's time, is skipped by the plans that explore (most of them:
  # experiments/results/bench_li2020_parts_cpu.md, "The re-explore pass"); under vmap a chunk
  # runs it if any of its robots needs it (a batched lax.cond would run it for every chunk). The
  # results are those of one two-channel pass.
  gains = cell_gains(view, entropy_map, params, weights["h0"], r_e_cells(config), settings.eq21)
  # A path's gain is what its road-mark points add to the region of P_0, where the robot stands
  # (see the comment before the scores below): its Eq 20 sum less the root's.
  added = lambda gain: gain - gain[root]
  gaining = lambda new: candidates & (new > 1e-6)  # the candidates an exploring plan weighs

  def more_passes(carry):
    k, sums = carry
    return (k == 0) | ((k == 1) & ~jnp.any(gaining(added(sums[0]))))

  def one_pass(carry):
    k, sums = carry
    channel = jax.lax.dynamic_slice_in_dim(gains, k, 1)
    sums_k = path_gains(config, view, robot, sp.pred, channel, visible_sums)[:, 0]
    return k + 1, sums.at[k].set(sums_k)

  _, (gain, reexplore) = jax.lax.while_loop(
      more_passes, one_pass, (jnp.int32(0), jnp.zeros((2, h * w), jnp.float32)))

  # Eq 20 sums over the road-mark points p_1 ... p_m of a path; the robot stands at P_0 (Li's
  # Figure 5), and the scan it took there is in the maps already (Algorithm 1, line 2). So the
  # gain of a path is what the regions of its road-mark points add to P_0's region: entropy that
  # is left in the robot's own region (what no scan from there removed, e.g. cells a sight chain
  # reaches round a wall corner that a beam does not) is no path's gain. Counting it made every
  # path gain (the Eq 22 fallback never came: robots shuttled between two cells), and under
  # select=1 it made the shortest paths the most efficient (a one-cell path scored the root's
  # gain over 0.1 m). The denominator is the metres the robot drives along the path.
  gain = added(gain)
  length = geometry[:, 0]
  score = jnp.where(weights["select"] > 0.5, gain / jnp.maximum(length, config.res), gain)
  score = jnp.where(gaining(gain), score, -jnp.inf)
  best = reductions.argmax(score, w)
  explore = jnp.isfinite(score[best])

  frontier_left = jnp.any(view.frontier.ravel() & reachable)
  needs_reloc = linalg.det3(robot.cov) > weights["det_sigma_max"]
  fallback_score = jnp.where(boundary, reexplore, -jnp.inf)
  fallback = reductions.argmax(fallback_score, w)
  can_fallback = jnp.isfinite(fallback_score[fallback]) & (frontier_left | needs_reloc)
  converged = ((weights["e_min"] > 0) &
               (average_observable_entropy(view, r_e_cells(config)) < weights["e_min"]))

  # Progress timeout: metres driven (straight lines between plans) since the belief last gained
  # a known cell.
  unknown = jnp.sum(view.unknown).astype(jnp.int32)
  step = jnp.where(memory["planned"], jnp.linalg.norm(robot.pose[:2] - memory["xy"]), 0.0)
  progressed = unknown < memory["unknown"]
  driven = jnp.where(progressed, 0.0, memory["driven"] + step)
  stuck = (weights["progress_m"] > 0) & (driven > weights["progress_m"])
  counts = {name: memory[name] for name in ("plans", "cut_plans", "reexplore_plans")}
  memory = {"entropy_map": entropy_map, "unknown": jnp.minimum(unknown, memory["unknown"]),
            "driven": driven,
            "xy": robot.pose[:2].astype(jnp.float32), "planned": jnp.bool_(True),
            "stuck": memory["stuck"] | stuck}

  chosen = jnp.where(explore, best, fallback)
  valid = (explore | can_fallback) & ~converged & ~stuck
  count = lambda name, happened: counts[name] + happened.astype(jnp.int32)
  memory.update(plans=count("plans", valid), cut_plans=count("cut_plans", valid & explore &
                                                               cut_short[best]),
                reexplore_plans=count("reexplore_plans", valid & ~explore))
  goal = jnp.stack([chosen // w, chosen % w]).astype(jnp.int32)
  cells, length_wp = extract_path(sp.pred, goal, config.path_capacity, source=robot.cell)
  look_at = frontiers.unknown_neighbour(goal, view.unknown, view.occupied)
  plan = base.Plan(waypoints=cells, length=jnp.where(valid, length_wp, 0).astype(jnp.int32),
                   goal=goal, look_at=look_at, valid=valid,
                   gain=jnp.where(explore, gain[chosen], reexplore[chosen]),
                   cost=sp.dist.ravel()[chosen] * config.res,
                   n_candidates=jnp.sum(candidates).astype(jnp.int32))
  return plan, memory


LI2020 = base.planner(
    "li2020", plan_li2020, defaults=Weights, settings=Settings(), validate=validate,
    size_settings=size_settings, init_memory=init_memory, step_hook=update_entropy_map,
    commits=True, slam="scan_matching",
    summary="Li et al. 2020: entropy-boundary paths, uncertainty-corrected, max gain")
