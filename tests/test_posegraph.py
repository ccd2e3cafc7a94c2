"""The pose graph (jaxplore.posegraph) against NumPy, NetworkX and hand-worked cases."""

import math

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest

from jaxplore import motion, posegraph
from jaxplore.config import ConfigError, make_params
from tests.conftest import EAGER_AND_JIT

N_CAP, M_CAP = 24, 8


def random_graph(rng, n, m, n_cap=N_CAP, m_cap=M_CAP):
  """A PoseGraph with n keyframes (chain) and m distinct loop edges (a, b), b − a >= 2."""
  chain_w = np.zeros(n_cap, np.float32)
  chain_w[1:n] = rng.uniform(0.5, 4.0, n - 1)
  pairs = set()
  while len(pairs) < m:
    a, b = sorted(rng.choice(n, 2, replace=False))
    if b - a >= 2:
      pairs.add((int(a), int(b)))
  loops = np.zeros((m_cap, 2), np.int32)
  if m:
    loops[:m] = sorted(pairs, key=lambda p: p[1])
  loop_w = np.zeros(m_cap, np.float32)
  loop_w[:m] = rng.uniform(0.5, 4.0, m)
  graph = posegraph.init(jnp.zeros(3), n_cap, m_cap)
  return graph.replace(chain_w=jnp.asarray(chain_w), loops=jnp.asarray(loops),
                       loop_w=jnp.asarray(loop_w), n_nodes=jnp.int32(n), n_loops=jnp.int32(m))


def to_networkx(graph):
  g = nx.Graph()
  n, m = int(graph.n_nodes), int(graph.n_loops)
  g.add_nodes_from(range(n))
  w = np.asarray(graph.chain_w, np.float64)
  for k in range(1, n):
    g.add_edge(k - 1, k, weight=w[k])
  for (a, b), lw in zip(np.asarray(graph.loops)[:m], np.asarray(graph.loop_w, np.float64)[:m]):
    g.add_edge(int(a), int(b), weight=lw)
  return g


def numpy_reduced_logdet(g, anchor=0):
  lap = nx.laplacian_matrix(g, nodelist=sorted(g.nodes), weight="weight").toarray()
  keep = [k for k in range(lap.shape[0]) if k != anchor]
  sign, value = np.linalg.slogdet(lap[np.ix_(keep, keep)])
  assert sign > 0
  return value


GRAPHS = [(12, 0), (12, 3), (17, 5), (24, 8), (2, 0)]


def cases(transform, all_cases):
  """Every case compiled; the first eagerly (eager dispatch dominates the time)."""
  return all_cases if transform is jax.jit else all_cases[:1]


# Compiled only: the structured log-det below also runs eagerly, and eager Cholesky and
# eigensolver calls cost seconds of one-off compiles each.
@pytest.mark.parametrize("transform", [jax.jit], ids=["jit"])
def test_dense_logdet_matches_slogdet_and_spanning_tree_count(transform):
  rng = np.random.default_rng(0)
  for n, m in cases(transform, GRAPHS):
    graph = random_graph(rng, n, min(m, max(0, n - 2)))
    g = to_networkx(graph)
    valid = jnp.arange(N_CAP) < n
    for anchor in (0, n - 1):
      got = transform(posegraph.reduced_logdet)(posegraph.graph_laplacian(graph), valid, anchor)
      np.testing.assert_allclose(float(got), numpy_reduced_logdet(g, anchor), rtol=1e-5, atol=1e-4)
    trees = nx.number_of_spanning_trees(g, weight="weight")
    np.testing.assert_allclose(float(got), math.log(trees), rtol=1e-5, atol=1e-4)


@EAGER_AND_JIT
def test_structured_logdet_matches_dense(transform):
  rng = np.random.default_rng(1)
  for n, m in cases(transform, GRAPHS):
    graph = random_graph(rng, n, min(m, max(0, n - 2)))
    logdet, resistance, _, _ = transform(posegraph.logdet_parts)(graph)
    want = numpy_reduced_logdet(to_networkx(graph))
    np.testing.assert_allclose(float(logdet), want, rtol=1e-5, atol=1e-4)
    w = np.asarray(graph.chain_w, np.float64)
    want = np.concatenate([[0.0], np.cumsum(1 / w[1:n])])
    np.testing.assert_allclose(np.asarray(resistance)[:n], want, rtol=1e-5)


