"""Toriz & Sánchez's Extended Random Exploration Graph and its baselines REG, SRG and SRT.

Four planners with one per-robot memory, the *exploration graph* (Toriz & Sánchez, Fig 1):

* ``ereg`` — Extended REG: the frontier of the current node is ranked deterministically (the
  "hierarchy of frontiers", Fig 3: smallest turn from the robot's heading first), the robot
  steps toward the chosen arc's approach point (Fig 4), nodes left with open arcs form the
  *frontier control list* (Fig 5), reached over the graph (Fig 6) when the current node has no
  arc left; back at node 0 when no arc and no listed node remain.
* ``reg`` — REG (Toriz et al. 2017): the same, with the arc and the direction in it drawn
  uniformly at random.
* ``srg`` — SRG (Franchi et al. 2009), as the Toriz introduction describes it: bridges between
  nodes whose LSRs overlap, an arc drawn with probability proportional to its width, no control
  list: a node without arcs sends the robot to the adjacent node with the widest open arcs, else
  to its parent in the tree; exploration stops back at the root.
* ``srt`` — SRT (Oriolo et al. 2004): a tree; a direction drawn uniformly over the free bins of
  the current LSR, the new node ``r·ρ`` along it valid when the belief lets the robot stand and
  arrive there and it is at least ``d_min`` from every node, up to ``I_max`` draws; with none
  valid, a turn in place toward the node's unseen directions if it has any (below), else back to
  the parent; exploration stops when the root has no valid draw and nothing unseen.

The algorithm (Fig 1) as this module runs it, one decision per call of the plan function (the
robot drives to its goal before deciding again; the engine calls the planner when the path is
done):

1. Node 0 is the start, with its LSR (:func:`reg_kernels.lsr_rays`, cast over 360° on the
   belief). On arrival at a destination the robot's position becomes a new node (PERCEPTION),
   with an edge to the node it came from; the bins of that node's chosen arc F_det are reopened
   and closed again where the new LSR covers them (VERIFICATION).
2. CURR_INTERSECTION: a bin of another node whose boundary point lies in the current LSR is
   closed, and so is a bin of the current node whose boundary point lies in another LSR; an edge
   joins the current node to every node within R whose straight segment is belief-traversable.
3. The frontier F = the circular runs of open bins of the current node.
4. F ≠ ∅: per run of width w, ``c = 2·arccos(((1 + r²)ρ² − R²) / (2rρ²))``
   (:func:`reg_kernels.coverable_width`, ρ = the run's longest ray); the approach direction φ* is
   the run's middle when w ≤ c, else c/2 in from the run's end nearer the heading, and F_det
   the run's bins within φ* ± c/2. The destination is ``q + r·ρ(φ*)·u(φ*)`` (DISPLACE), tried
   at 1, 0.75, 0.5 and 0.25 of the step; a run none of whose steps the robot can stand on and
   reach has F_det closed, and the choice is made again.
5. F = ∅: FIND_PATH, the listed node nearest over the graph (a dense Dijkstra,
   :func:`jaxplore.graph.node_graph.dijkstra`, where the paper runs a bidirectional A*), driven
   to hop by hop along the graph with grid shortest paths between nodes.
6. No arc and no listed node: back to node 0 along the graph, then the plan is invalid and the
   engine ends the episode.

Decisions (the paper is silent; see also the module's settings):

* Perception happens at every step in jaxplore, so the belief knows more than the LSRs: an
  arc may lead into space the robot has already seen while driving. With
  ``belief_arcs`` (default) a free bin is also closed when no frontier cell of the
  belief (a free cell next to an unknown one) lies within ``arc_reach`` of the end of its ray;
  checked when its node is created and for every node at every decision. (Testing only the
  bin's central ray for unknown cells is not enough: at a corridor's corner the unseen part
  lies in the shadow of the corner, which no ray from the node enters, and a ray that grazes
  the corner reaches R in free space and then meets the far wall.) ``belief_arcs = False``
  keeps the paper's arcs, from the LSRs alone.
* The free boundary of an LSR includes its shadow edges (``shadow_arcs``, default): where a
  bin's ray is longer than a neighbour's by more than ``shadow_jump``, the LSR's boundary runs
  radially between their ends, along the shadow of what the shorter ray stops on, with unseen
  space beside it; the longer bin is a free bin though its ray ends on an obstacle
  (:func:`reg_kernels.shadow_bins`). With ``belief_arcs`` it stays open while a frontier cell
  lies within ``arc_reach`` of the middle of its shadow edge (a wall seen at a grazing angle
  makes depth jumps too, but its edges run along the wall, away from any frontier). Without the
  rule a free bin is only a ray that reaches R or stops on unknown space, and a node beside a
  corridor's corner, or in a room below its door, whose rays past the corner or through the door
  all end on a far wall within R, has no arc toward the space behind them: it is closed for
  good, and with it the arcs of the nodes before it that its LSR covers (on the ``corridors``
  world, 4 of 10 REG runs ended at 11-97 % coverage so).
* A step shorter than ``arrive_tol`` (an arc whose ray stops on unknown space right beside
  the node, e.g. the sector behind the robot that its 240° lidar has not seen) is a turn in
  place: the robot faces the arc, and the current node's LSR is cast again instead of a node
  being added beside it. A step may not end within ``d_sep`` of another node (the same step
  from the same arc again makes no progress).
* SRT's look around. Oriolo et al.'s LSR is perceived all around the node (their robots sense
  360°); with a narrower sensor (the ``toriz`` preset's 240°) the sector behind the robot is
  unseen when it arrives at a node, and its free bins' rays stop on unknown space beside the
  robot: too short for a step of at least ``d_min``. A robot that started facing a wall had no
  valid draw at all and SRT ended at its root at once (``corridors``, seed 2: 3.5 % coverage).
  So when no draw is valid and the node has *unseen* bins (free, the ray stopping on unknown
  space, ``r·ρ < d_min``), the robot turns in place to face the widest run of them (its middle,
  or ``fov/2`` in from its end nearer the heading when the sensor's field of view is narrower
  than the run), the node's LSR is cast again and the draws are made again. The bins looked at
  leave the node's ``open`` row (SRT's record of the bins not yet looked at) and come back only
  where the new ray grew, so a node is turned at a bounded number of times. Looking only when
  the draws fail (not at every node) keeps every episode without such a node unchanged.
* REG and SRG: a drawn direction none of whose steps works closes the bin it lies in, not the
  whole F_det around it (Extended REG's ranked approach points close F_det, step 4d).
* A robot whose path ends away from its destination (a path cut by the path capacity, a cell
  found occupied) is sent there again up to ``retries`` times. An exploration step that still
  fails ends where the robot is: that position becomes the new node. A hop that fails removes
  the graph edge it followed.
* Node capacity (a static setting) is never overwritten: when it is full the robot stops
  exploring, returns to node 0 and the memory's ``overflow`` flag says so.
* Node positions are cell centres of the robot's estimated cell (the planner works in the grid's
  cell units; the world origin is not part of its context).
"""

