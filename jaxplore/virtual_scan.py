"""Virtual scans: the simulator's lidar cast into a robot's *belief*, and what it would gain.

A planner that scores a candidate pose by the information a scan from there would bring (Bai et
al. 2016's mutual information; Li et al. 2020's "Method 29") needs the scan it expects: the
beams of :mod:`jaxplore.sensor` cast from the candidate against the belief instead of the truth.
A believed-occupied cell stops a beam; free and unknown cells let it through (an unknown cell
may well be free; the expected scan is the optimistic one, as in Bai et al.'s code, where a ray
through unknown space reaches its full range). The cells are found by the engine's own exact
traversal (:func:`jaxplore.sensor.measure` and :func:`jaxplore.sensor.mark_observed`), so a
virtual scan from a pose marks exactly the cells a real scan would if the belief were the truth.

:func:`observation_gain` says what adding that observation to the belief with the inverse
sensor model (:func:`jaxplore.mapping.update_logodds`) would change, without writing the map:

* kind 0: the drop of the map entropy Σ Ĥ(c) (Li Eq 2), nats;
* kind 1: the area that becomes known (unknown before, free or occupied after), m²;
* kind 2: the area that becomes believed free (Bai et al.'s code: the free volume after the
  virtual scan minus before), m².
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from jaxplore import mapping, sensor

ENTROPY, KNOWN_AREA, FREE_AREA = 0, 1, 2


def n_crossings(shape) -> int:
  """Crossings per axis enough for any beam to leave an (H, W) grid (a static loop bound; the
  walks stop at the range, so a generous bound costs nothing)."""
  return int(math.ceil(math.hypot(*shape))) + 2


def cast(occupied_framed, shape, u0, v0, angles, r_max_cells, dirs=None):
  """One virtual scan: the observation a lidar at (u0, v0) would make if the belief were true.

  Args:
    occupied_framed: :func:`jaxplore.sensor.frame_truth` of the believed-occupied cells.
    shape: static (H, W).
    u0, v0: the sensor position in cell units (column, row coordinates).
    angles: f32[n] absolute beam angles (:func:`jaxplore.sensor.beam_angles`).
    r_max_cells: the range in cells (traced).
    dirs: the beams' :func:`jaxplore.sensor.directions`, if the caller has them.

  Returns:
    int8[H, W]: 1 seen free, 2 seen occupied, 0 not seen (:func:`sensor.observation_grid`).
  """
  n_cross = n_crossings(shape)
  scan = sensor.measure(occupied_framed, shape, u0, v0, angles, r_max_cells, n_cross, dirs=dirs)
  end_rows, end_cols = sensor.end_cells(scan, u0, v0, jnp.bool_(True), dirs)
  observed = sensor.mark_observed(sensor.empty_observation(shape), shape, scan, u0, v0, end_rows,
                                  end_cols, n_cross, dirs=dirs)
  return sensor.observation_grid(observed, shape)


def cell_gains(logodds, params, kind, res):
  """What one observation of each cell would gain: (if seen free, if seen occupied), f32[H, W].

  Args:
    logodds: f32[H, W] the belief.
    params: supplies ``l_free``, ``l_occ``, ``l_min``, ``l_max``, ``p_free``, ``p_occ``.
    kind: 0 entropy drop (nats), 1 newly known area (m²), 2 newly free area (m²); may be traced.
    res: metres per cell.
  """
  after_free = jnp.clip(logodds + params.l_free, params.l_min, params.l_max)
  after_occ = jnp.clip(logodds + params.l_occ, params.l_min, params.l_max)
  before = mapping.entropy_of_logodds(logodds)
  free_level, occ_level = mapping.logit(params.p_free), mapping.logit(params.p_occ)
  known = lambda l: (l < free_level) | (l > occ_level)
  area = jnp.float32(res * res)
  was_known, was_free = known(logodds), logodds < free_level
  by_kind = lambda entropy, known_area, free_area: jnp.where(
      kind == ENTROPY, entropy, jnp.where(kind == KNOWN_AREA, known_area, free_area))
  gain_free = by_kind(before - mapping.entropy_of_logodds(after_free),
                      jnp.where(~was_known & known(after_free), area, 0.0),
                      jnp.where(~was_free & (after_free < free_level), area, 0.0))
  gain_occ = by_kind(before - mapping.entropy_of_logodds(after_occ),
                     jnp.where(~was_known & known(after_occ), area, 0.0),
                     jnp.where(was_free & ~(after_occ < free_level), -area, 0.0))
  return gain_free.astype(jnp.float32), gain_occ.astype(jnp.float32)


def tabulated_gain(gains, observed):
  """The gain of an observation (int8[H, W]) from :func:`cell_gains`' tables ``gains``."""
  gain_free, gain_occ = gains
  return jnp.sum(jnp.where(observed == 1, gain_free, jnp.where(observed == 2, gain_occ, 0.0)))


def observation_gain(logodds, observed, params, kind=ENTROPY, res=1.0):
  """What integrating ``observed`` (int8[H, W]: 1 free, 2 occupied) into ``logodds`` would gain.

  The map is not written. Kinds as in :func:`cell_gains`: the drop of Σ Ĥ (nats, Li Eq 2), the
  newly known area or the newly free area (m², ``res`` metres per cell). The free area counts a
  cell believed free that a scan would turn occupied as a loss, so kind 2 is exactly the change
  of the believed-free area.
  """
  return tabulated_gain(cell_gains(logodds, params, kind, res), observed)
