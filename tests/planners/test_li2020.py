"""Li et al. 2020's planner against oracles: NumPy Eq 4, SciPy Dijkstra, a NumPy loop of Eq 17,
the exact union of swept cells (Eq 20)."""

import dataclasses
import functools
import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from jaxplore import mapping
from jaxplore.config import make_params
from jaxplore.graph.dijkstra import extract_path, shortest_paths
from jaxplore.planners import base, li2020

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
from bench_visible_gains import visible_gains_one_loop  # noqa: E402  (visible_gains at 0c98c96)

H, W = 26, 34
# R_e = 3 cells (3 * 0.1 m / 0.1 m: 3.0000000000000004, the nearest a float gets).
SETTINGS = li2020.Settings(r_e=3 * 0.1)
CONFIG = base.PlannerContext(height=H, width=W, res=0.1, max_inflation_cells=2, path_capacity=128,
                             settings=SETTINGS)


# Jitted once per static context and shared by the tests (compiles dominate this file's time).
TREE = jax.jit(li2020.tree_quantities, static_argnums=0)
PLAN = jax.jit(li2020.plan_li2020, static_argnums=0)
ROAD_MARKS = dataclasses.replace(CONFIG, settings=dataclasses.replace(SETTINGS, road_mark_m=0.5))


def weights(**kw):
  w = dict(li2020.DEFAULTS, **kw)
  return {k: jnp.float32(v) for k, v in w.items()}


def belief(seed=0):
  """A belief with free rooms, a wall, an unknown region and a patchy entropy map."""
  rng = np.random.default_rng(seed)
  state = np.zeros((H, W), int)  # 0 free, 1 occupied, 2 unknown
  state[0, :] = state[-1, :] = state[:, 0] = state[:, -1] = 1
  state[10, 5:25] = 1
  state[:, 26:] = 2
  state[18:22, 8:12] = 1
  l = np.where(state == 0, -3.0, np.where(state == 1, 3.0, 0.0)).astype(np.float32)
  entropy = np.where(state == 2, math.log(2), rng.uniform(0.1, 0.69, (H, W))).astype(np.float32)
  entropy[3:8, 3:12] = 0.05  # a well-mapped patch
  return state, l, entropy


def make_view(l, entropy, params):
  free, occ, unk = mapping.classify(jnp.asarray(l), params)
  inflated = mapping.inflate(occ, params.r_robot / CONFIG.res, CONFIG.max_inflation_cells)
  return base.BeliefView(logodds=jnp.asarray(l), free=free, occupied=occ,
                         unknown=unk, inflated=inflated, traversable=free & ~inflated,
                         frontier=mapping.frontier(free, unk, occ), blacklist=jnp.zeros((H, W), bool))


def memory_for(ctx, params, entropy):
  """A robot's memory whose entropy map is ``entropy`` (what li2020 plans on)."""
  return dict(li2020.init_memory(ctx, params), entropy_map=jnp.asarray(entropy))


def params_for(**planner):
  return make_params(r_robot=0.2, planner=dict(li2020.DEFAULTS, **planner))


def unscaled(params):
  """Li's V_n of Eq 16 as printed (σ = 1: the std of a step is its length), so that Σ grows
  within the few metres of a hand-made map."""
  return params.replace(odom_noise_d=jnp.float32(1.0), odom_noise_phi=jnp.float32(1.0))


def robot_at(cell, theta=0.3, cov=1e-4):
  return base.RobotView(pose=jnp.asarray([0.0, 0.0, theta], jnp.float32), cell=jnp.asarray(cell, jnp.int32),
                        cov=jnp.eye(3, dtype=jnp.float32) * cov)


def test_boundaries_match_numpy_reading_of_eq4():
  params = params_for()
  _, l, entropy = belief()
  view = make_view(l, entropy, params)
  tau = 0.4
  b_e, b_g = li2020.boundaries(view, jnp.asarray(entropy), jnp.float32(tau))
  trav = np.asarray(view.traversable)
  high = entropy > tau
  # conv of `high` with a 3x3 kernel of ones (outside counts as high: no boundary at the border)
  conv = ndimage.convolve(high.astype(int), np.ones((3, 3), int), mode="constant", cval=1)
  np.testing.assert_array_equal(np.asarray(b_e), trav & high & (conv < 9))
  blocked = np.asarray(view.inflated) & ~trav
  conv_g = ndimage.convolve(blocked.astype(int), np.ones((3, 3), int), mode="constant", cval=1)
  np.testing.assert_array_equal(np.asarray(b_g), trav & (conv_g > 0))


def scipy_graph(node_cost):
  h, w = node_cost.shape
  idx = np.arange(h * w).reshape(h, w)
  rows, cols, data = [], [], []
  for di in (-1, 0, 1):
    for dj in (-1, 0, 1):
      if (di, dj) == (0, 0):
        continue
      for i in range(h):
        for j in range(w):
          ii, jj = i + di, j + dj
          if 0 <= ii < h and 0 <= jj < w and np.isfinite(node_cost[ii, jj]):
            rows.append(idx[i, j]); cols.append(idx[ii, jj])
            data.append((math.sqrt(2) if di and dj else 1.0) * node_cost[ii, jj])
  # explicit zeros must survive: SciPy drops structural zeros, so add a tiny epsilon
  data = np.asarray(data) + 0.0
  return coo_matrix((np.where(data == 0, 1e-30, data), (rows, cols)), shape=(h * w, h * w)).tocsr()


@pytest.mark.parametrize("k1", [0.0, 0.2])
def test_weighted_dijkstra_matches_scipy_with_zero_weights(k1):
  params = params_for()
  _, l, entropy = belief(1)
  view = make_view(l, entropy, params)
  b_e, b_g = li2020.boundaries(view, jnp.asarray(entropy), jnp.float32(0.4))
  cost = np.asarray(li2020.edge_weights(view, b_e, b_g, jnp.float32(k1), jnp.float32(0.6)))
  if k1 == 0.0:
    assert np.any(cost == 0.0)
  start = (5, 15)
  sp = shortest_paths(jnp.asarray(cost), jnp.asarray(start, jnp.int32))
  ref = dijkstra(scipy_graph(cost), indices=start[0] * W + start[1]).reshape(H, W)
  ref[start] = 0.0
  np.testing.assert_allclose(np.asarray(sp.dist), ref, rtol=1e-5, atol=1e-5)


def numpy_cov_along(cells, theta0, cov0, res, sigma_d, sigma_phi, spacing=1):
  """Plain loop of Li Eq 12, 16, 17 along waypoints: δd = each step's length; δφ = the turn
  between consecutive chords of road-mark points every ``spacing`` waypoints (the first chord
  turns from ``theta0``), 0 between road-mark points."""
  cov = np.array(cov0, np.float64)
  covs = [cov]
  xy = lambda i: np.array([cells[i][1] * res, cells[i][0] * res])
  chord = lambda i, j: math.atan2(*(xy(j) - xy(i))[::-1])
  for i in range(1, len(cells)):
    (xa, ya), (xb, yb) = xy(i - 1), xy(i)
    dphi = 0.0
    if i % spacing == 0:
      previous = chord(i - 2 * spacing, i - spacing) if i >= 2 * spacing else theta0
      turn = chord(i - spacing, i) - previous
      dphi = math.atan2(math.sin(turn), math.cos(turn))
    dd = math.hypot(xb - xa, yb - ya)
    j1 = np.array([[1, 0, ya - yb], [0, 1, xb - xa], [0, 0, 1]])
    v = np.diag([(sigma_d * dd) ** 2, (sigma_d * dd) ** 2, (sigma_phi * dphi) ** 2])
    cov = j1 @ cov @ j1.T + v  # J2 V J2ᵀ = V: V's x and y variances are equal
    covs.append(cov)
  return covs


