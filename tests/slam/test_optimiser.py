"""jaxplore.slam.optimiser against GTSAM 4.3 (BetweenFactorPose2, NonlinearFactorGraph.error,
LevenbergMarquardtOptimizer) on a square loop, a Manhattan grid world and GTSAM's own w100.graph;
padding, vmap, eager/jit, and the dense pieces against NumPy.

GTSAM is a test oracle (the dev extras install it), not a dependency of the package. Node 0 is held in GTSAM by a prior of σ = 1e-6; the costs compared are of the
between factors alone.
"""

import math
import re

import gtsam
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore.slam import optimiser as opt
from tests.conftest import EAGER_AND_JIT

# One capacity for the three reference graphs, so that one compiled program serves them:
# K = E − (N − 1) = 209 loop slots, more than w100.graph's 201 loops.
N_CAP, E_CAP = 128, 336
POSE_TOL = 1e-4  # m and rad, every coordinate of every pose
COST_ATOL, COST_RTOL = 1e-4, 1e-6  # the final cost: 1e-4 plus float32's resolution of it
# Two float32 runs to the same optimum: their costs differ by the cost's float32 noise, which the
# optimiser's rtol (2e-6) accepts as no change.
SAME_COST_RTOL = 5e-6

_optimise = jax.jit(opt.optimise, static_argnames=("max_iterations", "cg_max_iterations",
                                                   "loop_capacity"))


# --- graphs --------------------------------------------------------------------------------------


def _wrap(a):
  return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _between(a, b):
  c, s = math.cos(a[2]), math.sin(a[2])
  dx, dy = b[0] - a[0], b[1] - a[1]
  return np.array([c * dx + s * dy, -s * dx + c * dy, _wrap(b[2] - a[2])])


def _compose(a, d):
  c, s = math.cos(a[2]), math.sin(a[2])
  return np.array([a[0] + c * d[0] - s * d[1], a[1] + s * d[0] + c * d[1], _wrap(a[2] + d[2])])


def _information(rng, sigma):
  """A non-diagonal information matrix: covariance diag(σ²) with a little x–θ correlation,
  rotated in the plane."""
  phi = rng.uniform(-np.pi, np.pi)
  rot = np.array([[math.cos(phi), -math.sin(phi), 0], [math.sin(phi), math.cos(phi), 0], [0, 0, 1]])
  cov = np.diag(np.square(sigma))
  cov[0, 2] = cov[2, 0] = 0.3 * sigma[0] * sigma[2]
  return np.linalg.inv(rot @ cov @ rot.T)


class Graph:
  """A pose graph in float64: initial poses f64[n, 3]; edges src, dst, measured, information."""

  def __init__(self, init, src, dst, measured, information):
    self.init = np.asarray(init, np.float64)
    self.src = np.asarray(src, np.int64)
    self.dst = np.asarray(dst, np.int64)
    self.measured = np.asarray(measured, np.float64)
    self.information = np.asarray(information, np.float64)

  @property
  def n(self):
    return len(self.init)


def _simulate(truth, pairs, rng, sigma_odo, sigma_loop, noise=1.0):
  """Odometry (i − 1 → i) and the loop pairs measured from ``truth`` with noise of ``noise``
  times their σ; the initial poses are the odometry dead-reckoned from the true first pose."""
  src, dst, meas, info = [], [], [], []
  for (a, b), sigma in [((i - 1, i), sigma_odo) for i in range(1, len(truth))] + [
      (p, sigma_loop) for p in pairs]:
    src.append(a)
    dst.append(b)
    meas.append(_between(truth[a], truth[b]) + noise * rng.normal(0.0, sigma))
    info.append(_information(rng, np.asarray(sigma)))
  init = [truth[0]]
  for k in range(len(truth) - 1):
    init.append(_compose(init[-1], meas[k]))
  return Graph(init, src, dst, meas, info)