from __future__ import annotations

import dataclasses
import math
import types
from typing import Any

import chex
import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import pytrees
from jaxplore.errors import ConfigError, shown
from jaxplore.frontiers import plan_to, reachable_paths
from jaxplore.graph import node_graph
from jaxplore.planners import base
from jaxplore.planners import reg_kernels as K
from jaxplore.settings import setting

START, EXPLORE, TRAVEL, DONE = 0, 1, 2, 3
MODES = {START: "start", EXPLORE: "explore", TRAVEL: "travel", DONE: "done"}

# DISPLACE's fallbacks: fractions of the step r·ρ(φ*) tried in turn.
STEP_SCALES = (1.0, 0.75, 0.5, 0.25)

@dataclasses.dataclass(frozen=True)
class Weights:
  """Traced weights of the REG family (``params.planner[name]``; sweeping them never recompiles)."""

  R: float = setting(4.0, "the LSR radius R (Toriz & Sánchez: the sensor range), <= the setting "
                     "max_radius", unit="m", gt=0)
  r: float = setting(0.5, "DISPLACE's step r·ρ(φ*) as a fraction of the LSR radius (r < 1)",
                     gt=0, lt=1)
  d_min: float = setting(1.0, "SRT: the least distance of a new node from every node", unit="m",
                         ge=0)
  I_max: float = setting(30.0, "SRT: the most direction draws per decision (<= the setting "
                         "max_draws)", ge=1)
  d_sep: float = setting(0.5, "REG, SRG: the least distance of a new node from every node but "
                         "the current", unit="m", ge=0)
  arrive_tol: float = setting(0.3, "the distance at which a destination counts as reached (a "
                              "shorter step is a turn in place)", unit="m", ge=0)
  retries: float = setting(3.0, "times a robot is sent again to a destination it did not reach",
                           ge=0)
  shadow_jump: float = setting(0.5, "with shadow_arcs: the least depth jump between bins that "
                               "is a sensor shadow", unit="m", ge=0)


DEFAULTS = {f.name: f.default for f in dataclasses.fields(Weights)}


@dataclasses.dataclass(frozen=True)
class Settings:
  """Static settings of the REG family (a change recompiles; ``nodes`` and ``bins`` fix shapes).

  Attributes:
    nodes: node capacity N of the exploration graph.
    bins: angular bins B of an LSR (3° at 120).
    max_radius: the largest LSR radius ``R`` allowed, m (it bounds the rays cast).
    belief_arcs: arcs are also closed by the belief (True), or by the LSRs alone as in the paper
      (False); see the module docstring.
    arc_reach: with ``belief_arcs``, a free bin stays open while a frontier cell of the belief
      lies within this many metres (rows and columns) of the end of its ray.
    widest_first: Extended REG's ranking of arcs (Fig 3, not in the text): False = smallest
      turn from the heading first, ties to the wider arc, then the lower bin; True = widest arc
      first, ties to the smaller turn.
    max_draws: static bound on SRT's ``I_max``.
    shadow_arcs: an obstacle bin whose ray is longer than a neighbour's by more than the weight
      ``shadow_jump`` is a free bin (:func:`reg_kernels.shadow_bins`: the LSR's boundary runs
      along a sensor shadow there), True; or only rays that reach R or stop on unknown space are
      free (False: the rule of the earlier versions, under which a node beside a corner or a
      door sees no arc into the space behind it).
  """

  nodes: int = setting(256, "node capacity N of the exploration graph", static=True, ge=2,
                       integer=True)
  bins: int = setting(120, "angular bins B of an LSR (3° at 120)", static=True, ge=8,
                      integer=True)
  max_radius: float = setting(4.0, "the largest LSR radius R allowed (it bounds the rays cast)",
                              unit="m", static=True, gt=0)
  belief_arcs: bool = setting(True, "arcs are also closed by the belief (true), or by the LSRs "
                              "alone as in the paper (false)", static=True, boolean=True)
  arc_reach: float = setting(0.5, "with belief_arcs: a free bin stays open while a frontier cell "
                             "lies within this of the end of its ray", unit="m", static=True,
                             ge=0)
  widest_first: bool = setting(False, "Extended REG's ranking of arcs (Fig 3): smallest turn "
                               "from the heading first (false), or widest arc first (true)",
                               static=True, boolean=True)
  max_draws: int = setting(64, "static bound on SRT's I_max", static=True, ge=1, integer=True)
  shadow_arcs: bool = setting(True, "an obstacle bin past a depth jump of more than "
                              "shadow_jump (a sensor shadow) is a free bin", static=True,
                              boolean=True)


