"""Occupancy belief (log-odds), cell entropy, the entropy map, inflation and neighbourhood masks.

Equations are Li et al. 2020's: cell entropy Eq 2, the smoothed entropy map Eq 3, the update radius
``R_u = α·R_e`` (Eq 7). Neighbourhood sums use shifted slices of a framed array (DESIGN.md: 50x
faster than a convolution here).
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
  """(free, occupied, unknown) bool masks of the belief under the ``p_free``/``p_occ`` thresholds."""
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


def inflate(mask, radius_cells, max_cells: int):
  """Dilates ``mask`` by a disc of radius ``radius_cells`` (traced, <= ``max_cells``, static).

  A cell is set when a set cell lies within Euclidean distance ``radius_cells`` (centre to
  centre). The grid outside counts as unset.
  """
  if max_cells == 0:
    return mask
  h, w = mask.shape
  m = max_cells
  framed = jnp.pad(mask, m, constant_values=False)
  out = mask
  for di in range(-m, m + 1):
    for dj in range(-m, m + 1):
      if (di, dj) == (0, 0) or di * di + dj * dj > m * m:
        continue
      view = jax.lax.slice(framed, (m + di, m + dj), (m + di + h, m + dj + w))
      within = jnp.float32(di * di + dj * dj) <= radius_cells * radius_cells + 1e-6
      out = out | (view & within)
  return out


def frontier(free, unknown, occupied):
  """Belief-free cells with an unknown 8-neighbour (SPEC §4, Yamauchi 1997).

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
  """Inverse sensor model: add ``l_free``/``l_occ`` once per observed cell, clamp to [l_min, l_max]."""
  delta = jnp.where(observed == 2, params.l_occ, jnp.where(observed == 1, params.l_free, 0.0))
  return jnp.clip(logodds + delta, params.l_min, params.l_max)


def window_start(center, size: int, extent: int):
  """Top-left index of a ``size`` window centred on ``center`` and clamped inside ``extent``."""
  return jnp.clip(center - size // 2, 0, max(extent - size, 0))


def update_entropy_map(entropy_map, logodds, robot_rc, radius_cells, k, window: int):
  """Li Eq 3 within ``R_u`` of the robot: ``H ← k·H + (1−k)·Ĥ(P)``; cells farther keep their value.

  Args:
    entropy_map: f32[H, W], the smoothed entropy map I_e.
    logodds: f32[H, W] belief after this step's scan.
    robot_rc: f32[2] robot position in cell units (row, col coordinates).
    radius_cells: R_u = α·R_e in cells (traced).
    k: smoothing factor of Eq 3.
    window: static side of the square window that bounds R_u.
  """
  h, w = entropy_map.shape
  sh, sw = min(window, h), min(window, w)
  r0 = window_start(jnp.floor(robot_rc[0]).astype(jnp.int32), sh, h)
  c0 = window_start(jnp.floor(robot_rc[1]).astype(jnp.int32), sw, w)
  e = jax.lax.dynamic_slice(entropy_map, (r0, c0), (sh, sw))
  l = jax.lax.dynamic_slice(logodds, (r0, c0), (sh, sw))
  rows = r0 + jnp.arange(sh, dtype=jnp.float32)[:, None] + 0.5
  cols = c0 + jnp.arange(sw, dtype=jnp.float32)[None, :] + 0.5
  near = (rows - robot_rc[0]) ** 2 + (cols - robot_rc[1]) ** 2 <= radius_cells**2
  e = jnp.where(near, k * e + (1.0 - k) * entropy_of_logodds(l), e)
  return jax.lax.dynamic_update_slice(entropy_map, e, (r0, c0))