def square_graph(seed=0, side=5, laps=3, noise=1.0):
  """Laps of a square of ``side`` metres, a keyframe every metre (turning left at the corners);
  a loop closure from every other keyframe of a lap to the same place one lap before."""
  rng = np.random.default_rng(seed)
  per_lap = 4 * side
  truth = [np.array([0.0, 0.0, 0.0])]
  for k in range(1, laps * per_lap):
    turn = np.pi / 2 if k % side == 0 else 0.0
    truth.append(_compose(truth[-1], [1.0, 0.0, turn]))
  pairs = [(k - per_lap, k) for k in range(per_lap, len(truth), 2)]
  return _simulate(truth, pairs, rng, np.array([0.05, 0.05, 0.02]), np.array([0.02, 0.02, 0.01]),
                   noise)


def grid_graph(seed=0, n=120, box=6):
  """A Manhattan world: one metre forward per keyframe on a lattice, turning ±90° at random or
  at the walls of a ``box`` x ``box`` metre room; a loop closure whenever a keyframe is on the
  lattice point of one at least 4 keyframes older (to the oldest)."""
  rng = np.random.default_rng(seed)
  truth = [np.array([0.0, 0.0, 0.0])]
  for _ in range(1, n):
    p = truth[-1]
    options = [0.0, np.pi / 2, -np.pi / 2, np.pi]
    weights = np.array([0.6, 0.2, 0.2, 0.0])
    for _ in range(50):
      turn = rng.choice(options, p=weights / weights.sum())
      nxt = _compose(p, [0.0, 0.0, turn])
      nxt = _compose(nxt, [1.0, 0.0, 0.0])
      if np.all(np.round(nxt[:2]) >= 0) and np.all(np.round(nxt[:2]) <= box):
        break
      weights = np.array([0.25, 0.25, 0.25, 0.25])
    truth.append(np.array([round(nxt[0]), round(nxt[1]), nxt[2]]))
  pairs = []
  for j in range(len(truth)):
    older = [i for i in range(j - 3) if np.allclose(truth[i][:2], truth[j][:2])]
    if older:
      pairs.append((older[0], j))
  return _simulate(truth, pairs, rng, np.array([0.03, 0.03, 0.01]), np.array([0.02, 0.02, 0.005]))


def w100_graph():
  """GTSAM's w100.graph (Olson's Manhattan world, 100 poses and 300 edges, unit information);
  the initial poses are the file's."""
  graph, values = gtsam.load2D(gtsam.findExampleDataFile("w100.graph"))
  init = [[values.atPose2(i).x(), values.atPose2(i).y(), values.atPose2(i).theta()]
          for i in range(values.size())]
  src, dst, meas, info = [], [], [], []
  for k in range(graph.size()):
    f = graph.at(k)
    a, b = f.keys()
    m = f.measured()
    src.append(a)
    dst.append(b)
    meas.append([m.x(), m.y(), m.theta()])
    r = f.noiseModel().R()
    info.append(r.T @ r)
  return Graph(init, src, dst, meas, info)


def arrays(graph: Graph, n_cap=None, e_cap=None, seed=None):
  """(poses f32[N, 3], node_valid bool[N], Edges) at capacity (n_cap, e_cap). With a ``seed``
  the padding is garbage (NaN and huge poses, edges to out-of-range and invalid nodes, NaN
  measurements) and the valid edges are scattered among the invalid ones."""
  n, e = graph.n, len(graph.src)
  n_cap, e_cap = n_cap or n, e_cap or e
  poses = np.zeros((n_cap, 3), np.float32)
  src = np.zeros(e_cap, np.int32)
  dst = np.zeros(e_cap, np.int32)
  meas = np.zeros((e_cap, 3), np.float32)
  info = np.tile(np.eye(3, dtype=np.float32), (e_cap, 1, 1))
  valid = np.zeros(e_cap, bool)
  order = np.arange(e_cap)
  if seed is not None:
    rng = np.random.default_rng(seed)
    poses[n:] = rng.normal(0.0, 1e4, (n_cap - n, 3))
    poses[n::3] = np.nan
    src[:] = rng.integers(-3, n_cap + 3, e_cap)
    dst[:] = rng.integers(0, n_cap, e_cap)
    meas[:] = rng.normal(0.0, 1e3, (e_cap, 3))
    meas[::2] = np.nan
    info[1::2] *= np.float32(np.nan)
    order = rng.permutation(e_cap)
  slots = order[:e]
  poses[:n] = graph.init
  src[slots], dst[slots] = graph.src, graph.dst
  meas[slots], info[slots], valid[slots] = graph.measured, graph.information, True
  node_valid = np.arange(n_cap) < n
  edges = opt.Edges(src=jnp.asarray(src), dst=jnp.asarray(dst), measured=jnp.asarray(meas),
                    information=jnp.asarray(info), valid=jnp.asarray(valid))
  return jnp.asarray(poses), jnp.asarray(node_valid), edges