@pytrees.dataclass(frozen=True)
class Memory:
  """One robot's exploration graph and where it is in Fig 1's loop (N nodes, B bins).

  Attributes:
    uv: f32[N, 2] node positions (column, row), cell units.
    rho: f32[N, B] LSR ray lengths, cells.
    obstacle: bool[N, B] bins whose ray stops on an occupied cell before R (the others, and
      with ``shadow_arcs`` the shadow bins among them, are free bins).
    open: bool[N, B] free bins still on the node's frontier (SRT: free bins it has not turned
      to look at).
    adjacent: bool[N, N] graph edges (symmetric).
    parent: i32[N] the node each node was reached from (-1 for node 0 and unused slots).
    count: i32 nodes in use.
    current: i32 the node the robot is at, or last left (-1 before node 0).
    mode: i32 START, EXPLORE (driving to a new node), TRAVEL (driving to node ``hop``), DONE.
    pending: bool[B] F_det: the current node's bins being explored (closed until verified).
    turn: bool the exploration step is a turn in place (a step shorter than ``arrive_tol``; SRT:
      a look at unseen directions).
    dest: f32[2] where the robot is driving (u, v): q_dest, or node ``hop``.
    phi: f32 the approach direction φ* of the current exploration step, rad.
    hop: i32 the node driven to in TRAVEL (-1 otherwise).
    tries: i32 times the robot was sent to ``dest`` again.
    overflow: bool the node capacity was reached (exploration stopped early).
    decisions: i32 decisions taken (calls that did not just resend the robot).
  """

  uv: chex.Array
  rho: chex.Array
  obstacle: chex.Array
  open: chex.Array
  adjacent: chex.Array
  parent: chex.Array
  count: chex.Array
  current: chex.Array
  mode: chex.Array
  pending: chex.Array
  turn: chex.Array
  dest: chex.Array
  phi: chex.Array
  hop: chex.Array
  tries: chex.Array
  overflow: chex.Array
  decisions: chex.Array


def init_memory(ctx, params) -> Memory:
  """An empty exploration graph (the first plan adds node 0 where the robot stands)."""
  n, b = ctx.settings.nodes, ctx.settings.bins
  return Memory(
      uv=jnp.zeros((n, 2), jnp.float32), rho=jnp.zeros((n, b), jnp.float32),
      obstacle=jnp.zeros((n, b), bool), open=jnp.zeros((n, b), bool),
      adjacent=jnp.zeros((n, n), bool), parent=jnp.full((n,), -1, jnp.int32),
      count=jnp.int32(0), current=jnp.int32(-1), mode=jnp.int32(START),
      pending=jnp.zeros((b,), bool), turn=jnp.bool_(False), dest=jnp.zeros((2,), jnp.float32),
      phi=jnp.float32(0), hop=jnp.int32(-1), tries=jnp.int32(0), overflow=jnp.bool_(False),
      decisions=jnp.int32(0))


def validate(weights, params, ctx) -> None:
  """Host-side checks of the weights and settings, before compute."""
  s = ctx.settings
  if not isinstance(s, Settings):
    raise ConfigError(f"REG planners need their Settings, got {s!r}")
  w = {k: np.asarray(weights.get(k, v), np.float64) for k, v in DEFAULTS.items()}
  # The single-value ranges are declared (Weights, Settings) and checked by the engine; these
  # relate a weight to a setting.
  checks = [  # (name, where it is fine, what it must be)
      ("R", w["R"] <= s.max_radius + 1e-6,
       f"<= the setting max_radius = {s.max_radius} m (raise it)"),
      ("I_max", w["I_max"] <= s.max_draws,
       f"<= the setting max_draws = {s.max_draws} (raise it)"),
  ]
  for name, ok, what in checks:
    if not np.all(ok):
      raise ConfigError(f"REG parameter {name} must be {what}, got {shown(w[name], ~ok)}")
  r_max = np.asarray(params.r_max, np.float64)
  if s.belief_arcs and np.any(r_max > w["R"] + 1e-6):
    raise ConfigError(
        f"REG: the lidar's r_max = {np.max(r_max):g} m is longer than the LSR radius R = "
        f"{np.min(w['R']):g} m (Toriz & Sánchez's R is the sensor range): with belief_arcs every "
        f"arc ends in space the scans have already seen and is closed, so the planner stops "
        f"early (ereg on lab at r_max 6 m: 12-80 % coverage). Use the toriz preset "
        f"(--preset toriz: a 4 m lidar), set R to the range (and the setting max_radius with "
        f"it), or belief_arcs=false")


def _weights(params) -> dict:
  return {name: jnp.asarray(params.planner.get(name, value), jnp.float32)
          for name, value in DEFAULTS.items()}


def _cell(uv, height: int, width: int):
  """i32[..., 2] (row, col) of the cell holding (u, v), clipped into the grid."""
  col = jnp.clip(jnp.floor(uv[..., 0]).astype(jnp.int32), 0, width - 1)
  row = jnp.clip(jnp.floor(uv[..., 1]).astype(jnp.int32), 0, height - 1)
  return jnp.stack([row, col], axis=-1)


def _inside_grid(uv, height: int, width: int):
  return ((uv[..., 0] >= 0) & (uv[..., 0] < width) & (uv[..., 1] >= 0) & (uv[..., 1] < height))


def _unit(angle):
  return jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)


