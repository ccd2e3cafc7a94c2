"""The scan_matching SLAM model in the engine (jaxplore.slam.model through jaxplore.robot)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import memory, metrics, motion, posegraph, results, robot, sensor, sim
from jaxplore.config import ConfigError, SimConfig, make_params, validate_params
from jaxplore.slam import accuracy, model
from tests.conftest import box_world

RES = 0.1
GRID = box_world(24, 40, RES, walls=((8, 16, 14, 22),))
STEPS = 140
# Twice around the central block (east along row 4, north along col 26, west along row 19, south
# along col 4): the second lap revisits the first one's keyframes.
LAP = ([(4, c) for c in range(4, 27)] + [(r, 26) for r in range(5, 20)]
       + [(19, c) for c in range(25, 3, -1)] + [(r, 4) for r in range(18, 4, -1)])
ROUTE = LAP + LAP
NOISY = dict(odom_noise_d=0.1, odom_noise_phi=0.1)


def slam_config(slam="scan_matching", **overrides):
  # coverage_goal > 1: the drive never ends early (the lidar sees the whole box at once).
  params = make_params(res=RES, r_max=2.5, fov=2 * math.pi, loop_min_age=8.0, loop_radius=2.0,
                       coverage_goal=2.0, **NOISY)
  bound = posegraph.keyframe_bound(STEPS + 1, params.v_max, params.w_max, params.dt,
                                   params.kf_dist, params.kf_rot)
  kwargs = dict(height=GRID.shape[0], width=GRID.shape[1], res=RES, n_beams=120,
                max_range_cells=25, max_steps=STEPS + 1, path_capacity=len(ROUTE),
                planner="nearest_frontier", max_inflation_cells=2, graph_nodes=bound,
                graph_loops=16, max_loop_cells=20, slam=slam, pose_noise=True)
  kwargs.update(overrides)
  return SimConfig(**kwargs), params


def drives(config, params, seeds):
  """One robot following ROUTE (no planner) per seed; per step its record, the keyframes' ATE
  and the belief's RMSE against the truth. One jitted function for the seeds: traced and
  compiled once, not once per seed."""
  world = sim.make_world(GRID, 0.2)
  truth = jnp.asarray(GRID.occupied, jnp.float32)

  def body(params, state):
    state, rec = robot.step(config, world, params, state)
    extra = {}
    if state.graph is not None and state.graph.truth is not None:
      g = state.graph
      valid = jnp.arange(g.poses.shape[0]) < g.n_nodes
      extra["ate"] = accuracy.absolute_trajectory_error(g.poses, g.truth, valid)
    p = jax.nn.sigmoid(state.logodds)
    extra["map_rmse"] = jnp.sqrt(jnp.mean((p - truth) ** 2))
    return state, (rec, extra)

  @jax.jit
  def run(params, key):
    start = jnp.asarray([0.45, 0.45, 0.0])
    state = robot.reset(config, world, params, key, start)
    state = state.replace(waypoints=jnp.asarray(ROUTE, jnp.int32), path_len=jnp.int32(len(ROUTE)),
                          path_idx=jnp.int32(1), look_at=jnp.asarray(ROUTE[-1], jnp.int32))
    # params traced in every step too (closed over, its numbers were constants of the program:
    # one compile per setting of a fixture, not one for them all)
    return jax.lax.scan(lambda state, _: body(params, state), state, None, length=STEPS)

  return [(world, jax.tree.map(np.asarray, run(params, jax.random.PRNGKey(seed))))
          for seed in seeds]


SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def slam_drives():
  config, params = slam_config()
  return config, params, drives(config, params, SEEDS)


@pytest.fixture(scope="module")
def unmatched_drives(slam_drives):
  """The same SLAM with its front end refusing every match (a response of 1 is never reached):
  keyframes dead-reckoned, drift corrected by loop closures alone. Same program (a traced
  parameter)."""
  config, params, _ = slam_drives
  # 5 % odometry noise: enough drift for a closure to correct, little enough that the drive's
  # path is not cut short by walls mapped in the wrong place (the motion gate of robot.step).
  # Each value keeps its leaf's type (slam_min_response is a weakly typed default): a strongly
  # typed float32 in its place was another program, compiled again (~15 s).
  params = params.replace(slam_min_response=1.0, odom_noise_d=jnp.float32(0.05),
                          odom_noise_phi=jnp.float32(0.05))
  return drives(config, params, SEEDS)


@pytest.fixture(scope="module")
def dead_reckoning_drives():
  """The same drives with the oracle model and relocalisation switched off: dead reckoning."""
  config, params = slam_config(slam="oracle", graph_nodes=0)
  params = params.replace(reloc_min_hits=jnp.float32(1e9))
  return drives(config, params, SEEDS)


def test_scan_matching_corrects_odometry_that_dead_reckoning_does_not(slam_drives,
                                                                       dead_reckoning_drives):
  _, _, drives = slam_drives
  slam_error = np.array([rec.pose_error[-1] for _, (_, (rec, _)) in drives])
  dead = np.array([rec.pose_error[-1] for _, (_, (rec, _)) in dead_reckoning_drives])
  # 10 % odometry noise over ~13 m: decimetres dead-reckoned; centimetres matched.
  assert np.all(dead > 0.05), dead
  assert np.all(slam_error < 0.05), slam_error
  assert np.mean(slam_error) < 0.25 * np.mean(dead)


def test_keyframes_edges_and_closures_are_what_the_graph_says(slam_drives):
  config, params, drives = slam_drives
  closures = 0
  for _, ((state, (rec, extra))) in drives:
    g = state.graph
    n, m = int(g.n_nodes), int(g.n_loops)
    assert 10 <= n <= config.graph_nodes
    # The loop list holds the closures and the near links; only a closure is optimised.
    link = np.asarray(g.loop_link[:m])
    revoked = np.asarray(g.loop_revoked[:m])
    closed = int(np.sum(~link))
    assert not g.loop_link[m:].any() and not g.loop_revoked[m:].any()
    # A revoked edge has no weight and no say in the optimisation (slam_model.optimise).
    assert np.all(np.asarray(g.loop_w[:m])[revoked] == 0)
    # An odometry edge measures the relative pose of consecutive estimates as they were added
    # (optimisations move the poses later; before the first closure they agree).
    first = int(np.argmax(rec.loop_closures > 0)) if m else STEPS
    np.testing.assert_array_less(-1, rec.loop_closures)
    assert rec.loop_closures[-1] == int(np.sum(~link & ~revoked))
    assert rec.near_links[-1] == int(np.sum(link & ~revoked))
    assert rec.revoked[-1] == int(np.sum(revoked))
    assert rec.false_closures[-1] == int(np.sum(g.loop_false[:m] & ~link & ~revoked))
    # A near link comes after a closure, never before the first.
    if link.any():
      assert not link[0]
    # Weights are the D-optimality of the information matrices.
    info = g.chain_info[1:n]
    np.testing.assert_allclose(g.chain_w[1:n], np.cbrt(np.linalg.det(info)), rtol=1e-3)
    for a, b in g.loops[:m]:
      assert b - a >= params.loop_min_age
    assert int(g.optimisations) == closed
    closures += closed
    del first
  assert closures >= 1, "no drive closed a loop on its second lap"


def test_a_closed_loop_lowers_the_trajectory_and_map_error(unmatched_drives):
  closed = 0
  for _, ((state, (rec, extra))) in unmatched_drives:
    assert int(state.graph.matches_rejected) == int(state.graph.n_nodes) - 1
    # Just before each closure (dead-reckoned since the last one) and just after it.
    for k in np.nonzero(np.diff(rec.loop_closures) > 0)[0] + 1:
      closed += 1
      assert extra["ate"][k] < extra["ate"][k - 1], (extra["ate"][k - 1], extra["ate"][k])
      assert extra["map_rmse"][k] < extra["map_rmse"][k - 1]
      assert rec.pose_error[k] < rec.pose_error[k - 1]
  assert closed >= 2 * len(SEEDS) - 1, f"{closed} closures in {len(SEEDS)} dead-reckoned drives"


def test_closures_are_true_and_trajectory_error_small(slam_drives):
  _, _, drives = slam_drives
  for _, ((state, (rec, extra))) in drives:
    g = state.graph
    m = int(g.n_loops)
    assert not g.loop_false[:m].any()
    assert extra["ate"][-1] < 0.05


def test_episode_table_carries_the_slam_columns(slam_drives):
  config, _, drives = slam_drives
  world, (state, (rec, _)) = drives[0]
  batch = lambda tree: jax.tree.map(lambda x: None if x is None else np.asarray(x)[None], tree)
  records = jax.tree.map(lambda x: np.asarray(x)[:, None], rec)
  episodes, curves = results.tables(config, GRID, world, batch(state), records, 1.0)
  row = episodes.iloc[0]
  g = state.graph
  n = int(g.n_nodes)
  valid = np.arange(g.poses.shape[0]) < n
  np.testing.assert_allclose(row["ate_m"], accuracy.absolute_trajectory_error(
      g.poses, g.truth, valid), rtol=1e-5)
  link = np.asarray(g.loop_link[:int(g.n_loops)])
  revoked = np.asarray(g.loop_revoked[:int(g.n_loops)])
  assert row["loop_closures"] == int(np.sum(~link & ~revoked))
  assert row["near_links"] == int(np.sum(link & ~revoked))
  assert row["revoked"] == int(np.sum(revoked))
  assert 0 <= row["misplaced_walls"] <= 1
  assert {"rpe_m_per_m", "false_closures", "false_links", "false_revoked", "matches_rejected",
          "optimisations"} <= set(row.index)
  assert {"loop_closures", "false_closures", "near_links", "revoked"} <= set(curves.columns)


def test_rebuilt_map_at_the_true_poses_matches_the_truth(slam_drives):
  config, params, drives = slam_drives
  world, (state, _) = drives[0]
  g = jax.tree.map(jnp.asarray, state.graph).replace(poses=jnp.asarray(state.graph.truth))
  offsets = model.beam_offsets(params, config.n_beams)
  logodds = jnp.zeros((1, config.height, config.width), jnp.float32)
  logodds, entropy, covered = model.rebuild(logodds, 0, g, g.ranges, offsets, world.origin, RES,
                                            world.reachable, params, config.max_range_cells + 1,
                                            False)
  grid = np.asarray(logodds[0])
  occupied = grid > 0
  assert occupied.sum() > 50
  # Every wall the keyframes drew is a true wall (within the cell a face point may round to).
  assert float(accuracy.misplaced_walls(occupied, GRID.occupied)) == 0.0
  np.testing.assert_allclose(float(entropy),
                             float(jnp.sum(jax.vmap(jax.vmap(
                                 lambda l: -(jax.nn.sigmoid(l) * jax.nn.log_sigmoid(l)
                                             + jax.nn.sigmoid(-l) * jax.nn.log_sigmoid(-l))))(
                                     logodds[0]))), rtol=1e-4)
  free = (grid < np.log(params.p_free / (1 - params.p_free))) & np.asarray(world.reachable)
  assert float(covered) == free.sum()


def test_facing_drops_a_wall_seen_from_its_far_side():
  # A wall along x = 1 seen from the origin (its west face); the points face (0, y) viewpoints.
  y = jnp.linspace(-1.0, 1.0, 21)
  x = jnp.ones_like(y)
  hit = jnp.ones_like(y, bool)
  near = model.facing(x, y, hit, jnp.array([0.0, 0.0]), jnp.array([0.2, 0.5]), RES)
  far = model.facing(x, y, hit, jnp.array([0.0, 0.0]), jnp.array([2.0, 0.5]), RES)
  assert bool(near.all()) and not bool(far.any())
  # An isolated point (no neighbour within 3 cells) is dropped.
  lone = model.facing(jnp.array([1.0, 5.0, 9.0]), jnp.array([0.0, 3.0, 0.0]),
                      jnp.ones(3, bool), jnp.zeros(2), jnp.array([0.1, 0.0]), RES)
  assert not bool(lone.any())


def test_dead_reckoning_error_follows_the_odometry_covariance():
  """Monte Carlo over seeds: the spread of dead-reckoned poses after a fixed drive matches the
  covariance propagated by Li Eq 17 with the simulated odometry noise (Eq 16's form)."""
  d_step, phi_step, n_steps, n_seeds = 0.1, 0.05, 60, 4000
  sigma = jnp.float32(0.05)

  def one(key):
    def body(carry, k):
      est, true, cov = carry
      inc = motion.increment(d_step, phi_step)
      std = jnp.stack([sigma * d_step, sigma * d_step, sigma * phi_step])
      noisy = inc + std * jax.random.normal(k, (3,))
      new_true = motion.compound(true, inc)
      new_est = motion.compound(est, noisy)
      v_n = motion.odometry_covariance(jnp.float32(d_step), jnp.float32(phi_step), sigma, sigma)
      cov = motion.propagate_covariance(cov, est, new_est, v_n)
      return (new_est, new_true, cov), None

    zero = jnp.zeros(3)
    (est, true, cov), _ = jax.lax.scan(body, (zero, zero, jnp.zeros((3, 3))),
                                       jax.random.split(key, n_steps))
    return est - true, cov

  err, cov = jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(0), n_seeds))
  empirical = np.cov(np.asarray(err, np.float64).T)
  predicted = np.asarray(cov, np.float64).mean(axis=0)
  # Standard error of a variance from 4000 samples: ~2.2 %; first-order propagation adds a little.
  np.testing.assert_allclose(np.diag(empirical), np.diag(predicted), rtol=0.1)


