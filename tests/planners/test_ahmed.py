"""Ahmed et al. 2024 (ahmed) and AGS (ags) kernels against plain NumPy readings of the paper and of
the authors' code, and the hallucinated U1 against the log-det of the rebuilt graph (NetworkX)."""

import functools
import math

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest

from jaxplore import posegraph
from jaxplore.config import make_params
from jaxplore.planners import ahmed, base
from tests.conftest import EAGER_AND_JIT


# --- path entropy --------------------------------------------------------------------------------


def greedy_line(start, end):
  """The 4-connected walk from start to end that takes, at each step, the row or column move
  whose cell centre is nearer the segment (ties: the row move)."""
  (r0, c0), (r1, c1) = start, end
  dr, dc = r1 - r0, c1 - c0
  sr, sc = int(np.sign(dr)), int(np.sign(dc))
  cells = [(r0, c0)]
  a = b = 0  # row and column moves made
  while a < abs(dr) or b < abs(dc):
    # Distance to the segment is proportional to |a·|dc| − b·|dr||.
    row_err = abs((a + 1) * abs(dc) - b * abs(dr)) if a < abs(dr) else math.inf
    col_err = abs(a * abs(dc) - (b + 1) * abs(dr)) if b < abs(dc) else math.inf
    if row_err <= col_err:
      a += 1
    else:
      b += 1
    cells.append((r0 + sr * a, c0 + sc * b))
  return cells


LINE = jax.jit(ahmed.line_cells, static_argnums=2)


def test_line_cells_match_a_greedy_walk():
  rng = np.random.default_rng(0)
  pairs = [((3, 3), (3, 9)), ((2, 8), (9, 8)), ((0, 0), (5, 5)), ((7, 1), (2, 12))]
  pairs += [(tuple(rng.integers(0, 20, 2)), tuple(rng.integers(0, 20, 2))) for _ in range(30)]
  for start, end in pairs:
    cells, count = LINE(jnp.asarray(start, jnp.int32), jnp.asarray(end, jnp.int32), 40)
    want = greedy_line(start, end)
    assert int(count) == len(want)
    np.testing.assert_array_equal(np.asarray(cells)[: len(want)], np.asarray(want))
    steps = np.abs(np.diff(np.asarray(want), axis=0)).sum(axis=1)
    assert np.all(steps == 1)


def entropy_bits(p):
  return -(p * math.log2(p) + (1 - p) * math.log2(1 - p))


@EAGER_AND_JIT
def test_path_entropy_matches_a_numpy_reading_of_eq_4_5(transform):
  # A hand-made belief: unknown cells marked U, known ones '.' or '#'.
  rows = ["..........",
          "...UUU....",
          "...UUU..#.",
          "..........",
          "UUUUUUUUUU",
          "......#..."]
  unknown = np.array([[ch == "U" for ch in row] for row in rows])
  fn = transform(functools.partial(ahmed.path_entropy, n_max=16))
  for start, end, p_unk, p_known in [((0, 0), (0, 9), 0.1, 0.45), ((0, 0), (5, 9), 0.1, 0.45),
                                     ((2, 4), (4, 1), 0.2, 0.4), ((3, 3), (3, 3), 0.1, 0.45)]:
    cells = greedy_line(start, end)
    bits = [entropy_bits(p_unk) if unknown[r, c] else entropy_bits(p_known) for r, c in cells]
    want = sum(bits) / len(cells)
    got = fn(jnp.asarray(unknown), jnp.asarray(start, jnp.int32), jnp.asarray(end, jnp.int32),
             jnp.float32(p_unk), jnp.float32(p_known))
    np.testing.assert_allclose(float(got), want, rtol=1e-6)
  # All unknown: 1 − E/K = 1 − H₂(0.1) ≈ 0.531; all known: 1 − H₂(0.45) ≈ 0.0072.
  assert entropy_bits(0.1) == pytest.approx(0.469, abs=1e-3)


# --- neighbourhoods and candidates ---------------------------------------------------------------


def test_disc_counts_match_numpy():
  rng = np.random.default_rng(1)
  masks = rng.random((2, 15, 17)) < 0.4
  fn = jax.jit(ahmed.disc_counts, static_argnums=3)
  for cell, radius in [((7, 8), 3.0), ((0, 0), 2.5), ((14, 16), 4.0), ((3, 12), 1.0)]:
    n, counts = fn(jnp.asarray(masks), jnp.asarray(cell, jnp.int32), jnp.float32(radius), 4)
    r, c = np.mgrid[:15, :17]
    disc = (r - cell[0]) ** 2 + (c - cell[1]) ** 2 <= radius**2
    assert int(n) == disc.sum()
    np.testing.assert_array_equal(np.asarray(counts), [(m & disc).sum() for m in masks])