def _set_row(array, value, row, when):
  """``array`` with row ``row`` replaced by ``value`` where ``when`` (a select over the whole
  array: cheaper to compile than a scatter, and these arrays are small)."""
  mask = (jnp.arange(array.shape[0]) == row) & when
  return jnp.where(mask.reshape((-1,) + (1,) * (array.ndim - 1)), value[None] if array.ndim > 1
                   else value, array)


def _pair(index, a, b):
  """bool[N, N]: the two entries (a, b) and (b, a) of a symmetric matrix."""
  row_a, row_b = index == a, index == b
  return (row_a[:, None] & row_b[None, :]) | (row_b[:, None] & row_a[None, :])


def _segments_clear(traversable, start, ends, samples: int):
  """bool[N]: whether the straight segments from ``start`` to each of ``ends`` (f32[N, 2], u v)
  stay on traversable cells, sampled every half cell or finer (``samples`` points)."""
  height, width = traversable.shape
  t = jnp.linspace(0.0, 1.0, samples, dtype=jnp.float32)
  points = start[None, None, :] + t[None, :, None] * (ends - start[None, :])[:, None, :]
  cells = _cell(points, height, width)
  ok = traversable[cells[..., 0], cells[..., 1]] & _inside_grid(points, height, width)
  return jnp.all(ok, axis=1)


def _run_bins(runs: K.Runs, bins: int):
  """bool[M, B]: the bins of each run."""
  b = jnp.arange(bins, dtype=jnp.int32)
  offset = jnp.mod(b[None, :] - runs.start[:, None], bins)
  return runs.valid[:, None] & (offset < runs.length[:, None])


def _draw(weight, u):
  """The index drawn with probability ∝ ``weight`` (f32[K] >= 0) by the uniforms ``u`` (any
  shape, in [0, 1)): the inverse of the cumulative distribution."""
  total = jnp.cumsum(weight)
  target = u[..., None] * total[-1]
  index = jnp.sum(total.reshape((1,) * jnp.ndim(u) + total.shape) <= target, axis=-1)
  return jnp.minimum(index, weight.shape[0] - 1).astype(jnp.int32)


def _arc_candidates(variant: str, widest_first: bool, runs: K.Runs, rho_c, theta, r, radius, key):
  """Per run: the approach direction φ, its F_det bins, and an order (lower = tried first).

  Returns (phi f32[M], fdet bool[M, B], order f32[M], eligible bool[M]).
  """
  bins = rho_c.shape[0]
  width_per_bin = 2 * jnp.pi / bins
  in_run = _run_bins(runs, bins)
  lo = -jnp.pi + runs.start.astype(jnp.float32) * width_per_bin
  width = runs.length.astype(jnp.float32) * width_per_bin
  rho_run = jnp.max(jnp.where(in_run, rho_c[None, :], 0.0), axis=1)
  cover = K.coverable_width(rho_run, r, radius)
  phi_b = K.bin_angles(bins)
  if variant == "ereg":
    fits = width <= cover
    lo_first = jnp.abs(K.wrap(lo - theta)) <= jnp.abs(K.wrap(lo + width - theta))
    phi = jnp.where(fits, lo + 0.5 * width, jnp.where(lo_first, lo + 0.5 * cover,
                                                      lo + width - 0.5 * cover))
    turn = jnp.abs(K.wrap(phi - theta))
    start = runs.start.astype(jnp.float32)
    keys = (-width, turn, start) if widest_first else (turn, -width, start)
    # Lexicographic rank: how many valid runs come before each (start bins are distinct).
    before = jnp.zeros((width.shape[0], width.shape[0]), bool)
    for key_k in reversed(keys):
      lower = key_k[None, :] < key_k[:, None]
      before = lower | ((key_k[None, :] == key_k[:, None]) & before)
    rank = jnp.sum(before & runs.valid[None, :], axis=1)
    eligible = runs.valid
    order = jnp.where(eligible, rank.astype(jnp.float32), jnp.inf)
  else:
    u = jax.random.uniform(key, (2,))
    weight = jnp.where(runs.valid, 1.0 if variant == "reg" else width, 0.0)
    chosen = _draw(weight, u[0])
    phi = lo + u[1] * width  # only the chosen run's φ is used
    eligible = runs.valid & (jnp.arange(runs.valid.shape[0]) == chosen)
    order = jnp.where(eligible, 0.0, jnp.inf)
  fdet = in_run & (jnp.abs(K.wrap(phi_b[None, :] - phi[:, None])) <= 0.5 * cover[:, None])
  # The bin holding φ is always part of F_det (a narrow cover could miss every bin centre).
  fdet = fdet | (in_run & (jnp.arange(bins)[None, :] == K.bin_of(phi, bins)[:, None]))
  return phi, fdet, order, eligible