@pytest.mark.parametrize("transform", [jax.jit], ids=["jit"])
def test_extended_logdet_matches_the_rebuilt_graph(transform):
  """A pendant chain of new nodes with loop closures: the low-rank update equals the log-det of
  the whole extended graph rebuilt from scratch."""
  rng = np.random.default_rng(2)
  extend = transform(posegraph.extended_logdet)
  for n, m in cases(transform, [(12, 3), (20, 6), (24, 0)]):
    graph = random_graph(rng, n, m)
    parts = posegraph.logdet_parts(graph)
    for p_valid in cases(transform, (3, 0, 1, 5)):
      new_w = rng.uniform(0.5, 4.0, 5).astype(np.float32)
      new_valid = np.arange(5) < p_valid
      loop_to = rng.integers(0, n - 1, 5).astype(np.int32)  # n - 1 would double the chain edge
      loop_w = np.where(rng.random(5) < 0.6, rng.uniform(0.5, 4.0, 5), 0.0).astype(np.float32)
      got = extend(graph, parts, jnp.asarray(new_w), jnp.asarray(new_valid), jnp.asarray(loop_to),
                   jnp.asarray(loop_w))
      g = to_networkx(graph)
      prev = n - 1
      for p in range(p_valid):
        node = n + p
        g.add_edge(prev, node, weight=float(new_w[p]))
        if loop_w[p] > 0:
          g.add_edge(int(loop_to[p]), node, weight=float(loop_w[p]))
        prev = node
      np.testing.assert_allclose(float(got), numpy_reduced_logdet(g), rtol=1e-5, atol=1e-4)


@EAGER_AND_JIT
def test_algebraic_connectivity_matches_networkx(transform):
  rng = np.random.default_rng(3)
  for n, m in cases(transform, GRAPHS[:-1]):
    graph = random_graph(rng, n, m)
    valid = jnp.arange(N_CAP) < n
    got = transform(posegraph.algebraic_connectivity)(posegraph.graph_laplacian(graph), valid)
    want = nx.algebraic_connectivity(to_networkx(graph), weight="weight", method="lanczos",
                                     tol=1e-10)
    np.testing.assert_allclose(float(got), want, rtol=1e-4, atol=1e-6)


def test_degree_and_tree_connectivity():
  rng = np.random.default_rng(4)
  graph = random_graph(rng, 17, 5)
  g = to_networkx(graph)
  np.testing.assert_allclose(float(posegraph.average_degree(17, 16 + 5)),
                             np.mean([d for _, d in g.degree()]))
  logdet = numpy_reduced_logdet(g)
  np.testing.assert_allclose(float(posegraph.tree_connectivity(jnp.float32(logdet), 17)),
                             logdet / (15 * math.log(17)), rtol=1e-6)
  # The complete graph with unit weights has n^(n-2) spanning trees (Cayley): tau-hat = 1.
  k7 = nx.complete_graph(7)
  nx.set_edge_attributes(k7, 1.0, "weight")
  tau = posegraph.tree_connectivity(jnp.float32(numpy_reduced_logdet(k7)), 7)
  np.testing.assert_allclose(float(tau), 1.0, rtol=1e-6)


@EAGER_AND_JIT
def test_d_optimality_of_known_matrices(transform):
  q, _ = np.linalg.qr(np.random.default_rng(5).normal(size=(3, 3)))
  info = q @ np.diag([2.0, 4.0, 8.0]) @ q.T
  d_opt = transform(posegraph.d_optimality)
  np.testing.assert_allclose(float(d_opt(jnp.asarray(info, jnp.float32))), 4.0, rtol=1e-5)
  # Ahmed et al.'s hallucinated odometry information, ODOM_COV^-1 / 2: D-opt 21.38.
  odom_cov = np.array([[0.04, 0.001, 0.0], [0.001, 0.04, 0.0], [0.0, 0.0, 0.008]])
  fim = np.linalg.inv(odom_cov) / 2
  np.testing.assert_allclose(float(d_opt(jnp.asarray(fim, jnp.float32))),
                             np.linalg.det(fim) ** (1 / 3), rtol=1e-5)
  assert abs(float(posegraph.d_optimality(jnp.asarray(fim, jnp.float32))) - 21.38) < 0.01
  cov = jnp.asarray(np.linalg.inv(info), jnp.float32)
  d_opt_cov = transform(posegraph.d_optimality_of_covariance)
  np.testing.assert_allclose(float(d_opt_cov(cov)), 4.0, rtol=1e-5)


# --- growing the graph ---------------------------------------------------------------------------

RES = 0.1
PARAMS = make_params(kf_dist=0.3, kf_rot=0.3, loop_radius=0.8, loop_min_age=3.0)
FREE_LOGIT = -3.0


