"""Geometry of the Random Exploration Graph family (Toriz & Sánchez; Oriolo et al.'s SRT).

A node of the exploration graph holds a *local safe region* (LSR): a star-shaped region around
its position ``q``, sampled in ``B`` equal angular bins. Bin ``b`` covers the angles
``[-π + b·Δ, -π + (b + 1)·Δ)`` (``Δ = 2π / B``) and its central ray is at
``φ_b = -π + (b + ½)·Δ``; ``ρ[b]`` is the distance along that ray to the first belief cell that
is not free, capped at the LSR radius ``R``. A bin is an *obstacle* bin when its ray stops on an
occupied cell before ``R``, a *free* bin when it reaches ``R`` or stops on an unknown cell.

Positions are continuous cell coordinates ``(u, v)`` = (column, row) and angles are measured
from the +u axis toward +v, as in :mod:`jaxplore.sensor` (rows grow with y, so these are the
world's x, y directions and angles). Distances are in cells.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplore import sensor

# Belief classes as one small integer grid (one gather per ray entry instead of three).
FREE, UNKNOWN, OCCUPIED = 0, 1, 2


def belief_classes(free, occupied):
  """i32[H, W]: FREE, UNKNOWN or OCCUPIED per cell of a belief's masks."""
  return jnp.where(free, FREE, jnp.where(occupied, OCCUPIED, UNKNOWN)).astype(jnp.int32)


def bin_angles(bins: int):
  """f32[B]: the central ray angle ``φ_b = -π + (b + ½)·2π/B`` of every bin."""
  return (-jnp.pi + (jnp.arange(bins, dtype=jnp.float32) + 0.5) * (2 * jnp.pi / bins)).astype(
      jnp.float32)


def bin_of(angle, bins: int):
  """i32: the bin holding ``angle`` (rad, any value; wrapped into [-π, π))."""
  index = jnp.floor((angle + jnp.pi) * (bins / (2 * jnp.pi))).astype(jnp.int32)
  return jnp.mod(index, bins)


def wrap(angle):
  """``angle`` wrapped into [-π, π)."""
  return jnp.mod(angle + jnp.pi, 2 * jnp.pi) - jnp.pi


class Rays(NamedTuple):
  """The LSR rays of one node (leaves f32/bool[B]).

  Attributes:
    rho: distance along each bin's central ray to the first cell that is not free, capped at R.
    obstacle: the ray stops on an occupied cell (or the map's edge) before R.
  """

  rho: jax.Array
  obstacle: jax.Array


def lsr_rays(classes, uv, radius, n_cross: int, bins: int) -> Rays:
  """The LSR of a node at ``uv``: Toriz & Sánchez's PERCEPTION, cast on the belief.

  Each bin's central ray is traversed exactly (:func:`jaxplore.sensor.trace`, the lidar's own
  traversal, with its rule that a ray through a corner between two diagonal cells meets one of
  them). Cells outside the grid count as occupied.

  Args:
    classes: i32[H, W] from :func:`belief_classes`.
    uv: f32[2] the node's position (column, row), cell units.
    radius: the LSR radius R, cells (traced).
    n_cross: static grid-line crossings per axis traced, > radius.
    bins: static number of bins B.

  Returns:
    :class:`Rays`.
  """
  height, width = classes.shape
  cells = sensor.trace(uv[0], uv[1], bin_angles(bins), n_cross)
  inside = (cells.rows >= 0) & (cells.rows < height) & (cells.cols >= 0) & (cells.cols < width)
  kind = jnp.where(inside, classes.at[cells.rows, cells.cols].get(mode="fill", fill_value=OCCUPIED),
                   OCCUPIED)
  first = lambda mask: jnp.min(jnp.where(mask, cells.t, jnp.inf), axis=1)
  t_occupied = first(kind == OCCUPIED)
  t_unknown = first(kind == UNKNOWN)
  t_stop = jnp.minimum(t_occupied, t_unknown)
  # A tie (the same distance) goes to the occupied cell: the ray is blocked there.
  obstacle = (t_occupied <= t_unknown) & (t_stop < radius)
  return Rays(rho=jnp.minimum(t_stop, radius).astype(jnp.float32), obstacle=obstacle)


def shadow_bins(rho, jump):
  """bool[B]: bins on the far side of a depth jump of the LSR's boundary (a sensor shadow).

  The LSR is the star-shaped polygon of the rays' ends; where a ray ``ρ[b]`` is longer than a
  neighbour's ``ρ[b ± 1]`` by more than ``jump``, the polygon's edge between their ends runs
  radially through free space, along the shadow of the obstacle the shorter ray stops on, with
  unseen space beside it (the part of a corridor behind a corner, the sides of a corridor seen
  through a door). That edge is boundary of the LSR that no obstacle bounds, as its free
  frontier segments are (Toriz & Sánchez do not define them ray by ray), though the ray of bin
  ``b`` itself ends on an obstacle; the bin to step along toward it is the longer one, ``b``.

  Args:
    rho: f32[B] the rays' lengths (any unit).
    jump: the least depth difference that makes a shadow edge (same unit as ``rho``).
  """
  shorter = jnp.minimum(jnp.roll(rho, 1), jnp.roll(rho, -1))
  return rho - shorter > jump


