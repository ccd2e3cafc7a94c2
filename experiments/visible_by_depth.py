"""A GPU candidate for li2020's visible gains: the sight-line tree walked a whole depth at a time.

``jaxplore.planners.li2020.visible_gains`` walks the tree of sight lines (``li2020.ray_tree``)
group of subtrees by group, depth by depth, ``block`` offsets per loop step: for R_e = 57 cells
(``lab``) ~1,950 loop steps of small kernels (1,697 blocks of 8 in 261 steps of the outer
loop). On a GPU that chain is the plan's latency: on one H200 the visible gains of 4 robots
took 113 ms a call, of 256 robots 653 ms (``experiments/results/bench_accelerator_gpu.md``),
most of a li2020 step on ``lab``.

Here every offset of one depth of the tree, all subtrees together, is a row of one batch, taken
``block`` rows (64 by default) per loop step: 185 loop steps for R_e = 57, each a few gathers
and reductions over [block, H, W]. An offset's mask is its parent's (a row of the previous
depth's buffer) cut where the chain steps diagonally between two occupied cells, as in the
package. The masks of two depths live in one buffer [2, rows, H, W] (indexed by depth parity,
written in place).

An earlier session tried a depth at once with the groups kept apart (~900 loop steps), and on
one H200 it was slower: 16 ms per plan, the README says, against the blocks' 2.6 ms at 256
robots and 28 ms at 4 (the batch of the 16 ms was not recorded), every offset's window
materialised in memory, as here. Since then a lockstep round plans in a chunk of 4 or 16 when
that holds every robot that needs a plan, where the blocks' loop steps cost the latency; that
is the case this candidate is for: if it wins there and loses at 64 robots and more, it belongs
in the small chunks only.

The sums are the package's up to float summation order: a depth's rows are summed as a batch,
not one after the other, so the gains differ in their last bits, and a plan whose best
candidates tie to those bits may pick another. Not in the package until a GPU shows it wins;
``bench_lockstep_variants.py --variants visible_by_depth`` and ``bench_visible_blocks.py
--by-depth`` time it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import mapping
from jaxplore.planners import li2020

BLOCK = 64


@functools.lru_cache(maxsize=None)
def depth_tables(radius: float, block: int = BLOCK):
  """The offsets of :func:`li2020.ray_tree` by depth, in loop steps of ``block`` rows.

  Returns (rows i32[T, block, 6]: per row its offset (row, col), its parent's (row, col), its
  parent's row in the previous depth's buffer (``slots`` for the centre) and its step's index
  in ``mapping.NEIGHBOURS_8``; start i32[T]: the buffer row of the step's first row; parity
  i32[T]: the depth's parity; valid bool[T, block]; member bool[T, block, 8]: crescent
  memberships; slots: the buffer rows a depth may fill).
  """
  offsets, depth, member, sides = li2020.ray_tree(radius)
  parents = np.stack([sides[:, 1, 0], sides[:, 0, 1]], -1)
  slot_of = {}
  rows, start, parity, valid, members = [], [], [], [], []
  widest = 0
  for d in range(1, int(depth.max()) + 1):
    at = np.flatnonzero(depth == d)
    for position, i in enumerate(at):
      slot_of[tuple(offsets[i])] = position
    widest = max(widest, len(at))
    for first in range(0, len(at), block):
      chunk = at[first:first + block]
      table = np.zeros((block, 6), np.int32)
      member_rows = np.zeros((block, 8), bool)
      for r, i in enumerate(chunk):
        o, p = offsets[i], parents[i]
        direction = mapping.NEIGHBOURS_8.index((int(o[0] - p[0]), int(o[1] - p[1])))
        parent = -1 if d == 1 else slot_of[tuple(p)]
        table[r] = (o[0], o[1], p[0], p[1], parent, direction)
        member_rows[r] = member[i]
      rows.append(table)
      start.append(first)
      parity.append(d % 2)
      valid.append(np.arange(block) < len(chunk))
      members.append(member_rows)
  slots = -(-widest // block) * block
  rows = np.stack(rows)
  rows[..., 4] = np.where(rows[..., 4] < 0, slots, rows[..., 4])
  return (rows, np.asarray(start, np.int32), np.asarray(parity, np.int32), np.stack(valid),
          np.stack(members), slots)


def visible_gains_by_depth(gains, occupied, radius: float, block: int = BLOCK):
  """:func:`li2020.visible_gains` (same arguments but ``block``: rows per loop step, here a
  part of one depth of the tree), up to float summation order."""
  rows, start, parity, valid, member, slots = depth_tables(radius, block)
  _, h, w = gains.shape
  pad, framed_gain, clear, corners = li2020.sight_fields(gains, occupied, radius)

  def at(field, row, col):
    """``field``'s [..., H, W] window of the cells ``v + (row, col)``."""
    lead = field.shape[:-2]
    return jax.lax.dynamic_slice(field, (0,) * len(lead) + (row + pad, col + pad), lead + (h, w))

  def one_step(carry, table):
    masks, full, crescent = carry
    step_rows, first, odd, ok, member_rows = table
    previous = jax.lax.dynamic_index_in_dim(masks, 1 - odd, 0, keepdims=False)
    parent_masks = previous[step_rows[:, 4]]
    # One slice of the stack per row: ``corners[k]`` first would gather a whole framed plane.
    corner = jax.vmap(lambda k, r, col: jax.lax.dynamic_slice(
        corners, (k, r + pad, col + pad), (1, h, w))[0])(
            step_rows[:, 5], step_rows[:, 2], step_rows[:, 3])
    seen = parent_masks & corner & ok[:, None, None]
    clear_there, shifted = jax.vmap(lambda r, col: (at(clear, r, col), at(framed_gain, r, col)))(
        step_rows[:, 0], step_rows[:, 1])
    masks = jax.lax.dynamic_update_slice(masks, (seen & clear_there)[None], (odd, first, 0, 0))
    contribution = jnp.where(seen[:, None], shifted, 0.0)  # [block, C, H, W]
    full = full + jnp.sum(contribution, 0)
    crescent = crescent + jnp.stack([
        jnp.sum(jnp.where(member_rows[:, n, None, None, None], contribution, 0.0), 0)
        for n in range(8)])
    return (masks, full, crescent), None

  # Row ``slots`` of both depths' buffers is the centre's mask (every cell sees itself).
  masks = jnp.zeros((2, slots + 1, h, w), bool).at[:, slots].set(True)
  crescent = jnp.zeros((8,) + gains.shape, gains.dtype)
  tables = tuple(jnp.asarray(a) for a in (rows, start, parity, valid, member))
  (_, full, crescent), _ = jax.lax.scan(one_step, (masks, gains, crescent), tables)
  return full, crescent