@pytest.mark.parametrize("road_mark_m", [0.0, 0.5])
def test_tree_covariance_matches_numpy_loop_of_eq17(road_mark_m):
  params = params_for()
  params = params.replace(odom_noise_d=jnp.float32(0.5), odom_noise_phi=jnp.float32(0.3))
  _, l, entropy = belief(2)
  view = make_view(l, entropy, params)
  b_e, b_g = li2020.boundaries(view, jnp.asarray(entropy), jnp.float32(0.4))
  cost = li2020.edge_weights(view, b_e, b_g, jnp.float32(0.2), jnp.float32(0.6))
  robot = robot_at((5, 15), theta=0.7, cov=2e-3)
  sp = shortest_paths(cost, robot.cell)
  ctx = ROAD_MARKS if road_mark_m else dataclasses.replace(CONFIG, settings=dataclasses.replace(SETTINGS, road_mark_m=0.0))
  spacing = li2020.road_mark_cells(ctx)
  assert spacing == (1 if road_mark_m == 0 else 5)
  gains = li2020.cell_gains(view, jnp.asarray(entropy), params, jnp.float32(math.log(2)), li2020.r_e_cells(CONFIG))
  sums, cov, _ = TREE(ctx, view, robot, params, sp.pred, gains)
  rng = np.random.default_rng(0)
  reachable = np.argwhere(np.isfinite(np.asarray(sp.dist)))
  for goal in reachable[rng.choice(len(reachable), 12, replace=False)]:
    cells, n = extract_path(sp.pred, jnp.asarray(goal, jnp.int32), CONFIG.path_capacity)
    cells = np.asarray(cells)[: int(n)]
    ref = numpy_cov_along(cells, 0.7, np.asarray(robot.cov), CONFIG.res, 0.5, 0.3, spacing)[-1]
    got = np.asarray(cov[goal[0] * W + goal[1]])
    np.testing.assert_allclose(got, ref, rtol=2e-3, atol=1e-7)
    # path length is the sum of step lengths
    steps = np.linalg.norm(np.diff(cells, axis=0), axis=1).sum() * CONFIG.res
    np.testing.assert_allclose(float(sums[goal[0] * W + goal[1], 2]), steps, rtol=1e-5, atol=1e-6)


def test_path_gain_counts_each_swept_cell_once():
  rng = np.random.default_rng(3)
  gain = jnp.asarray(rng.uniform(0, 1, (H, W)), jnp.float32)
  forward = np.array([[10, c] for c in range(5, 20)])
  back_and_forth = np.concatenate([forward, forward[::-1], forward])
  pad = lambda c: jnp.asarray(np.pad(c, ((0, 64 - len(c)), (0, 0))), jnp.int32)
  g1 = float(li2020.path_gain(gain, pad(forward), len(forward), 3.0))
  g2 = float(li2020.path_gain(gain, pad(back_and_forth), len(back_and_forth), 3.0))
  assert g1 == pytest.approx(g2)
  # and equals a NumPy union of discs
  covered = np.zeros((H, W), bool)
  ii, jj = np.mgrid[0:H, 0:W]
  for r, c in forward:
    covered |= (ii - r) ** 2 + (jj - c) ** 2 <= 9.0
  assert g1 == pytest.approx(float(np.asarray(gain)[covered].sum()), rel=1e-5)


def test_tree_gain_equals_exact_union_on_open_ground():
  params = params_for()
  state, l, entropy = belief(4)
  l[:, :] = -3.0
  l[0, :] = l[-1, :] = l[:, 0] = l[:, -1] = 3.0
  view = make_view(l, entropy, params)
  cost = jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32)
  robot = robot_at((12, 15))
  sp = shortest_paths(cost, robot.cell)
  gains = li2020.cell_gains(view, jnp.asarray(entropy), params, jnp.float32(math.log(2)), li2020.r_e_cells(CONFIG))
  sums, _, _ = TREE(CONFIG, view, robot, params, sp.pred, gains)
  for goal in [(12, 25), (4, 15), (20, 5), (5, 28)]:
    cells, n = extract_path(sp.pred, jnp.asarray(goal, jnp.int32), CONFIG.path_capacity)
    exact = float(li2020.path_gain(gains[0], cells, n, li2020.r_e_cells(CONFIG)))
    assert float(sums[goal[0] * W + goal[1], 0]) == pytest.approx(exact, rel=1e-4)


# Op by op once (select only changes a traced weight), compiled with both selection rules.
@pytest.mark.parametrize("transform, select", [(lambda f: f, 0.0), (jax.jit, 0.0), (jax.jit, 1.0)],
                         ids=["eager-0.0", "jit-0.0", "jit-1.0"])
def test_plan_is_safe_and_within_the_covariance_limit(transform, select):
  det_max = 1.0  # with Li's V_n unscaled: cuts candidate paths after about a metre here
  params = unscaled(params_for(select=select, det_sigma_max=det_max))
  state, l, entropy = belief(5)
  view = make_view(l, entropy, params)
  robot = robot_at((5, 15), cov=1e-3)
  memory = memory_for(CONFIG, params, entropy)
  if transform is jax.jit:
    plan, _ = PLAN(CONFIG, view, robot, params, jax.random.PRNGKey(0), memory)
  else:
    plan, _ = li2020.plan_li2020(CONFIG, view, robot, params, jax.random.PRNGKey(0), memory)
  assert bool(plan.valid) and int(plan.n_candidates) > 0  # an exploration plan, not the fallback
  n = int(plan.length)
  cells = np.asarray(plan.waypoints)[:n]
  assert n >= 2 and tuple(cells[0]) == (5, 15)
  assert (state[cells[:, 0], cells[:, 1]] == 0).all()  # never occupied or unknown
  assert np.asarray(view.traversable)[cells[:, 0], cells[:, 1]].all()
  covs = numpy_cov_along(cells, 0.3, np.asarray(robot.cov), CONFIG.res, 1.0, 1.0,
                         li2020.road_mark_cells(CONFIG))
  assert max(np.linalg.det(c) for c in covs) <= det_max * (1 + 1e-3)


def test_k1_below_k2_is_enforced():
  from jaxplore.config import ConfigError
  with pytest.raises(ConfigError, match="k1 < k2"):
    li2020.validate({k: np.asarray(v) for k, v in dict(li2020.DEFAULTS, k1=0.7, k2=0.6).items()},
                    params_for(), CONFIG)
  # One per robot (a sweep's batch): each bad pair named once, the good ones not at all.
  weights = {k: np.full(6, v, np.float32) for k, v in li2020.DEFAULTS.items()}
  weights["k1"] = np.array([0.1, 0.7, 0.7, 0.2, 0.95, 0.1], np.float32)
  weights["k2"] = np.array([0.5, 0.6, 0.6, 0.9, 0.5, 0.5], np.float32)
  with pytest.raises(ConfigError, match=r"\(k1, k2\) = \(0.7, 0.6\), \(0.95, 0.5\)$"):
    li2020.validate(weights, params_for(), CONFIG)