def observe_jit():
  return jax.jit(lambda g, pose, dd, dphi, logodds: posegraph.observe(
      g, pose, jnp.diag(jnp.stack([dd, dd, dphi])) * 0.01, motion.increment(dd, dphi),
      jnp.bool_(True), logodds, jnp.zeros(2), RES, PARAMS, 24))


OBSERVE = observe_jit()


def drive(graph, poses, logodds):
  """Feeds a sequence of estimated poses to ``observe``: each step turns by the heading change,
  then drives straight to the next position (``dd`` along the new heading)."""
  prev = np.asarray(poses[0], np.float32)
  for pose in poses[1:]:
    pose = np.asarray(pose, np.float32)
    dd = float(np.hypot(*(pose[:2] - prev[:2])))
    dphi = float(np.angle(np.exp(1j * (pose[2] - prev[2]))))
    graph = OBSERVE(graph, jnp.asarray(pose), jnp.float32(dd), jnp.float32(dphi), logodds)
    prev = pose
  return graph


def test_keyframes_every_kf_dist_and_kf_rot_with_accumulated_covariance():
  logodds = jnp.full((20, 20), FREE_LOGIT)
  graph = posegraph.init(jnp.asarray([0.5, 0.5, 0.0]), 16, 4)
  # 0.1 m steps along x: a keyframe every 0.3 m
  poses = [[0.5 + 0.1 * k, 0.5, 0.0] for k in range(8)]
  # then turn in place by 0.2 rad steps: a keyframe every 2 steps (0.4 rad >= 0.3)
  poses += [[1.2, 0.5, 0.2 * k] for k in range(1, 5)]
  graph = drive(graph, poses, logodds)
  kf = np.asarray(graph.poses)[: int(graph.n_nodes)]
  # Float32 sums of 0.1 reach 0.3 after 3 or 4 steps; the first keyframe is at x = 0.8 or 0.9.
  assert int(graph.n_nodes) >= 3
  np.testing.assert_allclose(kf[-1], [1.2, 0.5, 0.8], atol=1e-5)
  np.testing.assert_allclose(kf[-2], [1.2, 0.5, 0.4], atol=1e-5)
  # The turn-only edge: covariance 0.018² I + Σ V_n of its two steps (dphi = 0.2: 0.002 each).
  cov = np.diag([0.018**2, 0.018**2, 0.018**2 + 2 * 0.002])
  np.testing.assert_allclose(float(graph.chain_w[int(graph.n_nodes) - 1]),
                             np.linalg.det(cov) ** (-1 / 3), rtol=1e-4)


def loop_scene(blocked=False, heading=0.0):
  """Out along y = 0.5 and back: keyframes 0.3 m apart; returning close to an old keyframe."""
  logodds = np.full((20, 20), FREE_LOGIT, np.float32)
  if blocked:
    logodds[6, :] = 3.0  # a believed wall between y = 0.5 and y = 0.9 (row 6 = y in [0.6, 0.7))
  poses = [[0.5 + 0.1 * k, 0.5, 0.0] for k in range(16)]  # to x = 2.0
  poses += [[2.0 - 0.1 * k, 0.9, heading] for k in range(1, 16)]  # back along y = 0.9
  graph = posegraph.init(jnp.asarray(poses[0]), 32, 4)
  return drive(graph, poses, jnp.asarray(logodds))


def test_loop_closure_to_the_nearest_old_keyframe():
  graph = loop_scene()
  n, m = int(graph.n_nodes), int(graph.n_loops)
  assert m >= 1
  poses = np.asarray(graph.poses)
  for a, b in np.asarray(graph.loops)[:m]:
    assert b - a >= 3
    d = np.hypot(*(poses[a, :2] - poses[b, :2]))
    assert d <= 0.8 + 1e-6
    # a is the nearest keyframe at least 3 older with |Δθ| <= 90°
    ages = np.arange(n)
    ok = (ages <= b - 3) & (np.hypot(*(poses[:n, :2] - poses[b, :2]).T) <= 0.8)
    assert d <= np.min(np.hypot(*(poses[:n][ok, :2] - poses[b, :2]).T)) + 1e-6
  np.testing.assert_allclose(np.asarray(graph.loop_w)[:m], 1 / 0.018**2, rtol=1e-5)


def test_no_loop_closure_through_a_wall_or_facing_away():
  assert int(loop_scene(blocked=True).n_loops) == 0
  assert int(loop_scene(heading=math.pi).n_loops) == 0