# --- GTSAM ---------------------------------------------------------------------------------------


def _pose2(p):
  return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


def gtsam_graph(graph: Graph, poses=None):
  """(NonlinearFactorGraph of the between factors, Values at ``poses`` (default: initial))."""
  factors = gtsam.NonlinearFactorGraph()
  for a, b, m, info in zip(graph.src, graph.dst, graph.measured, graph.information):
    factors.add(gtsam.BetweenFactorPose2(int(a), int(b), _pose2(m),
                                         gtsam.noiseModel.Gaussian.Information(info)))
  values = gtsam.Values()
  for i, p in enumerate(graph.init if poses is None else poses):
    values.insert(i, _pose2(p))
  return factors, values


def gtsam_optimum(graph: Graph):
  """GTSAM's Levenberg–Marquardt to convergence (tolerances 1e-12) with node 0 held by a prior
  of σ = 1e-6: (poses f64[n, 3], cost of the between factors there)."""
  factors, values = gtsam_graph(graph)
  anchored = gtsam.NonlinearFactorGraph(factors)
  anchored.add(gtsam.PriorFactorPose2(0, _pose2(graph.init[0]),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
  params = gtsam.LevenbergMarquardtParams()
  params.setRelativeErrorTol(1e-12)
  params.setAbsoluteErrorTol(1e-12)
  params.setMaxIterations(200)
  result = gtsam.LevenbergMarquardtOptimizer(anchored, values, params).optimize()
  poses = np.array([[result.atPose2(i).x(), result.atPose2(i).y(), result.atPose2(i).theta()]
                    for i in range(graph.n)])
  return poses, factors.error(result)


def assert_poses_close(got, want, tol=POSE_TOL):
  d = np.asarray(got, np.float64) - np.asarray(want, np.float64)
  d[:, 2] = _wrap(d[:, 2])
  worst = np.unravel_index(np.argmax(np.abs(d)), d.shape)
  assert np.abs(d).max() <= tol, f"pose {worst[0]} coordinate {worst[1]} off by {d[worst]:.3g}"


def assert_matches_gtsam(result, graph: Graph):
  poses, cost = gtsam_optimum(graph)
  assert bool(result.converged)
  assert_poses_close(np.asarray(result.poses)[:graph.n], poses)
  np.testing.assert_allclose(float(result.final_cost), cost, rtol=COST_RTOL, atol=COST_ATOL)
  factors, initial = gtsam_graph(graph)
  np.testing.assert_allclose(float(result.initial_cost), factors.error(initial), rtol=1e-5)


# --- SE(2) and the cost --------------------------------------------------------------------------


def _angles():
  return np.array([0.0, 1e-7, -3e-6, 1e-4, -2e-3, 5e-3, 0.05, -0.19, 0.2, 0.21, -0.7, 1.5, 2.5,
                   -3.0, 3.1])


@EAGER_AND_JIT
def test_logmap_and_expmap_match_gtsam_at_every_angle(transform):
  theta = _angles()
  xy = np.random.default_rng(0).uniform(-3.0, 3.0, (len(theta), 2))
  poses = np.concatenate([xy, theta[:, None]], axis=1).astype(np.float32)
  log = np.asarray(transform(jax.vmap(opt.logmap))(jnp.asarray(poses)))
  want = np.array([gtsam.Pose2.Logmap(_pose2(p)) for p in poses.astype(np.float64)])
  np.testing.assert_allclose(log, want, rtol=2e-6, atol=1e-6)
  exp = np.asarray(transform(jax.vmap(opt.expmap))(jnp.asarray(poses)))
  pose = [gtsam.Pose2.Expmap(p) for p in poses.astype(np.float64)]
  want = np.array([[q.x(), q.y(), q.theta()] for q in pose])
  np.testing.assert_allclose(exp, want, rtol=2e-6, atol=1e-6)
  np.testing.assert_allclose(jax.vmap(opt.logmap)(jnp.asarray(exp)), poses, rtol=2e-6, atol=2e-6)


def _random_edges(rng, n, e):
  """Random poses (f32-representable) and edges whose errors stay clear of θ = ±π."""
  poses = np.concatenate([rng.uniform(-20, 20, (n, 2)), rng.uniform(-np.pi, np.pi, (n, 1))], 1)
  poses = poses.astype(np.float32).astype(np.float64)
  src = rng.integers(0, n, e)
  dst = (src + rng.integers(1, n, e)) % n
  meas, info = [], []
  for a, b in zip(src, dst):
    m = _between(poses[a], poses[b]) + rng.normal(0.0, [0.5, 0.5, 0.8])
    meas.append(np.asarray(m, np.float32).astype(np.float64))
    info.append(np.asarray(_information(rng, rng.uniform(0.05, 1.0, 3)), np.float32))
  return Graph(poses, src, dst, meas, np.asarray(info, np.float64))


@EAGER_AND_JIT
def test_between_error_and_cost_match_gtsam(transform):
  graph = _random_edges(np.random.default_rng(2), 30, 60)
  poses, node_valid, edges = arrays(graph)
  errors = np.asarray(transform(jax.vmap(opt.between_error))(poses[edges.src], poses[edges.dst],
                                                              edges.measured))
  factors, values = gtsam_graph(graph)
  # each factor's ½ rᵀ Ω r: the cost with that edge alone valid
  alone = np.asarray(transform(jax.vmap(lambda valid: opt.cost(poses, edges.replace(
      valid=valid))))(jnp.eye(len(graph.src), dtype=bool)))
  for k in range(factors.size()):
    f = factors.at(k)
    np.testing.assert_allclose(errors[k], f.unwhitenedError(values), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(alone[k], f.error(values), rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(transform(opt.cost)(poses, edges), factors.error(values), rtol=1e-5)
  # Invalid edges count for nothing, whatever they hold.
  padded_poses, _, padded = arrays(graph, 40, 90, seed=3)
  np.testing.assert_allclose(transform(opt.cost)(padded_poses, padded), factors.error(values),
                             rtol=1e-5)


# --- optimisation against GTSAM ------------------------------------------------------------------


@EAGER_AND_JIT
def test_square_loop_matches_gtsam(transform):
  graph = square_graph()  # 60 keyframes, 20 loop closures, at capacity
  result = (_optimise if transform is jax.jit else opt.optimise)(*arrays(graph))
  assert_matches_gtsam(result, graph)
  assert float(result.final_cost) < 0.05 * float(result.initial_cost)


def test_manhattan_grid_world_matches_gtsam():
  graph = grid_graph()
  assert graph.n == 120 and len(graph.src) - graph.n > 40  # plenty of loops
  assert_matches_gtsam(_optimise(*arrays(graph, N_CAP, E_CAP)), graph)


def test_gtsam_w100_dataset_matches_gtsam():
  """w100.graph ships with the GTSAM wheel (``findExampleDataFile``); so do w10000.graph,
  noisyToyGraph.txt and others, but not Intel or M3500."""
  graph = w100_graph()
  assert graph.n == 100 and len(graph.src) == 300
  assert_matches_gtsam(_optimise(*arrays(graph, N_CAP, E_CAP)), graph)


def _broken_square():
  """The square loop without the odometry edge 29 → 30: the rest of the second lap and the third
  hang on loop closures alone."""
  graph = square_graph(seed=4)
  keep = ~((graph.src == 29) & (graph.dst == 30))
  return Graph(graph.init, graph.src[keep], graph.dst[keep], graph.measured[keep],
               graph.information[keep])


def test_broken_chain_reaches_gtsams_optimum():
  graph = _broken_square()
  assert_matches_gtsam(_optimise(*arrays(graph, N_CAP, E_CAP)), graph)


def test_loops_past_the_preconditioners_capacity_reach_gtsams_optimum():
  """Room for 8 of the 20 loops: the other 12 are left to the conjugate gradients (given more
  iterations than by default)."""
  graph = _broken_square()
  result = _optimise(*arrays(graph), loop_capacity=8, cg_max_iterations=50, max_iterations=40)
  assert_matches_gtsam(result, graph)
  assert int(result.linear_iterations) > 10 * int(result.iterations)


# --- padding, vmap, anchors ----------------------------------------------------------------------


def test_noise_free_graph_returns_the_truth():
  graph = square_graph(seed=5, noise=0.0)
  start = graph.init.copy()
  start[1:] += np.random.default_rng(6).normal(0.0, 0.05, start[1:].shape)
  moved = Graph(start, graph.src, graph.dst, graph.measured, graph.information)
  result = _optimise(*arrays(moved, N_CAP, E_CAP))
  assert bool(result.converged)
  assert_poses_close(result.poses[:graph.n], graph.init, tol=2e-5)
  assert float(result.final_cost) < 1e-6


def test_padding_changes_nothing_and_unused_rows_stay_put():
  graph = grid_graph(seed=7, n=60)
  tight = _optimise(*arrays(graph))  # capacity = the graph
  poses, node_valid, edges = arrays(graph, N_CAP, E_CAP, seed=8)
  padded = _optimise(poses, node_valid, edges)
  assert bool(tight.converged) and bool(padded.converged)
  assert_poses_close(padded.poses[:graph.n], tight.poses, tol=2e-5)
  np.testing.assert_allclose(padded.final_cost, tight.final_cost, rtol=SAME_COST_RTOL)
  np.testing.assert_array_equal(padded.poses[graph.n:], poses[graph.n:])  # NaN and all
  np.testing.assert_array_equal(padded.poses[0], poses[0])  # the anchor


def test_vmap_over_graphs_equals_one_at_a_time():
  graphs = [square_graph(seed=9), grid_graph(seed=10, n=60), square_graph(seed=11, laps=2)]
  batch = [arrays(g, 64, 128, seed=s) for s, g in enumerate(graphs)]
  stacked = jax.tree.map(lambda *x: jnp.stack(x), *batch)
  together = jax.jit(jax.vmap(opt.optimise))(*stacked)
  for b, single in enumerate(batch):
    alone = _optimise(*single)
    assert bool(together.converged[b]) and bool(alone.converged)
    np.testing.assert_allclose(together.poses[b], alone.poses, atol=2e-5, equal_nan=True)
    np.testing.assert_allclose(together.final_cost[b], alone.final_cost, rtol=SAME_COST_RTOL)


def test_vmapped_program_calls_no_lapack_kernel():
  """The dense pieces are XLA operations: no LAPACK call, batched or not (jaxlib 0.10's batched
  kernels deadlock the engine under vmap on a multi-device CPU)."""
  batch = [arrays(square_graph(seed=s), 64, 96) for s in range(2)]
  stacked = jax.tree.map(lambda *x: jnp.stack(x), *batch)
  text = jax.jit(jax.vmap(opt.optimise)).lower(*stacked).as_text()
  assert "while" in text  # the text is the optimiser's
  assert not re.findall(r"custom_call @(lapack_\w+)", text)


# --- the dense pieces ----------------------------------------------------------------------------


@EAGER_AND_JIT
def test_block_tridiagonal_solve_matches_numpy(transform):
  rng = np.random.default_rng(12)
  n = 7
  a = rng.normal(size=(3 * n, 3 * n))
  band = np.abs(np.arange(3 * n)[:, None] // 3 - np.arange(3 * n)[None, :] // 3) <= 1
  a = np.where(band, a @ a.T, 0.0) + 3 * n * np.eye(3 * n)
  diag = np.stack([a[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(n)])
  upper = np.stack([np.zeros((3, 3))] + [a[3 * i - 3:3 * i, 3 * i:3 * i + 3] for i in range(1, n)])
  b = rng.normal(size=(n, 3, 2))

  @transform
  def solve(diag, upper, b):
    return opt.tridiagonal_solve(opt.tridiagonal_factor(diag, upper), b)

  got = solve(jnp.asarray(diag, jnp.float32), jnp.asarray(upper, jnp.float32),
              jnp.asarray(b, jnp.float32))
  want = np.linalg.solve(a, b.reshape(3 * n, 2)).reshape(n, 3, 2)
  np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)


@EAGER_AND_JIT
def test_blocked_cholesky_matches_numpy(transform):
  rng = np.random.default_rng(13)
  for n in (5, 100):  # under and over the block size (64)
    a = rng.normal(size=(n, n))
    a = a @ a.T / n + np.eye(n)
    r = rng.normal(size=n)
    chol = transform(opt._cholesky)(jnp.asarray(a, jnp.float32))
    np.testing.assert_allclose(np.asarray(chol.low)[:n, :n], np.linalg.cholesky(a), atol=2e-5)
    x = transform(opt._cholesky_solve)(chol, jnp.asarray(r, jnp.float32))
    np.testing.assert_allclose(x, np.linalg.solve(a, r), rtol=1e-4, atol=1e-5)


def test_pcg_matches_numpy():
  rng = np.random.default_rng(14)
  a = rng.normal(size=(40, 40))
  a = a @ a.T + np.diag(rng.uniform(1, 100, 40))
  b = rng.normal(size=40)
  diag = np.diag(a)
  x, k = jax.jit(lambda a, b, d: opt.pcg(lambda v: a @ v, lambda v: v / d, b, 1e-6, 200))(
      jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32), jnp.asarray(diag, jnp.float32))
  np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-3, atol=1e-5)
  assert 0 < int(k) < 200


# --- a bigger graph ------------------------------------------------------------------------------


def exploration_graph(seed=0, n=500, loops=100):
  """A random walk with persistent heading in a 20 m box, a keyframe every 0.5 m, and ``loops``
  closures between keyframes within 1.5 m and at least 20 apart."""
  rng = np.random.default_rng(seed)
  truth = [np.array([0.0, 0.0, 0.0])]
  for _ in range(1, n):
    heading = truth[-1][2] + rng.normal(0.0, 0.3)
    step = 0.5 * np.array([math.cos(heading), math.sin(heading)])
    if np.any(np.abs(truth[-1][:2] + step) > 10):
      heading, step = heading + np.pi, -step
    truth.append(np.array([*(truth[-1][:2] + step), _wrap(heading)]))
  xy = np.array(truth)[:, :2]
  near = np.linalg.norm(xy[:, None] - xy[None], axis=-1) < 1.5
  candidates = [(i, j) for j in range(n) for i in range(j - 20) if near[i, j]]
  pairs = [candidates[k] for k in rng.choice(len(candidates), loops, replace=False)]
  return _simulate(truth, pairs, rng, np.array([0.05, 0.05, 0.02]), np.array([0.03, 0.03, 0.01]))


@pytest.mark.slow  # ~8 s: a compile at N = 512, E = 640 and GTSAM on 600 factors
def test_chain_of_500_with_100_loops_matches_gtsam():
  graph = exploration_graph()
  assert_matches_gtsam(_optimise(*arrays(graph, 512, 640)), graph)