def _select_arc(variant: str, widest_first: bool, open_c, rho_c, q_c, theta, r, radius, acceptable,
                key, max_rounds: int):
  """Steps 3-4 of Fig 1 for the current node: the chosen direction and destination.

  ``acceptable(uv f32[..., 2]) -> bool[...]`` says whether a destination may be chosen (the
  robot can stand on it and reach it, ...). Returns (found, phi, dest f32[2], fdet bool[B],
  open_c with failed F_det closed).
  """
  bins = open_c.shape[0]
  scales = jnp.asarray(STEP_SCALES, jnp.float32)

  def body(carry):
    open_c, key, _, _, _, _, rounds = carry
    if variant == "ereg":
      k_draw = key
    else:
      key, k_draw = jax.random.split(key)
    runs = K.circular_runs(open_c)
    phi, fdet, order, eligible = _arc_candidates(variant, widest_first, runs, rho_c, theta, r,
                                                 radius, k_draw)
    step = r * rho_c[K.bin_of(phi, bins)]
    dest = (q_c[None, None, :] + scales[None, :, None] * step[:, None, None] *
            _unit(phi)[:, None, :])
    ok = acceptable(dest) & eligible[:, None]
    score = jnp.where(ok, order[:, None] * len(STEP_SCALES) + jnp.arange(len(STEP_SCALES))[None, :],
                      jnp.inf)
    best = jnp.argmin(score.ravel())
    found = jnp.isfinite(score.ravel()[best])
    run, scale = best // len(STEP_SCALES), best % len(STEP_SCALES)
    failed = eligible & jnp.where(found, order < order[run], True)
    if variant == "ereg":
      given_up = fdet  # step 4d: a run none of whose steps works loses its F_det
    else:
      # A failed random draw rejects its direction only (F_det spans up to 2·arccos(r/2),
      # about 150°, of which the drawn direction may be the one unreachable part).
      given_up = fdet & (jnp.arange(bins)[None, :] == K.bin_of(phi, bins)[:, None])
    closed = jnp.any(given_up & failed[:, None], axis=0) | (found & fdet[run])
    return (open_c & ~closed, key, found, phi[run], dest[run, scale], fdet[run] & found,
            rounds + 1)

  def cond(carry):
    open_c, _, found, _, _, _, rounds = carry
    return ~found & jnp.any(open_c) & (rounds < max_rounds)

  init = (open_c, key, jnp.bool_(False), jnp.float32(0), q_c, jnp.zeros((bins,), bool),
          jnp.int32(0))
  open_c, _, found, phi, dest, fdet, _ = jax.lax.while_loop(cond, body, init)
  return found, phi, dest, fdet, open_c


def _select_srt(obstacle_c, rho_c, q_c, uv, valid_nodes, r, d_min_cells, i_max, standable, key,
                max_draws: int):
  """SRT's step: up to I_max directions drawn uniformly over the free bins, the first valid one.

  Returns (found, phi, dest).
  """
  bins = rho_c.shape[0]
  free = ~obstacle_c
  u = jax.random.uniform(key, (2, max_draws))
  drawn = _draw(free.astype(jnp.float32), u[0])
  phi = -jnp.pi + (drawn.astype(jnp.float32) + u[1]) * (2 * jnp.pi / bins)
  dest = q_c[None, :] + (r * rho_c[drawn])[:, None] * _unit(phi)
  gap = dest[:, None, :] - uv[None, :, :]
  far = jnp.all((jnp.sum(gap * gap, axis=-1) >= d_min_cells**2) | ~valid_nodes[None, :], axis=1)
  ok = standable(dest) & far & (jnp.arange(max_draws) < i_max) & jnp.any(free)
  first = jnp.argmax(ok)
  return ok[first], phi[first], dest[first]


def _look_srt(unseen, theta, fov):
  """SRT's turn in place: where to face to see the widest run of ``unseen`` bins (bool[B]).

  The run's middle when the field of view ``fov`` (rad) spans it, else ``fov/2`` in from its end
  nearer the heading ``theta`` (the rest of the run is looked at by a later turn). Returns
  (any, phi, looked bool[B]: the run's bins within ``phi ± fov/2``, and always the bin of
  ``phi``).
  """
  bins = unseen.shape[0]
  runs = K.circular_runs(unseen)
  step = 2 * jnp.pi / bins
  pick = jnp.argmax(jnp.where(runs.valid, runs.length, -1))  # the widest; ties to the first
  lo = -jnp.pi + runs.start[pick].astype(jnp.float32) * step
  width = runs.length[pick].astype(jnp.float32) * step
  lo_first = jnp.abs(K.wrap(lo - theta)) <= jnp.abs(K.wrap(lo + width - theta))
  phi = jnp.where(width <= fov, lo + 0.5 * width,
                  jnp.where(lo_first, lo + 0.5 * fov, lo + width - 0.5 * fov))
  in_run = _run_bins(runs, bins)[pick]
  index = jnp.arange(bins)
  looked = in_run & ((jnp.abs(K.wrap(K.bin_angles(bins) - phi)) <= 0.5 * fov) |
                     (index == K.bin_of(phi, bins)))
  return jnp.any(unseen), K.wrap(phi), looked