@pytest.mark.parametrize("region", ["visible", "disc"])
def test_the_robots_own_disc_reads_nothing_across_the_top_and_left_borders(region):
  params = params_for()
  _, l, entropy = belief(6)
  view = make_view(l, entropy, params)
  robot = robot_at((1, 1))
  gains = np.zeros((2, H, W), np.float32)
  gains[:, -1, :] = 1.0  # only the last row and column gain: a disc at (1, 1) never reaches them
  gains[:, :, -1] = 1.0
  sp = shortest_paths(jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32), robot.cell)
  ctx = dataclasses.replace(ROAD_MARKS, settings=dataclasses.replace(SETTINGS, road_mark_m=0.5, region=region))
  sums, _, _ = TREE(ctx, view, robot, params, sp.pred, jnp.asarray(gains))
  assert float(sums[1 * W + 1, 0]) == 0.0 and float(sums[1 * W + 1, 1]) == 0.0


@pytest.mark.parametrize("eq21", ["sensor", "cell"])
def test_both_readings_of_eq21_match_their_formulas(eq21):
  params = params_for()
  rng = np.random.default_rng(7)
  l = rng.choice(np.array([-3.0, -1.0, 1.0, 3.0], np.float32), size=(H, W))  # every cell known
  entropy = rng.uniform(0.0, math.log(2), (H, W)).astype(np.float32)
  view = make_view(l, entropy, params)
  gain, reexplore = np.asarray(li2020.cell_gains(view, jnp.asarray(entropy), params, jnp.float32(0.6), 3.0, eq21))
  h_cell = lambda x: -(x * np.log(x) + (1 - x) * np.log(1 - x))
  k = float(params.planner["entropy_k"])
  if eq21 == "sensor":  # H' = k·H + (1−k)·H_obs, H_obs the entropy after one free observation
    after = k * entropy + (1 - k) * h_cell(1 / (1 + math.exp(1.0)))
  else:  # H' = Ĥ(P(c))
    after = h_cell(1 / (1 + np.exp(-l.astype(np.float64))))
  np.testing.assert_allclose(gain, np.maximum(entropy - after, 0.0), atol=1e-6)
  np.testing.assert_allclose(reexplore, np.maximum(0.6 - entropy, 0.0), atol=1e-6)
  assert (gain > 0).any() and (gain == 0).any()


def test_entropy_left_only_where_the_robot_stands_is_no_paths_gain():
  """Eq 20 sums over a path's road-mark points p_1 ... p_m, not over P_0 where the robot stands
  (its scan is in the maps already, Algorithm 1 line 2): entropy left only in the robot's own
  region is no path's gain. With nothing unknown left and Σ within its limit there is no Eq 22
  fallback either (Algorithm 1: no path means all is explored), so no plan."""
  params = params_for()
  state, l, _ = belief(8)
  l[:, 26:] = -3.0  # no unknown cells, no frontier
  l[0, :] = l[-1, :] = l[:, 0] = l[:, -1] = 3.0
  entropy = np.full((H, W), 0.01, np.float32)
  entropy[5, 15] = math.log(2)  # only the robot's own cell has entropy to lose
  view = make_view(l, entropy, params)
  plan, _ = PLAN(CONFIG, view, robot_at((5, 15)), params, jax.random.PRNGKey(0),
                 memory_for(CONFIG, params, entropy))
  gain = np.asarray(li2020.cell_gains(view, jnp.asarray(entropy), params, jnp.float32(math.log(2)), 3.0))[0]
  assert gain[5, 15] > 0 and gain.sum() == gain[5, 15]
  assert not bool(plan.valid) and int(plan.length) == 0


def open_room(robot_cell, entropy_left):
  """A known room (walls round it) with unknown space beyond column 26, entropy 0.3 in the known
  cells (no gain: below H_obs), ln 2 in the unknown ones and in the robot's own disc of radius
  ``entropy_left`` (entropy that no scan from there has removed), 0.65 in the last known columns
  (cells seen once: the entropy boundary B_e next to the unknown space)."""
  l = np.full((H, W), -3.0, np.float32)
  l[:, 26:] = 0.0
  l[0, :] = l[-1, :] = l[:, 0] = l[:, -1] = 3.0
  entropy = np.where(l == 0.0, math.log(2), 0.3).astype(np.float32)
  entropy[1:-1, 23:26] = 0.65
  ii, jj = np.mgrid[0:H, 0:W]
  entropy[(ii - robot_cell[0]) ** 2 + (jj - robot_cell[1]) ** 2 <= entropy_left ** 2] = math.log(2)
  return l, entropy


def numpy_union_gain(gain, cells, radius):
  """Σ gain over the union of the discs of radius ``radius`` round ``cells`` (Eq 20, each cell
  once), in NumPy."""
  ii, jj = np.mgrid[0:gain.shape[0], 0:gain.shape[1]]
  covered = np.zeros(gain.shape, bool)
  for r, c in cells:
    covered |= (ii - r) ** 2 + (jj - c) ** 2 <= radius * radius
  return float(gain[covered].sum())


def test_gain_per_metre_weighs_what_a_path_adds_to_the_robots_own_region():
  """select=1 on a hand-made room: the robot stands in a disc of entropy that no scan from there
  removed, and 2 m away unknown space waits. Counting the robot's own region in every path (as
  Eq 20 at P_0) scored a one-cell step its disc's gain over 0.1 m, and the robot shuffled from
  cell to cell for ever (lab, select=1: coverage flat at 0.66 for 600 s). A path's gain is what
  the regions of its road-mark points p_1 ... p_m add to the robot's own (P_0, Li's Figure 5,
  whose scan is in the maps): no one-cell step adds anything here, the far path does."""
  params = params_for(select=1.0)
  robot = robot_at((12, 5), theta=0.0)
  l, entropy = open_room((12, 5), 3.0)
  view = make_view(l, entropy, params)
  gain = np.asarray(li2020.cell_gains(view, jnp.asarray(entropy), params, jnp.float32(math.log(2)), 3.0))[0]
  own = numpy_union_gain(gain, [(12, 5)], 3.0)
  assert own > 1.0  # a one-cell path used to score more than 10 nats per metre
  for step in mapping.NEIGHBOURS_8:  # what each one-cell path adds: nothing
    assert numpy_union_gain(gain, [(12, 5), (12 + step[0], 5 + step[1])], 3.0) == own
  plan, _ = PLAN(CONFIG, view, robot, params, jax.random.PRNGKey(0),
                 memory_for(CONFIG, params, entropy))
  n = int(plan.length)
  cells = np.asarray(plan.waypoints)[:n]
  assert bool(plan.valid) and n >= 15 and cells[-1][1] >= 20  # toward the unknown space
  added = numpy_union_gain(gain, cells, 3.0) - own  # the plan's gain, read plainly
  assert added > 0.5
  np.testing.assert_allclose(float(plan.gain), added, rtol=1e-4)


