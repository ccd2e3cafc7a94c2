"""SRT's turn in place: a robot with a limited field of view looks at the directions it has not
seen before it gives a node up.

The world: a 1.2 m corridor 6.8 m long, closed at both ends; the robot starts 0.6 m from its east
end, facing it. With the `toriz` lidar (240°) every ray it sees ends on a wall within 0.85 m, so
no step r·ρ reaches d_min (r·ρ <= 0.5 · 0.85 m < 1 m), and the 120° behind it are unseen: its
rays stop on unknown space beside the robot. Without a turn SRT had no valid draw at its root
and the episode ended at its first step.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import runner, sim
from jaxplore.maps import generate
from jaxplore.planners import reg
from jaxplore.planners import reg_kernels as K

RES = 0.2
CORRIDOR = [(0.6, 0.6, 7.4, 1.8)]  # x 0.6-7.4 m, y 0.6-1.8 m
START = (6.8, 1.2, 0.0)  # facing the east end, 0.6 m away
STEPS = 90


def test_srt_turns_to_its_unseen_side_at_a_start_facing_a_wall():
  grid = generate.floor_plan(8.0, 2.4, RES, CORRIDOR, name="dead_end")
  _, config, params, _ = runner.prepare(world=grid, planner="srt", robots=1, preset="toriz",
                                        max_steps=STEPS,
                                        params={"coverage_goal": 1.5, "slam": "oracle"},
                                        plan_window=0)
  world = sim.make_world(grid, float(params.r_robot), START[:2])

  @jax.jit
  def episode(key):
    state = sim.reset(config, world, params, key, jnp.asarray(START, jnp.float32))

    def body(state, _):
      state = jax.lax.cond(sim.needs_plan(config, state),
                           lambda s: sim.plan(config, world, params, s), lambda s: s, state)
      state, _ = sim.step(config, world, params, state)
      m = state.memory
      return state, (m.decisions, m.mode, m.turn, m.count, m.rho[0], state.pose)
    return jax.lax.scan(body, state, None, length=STEPS)

  state, (decisions, mode, turn, count, rho_0, pose) = jax.tree.map(
      np.asarray, episode(jax.random.PRNGKey(0)))
  # The first decision is a turn in place toward the unseen west, not the end of the episode.
  assert decisions[0] == 1 and mode[0] == reg.EXPLORE and turn[0]
  assert np.max(np.abs(pose[: np.argmax(decisions >= 2), :2] - np.asarray(START[:2]))) < RES
  # Before the turn node 0's western ray stopped on unknown space beside the robot; once the
  # robot has looked, it runs 4 m (R) down the corridor, and SRT steps r·R = 2 m along it.
  west = int(K.bin_of(jnp.float32(math.pi), 120))
  assert rho_0[0, west] * RES < 0.5
  assert rho_0[-1, west] * RES == reg.DEFAULTS["R"]
  assert count[-1] >= 2 and pose[:, 0].min() < START[0] - 1.5  # nodes west, past d_min
  # It explored the whole corridor and backtracked to its root, where nothing is left.
  assert int(state.reason) == sim.EXHAUSTED and int(state.memory.current) == 0
  assert float(state.covered) == float(world.n_reachable)


def test_look_direction_is_the_unseen_run_middle_or_one_field_of_view_in():
  bins = 120
  unseen = np.zeros(bins, bool)
  unseen[62:102] = True  # 120° (40 bins) behind a robot facing bin 22's ray
  look = jax.jit(reg._look_srt)
  fov = math.radians(240.0)
  found, phi, looked = look(jnp.asarray(unseen), jnp.float32(0.0), jnp.float32(fov))
  assert bool(found)
  np.testing.assert_allclose(float(phi), -math.pi + 82 * 2 * math.pi / bins, atol=1e-5)
  np.testing.assert_array_equal(np.asarray(looked), unseen)  # the whole run is in view
  # A 87° camera cannot see the 120° at once: it faces 43.5° in from the run's end nearer its
  # heading (heading 0°: the run's low end, bin 62's edge at 6°; its high end is at 126°), and
  # looks at those bins only; from a heading of 150° it faces in from the high end.
  narrow = math.radians(87.0)
  found, phi, looked = look(jnp.asarray(unseen), jnp.float32(0.0), jnp.float32(narrow))
  low = -math.pi + 62 * 2 * math.pi / bins
  np.testing.assert_allclose(float(phi), low + narrow / 2, atol=1e-5)
  centres = np.asarray(K.bin_angles(bins))
  expected = unseen & (np.abs(centres - (low + narrow / 2)) <= narrow / 2 + 1e-6)
  np.testing.assert_array_equal(np.asarray(looked), expected)
  assert 0 < expected.sum() < unseen.sum()
  _, phi, _ = look(jnp.asarray(unseen), jnp.float32(math.radians(150.0)), jnp.float32(narrow))
  np.testing.assert_allclose(float(phi), low + math.radians(120.0) - narrow / 2, atol=1e-5)
  found, _, looked = look(jnp.zeros(bins, bool), jnp.float32(0.0), jnp.float32(fov))
  assert not bool(found)