@EAGER_AND_JIT
def test_a_segment_off_the_grid_is_not_free_on_any_side(transform):
  """``line_free`` against a plain loop over its sample points: a cell off the grid is never
  free, on the top and left sides too (a negative index once wrapped to the far, free edge)."""
  h, w, res, samples = 12, 16, 0.1, 40
  logodds = np.full((h, w), FREE_LOGIT, np.float32)
  logodds[5, 6:9] = 3.0  # one believed wall inside
  line_free = transform(lambda a, b: posegraph.line_free(jnp.asarray(logodds), a, b,
                                                         jnp.zeros(2), res, FREE_LOGIT + 1.0, samples))
  rng = np.random.default_rng(4)
  ends = rng.uniform([-0.35, -0.35], [w * res + 0.35, h * res + 0.35], (60, 2)).astype(np.float32)
  results, expected = [], []
  for a, b in zip(ends[::2], ends[1::2]):
    points = a + np.linspace(0.0, 1.0, samples, dtype=np.float32)[:, None] * (b - a)
    rows = np.floor(points[:, 1] / res).astype(int)
    cols = np.floor(points[:, 0] / res).astype(int)
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    expected.append(bool(inside.all()) and bool((logodds[rows, cols] < FREE_LOGIT + 1.0).all()))
    results.append(bool(line_free(jnp.asarray(a), jnp.asarray(b))))
  assert results == expected
  assert any(expected) and not all(expected)
  # Off the top-left corner: rows and columns -1, whose wrapped cells are free.
  assert not bool(line_free(jnp.asarray([0.05, 0.55]), jnp.asarray([-0.05, 0.55])))
  assert not bool(line_free(jnp.asarray([0.55, 0.05]), jnp.asarray([0.55, -0.05])))


def test_full_loop_list_counts_dropped_closures():
  logodds = jnp.full((20, 20), FREE_LOGIT)
  poses = [[0.5 + 0.1 * k, 0.5, 0.0] for k in range(16)]
  poses += [[2.0 - 0.1 * k, 0.9, 0.0] for k in range(1, 16)]
  graph = drive(posegraph.init(jnp.asarray(poses[0]), 32, 1), poses, logodds)
  assert int(graph.n_loops) == 1
  assert int(graph.loops_dropped) >= 1
  assert int(graph.loops_dropped) + 1 == int(loop_scene().n_loops)


def test_capacity_refusal_names_the_numbers():
  params = make_params(v_max=0.3, w_max=0.8, dt=0.5, kf_dist=0.3, kf_rot=0.3)
  # Per step: 0.15 / 0.3 + 0.4 / 0.3 > 1, so every step may make a keyframe.
  assert posegraph.keyframe_bound(1000, 0.3, 0.8, 0.5, 0.3, 0.3) == 1001
  want = 1 + math.ceil(1000 * (0.5 + 0.05 / 0.3) * (1 + 1e-4))
  assert posegraph.keyframe_bound(1000, 0.3, 0.1, 0.5, 0.3, 0.3) == want
  message = r"holds 512 keyframes.*1000 steps.*create 1001.*graph_nodes to 1001"
  with pytest.raises(ConfigError, match=message):
    posegraph.check_capacity(512, 1000, params)
  posegraph.check_capacity(1001, 1000, params)


def test_a_scan_matching_run_has_loop_slots_for_the_distance_it_can_drive():
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec
  params = make_params(v_max=0.25, dt=0.4, loop_radius=4.0, link_spacing=1.0)
  # 1,000 steps of at most 0.1 m: 100 m, a closure per 4 m and a link per metre, 10 % more.
  assert posegraph.loop_bound(1000, params, keyframes=400) == math.ceil(1.1 * (25 + 100))
  assert posegraph.loop_bound(1000, params.replace(link_radius=0.0), 400) == math.ceil(1.1 * 25)
  # A sweep: the largest over its values; a link spacing of 0 links at every keyframe.
  sweep = params.replace(loop_radius=np.array([2.0, 4.0]), link_spacing=np.array([0.0, 1.0]))
  assert posegraph.loop_bound(1000, sweep, keyframes=400) == math.ceil(1.1 * (50 + 400))
  run = lambda **kw: resolve(RunSpec.create(world="lab", planner="nearest_frontier", robots=1,
                                            max_steps=500, **kw)).config
  sized = run(slam="scan_matching")
  assert sized.graph_loops == posegraph.loop_bound(500, make_params(), sized.graph_nodes)
  assert run(slam="scan_matching", graph_loops=64).graph_loops == 64
  assert run(slam="oracle", pose_graph=True).graph_loops == 256  # the oracle's proximity graph