@pytest.mark.parametrize("region", ["beams", "visible", "disc"])
def test_gain_per_metre_never_takes_a_step_of_a_few_cells_while_a_farther_frontier_gains(region):
  """Issue 41's select=1 stall, in each gain region: entropy left in the robot's own region (no
  scan from where it stands removed it) and a frontier 2 m away. A path shorter than a few cells
  adds nothing to the robot's own region (P_0's, whose scan is in the maps: Li's Figure 5,
  Algorithm 1 line 2), so gain per metre takes the farther path. Counted at the root, that
  entropy made a one-cell step score it over 0.1 m (lab, robot seeds 0-3: all four timed out at
  0.66-0.99 coverage before d5b3007)."""
  params = params_for(select=1.0)
  ctx = dataclasses.replace(CONFIG, settings=dataclasses.replace(SETTINGS, region=region))
  l, entropy = open_room((12, 5), 3.0)
  view = make_view(l, entropy, params)
  plan, _ = PLAN(ctx, view, robot_at((12, 5), theta=0.0), params, jax.random.PRNGKey(0),
                 memory_for(ctx, params, entropy))
  n = int(plan.length)
  assert bool(plan.valid) and n > 5 and np.asarray(plan.waypoints)[n - 1][1] >= 20
  assert float(plan.gain) > 0.5


def branching_corridor():
  """Walls everywhere but an east-west corridor (rows 2-6) and a branch south from it
  (columns 17-21): a little unknown space at the corridor's east end, more down the branch."""
  l = np.full((H, W), 3.0, np.float32)
  l[2:7, 1:33] = -3.0
  l[7:25, 17:22] = -3.0
  l[2:7, 31:33] = 0.0
  l[14:25, 17:22] = 0.0
  return l, np.where(l == 0.0, math.log(2), 0.3).astype(np.float32)


def test_a_path_is_cut_where_the_covariance_grows_past_the_default_limit():
  """Eq 18-19 at the defaults (Σ_max from the loop closure's search window, V_n of the 3 %
  odometry noise). A robot facing east in a corridor: the unknown space down the south branch
  gains the most, the little at the corridor's end less. Well localised, the robot takes the
  branch. With its heading variance at 95 % of σ_θ,max² (its scans did not match for a while),
  the branch's turn (Eq 16's δφ) takes det Σ past det Σ_max (a NumPy loop of Eq 17), the
  branch's path is cut short of its gain, and the robot drives straight on, where det Σ grows
  by the distance terms only."""
  params = params_for()
  l, entropy = branching_corridor()
  view = make_view(l, entropy, params)
  det_max = li2020.DET_SIGMA_MAX
  assert float(params.planner["det_sigma_max"]) == pytest.approx(det_max)
  grown = np.diag([li2020.SIGMA_MAX_XY ** 2, li2020.SIGMA_MAX_XY ** 2,
                   0.95 * li2020.SIGMA_MAX_THETA ** 2]).astype(np.float32)
  spacing = li2020.road_mark_cells(CONFIG)
  ends = {}
  for name, cov in [("localised", np.eye(3, dtype=np.float32) * 1e-4), ("grown", grown)]:
    robot = base.RobotView(pose=jnp.asarray([0.0, 0.0, 0.0], jnp.float32),
                           cell=jnp.asarray((4, 4), jnp.int32), cov=jnp.asarray(cov))
    plan, memory = PLAN(CONFIG, view, robot, params, jax.random.PRNGKey(0),
                        memory_for(CONFIG, params, entropy))
    cells = np.asarray(plan.waypoints)[:int(plan.length)]
    assert bool(plan.valid) and float(plan.gain) > 0.1 and int(memory["reexplore_plans"]) == 0
    covs = numpy_cov_along(cells, 0.0, cov, CONFIG.res, 0.03, 0.03, spacing)
    assert max(np.linalg.det(c) for c in covs) <= det_max * (1 + 1e-4)
    ends[name] = (tuple(cells[-1]), float(plan.gain), cells, covs)
  (south, south_gain, south_cells, _), (east, east_gain, _, _) = ends["localised"], ends["grown"]
  assert south[0] >= 12 and 17 <= south[1] <= 21  # down the branch
  assert east[0] <= 6 and east[1] >= 28 and east_gain < south_gain  # on to the corridor's end
  # the branch's path from the grown covariance passes the limit after its turn
  from_grown = numpy_cov_along(south_cells, 0.0, grown, CONFIG.res, 0.03, 0.03, spacing)
  assert np.linalg.det(from_grown[-1]) > det_max
  # Without the corridor's end, the branch is the only way: the plan is its path, cut short of
  # the unknown space (rows 14 on) where det Σ reaches the limit, and counted as cut.
  l[2:7, 31:33] = -3.0
  entropy = np.where(l == 0.0, math.log(2), 0.3).astype(np.float32)
  robot = base.RobotView(pose=jnp.asarray([0.0, 0.0, 0.0], jnp.float32),
                         cell=jnp.asarray((4, 4), jnp.int32), cov=jnp.asarray(grown))
  plan, memory = PLAN(CONFIG, make_view(l, entropy, params), robot, params,
                      jax.random.PRNGKey(0), memory_for(CONFIG, params, entropy))
  cells = np.asarray(plan.waypoints)[:int(plan.length)]
  assert bool(plan.valid) and 7 <= cells[-1][0] < 14 and 17 <= cells[-1][1] <= 21
  assert int(memory["cut_plans"]) == 1 and int(memory["plans"]) == 1
  covs = numpy_cov_along(cells, 0.0, grown, CONFIG.res, 0.03, 0.03, spacing)
  assert np.linalg.det(covs[-1]) <= det_max * (1 + 1e-4)


def test_entropy_left_only_where_the_robot_stands_leads_to_the_reexplore_fallback():
  """Algorithm 1, lines 19-21, on a hand-made room: every candidate path is cut (Eq 18-19) about
  a metre out, short of the unknown space, and the only entropy the cut paths reach is the
  robot's own disc. No corrected path adds anything to what the robot observes where it stands,
  so the plan is Eq 22's: the uncut path of the largest re-explore metric, which counts only a
  well-mapped patch at the bottom of the room (h0 below every other cell's entropy). Counting
  the robot's own region in every path made each cut path 'gain' (intel: a robot shuttled
  between two cells for 2,000 steps, its disc holding unknown cells no beam reaches)."""
  det_max = 1.2  # Σ_0 = I: det Σ reaches it after about a metre (Eq 17, det ≈ (1 + 0.1 d)² · 1)
  params = unscaled(params_for(det_sigma_max=det_max, h0=0.1))
  robot = robot_at((8, 5), theta=0.0, cov=1.0)
  # Entropy within 2 cells of the robot: a path that turns back into its R_e disc (3 cells) after
  # leaving it would count the rim again (path_gains' one caveat), not these cells.
  l, entropy = open_room((8, 5), 2.0)
  entropy[20:24, 10:16] = 0.0  # the well-mapped patch, the only cells below h0
  view = make_view(l, entropy, params)
  plan, _ = PLAN(CONFIG, view, robot, params, jax.random.PRNGKey(0),
                 memory_for(CONFIG, params, entropy))
  n = int(plan.length)
  cells = np.asarray(plan.waypoints)[:n]
  assert bool(plan.valid) and n >= 10
  # the goal's R_e disc reaches the patch; the path leaves the covariance limit (no cut)
  patch = np.argwhere(entropy == 0.0)
  assert (np.hypot(*(patch - cells[-1]).T) <= 3.0).any()
  covs = numpy_cov_along(cells, 0.0, np.asarray(robot.cov), CONFIG.res, 1.0, 1.0,
                         li2020.road_mark_cells(CONFIG))
  assert np.linalg.det(covs[-1]) > det_max
  reexplore = np.asarray(li2020.cell_gains(view, jnp.asarray(entropy), params, jnp.float32(0.1), 3.0))[1]
  np.testing.assert_allclose(float(plan.gain), numpy_union_gain(reexplore, cells, 3.0), rtol=1e-4)