def _plan(variant: str, ctx, view: base.BeliefView, robot: base.RobotView, params, key,
          mem: Memory):
  s: Settings = ctx.settings
  n, bins = s.nodes, s.bins
  height, width = ctx.height, ctx.width
  w = _weights(params)
  res = ctx.res
  radius = w["R"] / res
  r = w["r"]
  belief_arcs = s.belief_arcs and variant != "srt"
  n_cross = int(math.ceil(s.max_radius / res)) + 2
  classes = K.belief_classes(view.free, view.occupied)
  node_index = jnp.arange(n, dtype=jnp.int32)

  here = robot.cell[::-1].astype(jnp.float32) + 0.5
  theta = robot.pose[2]
  node_cost = jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32)
  dist, pred = reachable_paths(ctx, view, robot, node_cost)

  def reachable(uv):
    cells = _cell(uv, height, width)
    return _inside_grid(uv, height, width) & jnp.isfinite(dist[cells[..., 0], cells[..., 1]])

  def standable(uv):
    cells = _cell(uv, height, width)
    return reachable(uv) & view.traversable[cells[..., 0], cells[..., 1]]

  # --- 1. where the last goal left the robot ---------------------------------------------------
  mode = mem.mode
  gap = here - mem.dest
  near = jnp.sum(gap * gap) <= (w["arrive_tol"] / res) ** 2
  moving = (mode == EXPLORE) | (mode == TRAVEL)
  keep_going = moving & ~near & reachable(mem.dest) & (mem.tries < w["retries"])
  explore_end = (mode == EXPLORE) & ~keep_going
  travel_end = (mode == TRAVEL) & ~keep_going
  travel_failed = travel_end & ~near
  start = mode == START
  decide = start | explore_end | travel_end
  # A turn in place perceives the current node again instead of adding a node beside it.
  turned = explore_end & mem.turn
  stepped = explore_end & ~mem.turn

  # --- 2. PERCEPTION + VERIFICATION + ADD: a new node where the robot stands -----------------
  cur = mem.current
  cur_safe = jnp.maximum(cur, 0)
  seen_from = jnp.where(turned, mem.uv[cur_safe], here)
  rays = K.lsr_rays(classes, seen_from, radius, n_cross, bins)
  jump = w["shadow_jump"] / res

  def shadows(rho_, obstacle_):
    """bool[..., B]: obstacle bins that are free by the shadow rule (none without it)."""
    if not s.shadow_arcs:
      return jnp.zeros(obstacle_.shape, bool)
    return obstacle_ & jnp.vectorize(lambda x: K.shadow_bins(x, jump), signature="(b)->(b)")(rho_)

  if belief_arcs:
    # At least one cell: a ray that stops on unknown space ends beside the frontier cell, not on it.
    near_frontier = K.dilate(view.frontier, max(1, int(round(s.arc_reach / res))))
    leads_on = lambda ends: near_frontier[_cell(ends, height, width)[..., 0],
                                          _cell(ends, height, width)[..., 1]]
  else:
    leads_on = lambda ends: jnp.ones(ends.shape[:-1], bool)

  def arc_leads_on(centre, rho_, obstacle_):
    """Whether each bin's arc leads on to unknown space (``belief_arcs``): a frontier cell near
    the end of its ray, or for a shadow bin near the middle of its shadow edge (its ray ends on
    the far wall; a wall seen at a grazing angle also makes depth jumps, and its edges run along
    the wall, away from any frontier)."""
    ends_ = K.boundary_points(centre, rho_)
    return jnp.where(shadows(rho_, obstacle_), leads_on(K.shadow_midpoints(centre, rho_)),
                     leads_on(ends_))
  add = start | stepped
  create = add & (mem.count < n) & ~mem.overflow
  overflow = mem.overflow | (add & (mem.count >= n))
  new = jnp.minimum(mem.count, n - 1)
  new_open = ((~rays.obstacle | shadows(rays.rho, rays.obstacle)) &
              arc_leads_on(seen_from, rays.rho, rays.obstacle))
  # VERIFICATION reopens F_det, which the new LSR closes again where it covers it (step 3).
  # After a turn in place, F_det reopens only where the node's ray grew by a cell or more (the
  # turn showed what lies that way), so every bin is turned to a bounded number of times.
  set_row = _set_row
  open_ = set_row(mem.open, mem.open[cur_safe] | mem.pending, cur_safe, stepped & (cur >= 0))
  grown = mem.pending & (rays.rho >= mem.rho[cur_safe] + 1.0)
  open_ = set_row(open_, (mem.open[cur_safe] | grown) & new_open, cur_safe, turned)
  uv = set_row(mem.uv, here, new, create)
  rho = set_row(set_row(mem.rho, rays.rho, new, create), rays.rho, cur_safe, turned)
  obstacle = set_row(set_row(mem.obstacle, rays.obstacle, new, create), rays.obstacle, cur_safe,
                     turned)
  open_ = set_row(open_, new_open, new, create)
  link = create & stepped & (cur >= 0)
  adjacent = mem.adjacent | (_pair(node_index, new, cur_safe) & link)
  parent = set_row(mem.parent, jnp.where(start, -1, cur), new, create)
  count = mem.count + create.astype(jnp.int32)
  # A hop that failed loses the edge it followed; a hop off the graph (a direct fallback) that
  # failed was to an unreachable node, whose arcs are given up.
  hop_safe = jnp.maximum(mem.hop, 0)
  was_edge = mem.adjacent[cur_safe, hop_safe]
  cut = travel_failed & (mem.hop >= 0)
  adjacent = adjacent & ~(_pair(node_index, cur_safe, hop_safe) & cut)
  open_ = set_row(open_, jnp.zeros((bins,), bool), hop_safe, cut & ~was_edge)
  current = jnp.where(create, new, jnp.where(travel_end & near, mem.hop, cur))
  c = jnp.maximum(current, 0)
  valid_nodes = node_index < count

  # --- 3. CURR_INTERSECTION ---------------------------------------------------------------------
  if variant != "srt":
    q_c = uv[c]
    offset = uv - q_c[None, :]
    separation = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
    others = valid_nodes & (node_index != c) & (separation <= 2 * radius)
    ends = jax.vmap(K.boundary_points)(uv, rho)  # [N, B, 2]
    in_current = K.inside_lsr(ends, q_c, rho[c]) & others[:, None]
    in_others = jax.vmap(lambda q, rho_j: K.inside_lsr(ends[c], q, rho_j))(uv, rho)
    closes_current = jnp.any(in_others & others[:, None], axis=0)
    intersected = set_row(open_ & ~in_current, open_[c] & ~closes_current, c, True)
    samples = 2 * int(math.ceil(s.max_radius / res)) + 1
    bridge = others & (separation <= radius) & _segments_clear(view.traversable, q_c, uv, samples)
    bridged = adjacent | (bridge[None, :] & (node_index == c)[:, None]) | (
        bridge[:, None] & (node_index == c)[None, :])
    open_ = jnp.where(decide, intersected, open_)
    # Bridges are added for a new node only: an edge cut after a failed hop stays cut.
    adjacent = jnp.where(create, bridged, adjacent)

    # The belief check of every node's arcs (belief_arcs).
    if belief_arcs:
      open_ = jnp.where(decide, open_ & jax.vmap(arc_leads_on)(uv, rho, obstacle), open_)

  # --- 4. explore from the current node ---------------------------------------------------------
  q_c = uv[c]
  may_explore = decide & (current >= 0) & ~overflow
  k_explore, _ = jax.random.split(key)
  if variant == "srt":
    blocked_c = obstacle[c] & ~shadows(rho[c], obstacle[c])
    found, phi, dest = _select_srt(blocked_c, rho[c], q_c, uv, valid_nodes, r, w["d_min"] / res,
                                   w["I_max"], standable, k_explore, s.max_draws)
    found = found & may_explore
    # No valid draw: before giving the node up (back to the parent, or the end at the root), the
    # robot turns to look at its unseen directions, free bins whose ray stops on unknown space
    # too near to step along (r·ρ < d_min), and the node's LSR is cast again (step 1).
    unseen = open_[c] & ~obstacle[c] & (rho[c] < radius) & (r * rho[c] < w["d_min"] / res)
    any_unseen, look_phi, looked = _look_srt(unseen, theta, params.fov)
    look = may_explore & ~found & any_unseen
    open_ = _set_row(open_, open_[c] & ~looked, c, look)
    phi = jnp.where(look, look_phi, phi)
    dest = jnp.where(look, q_c, dest)
    fdet = looked & look
    turn = look
    found = found | look
  else:
    tol = w["arrive_tol"] / res
    sep = w["d_sep"] / res
    others = valid_nodes & (node_index != c)

    def acceptable(points):
      # A step shorter than the arrival tolerance is a turn in place; a longer one must not land
      # on another node's place (the same step from the same arc again makes no progress).
      lead = (1,) * (points.ndim - 1)
      offset = points - q_c.reshape(lead + (2,))
      short = jnp.sum(offset * offset, axis=-1) < tol * tol
      gap = points[..., None, :] - uv.reshape(lead + uv.shape)
      apart = jnp.all((jnp.sum(gap * gap, axis=-1) >= sep * sep) | ~others.reshape(lead + (n,)),
                      axis=-1)
      return standable(points) & (short | apart)

    found, phi, dest, fdet, open_c = _select_arc(
        variant, s.widest_first, jnp.where(may_explore, open_[c], False), rho[c], q_c, theta, r,
        radius, acceptable, k_explore, bins + 1)
    open_ = _set_row(open_, open_c, c, may_explore)
    offset = dest - q_c
    turn = found & (jnp.sum(offset * offset) < tol * tol)

  # --- 5./6. no arc here: FIND_PATH to a listed node, or home, or stop ------------------------
  grid_to_node = dist[_cell(uv, height, width)[:, 0], _cell(uv, height, width)[:, 1]]
  node_reachable = valid_nodes & jnp.isfinite(grid_to_node)
  if variant in ("ereg", "reg"):
    gap = uv[:, None, :] - uv[None, :, :]
    lengths = jnp.sqrt(jnp.sum(gap * gap, axis=-1))
    weights = jnp.where(adjacent & valid_nodes[:, None] & valid_nodes[None, :], lengths, jnp.inf)
    graph_dist, graph_pred = node_graph.dijkstra(weights, c)
    listed = valid_nodes & jnp.any(open_, axis=1) & (node_index != c) & ~overflow
    by_graph = jnp.where(listed, graph_dist, jnp.inf)
    target = jnp.argmin(by_graph).astype(jnp.int32)
    via_graph = jnp.isfinite(by_graph[target])
    by_grid = jnp.where(listed & node_reachable, grid_to_node, jnp.inf)
    direct = jnp.argmin(by_grid).astype(jnp.int32)
    via_grid = ~via_graph & jnp.isfinite(by_grid[direct])
    # Listed nodes neither the graph nor the grid reaches are given up.
    stranded = listed & ~via_graph & ~via_grid
    open_ = jnp.where((decide & ~found)[None, None] & stranded[:, None], False, open_)
    home_hop = jnp.where(jnp.isfinite(graph_dist[0]), node_graph.first_hop(graph_pred, c, 0),
                         jnp.where(node_reachable[0], 0, -1))
    hop = jnp.where(via_graph, node_graph.first_hop(graph_pred, c, target),
                    jnp.where(via_grid, direct, jnp.where(c == 0, -1, home_hop)))
  elif variant == "srg":
    open_width = jnp.sum(open_.astype(jnp.int32), axis=1)
    candidates = adjacent[c] & valid_nodes & (node_index != c) & (open_width > 0) & ~overflow
    widest = jnp.argmax(jnp.where(candidates, open_width, -1)).astype(jnp.int32)
    hop = jnp.where(jnp.any(candidates), widest, parent[c])
  else:
    hop = parent[c]
  hop = jnp.where(current >= 0, hop, -1).astype(jnp.int32)

  explore = decide & found
  travel = decide & ~found & (hop >= 0)
  finished = (mode == DONE) | (decide & ~found & (hop < 0))
  hop_uv = uv[jnp.maximum(hop, 0)]
  new_dest = jnp.where(explore, dest, jnp.where(travel, hop_uv, mem.dest))
  new_phi = jnp.where(explore, phi, mem.phi)
  new_mode = jnp.where(finished, DONE, jnp.where(explore, EXPLORE, jnp.where(travel, TRAVEL, mode)))

  goal = _cell(new_dest, height, width)
  valid = ~finished
  cells, length, _ = plan_to(ctx, view, robot, pred, goal, valid)
  facing = _cell(new_dest + radius * _unit(new_phi), height, width)
  look_at = jnp.where(new_mode == EXPLORE, facing, goal)
  memory = Memory(
      uv=uv, rho=rho, obstacle=obstacle, open=open_, adjacent=adjacent, parent=parent, count=count,
      current=current.astype(jnp.int32), mode=new_mode.astype(jnp.int32),
      pending=jnp.where(explore, fdet, jnp.where(decide, False, mem.pending)),
      turn=jnp.where(explore, turn, jnp.where(decide, False, mem.turn)),
      dest=new_dest, phi=new_phi.astype(jnp.float32),
      hop=jnp.where(travel, hop, jnp.where(decide, -1, mem.hop)).astype(jnp.int32),
      tries=jnp.where(decide, 0, mem.tries + 1).astype(jnp.int32), overflow=overflow,
      decisions=mem.decisions + decide.astype(jnp.int32))
  plan = base.Plan(
      waypoints=cells, length=length, goal=goal, look_at=look_at.astype(jnp.int32), valid=valid,
      gain=jnp.float32(0),
      cost=jnp.where(valid, dist[goal[0], goal[1]], jnp.inf).astype(jnp.float32),
      n_candidates=jnp.sum(jnp.any(open_, axis=1) & valid_nodes).astype(jnp.int32))
  return plan, memory


