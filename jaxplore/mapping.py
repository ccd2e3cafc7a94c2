"""Occupancy belief (log-odds), cell entropy, the entropy map, inflation and neighbourhood masks.

Equations are Li et al. 2020's: cell entropy Eq 2, the smoothed entropy map Eq 3, the update radius
``R_u = α·R_e`` (Eq 7). Neighbourhood sums use shifted slices of a framed array (far faster than
``lax.conv_general_dilated`` on XLA:CPU: ``experiments/results/design_notes_cpu.md``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

LN2 = math.log(2.0)


def probability(logodds):
  """P(occupied) of a log-odds value."""
  return jax.nn.sigmoid(logodds)


def entropy_of_probability(p):
  """Cell entropy in nats, Li Eq 2: ``−P ln P − (1−P) ln(1−P)`` (0 at P ∈ {0, 1})."""
  p = jnp.asarray(p, jnp.float32)
  safe = lambda q: jnp.where(q > 0, q * jnp.log(jnp.where(q > 0, q, 1.0)), 0.0)
  return -safe(p) - safe(1.0 - p)


def entropy_of_logodds(logodds):
  """Li Eq 2 computed stably from log-odds with one ``exp`` and one ``log1p``.

  With ``e = exp(−|l|)``: ``H = log(1 + e) + |l|·e / (1 + e)`` (the entropy is even in ``l``).
  """
  a = jnp.abs(logodds)
  e = jnp.exp(-a)
  return jnp.log1p(e) + a * e / (1.0 + e)


def logit(p):
  return jnp.log(p) - jnp.log1p(-p)


def classify(logodds, params):
  """(free, occupied, unknown) bool masks of the belief under the ``p_free``/``p_occ``
  thresholds."""
  free = logodds < logit(params.p_free)
  occupied = logodds > logit(params.p_occ)
  return free, occupied, ~(free | occupied)


def frame(mask, value):
  """Pads a 2-D array with a 1-cell border of ``value``."""
  return jnp.pad(mask, 1, constant_values=value)


def shifted(framed, di: int, dj: int):
  """The (H, W) view of a framed array shifted by (di, dj): ``out[i, j] = a[i + di, j + dj]``."""
  h, w = framed.shape[0] - 2, framed.shape[1] - 2
  return jax.lax.slice(framed, (1 + di, 1 + dj), (1 + di + h, 1 + dj + w))


NEIGHBOURS_8 = tuple((di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0))


def any_neighbour(mask, border=False):
  """True where at least one 8-neighbour is set (the border counts as ``border``)."""
  framed = frame(mask, border)
  out = jnp.zeros(mask.shape, bool)
  for di, dj in NEIGHBOURS_8:
    out = out | shifted(framed, di, dj)
  return out


def neighbour_count(mask, border=False):
  """3x3 box sum including the centre (Li Eq 4's convolution with a kernel of ones, n = 3)."""
  framed = frame(mask.astype(jnp.int32), jnp.int32(border))
  out = jnp.zeros(mask.shape, jnp.int32)
  for di in (-1, 0, 1):
    for dj in (-1, 0, 1):
      out = out + shifted(framed, di, dj)
  return out


def within_radius(distance_sq, radius_cells):
  """The inflation's test, in cells: a squared centre distance d² is within the radius when
  ``d² <= r² + 1e-6`` (within, not only closer than; the tolerance absorbs float error)."""
  return distance_sq <= radius_cells * radius_cells + 1e-6


def _disc_views(mask, max_cells: int):
  """(d², ``mask`` shifted by (di, dj)) for each offset of the disc of radius ``max_cells``
  (static) but the centre; the grid outside counts as unset."""
  h, w = mask.shape
  m = max_cells
  framed = jnp.pad(mask, m, constant_values=False)
  for di in range(-m, m + 1):
    for dj in range(-m, m + 1):
      if (di, dj) != (0, 0) and di * di + dj * dj <= m * m:
        yield di * di + dj * dj, jax.lax.slice(framed, (m + di, m + dj), (m + di + h, m + dj + w))


def inflate(mask, radius_cells, max_cells: int):
  """Dilates ``mask`` by a disc of radius ``radius_cells`` (traced, <= ``max_cells``, static).

  A cell is set when a set cell lies within Euclidean distance ``radius_cells`` (centre to
  centre, :func:`within_radius`). The grid outside counts as unset.
  """
  out = mask
  for squared, view in _disc_views(mask, max_cells):
    out = out | (view & within_radius(jnp.float32(squared), radius_cells))
  return out


def distance_sq_within(mask, max_cells: int):
  """Squared distance (in cells², centre to centre) from each cell to the nearest set cell of
  ``mask`` within ``max_cells`` (static); int32's largest value where none is that close. The
  grid outside counts as unset.

  ``within_radius(distance_sq_within(mask, m), r)`` is :func:`inflate` ``(mask, r, m)``; the
  distance itself orders cells of the inflated zone by clearance.
  """
  far = jnp.int32(jnp.iinfo(jnp.int32).max)
  out = jnp.where(mask, jnp.int32(0), far)
  for squared, view in _disc_views(mask, max_cells):
    out = jnp.minimum(out, jnp.where(view, jnp.int32(squared), far))
  return out


def frontier(free, unknown, occupied):
  """Belief-free cells with an unknown 8-neighbour (Yamauchi 1997).

  A diagonal unknown neighbour counts only if at least one of the two cells beside the diagonal
  is not occupied: an unknown cell sealed off by two occupied cells (the inside of a wall corner)
  can never be seen from this cell, and counting it would create frontiers that never close.
  """
  fu, fo = frame(unknown, False), frame(occupied, True)
  seen = jnp.zeros(free.shape, bool)
  for di, dj in NEIGHBOURS_8:
    open_way = True
    if di != 0 and dj != 0:
      open_way = ~(shifted(fo, di, 0) & shifted(fo, 0, dj))
    seen = seen | (shifted(fu, di, dj) & open_way)
  return free & seen


def update_logodds(logodds, observed, params):
  """Inverse sensor model: add ``l_free``/``l_occ`` once per observed cell, clamp to
  [l_min, l_max]."""
  delta = jnp.where(observed == 2, params.l_occ, jnp.where(observed == 1, params.l_free, 0.0))
  return jnp.clip(logodds + delta, params.l_min, params.l_max)


def window_start(center, size: int, extent: int):
  """Top-left index of a ``size`` window centred on ``center`` and clamped inside ``extent``."""
  return jnp.clip(center - size // 2, 0, max(extent - size, 0))


def _after(x, *deps):
  """``x``, computed after ``deps`` (finite arrays broadcastable to ``x``).

  XLA:CPU writes a window of a loop-carried grid in place only if every read of that grid is
  scheduled before the write. A read whose value the written window does not depend on (a metric,
  a gather) may be scheduled after it, and XLA then copies the whole batch of grids instead, at
  every robot. Adding zero times the reads' results makes the write depend on them.
  """
  for dep in deps:
    x = x + jnp.float32(0.0) * jnp.asarray(dep, x.dtype)
  return x


def update_entropy_map(entropy_map, logodds, robot_rc, radius_cells, k, window: int, robot=None):
  """Li Eq 3 within ``R_u`` of the robot: ``H ← k·H + (1−k)·Ĥ(P)``; cells farther keep their value.

  Args:
    entropy_map: f32[H, W], the smoothed entropy map I_e (or f32[N, H, W] with ``robot``).
    logodds: f32[H, W] belief after this step's scan (or f32[N, H, W] with ``robot``).
    robot_rc: f32[2] robot position in cell units (row, col coordinates).
    radius_cells: R_u = α·R_e in cells (traced).
    k: smoothing factor of Eq 3.
    window: static side of the square window that bounds R_u.
    robot: None for single grids; else the i32 index of the robot whose grids (leading axis of
      stacked per-robot grids) are read and updated (in place inside :func:`per_robot`).
  """
  stacked = robot is not None
  h, w = entropy_map.shape[-2:]
  sh, sw = min(window, h), min(window, w)
  r0 = window_start(jnp.floor(robot_rc[0]).astype(jnp.int32), sh, h)
  c0 = window_start(jnp.floor(robot_rc[1]).astype(jnp.int32), sw, w)
  start = (robot, r0, c0) if stacked else (r0, c0)
  size = (1, sh, sw) if stacked else (sh, sw)
  e = jax.lax.dynamic_slice(entropy_map, start, size).reshape(sh, sw)
  l = jax.lax.dynamic_slice(logodds, start, size).reshape(sh, sw)
  rows = r0 + jnp.arange(sh, dtype=jnp.float32)[:, None] + 0.5
  cols = c0 + jnp.arange(sw, dtype=jnp.float32)[None, :] + 0.5
  near = (rows - robot_rc[0]) ** 2 + (cols - robot_rc[1]) ** 2 <= radius_cells**2
  e = jnp.where(near, k * e + (1.0 - k) * entropy_of_logodds(l), e)
  return jax.lax.dynamic_update_slice(entropy_map, e.reshape(size), start)


def integrate_observation(logodds, robot, observed, reachable, params, after=0.0,
                          whole_grid: bool = False):
  """Adds one scan to one robot's belief (Li's inverse sensor model).

  Every cell seen free adds ``l_free`` once, every cell seen occupied ``l_occ`` once (clamped to
  ``[l_min, l_max]``). By default only the tiles of ``observed`` that hold an observation are
  read, updated and written back, one at a time (in place inside :func:`per_robot`): a scan sees
  a few thousand cells, and the cell entropy (Li Eq 2) of a whole grid before and after the
  update, which a full-grid update needs for the entropy change, costs far more on a CPU than
  the update itself.

  With ``whole_grid`` (the ``lockstep`` strategy) the robot's whole grid is updated at once
  instead: batched by ``vmap`` on a GPU, the tile loop is a chain of small gathers and scatters
  per tile, and the whole-grid update made the whole step faster on one GPU
  (``experiments/results/bench_lockstep_variants_gpu.md``, the ``whole_grid`` rows; the
  ``tile_loop`` variant of ``experiments/bench_lockstep_variants.py`` undoes it). The beliefs and
  coverage are the tile loop's bit for bit; the entropy change is summed in another order, so
  it may differ in its last bits.

  Args:
    logodds: f32[N, H, W] per-robot beliefs; robot ``robot``'s grid is updated.
    robot: i32 index of the robot.
    observed: int8[ceil(H / T), ceil(W / T), T, T] tiles of the observation (cell (r, c) at
      ``[r // T, c // T, r % T, c % T]``): 1 seen free, 2 seen occupied, 0 not seen
      (:func:`jaxplore.sensor.observation_tiles`).
    reachable: bool[H, W] cells that count for coverage.
    params: supplies ``l_free``, ``l_occ``, ``l_min``, ``l_max``, ``p_free``.
    after: a finite scalar computed from reads of ``logodds`` that must happen before the update
      (see :func:`_after`).

  Returns:
    ``(logodds, d_entropy, d_covered)``: the updated beliefs, the change of the robot's map
    entropy Σ Ĥ (f32, nats) and of its count of reachable cells believed free (i32).
  """
  _, h, w = logodds.shape
  if whole_grid:
    return _integrate_whole_grid(logodds, robot, observed, reachable, params, after)
  n_cols, th, tw = observed.shape[1:]
  wh, ww = min(th, h), min(tw, w)
  seen = jnp.max(observed, axis=(2, 3)).ravel() > 0
  tiles = jnp.nonzero(seen, size=seen.size, fill_value=0)[0]
  free_threshold = logit(params.p_free)
  rows = jnp.arange(wh)[:, None]
  cols = jnp.arange(ww)[None, :]

  def update_tile(j, carry):
    logodds, d_entropy, d_covered = carry
    tile_row, tile_col = tiles[j] // n_cols, tiles[j] % n_cols
    top, left = tile_row * th, tile_col * tw
    # A tile past the grid's last row or column is read from a window moved back inside the
    # grid; the window's cells before the tile belong to the neighbouring tile.
    r0, c0 = jnp.minimum(top, h - wh), jnp.minimum(left, w - ww)
    padded = jnp.pad(observed[tile_row, tile_col], ((th, 0), (tw, 0)))
    obs = jax.lax.dynamic_slice(padded, (th + r0 - top, tw + c0 - left), (wh, ww))
    own = (r0 + rows >= top) & (c0 + cols >= left)
    old = jax.lax.dynamic_slice(logodds, (robot, r0, c0), (1, wh, ww))[0]
    reach = jax.lax.dynamic_slice(reachable, (r0, c0), (wh, ww))
    new = jnp.where(own, update_logodds(old, obs, params), old)
    d_entropy = d_entropy + (entropy_of_logodds(new) - entropy_of_logodds(old))
    d_covered = d_covered + ((reach & (new < free_threshold)).astype(jnp.int32)
                             - (reach & (old < free_threshold)).astype(jnp.int32))
    new = _after(new, d_entropy, d_covered)
    return jax.lax.dynamic_update_slice(logodds, new[None], (robot, r0, c0)), d_entropy, d_covered

  init = (logodds, _after(jnp.zeros((wh, ww), jnp.float32), after), jnp.zeros((wh, ww), jnp.int32))
  logodds, d_entropy, d_covered = jax.lax.fori_loop(0, jnp.sum(seen), update_tile, init)
  return logodds, jnp.sum(d_entropy), jnp.sum(d_covered)


def _integrate_whole_grid(logodds, robot, observed, reachable, params, after):
  """:func:`integrate_observation` on robot ``robot``'s whole grid at once (no tile loop)."""
  old = jax.lax.dynamic_index_in_dim(logodds, robot, 0, keepdims=False)
  n_rows, n_cols, th, tw = observed.shape
  grid = observed.transpose(0, 2, 1, 3).reshape(n_rows * th, n_cols * tw)
  grid = grid[: old.shape[0], : old.shape[1]]
  new = update_logodds(old, grid, params)
  d_entropy = jnp.sum(entropy_of_logodds(new) - entropy_of_logodds(old))
  free_threshold = logit(params.p_free)
  d_covered = (jnp.sum(reachable & (new < free_threshold)).astype(jnp.int32)
               - jnp.sum(reachable & (old < free_threshold)).astype(jnp.int32))
  new = _after(new, after, d_entropy, d_covered)
  return jax.lax.dynamic_update_index_in_dim(logodds, new, robot, 0), d_entropy, d_covered


def per_robot(fn, lockstep: bool = False):
  """Batches a one-robot update of per-robot grids as a loop over the robots, in place.

  ``fn(robot, grids, inputs) -> (grids, outputs)`` updates robot ``robot`` of ``grids`` (a pytree
  of arrays with a leading robot axis) and returns that robot's outputs. The result is a function
  of one robot, ``(grids, inputs) -> (grids, outputs)`` without the robot axis. Under ``vmap`` it
  calls ``fn`` for each robot in turn on the whole batch of grids, updated in place.

  Why not a plain ``vmap``: the per-robot work here is irregular. Under ``vmap`` a window at a
  per-robot offset becomes a gather and a scatter over the batch, a scatter into per-robot grids
  costs several times more per element than one robot's, and a data-dependent loop (a lidar walk
  that stops at the walls) runs for every robot until the slowest is done. One robot at a time, its
  maps stay in cache and each loop stops when that robot is done.

  With ``lockstep`` (an accelerator: :func:`jaxplore.config.resolve_strategy`), ``vmap`` batches
  the one-robot update as it is, one kernel per stage for the whole batch: a loop over the
  robots would be a chain of small kernels as long as the batch.
  """
  def plain(grids, inputs):
    grids, outputs = fn(0, jax.tree.map(lambda g: g[None], grids), inputs)
    return jax.tree.map(lambda g: g[0], grids), outputs

  if lockstep:
    return plain
  one = jax.custom_batching.custom_vmap(plain)

  @one.def_vmap
  def batched(axis_size, in_batched, grids, inputs):
    grids_batched, inputs_batched = in_batched
    grids = jax.tree.map(lambda g, b: g if b else jnp.broadcast_to(g, (axis_size,) + g.shape),
                         grids, grids_batched)
    robot_inputs = lambda i: jax.tree.map(lambda x, b: x[i] if b else x, inputs, inputs_batched)
    out_shapes = jax.eval_shape(lambda g: fn(0, g, robot_inputs(0))[1], grids)
    outputs = jax.tree.map(lambda s: jnp.zeros((axis_size,) + s.shape, s.dtype), out_shapes)

    def body(i, carry):
      grids, outputs = carry
      grids, out = fn(i, grids, robot_inputs(i))
      return grids, jax.tree.map(lambda acc, o: acc.at[i].set(o), outputs, out)

    result = jax.lax.fori_loop(0, axis_size, body, (grids, outputs))
    return result, jax.tree.map(lambda _: True, result)

  return one