def test_the_progress_timeout_ends_a_robot_that_drives_without_mapping_anything():
  params = params_for(progress_m=20.0)
  _, l, entropy = belief(9)
  view = make_view(l, entropy, params)
  memory = memory_for(CONFIG, params, entropy)
  valid = []
  for i in range(9):  # 3 m between plans, the belief never changes
    robot = robot_at((5, 15)).replace(pose=jnp.asarray([3.0 * (i % 2), 0.0, 0.3], jnp.float32))
    plan, memory = PLAN(CONFIG, view, robot, params, jax.random.PRNGKey(i), memory)
    valid.append(bool(plan.valid))
  # driven: 0, 3, ..., 18 m (valid), 21 m > 20 m: stuck for good
  assert valid == [True] * 7 + [False] * 2 and bool(memory["stuck"])
  # a cell becoming known resets the distance
  l2 = l.copy()
  l2[:, 26] = -3.0
  memory = dict(memory, stuck=jnp.bool_(False))
  plan, memory = PLAN(CONFIG, make_view(l2, entropy, params), robot_at((5, 15)), params,
                      jax.random.PRNGKey(0), memory)
  assert bool(plan.valid) and float(memory["driven"]) == 0.0


def test_two_pockets_behind_slits_make_a_two_cycle_that_the_progress_timeout_ends():
  """A hand-made belief with the livelock: a mapped corridor with two slits too narrow for the
  robot, each into an unknown room. The rooms' cells near a slit count as observable (reached
  from the slit's free cell through unknown cells), but no scan from the corridor will ever
  map them, so their entropy never falls. From near one slit the best path goes to the other
  and back: a 2-cycle over a belief that never changes, until the progress timeout."""
  params = params_for(progress_m=20.0)
  l = np.full((H, W), -3.0, np.float32)
  l[:9, :] = 0.0  # the unknown rooms above the corridor
  l[9, :] = 3.0  # their wall, with two slits
  l[9, 5] = l[9, 28] = -3.0
  l[16:, :] = 3.0
  l[:, 0] = l[:, -1] = 3.0
  l[:9, 16:18] = 3.0  # the wall between the two rooms
  entropy = np.where(l == 0.0, math.log(2), 0.05).astype(np.float32)
  view = make_view(l, entropy, params)
  assert not np.asarray(view.traversable)[9, [5, 28]].any()  # the robot cannot pass a slit
  memory = memory_for(CONFIG, params, entropy)
  cell, sides, driven = (12, 5), [], 0.0
  for i in range(30):
    pose = jnp.asarray([(cell[1] + 0.5) * CONFIG.res, (cell[0] + 0.5) * CONFIG.res, 0.0], jnp.float32)
    robot = robot_at(cell).replace(pose=pose)
    plan, memory = PLAN(CONFIG, view, robot, params, jax.random.PRNGKey(i), memory)
    if not bool(plan.valid):
      break
    goal = tuple(int(v) for v in np.asarray(plan.goal))
    sides.append("left" if goal[1] < 17 else "right")
    driven += math.hypot(goal[0] - cell[0], goal[1] - cell[1]) * CONFIG.res
    cell = goal
  # The 2-cycle: after a step toward the first slit, every plan crosses to the other one ...
  assert sides[1:7] == ["right", "left"] * 3
  assert all(a != b for a, b in zip(sides[1:], sides[2:]))
  # ... until 20 m without a newly known cell end the episode.
  assert not bool(plan.valid) and bool(memory["stuck"])
  assert 20.0 - 3.5 <= driven <= 20.0 + 3.5


VISIBLE = jax.jit(li2020.visible_gains, static_argnums=2)


_LOS_CACHE = {}


def line_of_sight_sums(gains, occupied, radius, samples=512):
  """Cached :func:`_line_of_sight_sums` (the eager and the jitted test share one brute force)."""
  key = (gains.tobytes(), occupied.tobytes(), radius)
  if key not in _LOS_CACHE:
    _LOS_CACHE[key] = _line_of_sight_sums(gains, occupied, radius, samples)
  return _LOS_CACHE[key]


def _line_of_sight_sums(gains, occupied, radius, samples=512):
  """Brute force: at every cell v, the sum of ``gains`` over the cells c within ``radius`` such
  that no occupied cell other than v and c holds a point of the segment between their centres
  (sampled at ``samples`` points; a power of two never lands exactly on a cell corner). Also
  returns, per v, the number of shadow-edge cells: cells of the disc seen from v with a
  4-neighbour in the disc that is not, or the other way round."""
  h, w = occupied.shape
  t = (np.arange(samples) + 0.5) / samples
  out = np.zeros(gains.shape)
  edges = np.zeros((h, w), int)
  r = int(math.floor(radius))
  for vi in range(h):
    for vj in range(w):
      seen = np.full((2 * r + 3, 2 * r + 3), -1)  # -1 outside the disc, else 0 / 1
      for di in range(-r, r + 1):
        for dj in range(-r, r + 1):
          ci, cj = vi + di, vj + dj
          if di * di + dj * dj > radius * radius or not (0 <= ci < h and 0 <= cj < w):
            continue
          si = np.floor(vi + t * di + 0.5).astype(int)
          sj = np.floor(vj + t * dj + 0.5).astype(int)
          inner = ~(((si == vi) & (sj == vj)) | ((si == ci) & (sj == cj)))
          seen[di + r + 1, dj + r + 1] = not occupied[si[inner], sj[inner]].any()
          if seen[di + r + 1, dj + r + 1]:
            out[:, vi, vj] += gains[:, ci, cj]
      core = seen[1:-1, 1:-1]
      differs = np.zeros(core.shape, bool)
      for a, b in ((0, 1), (2, 1), (1, 0), (1, 2)):
        other = seen[a:a + core.shape[0], b:b + core.shape[1]]
        differs |= (other >= 0) & (other != core)
      edges[vi, vj] = int((differs & (core >= 0)).sum())
  return out, edges