SETTINGS = Settings()
# Their LSR radius R is the sensor's range: Toriz & Sánchez's 4 m lidar is theirs.
@dataclasses.dataclass(frozen=True)
class ExplorationGraph:
  """One robot's exploration graph in metres (host side, NumPy), for tables and figures.

  Attributes:
    nodes: f32[n, 2] node positions (x, y), m.
    parent: i32[n] the node each node was reached from (-1 for node 0).
    edges: i32[E, 2] node pairs (i < j) joined by an edge.
    lsr: f32[n, B, 2] the LSR polygons: the end of every bin's central ray, m.
    open: bool[n, B] bins still on a node's frontier; obstacle: bool[n, B] bins whose ray
      stops on an occupied cell.
    current: the node the robot is at (or last left); mode: its mode name.
    overflow: the node capacity was reached and exploration stopped early.
  """

  nodes: np.ndarray
  parent: np.ndarray
  edges: np.ndarray
  lsr: np.ndarray
  open: np.ndarray
  obstacle: np.ndarray
  current: int
  mode: str
  overflow: bool


def exploration_graph(memory, res: float, origin) -> ExplorationGraph:
  """The exploration graph of one robot's :class:`Memory` in world coordinates: ``x = origin_x +
  u·res``, ``y = origin_y + v·res``. ``memory``: its leaves by field name (a mapping, as
  :func:`jaxplore.results.memory_arrays` names them, or the Memory itself; any array type)."""
  if isinstance(memory, Memory):
    memory = {f.name: getattr(memory, f.name) for f in dataclasses.fields(Memory)}
  memory = types.SimpleNamespace(**memory)
  count = int(np.asarray(memory.count))
  uv = np.asarray(memory.uv, np.float64)[:count]
  rho = np.asarray(memory.rho, np.float64)[:count]
  bins = rho.shape[1]
  phi = -np.pi + (np.arange(bins) + 0.5) * (2 * np.pi / bins)
  ends = uv[:, None, :] + rho[..., None] * np.stack([np.cos(phi), np.sin(phi)], axis=-1)[None]
  origin = np.asarray(origin, np.float64)
  adjacent = np.asarray(memory.adjacent, bool)[:count, :count]
  i, j = np.nonzero(np.triu(adjacent, 1))
  return ExplorationGraph(
      nodes=(origin + uv * res).astype(np.float32), parent=np.asarray(memory.parent)[:count],
      edges=np.stack([i, j], axis=-1).astype(np.int32),
      lsr=(origin + ends * res).astype(np.float32),
      open=np.asarray(memory.open, bool)[:count],
      obstacle=np.asarray(memory.obstacle, bool)[:count],
      current=int(np.asarray(memory.current)), mode=MODES[int(np.asarray(memory.mode))],
      overflow=bool(np.asarray(memory.overflow)))


