"""The drift since the last loop closure (jaxplore.slam.model.drift and restart_drift) on
hand-made chains, against a plain NumPy reading of its rule: the dead-reckoned prediction from
the previous keyframe (Li Eq 17), fused, where the scan matched, with the match taken relative to
the oldest keyframe of the local chain."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import motion, posegraph
from jaxplore.config import make_params
from jaxplore.slam import model

LOOP_MIN_AGE = 6.0
ODOMETRY = np.diag([0.03 ** 2, 0.03 ** 2, math.radians(1.0) ** 2])
PRECISE = np.diag([0.02 ** 2, 0.02 ** 2, math.radians(0.5) ** 2])
# A match along a corridor on the x axis: it cannot tell where along it the robot is.
CORRIDOR = np.diag([10.0 ** 2, 0.02 ** 2, math.radians(0.5) ** 2])


def numpy_drift(poses, matched, match_cov, restarts):
  """The drift at each keyframe of a chain, the rule read in NumPy: ``restarts`` maps a keyframe
  to the covariance it restarts from (a closure or link there)."""
  def compounded(a, i, cov, increment):
    j1 = np.eye(3)
    j1[0, 2] = poses[a][1] - poses[i][1]
    j1[1, 2] = poses[i][0] - poses[a][0]
    return j1 @ cov @ j1.T + increment

  drift, since = [np.zeros((3, 3))], 0
  for i in range(1, len(poses)):
    predicted = compounded(i - 1, i, drift[i - 1], ODOMETRY)
    if matched[i]:
      anchor = min(max(int(math.floor(i - LOOP_MIN_AGE)) + 1, since), i - 1)
      anchored = compounded(anchor, i, drift[anchor], match_cov)
      drift.append(np.linalg.inv(np.linalg.inv(predicted) + np.linalg.inv(anchored)))
    else:
      drift.append(predicted)
    if i in restarts:
      drift[i], since = restarts[i], i
  return np.stack(drift)


def chain(poses, matched, match_cov, restarts, jit):
  params = make_params(loop_min_age=LOOP_MIN_AGE)
  graph = posegraph.init(jnp.asarray(poses[0]), len(poses) + 1, 4, beams=8)

  def add(graph, pose, matched, restart, restart_cov):
    cov = model.drift(params, graph, pose, jnp.asarray(ODOMETRY, jnp.float32),
                      jnp.asarray(match_cov, jnp.float32), matched)
    i = graph.n_nodes
    graph = graph.replace(keyframe_drift=graph.keyframe_drift.at[i].set(cov))
    graph = model.add_keyframe(graph, jnp.bool_(True), pose, pose, jnp.eye(3))
    return model.restart_drift(graph, restart, i, restart_cov)

  add = jax.jit(add) if jit else add
  drifts = [np.zeros((3, 3))]
  for i in range(1, len(poses)):
    restart = restarts.get(i)
    graph = add(graph, jnp.asarray(poses[i], jnp.float32), jnp.bool_(matched[i]),
                jnp.bool_(restart is not None),
                jnp.asarray(np.zeros((3, 3)) if restart is None else restart, jnp.float32))
    drifts.append(np.asarray(model.current_drift(graph)))
  return np.stack(drifts), graph


def straight(n, step=0.3):
  return np.array([[step * i, 0.1 * math.sin(i), 0.01 * i] for i in range(n)], np.float32)


def dead_reckoned(poses):
  """Li Eq 17 keyframe by keyframe, as motion.propagate_covariance compounds it (J2 V J2ᵀ = V:
  ODOMETRY is isotropic in x-y)."""
  cov = np.zeros((3, 3), np.float32)
  for i in range(1, len(poses)):
    cov = np.asarray(motion.propagate_covariance(jnp.asarray(cov), jnp.asarray(poses[i - 1]),
                                                 jnp.asarray(poses[i]),
                                                 jnp.asarray(ODOMETRY, jnp.float32)))
  return cov


@pytest.mark.parametrize("jit", [False, True])
def test_matched_drift_is_anchored_to_the_local_chain_not_compounded_per_keyframe(jit):
  poses = straight(41)
  matched = np.ones(41, bool)
  drifts, graph = chain(poses, matched, PRECISE, {}, jit)
  expected = numpy_drift(poses, matched, PRECISE, {})
  np.testing.assert_allclose(drifts, expected, rtol=1e-3, atol=1e-9)
  np.testing.assert_allclose(np.asarray(graph.keyframe_drift[:41]), expected, rtol=1e-3,
                             atol=1e-9)
  # 40 keyframes: the heading's variance grows by about one match per local chain (5
  # keyframes), not by one edge a keyframe.
  alone = dead_reckoned(poses)
  assert drifts[-1][2, 2] < 8 * PRECISE[2, 2] < 0.25 * alone[2, 2]


@pytest.mark.parametrize("jit", [False, True])
def test_dead_reckoned_drift_compounds_every_edge(jit):
  poses = straight(21)
  drifts, _ = chain(poses, np.zeros(21, bool), PRECISE, {}, jit)
  np.testing.assert_allclose(drifts[-1], dead_reckoned(poses), rtol=1e-4)
  assert drifts[-1][2, 2] == pytest.approx(20 * ODOMETRY[2, 2], rel=1e-4)


def test_along_a_corridor_the_drift_grows_along_it_only():
  poses = np.array([[0.3 * i, 0.0, 0.0] for i in range(41)], np.float32)
  matched = np.ones(41, bool)
  drifts, _ = chain(poses, matched, CORRIDOR, {}, False)
  np.testing.assert_allclose(drifts, numpy_drift(poses, matched, CORRIDOR, {}), rtol=1e-3,
                             atol=1e-9)
  alone = dead_reckoned(poses)
  assert drifts[-1][0, 0] > 0.9 * alone[0, 0]  # along: as dead reckoning
  assert drifts[-1][1, 1] < 0.1 * alone[1, 1]  # across (the lever of the heading): held
  assert drifts[-1][2, 2] < 0.25 * alone[2, 2]


def test_a_restart_is_where_the_drift_counts_from():
  poses = straight(31)
  matched = np.ones(31, bool)
  matched[12:15] = False  # three scans that did not match
  link = np.diag([0.05 ** 2, 0.05 ** 2, math.radians(1.0) ** 2])
  restarts = {10: np.zeros((3, 3)), 20: link}
  drifts, graph = chain(poses, matched, PRECISE, restarts, False)
  np.testing.assert_allclose(drifts, numpy_drift(poses, matched, PRECISE, restarts), rtol=1e-3,
                             atol=1e-9)
  assert int(graph.drift_from) == 20
  np.testing.assert_allclose(drifts[20], link, rtol=1e-6)
  # Two keyframes after the link: anchored at it, never at keyframes before it.
  assert drifts[22][2, 2] < link[2, 2] + PRECISE[2, 2]