@pytest.mark.parametrize("transform", [lambda f: f, lambda f: VISIBLE], ids=["eager", "jit"])
def test_visible_region_against_a_brute_force_line_of_sight_count(transform):
  rng = np.random.default_rng(11)
  gains = rng.uniform(0.1, 1.0, (2, 20, 24)).astype(np.float32)
  radius = 6.0
  # A straight wall across the whole grid: exact over the cells off the wall (the wall's own
  # cells may differ: a chain reaches a wall cell from the side where the segment to its centre
  # grazes a neighbouring wall cell first).
  wall = np.zeros((20, 24), bool)
  wall[9, :] = True
  gains[:, wall] = 0.0
  full, _ = transform(li2020.visible_gains)(jnp.asarray(gains), jnp.asarray(wall), radius)
  np.testing.assert_allclose(np.asarray(full)[:, ~wall], line_of_sight_sums(gains, wall, radius)[0][:, ~wall],
                             rtol=1e-5)  # viewpoints off the wall (a robot never stands in one)
  # Rooms with a door, a pillar and a diagonal wall: the 8-connected sight lines of ray_tree
  # depart from the segments by up to ~1 cell, so shadow edges may differ by a cell.
  rooms = wall.copy()
  rooms[9, 10:13] = False  # a door
  rooms[3:5, 4:6] = True  # a pillar
  rooms[:9, 17] = True
  for k in range(7):  # a diagonal wall in the lower half
    rooms[12 + k, 4 + k] = True
  ones = np.ones((1, 20, 24), np.float32)
  full, _ = transform(li2020.visible_gains)(jnp.asarray(ones), jnp.asarray(rooms), radius)
  ref, edges = line_of_sight_sums(ones, rooms, radius)
  got, ref = np.asarray(full)[0], ref[0]
  viewpoints = ~rooms
  assert (ref < np.asarray(VISIBLE(jnp.asarray(ones), jnp.zeros((20, 24), bool), radius)[0])[0]).any()
  # Region sizes differ by less than the shadow edges' cells, and by 2.8 % on average.
  assert (np.abs(got - ref) <= edges)[viewpoints].all()
  assert np.abs(got - ref)[viewpoints].sum() <= 0.05 * ref[viewpoints].sum()


def chain_walk_sums(gains, occupied, radius):
  """NumPy oracle of :func:`li2020.visible_gains`: at every cell v, for every disc offset, walk
  its ray_tree chain from v cell by cell. The offset's cell is seen unless a cell strictly
  between v and it is occupied, or a step passes between two occupied cells (the two cells
  beside it: for a straight step, the cells it steps from and to). Cells off the grid are clear
  and hold no gain. Returns (full, crescent) as visible_gains does, in float64."""
  offsets, _, member, sides = li2020.ray_tree(radius)
  parent = {tuple(o): (int(s[1, 0]), int(s[0, 1])) for o, s in zip(offsets, sides)}
  chains = {}
  for o in map(tuple, offsets):
    chain = [o]
    while chain[-1] != (0, 0):
      chain.append(parent[chain[-1]])
    chains[o] = chain[::-1]  # from (0, 0) to o
  h, w = occupied.shape
  clear = lambda i, j: not (0 <= i < h and 0 <= j < w) or not occupied[i, j]
  gain_at = lambda i, j: gains[:, i, j] if 0 <= i < h and 0 <= j < w else 0.0
  full = gains.astype(np.float64)
  crescent = np.zeros((8,) + gains.shape)
  for vi in range(h):
    for vj in range(w):
      for o, m in zip(map(tuple, offsets), member):
        cells = [(vi + a, vj + b) for a, b in chains[o]]
        seen = all(clear(*c) for c in cells[1:-1]) and all(
            clear(q[0], p[1]) or clear(p[0], q[1]) for p, q in zip(cells, cells[1:]))
        if seen:
          full[:, vi, vj] += gain_at(*cells[-1])
          crescent[m, :, vi, vj] += gain_at(*cells[-1])
  return full, crescent


SIGHT_CASES = ((2.5, (9, 8)), (4.0, (11, 13)), (5.3, (6, 9)))  # 5.3: past the grid, odd depth


@functools.lru_cache(maxsize=None)
def sight_case(radius, shape):
  """Random walls (a quarter of the cells: many diagonal steps squeeze between two) and gains:
  two channels of small integers (every float32 sum is exact, whatever its order), two of reals;
  with the chain walk's and the one-loop version's answers (the eager and the jitted test share
  them)."""
  rng = np.random.default_rng(int(radius * 10))
  occupied = rng.uniform(size=shape) < 0.25
  gains = np.concatenate([rng.integers(0, 5, (2,) + shape),
                          rng.uniform(0.0, 1.0, (2,) + shape)]).astype(np.float32)
  old = jax.jit(visible_gains_one_loop, static_argnums=2)(jnp.asarray(gains), jnp.asarray(occupied),
                                                          radius)
  return occupied, gains, chain_walk_sums(gains, occupied, radius), [np.asarray(x) for x in old]


@pytest.mark.parametrize("transform", [lambda f: f, lambda f: jax.jit(f, static_argnums=2)],
                         ids=["eager", "jit"])