_COMMON: dict[str, Any] = dict(
    defaults=Weights, settings=SETTINGS, validate=validate, init_memory=init_memory,
    commits=True, preset="toriz", memory_graph=exploration_graph, slam="scan_matching")


def plan_ereg(ctx, view, robot, params, key, memory):
  """Extended REG (Toriz & Sánchez, Fig 1); see the module docstring."""
  return _plan("ereg", ctx, view, robot, params, key, memory)


EREG = base.planner("ereg", plan_ereg, **_COMMON,
                    summary="Toriz & Sánchez's Extended REG: deterministic frontier "
                            "hierarchy, frontier control list, back to the start")


def plan_reg(ctx, view, robot, params, key, memory):
  """REG: Fig 1 with the arc and the direction in it drawn uniformly."""
  return _plan("reg", ctx, view, robot, params, key, memory)


REG = base.planner("reg", plan_reg, **_COMMON,
                   summary="Toriz et al.'s REG: a random arc and direction, frontier control list")


def plan_srg(ctx, view, robot, params, key, memory):
  """SRG as the Toriz introduction describes it; see the module docstring."""
  return _plan("srg", ctx, view, robot, params, key, memory)


SRG = base.planner("srg", plan_srg, **_COMMON,
                   summary="SRG (Franchi et al.): arcs drawn by width, bridges, no control "
                           "list")


def plan_srt(ctx, view, robot, params, key, memory):
  """SRT as the Toriz introduction describes it; see the module docstring."""
  return _plan("srt", ctx, view, robot, params, key, memory)


SRT = base.planner("srt", plan_srt, **_COMMON,
                   summary="SRT (Oriolo et al.): a random tree of LSRs, backtracking to the root")
