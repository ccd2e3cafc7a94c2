"""Single-source shortest paths on 8-connected grids, without a priority queue.

The graph: every cell is a node; the edge from a cell ``u`` to each of its 8 neighbours ``v``
weighs ``step(u, v) * node_cost[v]`` (``step`` = 1 orthogonally, sqrt(2) diagonally), and
``node_cost[v] = inf`` blocks ``v``. Callers scale ``node_cost`` by the grid resolution.

Distances: min-plus (Bellman-Ford) relaxation scheduled as *cone sweeping*. A loop down the
rows relaxes every cell of a row from the 3 cells of the row above (the cells of one row do not
depend on each other, so a step is one vector operation), then a loop up the rows, then the
same over the columns, left to right and right to left. One *round* of these 4 sweeps carries
a shortest path along every stretch of it whose moves agree with a sweep's direction, so open
rooms converge in a handful of rounds (mazes, whose paths turn at every corridor, need
hundreds). After each round, relaxing every cell once from its 8 neighbours (a single vector
pass, with the same float expressions as the sweeps) checks for a fixed point: distances that
are lengths of real paths and that no edge can lower are the shortest ones, so rounds repeat in
a ``lax.while_loop`` only while that check would still lower some cell. A room-like
map thus stops after the round that settles it instead of running a second round to find
nothing changed. Values only ever decrease, and every finite value is the float32 length of a
real path.

A grid still unsettled after ``TILES_AFTER_ROUNDS`` rounds (a maze) is finished *tile by tile*
(:func:`_finish_by_tiles`): in a round of a 256 x 256 maze only ~5 % of the cells change, yet
the sweeps visit them all, so the rounds go on only inside the 16 x 16 tiles that a relaxation
could still lower, least first, each settled by the same sweeps and check with its neighbours'
edge cells held fixed. On the maze benchmark (``experiments/bench_dijkstra.py``) a grid settles
several times sooner that way than by the sweeps alone (the numbers:
``experiments/results/design_notes_cpu.md``).

On an accelerator the sweeps are a chain of tiny kernels (a line step each: thousands of launches a
round, ``experiments/results/design_notes_cpu.md``). There the solver can instead relax every cell
from its 8 neighbours at once, pass after pass (synchronous Bellman-Ford, *relaxation*, one fused
kernel per pass; the fixed-point check every ``RELAXATION_PASSES_PER_CHECK`` passes).

All these schedules reach the same distances bit for bit: any order of these relaxations stops only
at the fixed point, and the fixed point is unique: each cell's value is then the least float32
left-to-right sum over the paths that reach it (it is the sum of one real path, and by induction
along any path, with rounding monotone, no larger than that path's sum). Relaxation needs as
many passes as the longest shortest path has moves, the sweeps as many rounds as it has turns.
(The fixed point stands whatever the order, provided every relaxation that could still lower a
cell is eventually made: the tiles keep that by waking a tile whenever a neighbour lowers one
of the cells at their common edge.)

Predecessors are chosen once, from the converged distances: a cell points at a neighbour with
a strictly smaller distance whose edge is tight. Strictly smaller distances make the field a
tree whatever the rounding. Cells with no such neighbour sit on a *plateau* of equal distances
(reached through zero-cost cells, or edges too cheap to move a float32 sum); they are attached
by a breadth-first search over tight equal-distance edges, each new cell pointing at one that
was attached in an earlier step, which keeps the tree acyclic. Maps without zero costs never
enter that search.

Performance notes (XLA:CPU, measured by ``experiments/bench_dijkstra.py``; the numbers:
``experiments/results/design_notes_cpu.md``):

* A chunk of C grids is solved together in a ``[H + 2, W + 2, C]`` layout: the C maps are
  interleaved in the minor axis, framed by a border of blocked cells so that neighbour reads
  are plain slices. The sweeps update rows in place (``fori_loop`` + ``dynamic_update_slice``):
  a ``lax.scan`` producing new rows was slower per row, and tracking predecessor codes
  during the sweeps multiplied the cost of each row step.
* Column sweeps run on the transposed array; with C minor, that transpose moves C-float blocks
  and is cheaper than transposing a ``[C, H, W]`` stack.
* Unrolling the row loop (``fori_loop(..., unroll=k)``) made XLA copy the whole array at
  every step, far slower.
* Tile by tile, each step cuts its tiles' costs from the grid again: cutting them all once
  and gathering 8 of them per step from the minor axis was slower on the maze benchmark.
  Taking more than ~2 tiles per grid per step visits more tiles before their inputs settle.
* The distances alone are swept; predecessors come from one stencil pass at the end, since
  XLA:CPU has no multi-output loop fusion and a second output per row step costs a second
  pass over its inputs.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

_SQRT2 = math.sqrt(2.0)

# Neighbour offsets (dr, dc) from a cell to a candidate predecessor, in order of preference.
_NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1))

# An edge u -> v counts as tight when dist[u] + w(u, v) <= dist[v] * (1 + _TIGHT_RTOL). The
# predecessor pass recomputes the sums the sweeps made; XLA may contract one of them into a
# fused multiply-add and the other not, so allow a few float32 ulps.
_TIGHT_RTOL = 2.0**-20

DEFAULT_CHUNK = 4

# Loop bounds are int32 counters; the default bounds of a large map (H * W rounds, times the
# tile steps or line passes in a round) can pass 2**31 - 1, which then caps them.
_INT32_MAX = 2**31 - 1

# How distances are computed: "sweeps" (cone sweeping, the default) or "relaxation" (every cell
# at once, pass after pass; see the module docstring).
METHODS = ("sweeps", "relaxation")

# A grid that the sweeps have not settled after this many rounds (a maze: its paths turn at
# every corridor) is finished tile by tile (:func:`_finish_by_tiles`): tiles of TILE x TILE
# cells, TILES_PER_STEP of every grid per step (measured best on a 256 x 256 maze, XLA:CPU).
# After 6 rounds: room-like and real maps settle in about that many and seldom get there,
# while mazes with 3-cell corridors need tens to hundreds of rounds by the sweeps alone and the
# tiles finish them several times sooner; fewer rounds slowed willow, more slowed the mazes
# (the numbers: experiments/results/design_notes_cpu.md).
TILES_AFTER_ROUNDS = 6
TILE = 16
TILES_PER_STEP = 2

# Relaxation passes between two fixed-point checks: each check is a reduction and, inside a
# while loop on an accelerator, a round trip to the host.
RELAXATION_PASSES_PER_CHECK = 16

# How ``vmap`` of :func:`shortest_paths` batches under each execution strategy
# (``SimConfig.strategy``): grids per chunk (None: the whole batch at once) and the method. On a
# CPU, chunks of 4 by cone sweeping; on an accelerator the whole batch by relaxation, where a
# loop over chunks of 4 would be a chain of small kernels as long as the batch.
STRATEGY_BATCHING: dict[str, tuple[int | None, str]] = {
    "per_robot": (DEFAULT_CHUNK, "sweeps"),
    "lockstep": (None, "relaxation"),
}


class ShortestPaths(NamedTuple):
  """Single-source shortest paths on one grid (fields gain a leading axis when batched).

  Attributes:
    dist: f32[H, W]; path cost from the source; inf where unreachable; 0 at the source.
    pred: i32[H, W]; flat index ``r * W + c`` of each cell's predecessor on a shortest path;
      -1 at the source and at unreachable cells.
    sweeps: i32[]; rounds of the 4 sweeps run, the tile steps of a grid finished tile by tile
      counted in whole-grid rounds (one round's worth of tile visits = 1); after the last one
      the fixed-point check found nothing to improve when ``converged``.
    converged: bool[]; False if ``max_sweeps`` rounds ran out before a fixed point (then
      ``dist`` is an upper bound and ``pred`` may be -1 at reachable cells).
  """

  dist: jax.Array
  pred: jax.Array
  sweeps: jax.Array
  converged: jax.Array


def default_max_sweeps(height: int, width: int) -> int:
  """The default bound on rounds for an H x W grid: ``H * W``, which no input can exceed.

  Take a shortest path with the fewest moves: it visits no cell twice, so it has at most
  ``H * W - 1`` moves, and each round fixes at least its next move (every move goes along one
  of the 4 sweeps), so after the last round needed the fixed-point check finds nothing. Real maps
  stop long before: ~5 rounds for 256 x 256 room-like worlds, ~150 for 256 x 256 mazes by the
  sweeps alone (~14 whole-grid rounds' worth when finished tile by tile).
  """
  return height * width


def _sweep_there_and_back(dist: jax.Array, cost: jax.Array, diagonal_cost: jax.Array) -> jax.Array:
  """Two sweeps over the lines (axis 0) of a framed ``[N + 2, M + 2, C]`` array, in place.

  Steps 0..N-1 go forward: line ``i`` = 1..N becomes the min of itself and the relaxation from
  the 3 neighbours in line ``i - 1`` (already updated). Steps N..2N-1 come back from line N to
  line 1, relaxing from line ``i + 1``.
  """
  num_lines, line_length = dist.shape[0] - 2, dist.shape[1] - 2

  def relax_line(step, dist):
    forward = step < num_lines
    line = jnp.where(forward, step + 1, 2 * num_lines - step)
    previous_line = jnp.where(forward, line - 1, line + 1)
    previous = lax.dynamic_index_in_dim(dist, previous_line, keepdims=False)
    old = lax.dynamic_index_in_dim(dist, line, keepdims=False)[1 : line_length + 1]
    step_cost = lax.dynamic_index_in_dim(cost, line, keepdims=False)[1 : line_length + 1]
    straight = previous[1 : line_length + 1] + step_cost
    # Taking the min before adding is exact: rounding is monotone, so
    # fl(min(a, b) + x) = min(fl(a + x), fl(b + x)).
    diagonal = jnp.minimum(previous[:line_length], previous[2:]) + lax.dynamic_index_in_dim(
        diagonal_cost, line, keepdims=False)[1 : line_length + 1]
    new = jnp.minimum(old, jnp.minimum(straight, diagonal))
    return lax.dynamic_update_slice(dist, new[None], (line, 1, 0))

  return lax.fori_loop(0, 2 * num_lines, relax_line, dist)


def _relaxed(dist: jax.Array, cost: jax.Array, diagonal_cost: jax.Array) -> jax.Array:
  """f32[H, W, C]: every cell of a framed ``[H + 2, W + 2, C]`` array relaxed once from its 8
  neighbours (not yet min'ed with its own value).

  The sums are the sweeps' own additions (``neighbour + cost``, ``min(diagonals) +
  diagonal_cost``, with the same precomputed ``diagonal_cost``), so a fixed point of the sweeps
  is a fixed point here. (Multiplying by sqrt(2) in both places is not enough: XLA may contract
  one product and sum into a fused multiply-add and not the other, and the check would then see
  a one-ulp improvement the sweeps can never make.)
  """
  height, width = dist.shape[0] - 2, dist.shape[1] - 2
  at = lambda dr, dc: dist[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width]
  straight = (jnp.minimum(jnp.minimum(at(-1, 0), at(1, 0)), jnp.minimum(at(0, -1), at(0, 1)))
              + cost[1:-1, 1:-1])
  diagonal = (jnp.minimum(jnp.minimum(at(-1, -1), at(-1, 1)), jnp.minimum(at(1, -1), at(1, 1)))
              + diagonal_cost[1:-1, 1:-1])
  return jnp.minimum(straight, diagonal)


def _lowered_by_one_relaxation(dist: jax.Array, cost: jax.Array,
                               diagonal_cost: jax.Array) -> jax.Array:
  """bool[C]: whether relaxing every cell of a framed ``[H + 2, W + 2, C]`` array once from its
  8 neighbours (:func:`_relaxed`) lowers any distance of each grid."""
  return jnp.any(_relaxed(dist, cost, diagonal_cost) < dist[1:-1, 1:-1], axis=(0, 1))


def _relax_every_cell(dist: jax.Array, cost: jax.Array, diagonal_cost: jax.Array) -> jax.Array:
  """One synchronous pass: every cell of a framed ``[H + 2, W + 2, C]`` array becomes the min of
  itself and its relaxation from its 8 neighbours (:func:`_relaxed`); the frame is kept."""
  new = jnp.minimum(dist[1:-1, 1:-1], _relaxed(dist, cost, diagonal_cost))
  return jnp.pad(new, ((1, 1), (1, 1), (0, 0)), constant_values=jnp.inf)


def _round_of_sweeps(dist, cost, diagonal_cost, cost_t, diagonal_cost_t):
  """The 4 sweeps over a framed ``[N + 2, M + 2, C]`` array (a whole grid, or tiles framed by
  their neighbours' edge cells), and bool[C]: whether one more relaxation would still lower a
  cell (checked on the column-major array the last sweeps leave, with the transposed costs
  ``cost_t``, ``diagonal_cost_t``: the 8-neighbourhood is symmetric under transposition)."""
  dist = _sweep_there_and_back(dist, cost, diagonal_cost)
  dist = _sweep_there_and_back(dist.transpose(1, 0, 2), cost_t, diagonal_cost_t)
  return dist.transpose(1, 0, 2), _lowered_by_one_relaxation(dist, cost_t, diagonal_cost_t)


def _tight_predecessors(dist: jax.Array, cost: jax.Array, diagonal_cost: jax.Array,
                        source: jax.Array) -> jax.Array:
  """Predecessors from converged distances, in the sweeps' ``[H + 2, W + 2, C]`` layout.

  A cell points at a neighbour over a tight edge that is strictly closer to the source, or,
  on a plateau of equal distances, at a neighbour attached in an earlier step of a
  breadth-first search; following ``pred`` thus strictly decreases (distance, step) and
  cannot cycle. Without plateaus the search stops after checking once.

  The choice is made as a neighbour code (the index into ``_NEIGHBOURS``) and turned into a flat
  index once at the end. Why: inside a loop (a chunk of a ``lax.map``, a planning round), XLA
  hoists every loop-invariant array out of it, and ``flat + offset`` for 8 offsets became 8
  materialised int32 grids that the stencil then read back. For the same reason the stencil
  reads the arrays the sweeps already hold (a ``[C, H, W]`` view of them was re-indexed
  through a transpose or a caller's slice at each of its 8 neighbour reads). Together, 64
  open 96 x 96 maps in chunks of 4: 163 -> 125 us per map (the distances alone: 76).

  Args:
    dist: f32[H + 2, W + 2, C]; converged distances in an inf frame.
    cost, diagonal_cost: f32[H + 2, W + 2, C]; the framed step costs the sweeps used.
    source: i32[C, 2].

  Returns:
    i32[C, H, W] flat predecessor indices, -1 at sources and unreachable cells.
  """
  height, width = dist.shape[0] - 2, dist.shape[1] - 2
  here = dist[1:-1, 1:-1]
  rows = lax.broadcasted_iota(jnp.int32, here.shape, 0)
  cols = lax.broadcasted_iota(jnp.int32, here.shape, 1)
  is_source = (rows == source[None, None, :, 0]) & (cols == source[None, None, :, 1])
  unreachable = jnp.isinf(here)

  def window(framed, dr, dc):
    return framed[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width]

  def choose(usable, dist, cost, diagonal_cost):
    """Code of the first neighbour k (in _NEIGHBOURS order) with a tight edge and
    usable(k, neighbour, here), else -1."""
    here = window(dist, 0, 0)
    tight_bound = here + here * jnp.float32(_TIGHT_RTOL)
    code = jnp.int32(-1)
    for k, (dr, dc) in reversed(list(enumerate(_NEIGHBOURS))):
      neighbour = window(dist, dr, dc)
      step_cost = window(diagonal_cost if dr and dc else cost, 0, 0)
      tight = neighbour + step_cost <= tight_bound
      code = jnp.where(tight & usable(k, neighbour, here), jnp.int32(k), code)
    return code

  code = choose(lambda k, neighbour, here: neighbour < here, dist, cost, diagonal_cost)
  # Materialised here, the choice is not recomputed by each of its readers below.
  code = lax.optimization_barrier(jnp.where(is_source | unreachable, -1, code))
  attached = (code >= 0) | is_source | unreachable

  def grow(carry):
    code, attached, _ = carry
    attached_framed = jnp.pad(attached, ((1, 1), (1, 1), (0, 0)))

    def level_and_attached(k, neighbour, here):
      dr, dc = _NEIGHBOURS[k]
      return (neighbour == here) & window(attached_framed, dr, dc) & ~attached

    # Tied to the loop-varying `attached` by a barrier, these inputs look loop-varying: XLA
    # would otherwise hoist the tight-edge tests out of the loop, run them even when the loop
    # never iterates, and materialise what they share with the choice above.
    inputs = lax.optimization_barrier((dist, cost, diagonal_cost, attached))[:3]
    new_code = lax.optimization_barrier(choose(level_and_attached, *inputs))
    newly_attached = (new_code >= 0) & ~attached
    code = jnp.where(newly_attached, new_code, code)
    return code, attached | newly_attached, jnp.any(newly_attached)

  plateau = ~jnp.all(attached)
  code, _, _ = lax.while_loop(lambda carry: carry[2], grow, (code, attached, plateau))
  offset = jnp.int32(0)
  for k, (dr, dc) in enumerate(_NEIGHBOURS):
    offset = jnp.where(code == k, jnp.int32(dr * width + dc), offset)
  pred = jnp.where(code >= 0, rows * width + cols + offset, -1)
  return pred.transpose(2, 0, 1)


def _finish_by_tiles(dist: jax.Array, cost: jax.Array, diagonal_cost: jax.Array,
                     max_steps: int) -> tuple[jax.Array, jax.Array]:
  """Takes framed ``[H + 2, W + 2, C]`` distances on to the fixed point, tile by tile.

  The grid is cut into ``TILE`` x ``TILE`` tiles. A tile is *pending* while a relaxation could
  lower one of its cells; its key is the least value such a relaxation would give. Each step
  takes the ``TILES_PER_STEP`` pending tiles of least key of every grid (Dijkstra's order, one
  level up) and settles them together, each framed by its neighbours' edge cells held fixed,
  by the whole grid's own rounds of sweeps and check; then it marks pending the neighbours of
  every tile whose edge cells it lowered. A tile left alone thus stays settled, so when no tile
  is pending the grid is at the fixed point: the same distances as the sweeps, bit for bit (see
  the module docstring). Work goes where values still change: ~5 % of a maze's cells change in
  a round of the sweeps, which visit all of them.

  Args:
    dist, cost, diagonal_cost: f32[H + 2, W + 2, C]; the sweeps' framed arrays.
    max_steps: static bound on steps.

  Returns:
    (dist f32[H + 2, W + 2, C], steps i32[C]: steps in which each grid had a pending tile).
  """
  height, width, chunk = dist.shape[0] - 2, dist.shape[1] - 2, dist.shape[2]
  size = TILE
  tile_rows, tile_cols = -(-height // size), -(-width // size)
  tiles = tile_rows * tile_cols
  per_step = min(TILES_PER_STEP, tiles)
  inf = jnp.float32(jnp.inf)

  # Pending tiles at the start: where one relaxation would lower a cell.
  relaxed = _relaxed(dist, cost, diagonal_cost)
  lowered = jnp.where(relaxed < dist[1:-1, 1:-1], relaxed, inf)
  # Blocked cells past the frame make the grid whole tiles.
  extra = ((0, tile_rows * size - height), (0, tile_cols * size - width), (0, 0))
  lowered, dist, cost, diagonal_cost = (jnp.pad(a, extra, constant_values=inf)
                                        for a in (lowered, dist, cost, diagonal_cost))
  key = lowered.reshape(tile_rows, size, tile_cols, size, chunk).min(axis=(1, 3))
  key = jnp.append(key.transpose(2, 0, 1).reshape(-1), inf)  # + the slot of off-grid neighbours

  grid = jnp.repeat(jnp.arange(chunk, dtype=jnp.int32), tiles)
  row = jnp.tile(jnp.arange(tiles, dtype=jnp.int32) // tile_cols, chunk)
  col = jnp.tile(jnp.arange(tiles, dtype=jnp.int32) % tile_cols, chunk)

  def cut(framed, g, r, c):
    """Framed tiles [T + 2, T + 2, K] (tile k of grid g[k] at tile row r[k], column c[k])."""
    one = lambda g, r, c: lax.dynamic_slice(framed, (r * size, c * size, g),
                                            (size + 2, size + 2, 1))
    return jax.vmap(one, out_axes=2)(g, r, c)[:, :, :, 0]

  # neighbour[t, k]: the tile beside tile t in direction _NEIGHBOURS[k]; C * tiles off the grid.
  neighbour: Any = []  # one i32[C * T] per direction, then stacked: i32[C * T, 8]
  for dr, dc in _NEIGHBOURS:
    inside = (row + dr >= 0) & (row + dr < tile_rows) & (col + dc >= 0) & (col + dc < tile_cols)
    neighbour.append(jnp.where(inside, grid * tiles + (row + dr) * tile_cols + col + dc,
                               chunk * tiles))
  neighbour = jnp.stack(neighbour, axis=1)
  edge = lambda d: slice(0, 1) if d < 0 else slice(size - 1, size) if d > 0 else slice(0, size)

  def step(carry):
    dist, key, steps, per_grid = carry
    least, chosen = lax.top_k(-key[:-1].reshape(chunk, tiles), per_step)
    chosen = (chosen + jnp.arange(chunk, dtype=jnp.int32)[:, None] * tiles).reshape(-1)
    pending = jnp.isfinite(least).reshape(-1)
    g, r, c = grid[chosen], row[chosen], col[chosen]
    tile_cost, tile_diagonal = cut(cost, g, r, c), cut(diagonal_cost, g, r, c)
    tile_cost_t, tile_diagonal_t = tile_cost.transpose(1, 0, 2), tile_diagonal.transpose(1, 0, 2)
    before = cut(dist, g, r, c)

    def settle(state):
      tile, _, rounds = state
      tile, lowered = _round_of_sweeps(tile, tile_cost, tile_diagonal, tile_cost_t, tile_diagonal_t)
      return tile, jnp.any(lowered) & (rounds < size * size), rounds + 1

    # *_like keeps the carry's type equal to the body's output under shard_map (varying axes).
    settling = jnp.ones_like(before[0, 0, 0], bool)
    after, _, _ = lax.while_loop(lambda state: state[1], settle, (before, settling, jnp.int32(0)))
    old, new = before[1:-1, 1:-1], after[1:-1, 1:-1]
    new = jnp.where(pending, new, old)
    write = lambda k, dist: lax.dynamic_update_slice(
        dist, lax.dynamic_slice_in_dim(new, k, 1, axis=2), (r[k] * size + 1, c[k] * size + 1, g[k]))
    dist = lax.fori_loop(0, chosen.shape[0], write, dist)
    lowered = jnp.where(new < old, new, inf)
    wake = jnp.stack([jnp.min(lowered[edge(dr), edge(dc)], axis=(0, 1))
                      for dr, dc in _NEIGHBOURS], 1)
    key = key.at[chosen].set(inf).at[neighbour[chosen]].min(wake).at[-1].set(inf)
    return dist, key, steps + 1, per_grid + jnp.any(pending.reshape(chunk, per_step), axis=1)

  def not_done(carry):
    _, key, steps, _ = carry
    return jnp.any(jnp.isfinite(key)) & (steps < min(max_steps, _INT32_MAX))

  init = (dist, key, jnp.int32(0), jnp.zeros_like(dist[0, 0], jnp.int32))
  dist, _, _, per_grid = lax.while_loop(not_done, step, init)
  return dist[: height + 2, : width + 2], per_grid


@functools.partial(jax.jit, static_argnames=("max_sweeps", "method", "tiles_after_rounds"))
def _solve_chunk(node_cost: jax.Array, source: jax.Array, max_sweeps: int,
                 method: str = "sweeps",
                 tiles_after_rounds: int = TILES_AFTER_ROUNDS) -> ShortestPaths:
  """Shortest paths for C grids at once; fields of the result have a leading axis C.

  ``method`` "relaxation" runs passes of :func:`_relax_every_cell`, ``RELAXATION_PASSES_PER_CHECK``
  between checks, at most ``max_sweeps * (H + W)`` passes (a round of sweeps makes ``2 (H + W)``
  line steps); ``sweeps`` then counts passes instead of rounds.
  """
  inf = jnp.float32(jnp.inf)
  framed_cost = jnp.pad(node_cost.transpose(1, 2, 0), ((1, 1), (1, 1), (0, 0)), constant_values=inf)
  # The barrier keeps XLA from fusing the interleaving transpose into every reader.
  cost_rows = lax.optimization_barrier(framed_cost)
  cost_cols = cost_rows.transpose(1, 0, 2)
  # Diagonal step costs are computed once, outside the loop, so every use adds the same floats.
  diagonal_rows = framed_cost * jnp.float32(_SQRT2)
  diagonal_cols = diagonal_rows.transpose(1, 0, 2)
  rows = lax.broadcasted_iota(jnp.int32, cost_rows.shape, 0)
  cols = lax.broadcasted_iota(jnp.int32, cost_rows.shape, 1)
  at_source = (rows == source[None, None, :, 0] + 1) & (cols == source[None, None, :, 1] + 1)
  dist = jnp.where(at_source, jnp.float32(0), inf)

  if method == "relaxation":
    return _relax_to_fixed_point(dist, cost_rows, diagonal_rows, source,
                                 min(max_sweeps * (node_cost.shape[1] + node_cost.shape[2]),
                                     _INT32_MAX))

  whole_grid_rounds = tiles_after_rounds if 0 < tiles_after_rounds < max_sweeps else max_sweeps

  def not_done(carry):
    _, rounds, active, _ = carry
    return jnp.any(active) & (rounds < whole_grid_rounds)

  def body(carry):
    dist, rounds, active, sweeps = carry
    # A grid that has converged stays put while the others in its chunk finish; a grid the
    # check can still lower gets another round, which relaxes every edge the check did.
    dist, changed = _round_of_sweeps(dist, cost_rows, diagonal_rows, cost_cols, diagonal_cols)
    return dist, rounds + 1, active & changed, sweeps + active.astype(jnp.int32)

  # *_like keeps the carry's type equal to the body's output under shard_map (varying axes).
  init = (dist, jnp.int32(0), jnp.ones_like(source[:, 0], bool), jnp.zeros_like(source[:, 0]))
  dist, _, active, sweeps = lax.while_loop(not_done, body, init)
  if max_sweeps > whole_grid_rounds:
    tiles = -(-node_cost.shape[1] // TILE) * -(-node_cost.shape[2] // TILE)
    steps_per_round = -(-tiles // TILES_PER_STEP)

    def finish(dist, sweeps):
      dist, steps = _finish_by_tiles(dist, cost_rows, diagonal_rows,
                                     (max_sweeps - whole_grid_rounds) * steps_per_round)
      # Rounds in whole-grid equivalents: a round's worth of tile visits counts as one.
      sweeps = sweeps + (steps + steps_per_round - 1) // steps_per_round
      return dist, sweeps, _lowered_by_one_relaxation(dist, cost_rows, diagonal_rows)

    dist, sweeps, active = lax.cond(jnp.any(active), finish,
                                    lambda dist, sweeps: (dist, sweeps, active), dist, sweeps)
  pred = _tight_predecessors(dist, cost_rows, diagonal_rows, source)
  return ShortestPaths(dist=dist[1:-1, 1:-1].transpose(2, 0, 1), pred=pred, sweeps=sweeps,
                       converged=~active)


def _relax_to_fixed_point(dist, cost, diagonal_cost, source, max_passes: int) -> ShortestPaths:
  """:func:`_solve_chunk` by synchronous relaxation passes, from the framed initial ``dist``."""
  per_check = RELAXATION_PASSES_PER_CHECK

  def not_done(carry):
    _, passes, active, _ = carry
    return jnp.any(active) & (passes < max_passes)

  def body(carry):
    dist, passes, active, count = carry
    for _ in range(per_check):
      dist = _relax_every_cell(dist, cost, diagonal_cost)
    # The last pass changed nothing: a fixed point (passes before it may have).
    changed = _lowered_by_one_relaxation(dist, cost, diagonal_cost)
    count = count + jnp.where(active, per_check, 0)
    return dist, passes + per_check, active & changed, count

  init = (dist, jnp.int32(0), jnp.ones_like(source[:, 0], bool), jnp.zeros_like(source[:, 0]))
  dist, _, active, passes = lax.while_loop(not_done, body, init)
  pred = _tight_predecessors(dist, cost, diagonal_cost, source)
  return ShortestPaths(dist=dist[1:-1, 1:-1].transpose(2, 0, 1), pred=pred, sweeps=passes,
                       converged=~active)


def _check_tiles_after_rounds(tiles_after_rounds: int) -> None:
  if tiles_after_rounds < 0:
    raise ValueError(f"tiles_after_rounds must be >= 0 (0 = never), got {tiles_after_rounds}")


def shortest_paths_batched(
    node_cost: jax.Array,
    source: jax.Array,
    *,
    chunk: int = DEFAULT_CHUNK,
    max_sweeps: int | None = None,
    method: str = "sweeps",
    tiles_after_rounds: int = TILES_AFTER_ROUNDS,
) -> ShortestPaths:
  """``shortest_paths`` for a batch of grids: a ``lax.map`` over chunks of ``chunk`` grids.

  Small chunks beat one pass over the whole batch on CPU: a chunk stops as soon as its own
  slowest grid converges, and its working set stays in cache. A batch that is not a multiple
  of ``chunk`` is padded with fully blocked grids (they converge in one round) that are
  dropped from the result.

  Args:
    node_cost: f32[B, H, W]; as in ``shortest_paths``.
    source: i32[B, 2]; one (row, col) source per grid.
    chunk: static number of grids solved together (capped at B).
    max_sweeps: static bound on rounds per grid; None = ``default_max_sweeps(H, W)``.
    method: static, ``"sweeps"`` or ``"relaxation"`` (:data:`METHODS`): the same results; see
      the module docstring for which is faster where.
    tiles_after_rounds: static; with ``"sweeps"``, the whole-grid rounds after which a grid
      not yet settled is finished tile by tile (the same results, faster on narrow mazes);
      0 = never, which also keeps the tiles' code out of the compiled program (and its
      compile time).

  Returns:
    A ``ShortestPaths`` whose fields have a leading batch axis B.
  """
  node_cost = jnp.asarray(node_cost, jnp.float32)
  source = jnp.asarray(source, jnp.int32)
  batch, height, width = node_cost.shape
  if max_sweeps is None:
    max_sweeps = default_max_sweeps(height, width)
  if method not in METHODS:
    raise ValueError(f"method must be one of {METHODS}, got {method!r}")
  _check_tiles_after_rounds(tiles_after_rounds)
  return _solve_in_chunks(node_cost, source, max(1, min(chunk, batch)), int(max_sweeps), method,
                          int(tiles_after_rounds))


@functools.partial(jax.jit, static_argnames=("chunk", "max_sweeps", "method", "tiles_after_rounds"))
def _solve_in_chunks(node_cost, source, chunk: int, max_sweeps: int, method: str,
                     tiles_after_rounds: int = TILES_AFTER_ROUNDS) -> ShortestPaths:
  batch, height, width = node_cost.shape
  num_chunks = -(-batch // chunk)
  padding = num_chunks * chunk - batch
  if padding:
    blocked = jnp.full((padding, height, width), jnp.inf, jnp.float32)
    node_cost = jnp.concatenate([node_cost, blocked])
    source = jnp.concatenate([source, jnp.zeros((padding, 2), jnp.int32)])
  result = lax.map(
      lambda args: _solve_chunk(*args, max_sweeps=max_sweeps, method=method,
                                tiles_after_rounds=tiles_after_rounds),
      (node_cost.reshape(num_chunks, chunk, height, width), source.reshape(num_chunks, chunk, 2)),
  )
  return jax.tree.map(lambda x: x.reshape((num_chunks * chunk,) + x.shape[2:])[:batch], result)


@functools.cache
def _single_grid_solver(max_sweeps: int, tiles_after_rounds: int, vmap_chunk: int | None,
                        vmap_method: str):
  """``shortest_paths`` for one grid, whose ``vmap`` becomes ``shortest_paths_batched``."""

  @jax.custom_batching.custom_vmap
  def solve(node_cost, source):
    result = _solve_chunk(node_cost[None], source[None], max_sweeps,
                          tiles_after_rounds=tiles_after_rounds)
    return jax.tree.map(lambda x: x[0], result)

  @solve.def_vmap
  def solve_batch(axis_size, in_batched, node_cost, source):
    cost_batched, source_batched = in_batched
    if not cost_batched:
      node_cost = jnp.broadcast_to(node_cost, (axis_size,) + node_cost.shape)
    if not source_batched:
      source = jnp.broadcast_to(source, (axis_size,) + source.shape)
    result = shortest_paths_batched(node_cost, source, chunk=vmap_chunk or axis_size,
                                    max_sweeps=max_sweeps, method=vmap_method,
                                    tiles_after_rounds=tiles_after_rounds)
    return result, ShortestPaths(True, True, True, True)

  return solve


def shortest_paths(
    node_cost: jax.Array,
    source: jax.Array,
    *,
    max_sweeps: int | None = None,
    tiles_after_rounds: int = TILES_AFTER_ROUNDS,
    vmap_chunk: int | None = DEFAULT_CHUNK,
    vmap_method: str = "sweeps",
) -> ShortestPaths:
  """Shortest paths from one source cell over an 8-connected grid.

  Written for one grid; ``jax.vmap`` of it runs ``shortest_paths_batched`` (chunks of
  ``vmap_chunk`` grids solved by ``vmap_method``; :data:`STRATEGY_BATCHING` gives them per
  execution strategy), which is several times faster on CPU than batching the loops.

  Args:
    node_cost: f32[H, W]; the cost of entering each cell per unit step, >= 0 (zeros allowed);
      inf = blocked. The edge u -> v weighs ``node_cost[v]`` orthogonally and
      ``sqrt(2) * node_cost[v]`` diagonally.
    source: i32[2]; (row, col) of the source, inside the grid. It gets distance 0 whatever its
      own cost, so a robot standing on a blocked cell still plans from it.
    max_sweeps: static bound on rounds of the 4 sweeps; None = ``default_max_sweeps(H, W)``.
    tiles_after_rounds: static; as in :func:`shortest_paths_batched` (0 = never).
    vmap_chunk: static; grids per chunk under ``vmap`` (None: the whole batch as one chunk).
    vmap_method: static; how a chunk is solved under ``vmap`` (:data:`METHODS`; the distances
      and predecessors are the same either way).

  Returns:
    A ``ShortestPaths`` with dist f32[H, W], pred i32[H, W], sweeps i32[], converged bool[].
  """
  node_cost = jnp.asarray(node_cost, jnp.float32)
  source = jnp.asarray(source, jnp.int32)
  if max_sweeps is None:
    max_sweeps = default_max_sweeps(*node_cost.shape)
  _check_tiles_after_rounds(tiles_after_rounds)
  if vmap_method not in METHODS:
    raise ValueError(f"method must be one of {METHODS}, got {vmap_method!r}")
  return _single_grid_solver(int(max_sweeps), int(tiles_after_rounds), vmap_chunk,
                             vmap_method)(node_cost, source)


@functools.partial(jax.jit, static_argnames="capacity")
def extract_path(
    pred: jax.Array,
    goal: jax.Array,
    capacity: int,
    *,
    source: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
  """The cells of the shortest path from the source to ``goal``, source first.

  Walks the predecessor field back from the goal into a ring buffer of ``capacity`` cells, so
  a path longer than ``capacity`` keeps its first ``capacity`` cells (the ones a robot follows
  next). The walk stops after H * W cells, so a corrupted (cyclic) ``pred`` cannot hang it.

  Args:
    pred: i32[H, W]; the ``pred`` field of ``ShortestPaths``.
    goal: i32[2]; (row, col) of the goal.
    capacity: static maximum number of cells returned.
    source: optional i32[2]; the source the field was computed from. With it, a walk that
      does not end at ``source`` (unreachable goal, corrupted field) gives length 0. Without
      it, ``pred`` alone cannot tell the source from an unreachable cell (both have pred -1):
      a goal with pred -1 counts as the source if some cell points at it, so the one case it
      gets wrong is goal == source when no neighbour of the source is reachable.

  Returns:
    cells: i32[capacity, 2]; (row, col) of the path cells, source first; rows at and past
      ``length`` are -1.
    length: i32[]; number of valid cells: min(cells on the path, capacity); 0 if unreachable.
  """
  if capacity < 1:
    raise ValueError(f"capacity must be at least 1, got {capacity}")
  height, width = pred.shape
  pred_flat = jnp.asarray(pred, jnp.int32).reshape(-1)
  goal = jnp.asarray(goal, jnp.int32)
  goal_flat = goal[0] * width + goal[1]

  def not_done(carry):
    cell, visited, _ = carry
    return (cell >= 0) & (visited < height * width)

  def walk_back(carry):
    cell, visited, ring = carry
    ring = ring.at[visited % capacity].set(cell)
    return pred_flat[cell], visited + 1, ring

  # *_like keeps the carry's type equal to the body's output under shard_map (varying axes).
  ring = jnp.full_like(goal_flat, -1, shape=(capacity,))
  init = (goal_flat, jnp.zeros_like(goal_flat), ring)
  cell, visited, ring = lax.while_loop(not_done, walk_back, init)
  root = ring[(visited - 1) % capacity]
  if source is None:
    # After a single visit the goal itself has pred -1: it is the source or unreachable.
    root_is_source = (visited > 1) | jnp.any(pred_flat == goal_flat)
  else:
    source = jnp.asarray(source, jnp.int32)
    root_is_source = root == source[0] * width + source[1]
  length = jnp.where((cell < 0) & root_is_source, jnp.minimum(visited, capacity), 0)
  # The ring holds the last `capacity` cells visited; visit i is path cell visited - 1 - i.
  position = jnp.arange(capacity, dtype=jnp.int32)
  flat = ring[(visited - 1 - position) % capacity]
  cells = jnp.stack([flat // width, flat % width], axis=-1)
  return jnp.where((position < length)[:, None], cells, -1), length