def test_tile_clusters_group_frontier_cells_by_square():
  rng = np.random.default_rng(2)
  frontier = rng.random((23, 31)) < 0.15
  got = jax.jit(ahmed.tile_clusters, static_argnums=(1, 2))(jnp.asarray(frontier), 5, 12)
  r, c = np.nonzero(frontier)
  tiles = {}
  for i, j in zip(r, c):
    tiles.setdefault((i // 5, j // 5), []).append((i, j))
  order = sorted(tiles, key=lambda t: (-len(tiles[t]), t[0] * 7 + t[1]))[:12]
  np.testing.assert_array_equal(np.asarray(got.size)[: len(order)], [len(tiles[t]) for t in order])
  for k, t in enumerate(order):
    np.testing.assert_allclose(np.asarray(got.centroid)[k], np.mean(tiles[t], axis=0), rtol=1e-5)
    ids = np.asarray(got.ids)
    assert all(ids[i, j] == k for i, j in tiles[t])
  assert int(got.count) == len(tiles)


def test_u1_and_digit_weight():
  n = jnp.int32(37)
  np.testing.assert_allclose(float(ahmed.u1_from_logdet(jnp.float32(120.0), n)),
                             37 ** (1 / 37) * math.exp(120 / 37), rtol=1e-6)
  for u1, rho in [(0.4, 10.0), (1.0, 10.0), (9.99, 10.0), (57.0, 100.0), (3086.4, 1e4),
                  (12345.0, 1e5)]:
    assert float(ahmed.digits_weight(jnp.float32(u1))) == pytest.approx(rho)


# --- hallucinated graph: low-rank U1 vs the rebuilt graph ----------------------------------------

H, W, RES = 30, 40, 0.1
W_AHMED = dict(ahmed.DEFAULTS)


def world_and_graph():
  """A belief with unknown and occupied patches, and a pose graph that went out and came back."""
  unknown = np.zeros((H, W), bool)
  unknown[:, 28:] = True
  unknown[20:, 10:18] = True
  occupied = np.zeros((H, W), bool)
  occupied[0, :] = occupied[:, 0] = True
  occupied[12:14, 5:20] = True
  n = 40
  t = np.arange(n)
  x = np.where(t < 20, 0.5 + 0.1 * t, 0.5 + 0.1 * (39 - t))
  y = np.where(t < 20, 0.6, 0.9)
  theta = np.where(t < 20, 0.0, np.pi)
  graph = posegraph.init(jnp.zeros(3), 48, 8)
  poses = np.zeros((48, 3), np.float32)
  poses[:n] = np.stack([x, y, theta], -1)
  chain_w = np.zeros(48, np.float32)
  chain_w[1:n] = np.random.default_rng(3).uniform(2000, 3500, n - 1)
  loops = np.zeros((8, 2), np.int32)
  loops[:3] = [[10, 29], [5, 34], [2, 37]]
  loop_w = np.zeros(8, np.float32)
  loop_w[:3] = 3086.4
  graph = graph.replace(poses=jnp.asarray(poses), chain_w=jnp.asarray(chain_w),
                        loops=jnp.asarray(loops), loop_w=jnp.asarray(loop_w), n_nodes=jnp.int32(n),
                        n_loops=jnp.int32(3))
  return unknown, occupied, graph


def numpy_hallucinated_u1(graph, unknown, occupied, node_cells, robot_pose, robot_cell, w,
                          sm_sigma):
  """The authors' hallucination rules read plainly, the whole graph rebuilt, U1 by slogdet."""
  n = int(graph.n_nodes)
  poses = np.asarray(graph.poses, np.float64)
  g = nx.Graph()
  g.add_nodes_from(range(n))
  for k in range(1, n):
    g.add_edge(k - 1, k, weight=float(graph.chain_w[k]))
  for (a, b), lw in zip(np.asarray(graph.loops)[: int(graph.n_loops)], np.asarray(graph.loop_w)):
    g.add_edge(int(a), int(b), weight=float(lw))
  odom_cov = np.array([[w["odom_var_xy"], w["odom_cov_xy"], 0],
                       [w["odom_cov_xy"], w["odom_var_xy"], 0],
                       [0, 0, w["odom_var_theta"]]])
  fim = np.linalg.inv(odom_cov) / 2
  dopt = np.exp(np.mean(np.log(np.linalg.eigvalsh(fim))))
  r, c = np.mgrid[:H, :W]
  prev_xy, prev_id = poses[n - 1, :2], n - 1
  closed = 0
  for p, cell in enumerate(node_cells):
    xy = np.asarray(robot_pose[:2]) + (np.asarray(cell) - np.asarray(robot_cell))[::-1] * RES
    theta = math.atan2(xy[1] - prev_xy[1], xy[0] - prev_xy[0])
    disc = (r - cell[0]) ** 2 + (c - cell[1]) ** 2 <= (w["info_radius"] / RES) ** 2
    u = (unknown & disc).sum() / disc.sum()
    occ = (occupied & disc).sum() / disc.sum()
    node = n + p
    g.add_edge(prev_id, node, weight=dopt * (1 + u))
    if occ > w["halluc_structure"]:
      best, best_d = None, math.inf
      for j in range(n):
        if j >= node - w["halluc_loop_age"]:
          continue
        d = math.hypot(*(poses[j, :2] - xy))
        turn = abs(math.remainder(poses[j, 2] - theta, 2 * math.pi))
        if d <= w["halluc_loop_radius"] and 1 - turn / math.pi > w["halluc_overlap"] and d < best_d:
          best, best_d = j, d
      if best is not None:
        loop_diff = (node - best) / (node + 1)
        g.add_edge(best, node, weight=w["lc_scale"] * loop_diff * occ / sm_sigma**2)
        closed += 1
    prev_xy, prev_id = xy, node
  lap = nx.laplacian_matrix(g, nodelist=sorted(g.nodes), weight="weight").toarray()
  sign, logdet = np.linalg.slogdet(lap[1:, 1:])
  assert sign > 0
  total = g.number_of_nodes()
  return total ** (1 / total) * math.exp(logdet / total), closed


@pytest.mark.parametrize("transform", [jax.jit], ids=["jit"])
def test_hallucinated_u1_equals_u1_of_the_rebuilt_graph(transform):
  unknown, occupied, graph = world_and_graph()
  robot = base.RobotView(pose=jnp.asarray([1.05, 0.85, 0.0]), cell=jnp.asarray([8, 10], jnp.int32),
                         cov=jnp.eye(3))
  params = make_params(planner=W_AHMED)
  w = {k: float(v) for k, v in params.planner.items()}
  masks = jnp.asarray(np.stack([unknown, occupied]))

  def u1(node_cells, node_valid):
    parts = posegraph.logdet_parts(graph)
    odom_cov = jnp.array([[0.04, 0.001, 0.0], [0.001, 0.04, 0.0], [0.0, 0.0, 0.008]])
    c = ahmed._Context(graph, parts, 0.5 * posegraph.d_optimality_of_covariance(odom_cov),
                       1.0 / params.scan_match_sigma**2, masks, 20, RES, robot,
                       ahmed._weights(params))
    logdet, n = ahmed.candidate_logdet(c, node_cells, node_valid)
    return ahmed.u1_from_logdet(logdet, n)

  fn = transform(u1)
  loops = []
  cases = [
      [(8, 12), (8, 20), (9, 27)],  # out into the unknown along the corridor
      [(8, 6), (7, 3)],  # back over the start: structure (walls) and old keyframes close loops
      [(10, 4)],
      [(25, 38)],  # far from every keyframe, no structure around: no loop
      [(8, 12), (6, 8), (7, 4), (9, 2), (8, 1)],
  ]
  for cells in cases:
    padded = np.zeros((6, 2), np.int32)
    padded[: len(cells)] = cells
    valid = np.arange(6) < len(cells)
    got = float(fn(jnp.asarray(padded), jnp.asarray(valid)))
    want, closed = numpy_hallucinated_u1(graph, unknown, occupied, cells, np.asarray(robot.pose),
                                         (8, 10), w, float(params.scan_match_sigma))
    np.testing.assert_allclose(got, want, rtol=2e-4)
    loops.append(closed)
  # Both the pendant-only and the low-rank paths ran.
  assert min(loops) == 0 and max(loops) >= 2, loops


# --- whole utility (Eq 9) ------------------------------------------------------------------------


def test_candidates_filters_and_eq_9_from_their_parts():
  """Every candidate's utility is U1 + (1 − E/K)·10^β + exp(−λ·d), with E/K the NumPy path
  entropy of its line; the filters of the authors' code hold for every candidate; the plan goes
  to the best one. (The grid, context and settings are the conformance test's, so both share
  one compiled planner.)"""
  from jaxplore import mapping
  from jaxplore.planners.base import PlannerContext
  h, w = 24, 32
  state = np.full((h, w), 2)  # 0 free, 1 occupied, 2 unknown
  state[2:20, 2:22] = 0
  state[2:20, 2] = state[2, 2:22] = state[19, 2:22] = 1
  state[8:12, 10:14] = 2  # an unknown pocket inside the known room
  state[14, 5:12] = 1
  logodds = np.where(state == 0, -3.0, np.where(state == 1, 3.0, 0.0)).astype(np.float32)
  params = make_params(res=0.1, r_robot=0.15, r_max=2.0, planner=W_AHMED)
  free, occ, unk = mapping.classify(jnp.asarray(logodds), params)
  inflated = mapping.inflate(occ, 1.5, 2)
  robot = base.RobotView(pose=jnp.asarray([0.65, 0.55, 0.0]), cell=jnp.asarray([5, 6], jnp.int32),
                         cov=jnp.eye(3))
  graph = posegraph.init(robot.pose, 16, 8)
  view = base.BeliefView(logodds=jnp.asarray(logodds), free=free, occupied=occ,
                         unknown=unk, inflated=inflated, traversable=free & ~inflated,
                         frontier=mapping.frontier(free, unk, occ),
                         blacklist=jnp.zeros((h, w), bool), pose_graph=graph)
  settings = ahmed.Settings()
  ctx = PlannerContext(height=h, width=w, res=0.1, path_capacity=64, max_inflation_cells=2,
                       max_steps=400, settings=settings)
  plan, found, keep, utility, u1, _ = jax.tree.map(np.asarray, ahmed.plan_and_scores(
      ctx, view, robot, params, jax.random.PRNGKey(0), graph, settings, True))
  assert keep.sum() >= 3
  best = int(np.argmax(utility))
  assert plan.valid and np.all(plan.goal == found.goal[best])
  np.testing.assert_allclose(plan.gain, utility[best], rtol=1e-6)
  r, c = np.mgrid[:h, :w]
  for k in np.nonzero(found.valid)[0]:
    goal = found.goal[k]
    disc = (r - goal[0]) ** 2 + (c - goal[1]) ** 2 <= 10.0**2
    unknown_area = (np.asarray(unk) & disc).sum() * 0.01
    dist = math.hypot(*(goal - np.array([5, 6]))) * 0.1
    want_keep = (not np.asarray(inflated)[goal[0], goal[1]] and unknown_area >= 0.45
                 and dist >= 0.25)
    assert keep[k] == want_keep
    if not keep[k]:
      assert utility[k] == -np.inf
      continue
    cells = greedy_line((5, 6), tuple(goal))
    e = np.mean([entropy_bits(0.1) if np.asarray(unk)[i, j] else entropy_bits(0.45)
                 for i, j in cells])
    rho = 10.0 ** (math.floor(math.log10(u1[k])) + 1 if u1[k] >= 1 else 1)
    np.testing.assert_allclose(utility[k], u1[k] + (1 - e) * rho + math.exp(-0.6 * dist), rtol=1e-5)


@pytest.mark.parametrize("planner, params, says", [
    ("ahmed", {"p_known": 1.0}, "planner 'ahmed': weight p_known must be in (0, 1), got 1"),
    ("ahmed", {"lambda": -0.5}, "planner 'ahmed': weight lambda must be >= 0, got -0.5"),
    ("ags", {"even": 0.5}, "planner 'ags': weight even must be"),
    ("ags", {"halluc_spacing": 0.0}, "planner 'ags': weight halluc_spacing must be > 0, got 0"),
    ("ahmed", {"max_new_nodes": 0}, "planner 'ahmed': setting max_new_nodes must be"),
    ("ags", {"cluster_m": -1.0}, "planner 'ags': setting cluster_m must be > 0, got -1"),
    ("ahmed", {"filter_radius": 2.5}, "ahmed: filter_radius must be in (0, 2.0] m"),
    ("ags", {"odom_cov_xy": 0.05}, "(|odom_cov_xy| < odom_var_xy), got 0.05 and 0.04")])
def test_a_weight_or_setting_out_of_range_is_refused_on_resolving(planner, params, says):
  """The declared ranges (Weights, AgsWeights, Settings) and the checks left to validate (the
  radii against Settings.disc_m, the covariance) refuse a bad value by name before compute."""
  from jaxplore.errors import ConfigError
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec
  with pytest.raises(ConfigError) as refused:
    resolve(RunSpec.create(world="lab", planner=planner, robots=1, params=params))
  assert says in str(refused.value)