def test_settings_are_checked_before_compute():
  with pytest.raises(ConfigError, match="slam must be one of"):
    SimConfig(height=10, width=10, res=0.1, slam="karto")
  with pytest.raises(ConfigError, match="graph_nodes must be > 0"):
    SimConfig(height=10, width=10, res=0.1, slam="scan_matching")
  with pytest.raises(ConfigError, match="slam_steps"):
    SimConfig(height=10, width=10, res=0.1, slam="scan_matching", graph_nodes=4, slam_steps=0)
  config, params = slam_config()
  assert config.pose_noise  # scan_matching corrects odometry error: it is always on
  for name, bad in (("slam_min_response", 1.5), ("loop_max_variance", -1.0),
                    ("loop_gate", float("nan")), ("slam_max_angle", 4.0)):
    with pytest.raises(ConfigError, match=name):
      validate_params(params.replace(**{name: jnp.float32(bad)}), config)


def test_memory_guard_counts_the_stored_scans():
  config, _ = slam_config()
  oracle, _ = slam_config(slam="oracle")
  # Every keyframe keeps its scan: n_beams float16 ranges.
  assert memory.graph_bytes(config) - memory.graph_bytes(oracle) >= (
      config.graph_nodes * config.n_beams * 2)
  assert memory.estimate_bytes(config, 4) > memory.estimate_bytes(oracle, 4)