def test_visible_gains_match_a_chain_walk_and_the_one_loop_version(transform):
  """Radii below, at and past the grid's size, integer and not: the integer channels (which
  cells are summed) identical, the real ones up to the order of the float32 sums."""
  for radius, shape in SIGHT_CASES:
    occupied, gains, walked, old = sight_case(radius, shape)
    got = transform(li2020.visible_gains)(jnp.asarray(gains), jnp.asarray(occupied), radius)
    for got_sum, walked_sum, old_sum in zip(got, walked, old):
      got_sum = np.asarray(got_sum)
      np.testing.assert_array_equal(got_sum[..., :2, :, :], walked_sum[..., :2, :, :])
      np.testing.assert_array_equal(got_sum[..., :2, :, :], old_sum[..., :2, :, :])
      np.testing.assert_allclose(got_sum, walked_sum, rtol=1e-6, atol=1e-6)
      np.testing.assert_allclose(got_sum, old_sum, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("block", [3, 8])
def test_visible_gains_in_blocks_are_the_sums_one_offset_at_a_time_bit_for_bit(block):
  """The lockstep strategy's blocks of offsets (a last block part empty, or wider than a depth)
  add the same numbers in the same order."""
  blocked = jax.jit(li2020.visible_gains, static_argnums=(2, 3))
  for radius, shape in SIGHT_CASES:
    occupied, gains = sight_case(radius, shape)[:2]
    args = jnp.asarray(gains), jnp.asarray(occupied), radius
    for got, want in zip(blocked(*args, block), VISIBLE(*args)):
      np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
  with pytest.raises(ValueError, match="block"):
    li2020.visible_gains(*args, 0)


@pytest.mark.parametrize("region, sums", [("beams", "_beam_sums"), ("visible", "_visible_sums")])
def test_the_planner_takes_the_visible_gain_blocks_of_the_engines_strategy(monkeypatch, region,
                                                                          sums):
  """Traced only: li2020 asks the region's sums for VISIBLE_BLOCK[strategy]."""
  blocks = []
  seen_sums = getattr(li2020, sums)
  monkeypatch.setattr(li2020, sums, lambda *args: blocks.append(args[5]) or seen_sums(*args))
  params = params_for()
  state, l, entropy = belief(5)
  view = make_view(l, entropy, params)
  for strategy in ("per_robot", "lockstep"):
    ctx = dataclasses.replace(CONFIG, strategy=strategy, settings=dataclasses.replace(SETTINGS, region=region))
    jax.eval_shape(lambda: li2020.plan_li2020(ctx, view, robot_at((5, 15)), params,
                                              jax.random.PRNGKey(0), memory_for(ctx, params, entropy)))
  assert blocks == [li2020.VISIBLE_BLOCK["per_robot"], li2020.VISIBLE_BLOCK["lockstep"]]
  assert blocks[0] != blocks[1]


BEAMS = jax.jit(li2020.beam_gains, static_argnums=(2, 3))


WINDOWS = ((16, 24), (24, 32), (40, 48))


def test_sum_windows_are_sized_from_the_grid_and_only_where_the_sums_are_dear():
  assert li2020.sum_windows(40, 48, 6.0) == ((40, 48),)
  windows = li2020.sum_windows(130, 170, 57.0)
  assert windows == ((72, 88), (130, 170))  # half of each side rounded up to 8 cells; the grid


def windowed_cases():
  """(gains, occupied, needed, expected window) on a 40 x 48 grid, R_e 6 cells (pad 7)."""
  rng = np.random.default_rng(21)
  occupied = rng.uniform(0, 1, (40, 48)) < 0.12
  everywhere = rng.uniform(0, 1, (2, 40, 48)).astype(np.float32)
  box = lambda r0, r1, c0, c1: np.pad(np.ones((r1 - r0, c1 - c0), bool),
                                       [(r0, 40 - r1), (c0, 48 - c1)])
  corner = everywhere * box(32, 40, 0, 8)  # gains in the bottom-left corner only: 15 x 15 + pad
  return [
      (everywhere, occupied, box(3, 19, 5, 29), 0),  # exactly the smallest window
      (everywhere, occupied, box(3, 20, 5, 29), 1),  # a row more
      (everywhere, occupied, box(30, 40, 20, 48), 1),  # against the bottom-right border
      (everywhere, occupied, box(0, 40, 0, 48), 2),
      (everywhere, occupied, box(0, 2, 0, 2) | box(38, 40, 46, 48), 2),  # two far corners
      (everywhere, occupied, np.zeros((40, 48), bool), 0),
      (corner, occupied, box(0, 40, 0, 48), 0),  # the window of the gains' rows and columns
      (np.zeros_like(everywhere), occupied, box(0, 40, 0, 48), 0),
  ]


def test_a_plan_on_a_window_of_the_sums_is_the_plan_on_the_grid(monkeypatch):
  """A robot in a small room (its shortest-path tree within the smallest window): the plan with
  windows (forced on this small grid) is the plan without, bit for bit."""
  state = np.ones((H, W), int)  # 0 free, 1 occupied, 2 unknown
  state[2:10, 2:13] = 0
  state[3:7, 13:16] = 2  # a pocket of unknown cells east of the room
  l = np.where(state == 0, -3.0, np.where(state == 1, 3.0, 0.0)).astype(np.float32)
  entropy = np.where(state == 2, math.log(2), 0.3).astype(np.float32)
  params = params_for()
  view = make_view(l, entropy, params)
  memory = memory_for(CONFIG, params, entropy)
  plans = []
  for min_work in (math.inf, 0.0):
    monkeypatch.setattr(li2020, "SUM_WINDOW_MIN_WORK", min_work)
    assert len(li2020.sum_windows(H, W, 3.0)) == (1 if min_work else 2)
    plan = jax.jit(lambda view, robot, memory: li2020.plan_li2020(  # a new trace each time
        CONFIG, view, robot, params, jax.random.PRNGKey(0), memory)[0])
    plans.append(jax.tree.map(np.asarray, plan(view, robot_at((5, 6)), memory)))
  assert plans[0].valid and plans[0].gain > 0
  for got, want in zip(jax.tree.leaves(plans[1]), jax.tree.leaves(plans[0])):
    np.testing.assert_array_equal(got, want)


GRID_SUMS = {"beams": BEAMS, "visible": jax.jit(li2020.visible_gains, static_argnums=(2, 3))}


def check_windowed(region, transform, cases):
  """The windowed sums at every needed viewpoint are the grid's, bit for bit, and the window
  taken is the smallest that holds the needed viewpoints with a gain within R_e."""
  sums = li2020._beam_sums if region == "beams" else li2020._visible_sums
  windowed = transform(lambda gains, occupied, needed: li2020.windowed_sums(
      sums, gains, occupied, needed, 6.0, 2, WINDOWS))
  window = transform(lambda gains, needed: li2020.sum_window(gains, needed, 6.0, WINDOWS)[0])
  expected = []
  for gains, occupied, needed, level in cases:
    assert int(window(jnp.asarray(gains), jnp.asarray(needed))) == level
    full, crescent = GRID_SUMS[region](jnp.asarray(gains), jnp.asarray(occupied), 6.0, 2)
    expected.append((np.where(needed, full, 0), np.where(needed[None], crescent, 0)))
    got_full, got_crescent = windowed(jnp.asarray(gains), jnp.asarray(occupied),
                                      jnp.asarray(needed))
    np.testing.assert_array_equal(np.where(needed, got_full, 0), expected[-1][0])
    np.testing.assert_array_equal(np.where(needed[None], got_crescent, 0), expected[-1][1])
  return windowed, expected


# The visible region (not the default) shares the windowing with the beams; its check is slow.
@pytest.mark.parametrize("region", ["beams", pytest.param("visible", marks=pytest.mark.slow)])
def test_windowed_sums_are_the_grids_at_the_needed_viewpoints_bit_for_bit(region):
  """Jitted, for a robot alone and for the robots of a vmapped chunk (each its own needs, the
  chunk on its largest window)."""
  cases = windowed_cases()
  windowed, expected = check_windowed(region, jax.jit, cases)
  stack = lambda k: jnp.asarray(np.stack([case[k] for case in cases]))
  got_full, got_crescent = jax.vmap(windowed)(stack(0), stack(1), stack(2))
  for (_, _, needed, _), (full, crescent), got, got_c in zip(cases, expected, got_full,
                                                              got_crescent):
    np.testing.assert_array_equal(np.where(needed, got, 0), full)
    np.testing.assert_array_equal(np.where(needed[None], got_c, 0), crescent)


def test_windowed_sums_eager_on_the_smallest_window_and_on_the_grid():
  cases = windowed_cases()
  check_windowed("beams", lambda f: f, [cases[0], cases[3]])




@pytest.mark.parametrize("radius", [3.0, 5.5])
def test_beams_on_open_ground_count_every_disc_offset_once(radius):
  """With nothing occupied every beam runs free: the sums are the plain disc sums and the crescent
  sums of ``crescents`` (NumPy), and every disc offset is owned by exactly one beam."""
  offsets, _, owned, own_counts, _, _ = li2020.beam_table(radius)
  disc = li2020.disc_offsets(radius)
  cells = [tuple(offsets[g, s, owned[g, s, j]]) for (g, s), n in np.ndenumerate(own_counts)
           for j in range(n)]
  assert sorted(cells) == sorted(o for o in disc if o != (0, 0))
  rng = np.random.default_rng(5)
  gains = rng.uniform(0, 1, (2, 14, 17)).astype(np.float32)
  full, crescent = BEAMS(jnp.asarray(gains), jnp.zeros((14, 17), bool), radius, 2)
  framed = np.pad(gains, [(0, 0), (8, 8), (8, 8)])
  shifted = lambda o: framed[:, 8 + o[0]:8 + o[0] + 14, 8 + o[1]:8 + o[1] + 17]
  np.testing.assert_allclose(np.asarray(full), sum(shifted(o) for o in disc), rtol=1e-5)
  for n, d in enumerate(mapping.NEIGHBOURS_8):
    np.testing.assert_allclose(np.asarray(crescent[n]),
                               sum(shifted(o) for o in li2020.crescents(radius)[d]), rtol=1e-5,
                               atol=1e-6)


@pytest.mark.parametrize("block", [2, 8])
def test_beam_sums_in_blocks_are_the_sums_one_add_at_a_time_bit_for_bit(block):
  """The strategies' blocks (VISIBLE_BLOCK) change only how many adds a loop step takes: the
  planning rounds of both strategies must stay alike bit for bit."""
  rng = np.random.default_rng(9)
  gains = jnp.asarray(rng.uniform(0, 1, (2, 20, 24)).astype(np.float32))
  occupied = jnp.asarray(rng.uniform(0, 1, (20, 24)) < 0.15)
  one = BEAMS(gains, occupied, 6.0, 1)
  np.testing.assert_array_equal(np.asarray(BEAMS(gains, occupied, 6.0, block)[0]), np.asarray(one[0]))
  np.testing.assert_array_equal(np.asarray(BEAMS(gains, occupied, 6.0, block)[1]), np.asarray(one[1]))


def straight_line_verdicts(occupied, radius, fractions=(0.02, 0.26, 0.5, 0.74, 0.98), samples=256):
  """For every viewpoint v and target t within ``radius`` (cell centres), whether all / none of
  the straight lines from v's centre to the points of t at ``fractions`` of its sides cross an
  occupied cell other than v and t (sampled). Returns (blocked, clear) bool[H·W, H·W], [t, v]."""
  h, w = occupied.shape
  n = h * w
  blocked, clear = np.zeros((n, n), bool), np.zeros((n, n), bool)
  s = (np.arange(samples) + 0.5) / samples
  pts = [(a - 0.5, b - 0.5) for a in fractions for b in fractions]
  for vi in range(h):
    for vj in range(w):
      for ti in range(h):
        for tj in range(w):
          if (ti - vi) ** 2 + (tj - vj) ** 2 > radius * radius or (ti, tj) == (vi, vj):
            continue
          hits = []
          for a, b in pts:
            rows = np.floor(vi + s * (ti + a - vi) + 0.5).astype(int)
            cols = np.floor(vj + s * (tj + b - vj) + 0.5).astype(int)
            inner = ~(((rows == vi) & (cols == vj)) | ((rows == ti) & (cols == tj)))
            hits.append(bool(occupied[rows[inner], cols[inner]].any()))
          blocked[ti * w + tj, vi * w + vj] = all(hits)
          clear[ti * w + tj, vi * w + vj] = not any(hits)
  return blocked, clear


def test_beams_never_see_round_a_wall_corner_that_every_straight_line_hits():
  """Which cells count as seen, cell by cell (one gain channel per target cell), on walls with
  ends, a pillar and a diagonal wall, against straight lines in NumPy: a target that every line
  from the viewpoint's centre to it crosses a wall at is never seen by the beams; one that every
  such line reaches is. The tree of sight lines (``visible_gains``) fails the first: its chains
  leave their segments by up to 1.5 cells and slip round wall ends (li2020 robots drove back and
  forth for the unknown cells behind such a corner, which no scan from there maps)."""
  h, w, radius = 11, 13, 5.5
  occupied = np.zeros((h, w), bool)
  occupied[0:6, 5] = True  # a wall ending at row 5
  occupied[8, 2] = True  # a pillar
  for k in range(4):
    occupied[7 + k // 2, 8 + k] = True  # a diagonal wall, cells touching at corners
  targets = np.eye(h * w, dtype=np.float32).reshape(h * w, h, w)
  seen_beams = np.asarray(BEAMS(jnp.asarray(targets), jnp.asarray(occupied), radius, 2)[0])
  seen_tree = np.asarray(VISIBLE(jnp.asarray(targets), jnp.asarray(occupied), radius)[0])
  seen_beams, seen_tree = (s.reshape(h * w, h * w) > 0.5 for s in (seen_beams, seen_tree))
  blocked, clear = straight_line_verdicts(occupied, radius)
  off_walls = ~occupied.ravel()[None, :]  # viewpoints a robot could stand on
  assert not (seen_beams & blocked & off_walls).any()
  assert (seen_beams | ~clear | ~off_walls).all()
  assert (seen_tree & blocked & off_walls).any()  # the tree's slips


def test_entropy_behind_a_known_wall_makes_the_disc_region_cycle_and_not_the_visible_one():
  """The livelock: a mapped corridor under a known wall, behind it unknown space made observable
  by two cells seen long ago. The whole-disc region counts the unknown cells near them from the
  corridor, which no scan from there can see: the robot drives from one place to the other and
  back over a belief that never changes, until the progress timeout. The visible region counts
  none of them: with nothing else to explore it ends at once, never returning. Jitted only
  (eagerly the 20-odd plans take ~100 s); the plan's eager path is tested above."""
  params = params_for(progress_m=20.0)
  l = np.zeros((H, W), np.float32)  # unknown
  l[10:16, 1:33] = -3.0  # the mapped corridor
  l[9, :] = l[16, :] = l[:, 0] = l[:, -1] = 3.0  # its known walls
  l[8, 6] = l[8, 24] = -3.0  # two cells seen long ago behind the upper wall
  entropy = np.where(l == 0.0, math.log(2), 0.05).astype(np.float32)
  view = make_view(l, entropy, params)
  runs = {}
  for region in ("disc", "visible"):
    ctx = dataclasses.replace(CONFIG, settings=dataclasses.replace(SETTINGS, r_e=0.5, region=region))
    plan_fn = functools.partial(PLAN, ctx)
    memory = memory_for(ctx, params, entropy)
    cell, goals = (12, 6), []
    for i in range(12):
      pose = jnp.asarray([(cell[1] + 0.5) * ctx.res, (cell[0] + 0.5) * ctx.res, 0.0], jnp.float32)
      plan, memory = plan_fn(view, robot_at(cell).replace(pose=pose), params,
                             jax.random.PRNGKey(i), memory)
      if not bool(plan.valid):
        break
      cell = tuple(int(v) for v in np.asarray(plan.goal))
      goals.append(cell)
    runs[region] = goals, bool(memory["stuck"])
  goals, stuck = runs["disc"]
  sides = ["left" if c < 17 else "right" for _, c in goals]
  assert len(goals) >= 6 and all(a != b for a, b in zip(sides, sides[1:]))  # the 2-cycle
  assert len(set(goals)) == 2 and stuck  # between two cells, ended by the progress timeout
  goals, stuck = runs["visible"]
  assert goals == [] and not stuck  # nothing visible to gain: no plan, not stuck