def shadow_midpoints(centre, rho):
  """f32[B, 2]: the middle of each bin's edge to its shorter neighbour's ray end, the edge that
  is a shadow edge when :func:`shadow_bins` holds."""
  ends = boundary_points(centre, rho)
  before, after = jnp.roll(ends, 1, axis=0), jnp.roll(ends, -1, axis=0)
  shorter = jnp.where((jnp.roll(rho, 1) <= jnp.roll(rho, -1))[:, None], before, after)
  return 0.5 * (ends + shorter)


def dilate(mask, cells: int):
  """bool[H, W]: cells with a set cell of ``mask`` within ``cells`` rows and columns (a square
  neighbourhood of side 2·cells + 1; outside the grid counts as unset)."""
  if cells <= 0:
    return mask
  window = 2 * cells + 1
  as_int = mask.astype(jnp.int32)
  rows = jax.lax.reduce_window(as_int, 0, jax.lax.max, (window, 1), (1, 1), "SAME")
  return jax.lax.reduce_window(rows, 0, jax.lax.max, (1, window), (1, 1), "SAME") > 0


def inside_lsr(points, centre, rho):
  """Whether points lie in the LSR of a node: ``|p − q| ≤ ρ[bin(angle(p − q))]``.

  Args:
    points: f32[..., 2] (u, v), cell units.
    centre: f32[2] the node's position ``q``.
    rho: f32[B] the node's ray lengths.

  Returns:
    bool[...].
  """
  offset = points - centre.reshape((1,) * (points.ndim - 1) + (2,))
  distance = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
  index = bin_of(jnp.arctan2(offset[..., 1], offset[..., 0]), rho.shape[-1])
  return distance <= rho[index]


def boundary_points(centre, rho):
  """f32[B, 2]: the end of every bin's central ray, ``q + ρ[b]·u(φ_b)``."""
  phi = bin_angles(rho.shape[-1])
  return centre[None, :] + rho[:, None] * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)


class Runs(NamedTuple):
  """Maximal circular runs of set bins (the frontier arcs F of a node).

  Slots ``M = B // 2 + 1`` (a circle of B bins holds at most B // 2 runs, or one full circle).
  Slot k < count holds the k-th run in the order the runs appear going round from the first
  unset bin.

  Attributes:
    start: i32[M] first bin of each run (going counter-clockwise, i.e. up the bin index).
    length: i32[M] bins in each run (0 in unused slots).
    valid: bool[M] the slot holds a run.
    count: i32 number of runs.
  """

  start: jax.Array
  length: jax.Array
  valid: jax.Array
  count: jax.Array  # type: ignore[assignment]  # a field named as tuple.count


def circular_runs(mask) -> Runs:
  """The maximal runs of ``True`` in a circular bool[B] (bin B − 1 neighbours bin 0).

  The circle is rolled so that an unset bin comes first; then no run wraps, run starts are set
  bins after an unset one, and a cumulative sum of the starts numbers the runs. A fully set
  circle is one run of B bins starting at bin 0.
  """
  bins = mask.shape[0]
  slots = bins // 2 + 1
  shift = jnp.argmax(~mask).astype(jnp.int32)  # 0 when every bin is set
  rolled = jnp.roll(mask, -shift)
  before = jnp.concatenate([jnp.zeros((1,), bool), rolled[:-1]])
  starts = rolled & ~before
  run_id = jnp.cumsum(starts.astype(jnp.int32)) - 1
  # Dense [M, B] membership (M·B is small): cheaper to compile than segment sums' scatters.
  member = rolled[None, :] & (run_id[None, :] == jnp.arange(slots, dtype=jnp.int32)[:, None])
  length = jnp.sum(member.astype(jnp.int32), axis=1)
  position = jnp.arange(bins, dtype=jnp.int32)
  first = jnp.min(jnp.where(member, position[None, :], bins), axis=1)
  count = jnp.sum(starts.astype(jnp.int32))
  valid = jnp.arange(slots) < count
  start = jnp.where(valid, jnp.mod(first + shift, bins), 0).astype(jnp.int32)
  return Runs(start=start, length=jnp.where(valid, length, 0), valid=valid, count=count)


def coverable_width(rho, r, radius):
  """The angle of a frontier arc of radius ``rho`` that the next LSR covers (Toriz & Sánchez's
  approach-point criterion, Figs 3–4).

  The next node sits at ``r·ρ`` from ``q`` along the arc's middle; a point of the arc at angle
  ψ from the middle is within ``R`` of it when
  ``ρ² + r²ρ² − 2rρ²·cos ψ ≤ R²``, so the covered width is
  ``c = 2·arccos(clip(((1 + r²)ρ² − R²) / (2rρ²), −1, 1))`` (``2·arccos(r/2)`` at ``ρ = R``;
  the whole circle when the arc lies within ``R − r·ρ`` of the next node).

  Args:
    rho: arc radius (any unit); r: step fraction in (0, 1); radius: R (same unit as ``rho``).
  """
  rho_sq = jnp.maximum(rho * rho, 1e-12)
  cosine = ((1.0 + r * r) * rho_sq - radius * radius) / (2.0 * jnp.maximum(r, 1e-12) * rho_sq)
  return 2.0 * jnp.arccos(jnp.clip(cosine, -1.0, 1.0))
