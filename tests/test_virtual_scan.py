"""Virtual scans into the belief against a NumPy ray caster (finely sampled rays that stop at the
first believed-occupied cell), and the gain of an observation against a NumPy loop of the
inverse sensor model and Li's Eq 2."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from conftest import EAGER_AND_JIT
from jaxplore import config, mapping, sensor, virtual_scan

STEP = 2e-4  # cells between reference samples
PARAMS = config.make_params()  # l_free -1, l_occ 2, clamp ±5, p_free 0.35, p_occ 0.65


def _belief(seed=0, h=40, w=44):
  """Log-odds: a walled room with two inner walls and a weak wall, a mapped free part, unknown
  elsewhere, and some cells of intermediate belief."""
  rng = np.random.default_rng(seed)
  l = np.zeros((h, w), np.float32)
  l[:, :26] = -3.0  # mapped free part
  l[0, :] = l[-1, :] = l[:, 0] = l[:, -1] = 4.0
  l[12:30, 18] = 4.0  # a believed wall
  l[25, 5:14] = 4.0
  l[8, 30:38] = 0.3  # a faint, still-unknown wall: beams pass
  mixed = rng.random((h, w)) < 0.05
  l[mixed] = rng.uniform(-2.0, 2.0, mixed.sum())
  return l


def _reference_observation(logodds, u0, v0, angles, r_max):
  """int8[H, W] (1 free, 2 occupied) and the cells some beam crosses for < 2e-3 cells (there
  either answer is right)."""
  h, w = logodds.shape
  occupied = logodds > mapping.logit(0.65)
  t = np.arange(0.0, r_max, STEP)[None, :]
  rows = np.floor(v0 + t * np.sin(angles)[:, None]).astype(int)
  cols = np.floor(u0 + t * np.cos(angles)[:, None]).astype(int)
  inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
  flat = np.where(inside, rows * w + cols, h * w)  # h * w: outside
  blocked = ~inside | occupied.ravel()[np.minimum(flat, h * w - 1)]
  stop = np.where(blocked.any(1), np.argmax(blocked, 1), t.size)
  before_stop = np.arange(t.size)[None, :] < stop[:, None]
  beam = np.arange(len(angles))[:, None]
  # Samples per (beam, cell): a cell a beam runs through for less than 2e-3 cells is marginal.
  samples = np.bincount((beam * (h * w + 1) + flat).ravel(), minlength=len(angles) * (h * w + 1))
  samples = samples.reshape(len(angles), h * w + 1)[:, :-1]
  seen = np.zeros(h * w + 1, np.int8)
  seen[flat[before_stop]] = 1
  hit = stop < t.size
  hit_cell = flat[np.arange(len(angles)), np.minimum(stop, t.size - 1)]
  seen[hit_cell[hit]] = 2
  touched = np.zeros((len(angles), h * w + 1), bool)
  touched[np.broadcast_to(beam, flat.shape)[before_stop], flat[before_stop]] = True
  touched[np.arange(len(angles))[hit], hit_cell[hit]] = True
  short = touched[:, :-1] & (samples * STEP < 2e-3)
  marginal = {divmod(int(i), w) for i in np.nonzero(short.any(0))[0]}
  return seen[:-1].reshape(h, w), marginal


def _reference_gain(logodds, observed, kind, res):
  """NumPy loop: integrate each observed cell once (l_free -1 / l_occ 2, clamp ±5) and sum the
  entropy drop (nats) or the newly known / newly free area (m²)."""
  def entropy(l):
    p = 1.0 / (1.0 + math.exp(-l))
    return -sum(q * math.log(q) for q in (p, 1.0 - p) if q > 0)
  free_level, occ_level = math.log(0.35 / 0.65), math.log(0.65 / 0.35)
  total = 0.0
  for (r, c), o in np.ndenumerate(observed):
    if o == 0:
      continue
    before = float(logodds[r, c])
    after = min(max(before + (-1.0 if o == 1 else 2.0), -5.0), 5.0)
    if kind == 0:
      total += entropy(before) - entropy(after)
    elif kind == 1:
      known = lambda l: l < free_level or l > occ_level
      total += res * res * (known(after) and not known(before))
    else:
      total += res * res * (int(after < free_level) - int(before < free_level))
  return total


CAST = jax.jit(lambda occ, u, v, a, r: virtual_scan.cast(occ, (40, 44), u, v, a, r))


def test_virtual_scan_sees_what_a_numpy_ray_caster_sees_in_the_belief():
  # Jitted only: the kernels it composes (sensor.measure, mark_observed) are tested eager too.
  logodds = _belief()
  framed = sensor.frame_truth(jnp.asarray(logodds > mapping.logit(0.65)))
  rng = np.random.default_rng(1)
  poses = [(3.5, 3.5), (10.3, 20.7), (22.2, 5.9), (15.61, 33.3)]
  seen_unknown = False
  for u0, v0 in poses:
    # Facing the unknown part (x > 26 cells), give or take: no beam starts on a grid line.
    theta = math.atan2(20.0 - v0, 35.0 - u0) + rng.uniform(-0.5, 0.5)
    angles = np.asarray(sensor.beam_angles(jnp.float32(theta), jnp.float32(math.radians(190)), 48))
    r_max = 15.0
    ours = np.asarray(CAST(framed, jnp.float32(u0), jnp.float32(v0), jnp.asarray(angles), jnp.float32(r_max)))
    reference, marginal = _reference_observation(logodds, u0, v0, angles.astype(np.float64), r_max)
    differ = {tuple(c) for c in np.argwhere(ours != reference).tolist()}
    assert differ <= marginal, (u0, v0, sorted(differ - marginal)[:5])
    assert np.all(ours[logodds > mapping.logit(0.65)] != 1)
    seen_unknown |= bool(np.any((ours == 1) & (logodds == 0.0)))
  assert seen_unknown  # beams went on through unknown cells


def test_virtual_scan_passes_unknown_cells_and_stops_at_occupied_ones():
  logodds = np.zeros((40, 44), np.float32)
  logodds[:, 30] = 4.0  # a believed wall at column 30; everything else unknown
  framed = sensor.frame_truth(jnp.asarray(logodds > 1.0))
  ours = np.asarray(CAST(framed, jnp.float32(10.5), jnp.float32(20.5), jnp.zeros(48, jnp.float32),
                         jnp.float32(30.0)))
  np.testing.assert_array_equal(np.nonzero(ours[20])[0], np.arange(10, 31))
  assert ours[20, 30] == 2 and np.all(ours[20, 10:30] == 1)
  assert np.sum(ours > 0) == 21


@EAGER_AND_JIT
def test_observation_gain_matches_a_numpy_loop(transform):
  logodds = _belief(2)
  rng = np.random.default_rng(3)
  observed = rng.choice(np.array([0, 1, 2], np.int8), size=logodds.shape, p=[0.6, 0.3, 0.1])
  gain = transform(lambda l, o, kind: virtual_scan.observation_gain(l, o, PARAMS, kind, 0.05))
  for kind in (0, 1, 2):
    expected = _reference_gain(logodds, observed, kind, 0.05)
    ours = float(gain(jnp.asarray(logodds), jnp.asarray(observed), jnp.int32(kind)))
    np.testing.assert_allclose(ours, expected, rtol=1e-4, atol=1e-5)


def test_gain_of_a_virtual_scan_is_the_change_the_real_update_would_make():
  logodds = _belief(4)
  framed = sensor.frame_truth(jnp.asarray(logodds > mapping.logit(0.65)))
  angles = sensor.beam_angles(jnp.float32(0.3), jnp.float32(2 * math.pi), 48)
  observed = CAST(framed, jnp.float32(12.4), jnp.float32(6.6), angles, jnp.float32(25.0))
  after = mapping.update_logodds(jnp.asarray(logodds), observed, PARAMS)
  drop = jnp.sum(mapping.entropy_of_logodds(jnp.asarray(logodds)) - mapping.entropy_of_logodds(after))
  np.testing.assert_allclose(float(virtual_scan.observation_gain(jnp.asarray(logodds), observed, PARAMS)),
                             float(drop), rtol=1e-4)
  free = lambda l: np.sum(np.asarray(l) < mapping.logit(0.35))
  np.testing.assert_allclose(float(virtual_scan.observation_gain(jnp.asarray(logodds), observed, PARAMS, 2, 0.1)),
                             0.01 * (free(after) - free(logodds)), rtol=1e-5)
