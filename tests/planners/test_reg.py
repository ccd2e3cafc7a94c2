"""The REG family in the engine: whole episodes on small corridor worlds, and the random draws.

The three worlds (a T-junction, a loop, and a room whose door opens on a corridor) have the same
shape, so one compiled rollout serves them all.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import runner, sim
from jaxplore.config import ConfigError
from jaxplore.maps import generate
from jaxplore.planners import base, reg
from jaxplore.planners import reg_kernels as K

RES = 0.2
SIDE = 12.8  # m: 64 x 64 cells
TEE = [(0.6, 9.4, 12.2, 11.4), (5.4, 0.6, 7.4, 9.4)]
LOOP = [(0.6, 0.6, 12.2, 2.6), (0.6, 10.2, 12.2, 12.2), (0.6, 0.6, 2.6, 12.2),
        (10.2, 0.6, 12.2, 12.2)]
# A 5 m x 3 m room, a 1.2 m door in its 0.2 m top wall, a 2 m corridor across: from the start,
# 1.4 m below the door, every ray through the door ends on the corridor's far wall within R, so
# the corridor is seen only between the shadows of the door's jambs.
ROOM = [(0.6, 0.6, 5.6, 3.6), (2.6, 3.6, 3.8, 3.8), (0.6, 3.8, 12.2, 5.8)]
STARTS = {"tee": (6.4, 1.6, 0.0), "loop": (1.6, 1.6, 0.0), "room": (3.2, 2.2, math.pi / 2)}
MAX_STEPS = 480


@pytest.fixture(scope="module")
def episodes():
  """ereg on the T-junction, the loop and the room: two robots each, with different keys and the
  same start, no pose noise; coverage never ends an episode (only the planner does).

  One robot at a time, the engine's single-robot planning round and motion step in a scan (a
  batch would compile the planner once per planning chunk size), 120 steps per call.
  """
  worlds = {"tee": generate.floor_plan(SIDE, SIDE, RES, TEE, name="tee"),
            "loop": generate.floor_plan(SIDE, SIDE, RES, LOOP, name="loop"),
            "room": generate.floor_plan(SIDE, SIDE, RES, ROOM, name="room")}
  _, config, params, _ = runner.prepare(world=worlds["tee"], planner="ereg", robots=1,
                                        preset="toriz", max_steps=MAX_STEPS,
                                        params={"coverage_goal": 1.5, "slam": "oracle"},
                                        plan_window=0)

  @jax.jit
  def start(world, key, pose):
    return sim.reset(config, world, params, key, pose)

  @jax.jit
  def advance(world, state):
    def body(state, _):
      state = jax.lax.cond(sim.needs_plan(config, state),
                           lambda s: sim.plan(config, world, params, s), lambda s: s, state)
      state, record = sim.step(config, world, params, state)
      return state, record
    return jax.lax.scan(body, state, None, length=120)

  out = {}
  for name, world_grid in worlds.items():
    world = sim.make_world(world_grid, float(params.r_robot), STARTS[name][:2])
    runs = []
    for seed in (0, 1):
      state = start(world, jax.random.PRNGKey(seed), jnp.asarray(STARTS[name], jnp.float32))
      records = []
      while not bool(state.done) and len(records) * 120 < MAX_STEPS:
        state, chunk = advance(world, state)
        records.append(chunk)
      runs.append((jax.tree.map(np.asarray, state),
                   jax.tree.map(lambda *x: np.concatenate(x), *records)))
    out[name] = (world_grid, world, runs)
  return out


@pytest.mark.parametrize("name", ["tee", "loop", "room"])
def test_ereg_covers_the_world_and_ends_back_at_node_0(episodes, name):
  grid, world, runs = episodes[name]
  for state, _ in runs:
    assert state.reason == sim.EXHAUSTED  # the planner ended the episode, not the budget
    assert float(state.covered) == float(world.n_reachable)  # 100 % coverage
    memory = state.memory
    assert int(memory.current) == 0 and int(memory.mode) == reg.DONE
    assert int(memory.count) >= 3 and not bool(memory.overflow)
    # The robot stands where node 0 is (within the arrival tolerance of its cell centre).
    node0 = np.asarray(grid.origin) + memory.uv[0] * RES
    assert np.linalg.norm(state.pose_est[:2] - node0) <= reg.DEFAULTS["arrive_tol"] + RES
    # The graph is symmetric, uses only nodes in use, and is connected.
    count = int(memory.count)
    adjacent = memory.adjacent
    assert not adjacent[count:].any() and (adjacent == adjacent.T).all()
    reached, frontier = {0}, [0]
    while frontier:
      for j in np.nonzero(adjacent[frontier.pop()])[0]:
        if j not in reached:
          reached.add(j)
          frontier.append(j)
    assert reached == set(range(count))


@pytest.mark.parametrize("name", ["tee", "loop", "room"])
def test_ereg_is_deterministic(episodes, name):
  """Different keys, same start, no noise: Extended REG draws nothing, so the runs are equal."""
  _, _, ((state_0, records_0), (state_1, records_1)) = episodes[name]
  for leaf_0, leaf_1 in zip(jax.tree.leaves(records_0), jax.tree.leaves(records_1)):
    np.testing.assert_array_equal(leaf_0, leaf_1)
  np.testing.assert_array_equal(state_0.memory.uv, state_1.memory.uv)
  assert not np.array_equal(state_0.key, state_1.key)


def test_a_lidar_longer_than_the_lsr_radius_is_refused_with_belief_arcs():
  """Toriz & Sánchez's R is the sensor range. With the li2020 preset's 15 m lidar and R = 4 m,
  every arc within R ends in space the scans have already seen and belief_arcs closes it: ereg
  stopped at 12-80 % of lab. Refused before compute, naming the numbers and the ways out, each
  of which resolves."""
  with pytest.raises(ConfigError, match=r"r_max = 15 m is longer than the LSR radius R = 4 m"):
    runner.prepare(world="open", res=0.5, planner="ereg", robots=2, preset="li2020")
  runner.prepare(world="open", res=0.5, planner="ereg", robots=2)  # toriz, the planner's own
  runner.prepare(world="open", res=0.5, planner="ereg", robots=2, preset="li2020",
                 planner_params={"belief_arcs": False})
  runner.prepare(world="open", res=0.5, planner="ereg", robots=2, preset="li2020",
                 planner_params={"R": 15.0, "max_radius": 15.0})


def arc_inputs():
  """A node in the open with three frontier arcs of different widths."""
  bins = 120
  open_c = np.zeros(bins, bool)
  open_c[5:25] = open_c[50:60] = open_c[80:110] = True
  rho = np.full(bins, 20.0, np.float32)
  return jnp.asarray(open_c), jnp.asarray(rho), jnp.array([50.0, 50.0])


def test_random_arc_choice_differs_across_keys_and_repeats_per_key():
  open_c, rho, q = arc_inputs()
  select = jax.jit(jax.vmap(
      lambda key: reg._select_arc("reg", False, open_c, rho, q, 0.0, 0.5, 20.0,
                                  lambda p: jnp.ones(p.shape[:-1], bool), key, 121)))
  keys = jax.random.split(jax.random.PRNGKey(0), 16)
  found, phi, dest, fdet, _ = select(keys)
  again = select(keys)[1]
  assert bool(found.all())
  np.testing.assert_array_equal(np.asarray(phi), np.asarray(again))
  assert len(np.unique(np.round(np.asarray(phi), 4))) == 16
  # Every drawn direction lies in an open arc, and F_det holds the bin it falls in.
  bins = K.bin_of(phi, 120)
  assert bool(open_c[bins].all()) and bool(fdet[jnp.arange(16), bins].all())


def test_draws_follow_their_weights():
  """REG draws an arc uniformly, SRG in proportion to its width, SRT a free bin uniformly: all
  through the inverse cumulative distribution of :func:`reg._draw`."""
  weight = jnp.array([0.0, 3.0, 1.0, 0.0, 6.0])
  u = jax.random.uniform(jax.random.PRNGKey(3), (20_000,))
  drawn = np.asarray(jax.jit(reg._draw)(weight, u))
  frequency = np.bincount(drawn, minlength=5) / drawn.size
  np.testing.assert_allclose(frequency, np.asarray(weight) / 10.0, atol=0.015)
  assert int(reg._draw(weight, jnp.float32(0.0))) == 1  # zero weights are never drawn


def test_ereg_arc_choice_is_the_smallest_turn_and_ignores_the_key():
  open_c, rho, q = arc_inputs()
  select = jax.vmap(lambda key, theta: reg._select_arc(
      "ereg", False, open_c, rho, q, theta, 0.5, 20.0, lambda p: jnp.ones(p.shape[:-1], bool), key,
      121))
  keys = jax.random.split(jax.random.PRNGKey(1), 2)
  # Heading along bin 55's ray: the arc [50, 60) is straight ahead, chosen whatever the key.
  theta = float(K.bin_angles(120)[55])
  found, phi, _, fdet, _ = select(keys, jnp.array([theta, theta]))
  assert bool(found.all()) and float(phi[0]) == float(phi[1])
  assert abs(float(phi[0]) - (-math.pi + 55 * 2 * math.pi / 120)) < 1e-5  # the arc's middle
  np.testing.assert_array_equal(np.nonzero(np.asarray(fdet[0]))[0], np.arange(50, 60))


def test_srt_draws_differ_across_keys_repeat_per_key_and_respect_d_min():
  bins = 120
  obstacle = jnp.zeros(bins, bool).at[:60].set(True)
  rho = jnp.full(bins, 20.0)
  q = jnp.array([50.0, 50.0])
  uv = jnp.zeros((8, 2)).at[0].set(q).at[1].set(q + jnp.array([0.0, 10.0]))
  valid = jnp.arange(8) < 2
  select = jax.jit(jax.vmap(lambda key: reg._select_srt(
      obstacle, rho, q, uv, valid, 0.5, 5.0, 30.0, lambda p: jnp.ones(p.shape[:-1], bool), key,
      64)))
  keys = jax.random.split(jax.random.PRNGKey(2), 16)
  found, phi, dest = select(keys)
  np.testing.assert_array_equal(np.asarray(phi), np.asarray(select(keys)[1]))
  assert bool(found.all()) and len(np.unique(np.round(np.asarray(phi), 4))) == 16
  assert not bool(obstacle[K.bin_of(phi, bins)].any())  # only free bins are drawn
  assert float(jnp.min(jnp.linalg.norm(dest - uv[1][None, :], axis=-1))) >= 5.0


def test_validate_names_the_numbers():
  """validate keeps the checks relating a weight to a setting; the declared range of a single
  weight is the engine's check (check_weights)."""
  spec = base.get_planner("ereg")
  ctx = base.PlannerContext(height=10, width=10, res=0.1, settings=spec.settings)
  with pytest.raises(ConfigError, match="max_radius = 4.0"):
    spec.validate({"R": np.float32(5.0)}, None, ctx)
  with pytest.raises(ConfigError, match=r"weight r must be in \(0, 1\)"):
    spec.check_weights({"r": np.float32(1.0)})
  with pytest.raises(ConfigError, match="max_draws = 64"):
    spec.validate({"I_max": np.float32(100.0)}, None, ctx)


@pytest.mark.parametrize("planner_params, message", [
    ({"r": 1.5}, r"planner 'ereg': weight r must be in \(0, 1\), got 1.5"),
    ({"I_max": 0.0}, r"planner 'ereg': weight I_max must be >= 1, got 0"),
    ({"d_sep": -0.5}, r"planner 'ereg': weight d_sep must be >= 0, got -0.5"),
    ({"bins": 4}, r"planner 'ereg': setting bins must be .*>= 8, got 4"),
    ({"arc_reach": -1.0}, r"planner 'ereg': setting arc_reach must be >= 0, got -1"),
])
def test_resolve_refuses_a_value_outside_its_declared_range(planner_params, message):
  """The declared ranges of the weights and settings are checked when a run is resolved, before
  any compute, naming the value."""
  with pytest.raises(ConfigError, match=message):
    runner.prepare(world="open", res=0.5, planner="ereg", robots=1,
                   planner_params=planner_params)
