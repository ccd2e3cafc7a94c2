"""Every registered planner against the planner contract (after jumanji's
``check_env_does_not_smoke`` and pgx's API tests): one robot and a vmapped batch, eager and
jitted, per_robot and lockstep; shapes and dtypes of the plan and of the memory; finite outputs; no retrace when a traced
number changes; a plan is a chain of 8-neighbours over believed-free cells only.

A planner added to the registry is checked here without a line of its own.
"""

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import mapping, posegraph
from jaxplore.config import make_params
from jaxplore.planners import base, planner_names
from tests.conftest import lapack_calls

H, W, L = 24, 32, 64
BATCH = 2


def belief_logodds():
  """Known rooms on the left (a wall with a door, a box), unknown space on the right."""
  state = np.zeros((H, W), int)  # 0 free, 1 occupied, 2 unknown
  state[0, :] = state[-1, :] = state[:, 0] = 1
  state[:, 20:] = 2
  state[12, 1:8] = state[12, 11:20] = 1
  state[4:7, 13:16] = 1
  state[5:9, 23:26] = 1  # a wall seen inside the unknown region
  return np.where(state == 0, -3.0, np.where(state == 1, 3.0, 0.0)).astype(np.float32)


def context(spec):
  return base.PlannerContext(height=H, width=W, res=0.1, path_capacity=L, max_inflation_cells=2,
                             max_steps=400, settings=spec.settings)


def view_and_robot(spec, params, cell, theta):
  logodds = jnp.asarray(belief_logodds())
  free, occupied, unknown = mapping.classify(logodds, params)
  inflated = mapping.inflate(occupied, params.r_robot / 0.1, 2)
  robot = base.RobotView(pose=jnp.asarray([cell[1] * 0.1 + 0.05, cell[0] * 0.1 + 0.05, theta],
                                          jnp.float32),
                         cell=jnp.asarray(cell, jnp.int32), cov=jnp.eye(3, dtype=jnp.float32) * 1e-4,
                         position=jnp.asarray(cell, jnp.float32) + 0.5)
  # A pose graph of one keyframe at the robot, for planners that read one.
  graph = posegraph.init(robot.pose, 16, 8) if spec.needs_pose_graph else None
  view = base.BeliefView(logodds=logodds, free=free, occupied=occupied,
                         unknown=unknown, inflated=inflated, traversable=free & ~inflated,
                         frontier=mapping.frontier(free, unknown, occupied),
                         blacklist=jnp.zeros((H, W), bool), pose_graph=graph)
  return view, robot


def params_of(spec, **overrides):
  return make_params(res=0.1, r_robot=0.15, r_max=2.0, planner=dict(spec.defaults, **overrides))


def one_plan(spec, ctx):
  """(params, key, cell, theta) -> (Plan, memory) for one robot, from a fresh memory."""
  def fn(params, key, cell, theta):
    view, robot = view_and_robot(spec, params, cell, theta)
    memory = spec.initial_memory(ctx, params)
    if spec.step_hook is not None:  # the reset's first scan (li2020: its entropy map)
      memory = spec.step_hook(ctx, params, memory, robot, view.logodds, jnp.bool_(True))
    return spec.propose(ctx, view, robot, params, key, memory)
  return fn


def inputs(batch=None):
  cells = np.array([[6, 4], [18, 10]], np.int32)
  thetas = np.array([0.3, -2.0], np.float32)
  keys = jax.random.split(jax.random.PRNGKey(7), 2)
  if batch is None:
    return keys[0], jnp.asarray(cells[0]), jnp.float32(thetas[0])
  return keys, jnp.asarray(cells), jnp.asarray(thetas)


def check_plan(plan, memory, initial_memory, logodds):
  """Shapes, dtypes, finiteness and a walkable path for one robot's answer (NumPy)."""
  chex.assert_shape(plan.waypoints, (L, 2))
  assert plan.waypoints.dtype == np.int32 and plan.goal.dtype == np.int32
  assert plan.look_at.dtype == np.int32 and plan.length.dtype == np.int32
  assert plan.valid.dtype == np.bool_ and plan.n_candidates.dtype == np.int32
  for name in ("length", "goal", "look_at", "valid", "gain", "cost", "n_candidates"):
    chex.assert_shape(getattr(plan, name), (2,) if name in ("goal", "look_at") else ())
  assert np.isfinite(plan.gain)
  assert 0 <= int(plan.length) <= L
  chex.assert_trees_all_equal_shapes_and_dtypes(memory, initial_memory)
  chex.assert_tree_all_finite(jax.tree.map(lambda x: np.asarray(x, np.float64), memory))
  if not plan.valid:
    return
  assert np.isfinite(plan.cost)
  cells = plan.waypoints[: int(plan.length)]
  free = logodds < 0
  assert free[cells[:, 0], cells[:, 1]].all(), "a plan through an occupied or unknown cell"
  steps = np.abs(np.diff(cells, axis=0))
  assert (steps.max(axis=1, initial=0) <= 1).all(), "waypoints are not 8-neighbours"


@pytest.fixture(scope="module", params=planner_names())
def planner(request):
  """The planner's one-robot function, and its jitted form that fails on a second trace (shared
  by the tests below: one compile per planner)."""
  spec = base.get_planner(request.param)
  ctx = context(spec)
  fn = one_plan(spec, ctx)
  params = params_of(spec)
  chex.clear_trace_counter()
  return spec, ctx, fn, params, jax.jit(chex.assert_max_traces(fn, n=1))


@pytest.fixture(scope="module")
def batch_plans(planner):
  """The planner's plans for a vmapped batch of BATCH robots (per_robot), and the text of the
  program that planned them, shared by the tests."""
  spec, ctx, fn, params, _ = planner
  batched = jax.tree.map(lambda x: jnp.broadcast_to(x, (BATCH,) + jnp.shape(x)), params)
  lowered = jax.jit(jax.vmap(fn)).lower(batched, *inputs(BATCH))
  plans = jax.tree.map(np.asarray, lowered.compile()(batched, *inputs(BATCH)))
  return batched, plans, lowered.as_text()


# A planner family's members run the same code with other settings: the suite keeps the fullest
# of each (ereg of reg.py, frt of godoy2023.py's, ahmed of ahmed.py's) under lockstep and eagerly,
# and leaves the others, ~5 s of compile or of eager dispatch each, to `pytest -m slow` (their
# jitted plans are checked below all the same).
FAMILY_REPEATS = ("reg", "srg", "srt", "ig", "ags")
ONE_OF_EACH_FAMILY = [pytest.param(name, marks=pytest.mark.slow) if name in FAMILY_REPEATS
                      else name for name in planner_names()]


@pytest.mark.parametrize("planner", ONE_OF_EACH_FAMILY, indirect=True)
def test_one_robot_eager_and_jitted_agree_and_conform(planner):
  spec, ctx, fn, params, jitted_fn = planner
  eager = jax.tree.map(np.asarray, fn(params, *inputs()))
  jitted = jax.tree.map(np.asarray, jitted_fn(params, *inputs()))
  initial = jax.tree.map(np.asarray, spec.initial_memory(ctx, params))
  check_plan(*eager, initial, belief_logodds())
  chex.assert_trees_all_close(eager, jitted, atol=1e-4, rtol=1e-4)


def test_batch_vmapped_conforms_and_equals_one_at_a_time(planner, batch_plans):
  spec, ctx, fn, params, jitted_fn = planner
  keys, cells, thetas = inputs(BATCH)
  plans, memories = batch_plans[1]
  initial = jax.tree.map(np.asarray, spec.initial_memory(ctx, params))
  for b in range(BATCH):
    plan_b, memory_b = jax.tree.map(lambda x: x[b], (plans, memories))
    check_plan(plan_b, memory_b, initial, belief_logodds())
    alone = jax.tree.map(np.asarray, jitted_fn(params, keys[b], cells[b], thetas[b]))
    chex.assert_trees_all_close((plan_b, memory_b), alone, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("planner", ONE_OF_EACH_FAMILY, indirect=True)
def test_a_batch_plans_the_same_under_both_strategies(planner, batch_plans):
  """The accelerator's strategy forced on a CPU: ``lockstep`` (shortest paths by relaxation, the
  planner's lockstep paths) plans a vmapped batch bit for bit as ``per_robot`` does."""
  spec, ctx, _, _, _ = planner
  batched, per_robot, _ = batch_plans
  lockstep_fn = one_plan(spec, dataclasses.replace(ctx, strategy="lockstep"))
  lockstep = jax.jit(jax.vmap(lockstep_fn))(batched, *inputs(BATCH))
  chex.assert_trees_all_equal(jax.tree.map(np.asarray, lockstep), per_robot)


def test_a_batch_calls_no_batched_lapack_kernel(batch_plans):
  """A batch's plan makes no LAPACK call over a batch of matrices: jaxlib's batched kernels split
  over XLA:CPU's thread pool and hung runs of a few robots on two host devices (gpbo, ahmed and
  ags did; :mod:`jaxplore.linalg`). Every planner's batched program is checked here; a run of
  each on two devices end to end is ``tests/test_smoke.py``."""
  calls = lapack_calls(batch_plans[2])
  assert all(batch_dims == "0" for _, batch_dims in calls), calls
  assert "func.func public @main" in batch_plans[2]  # the text is a program's


def test_changing_a_traced_number_does_not_retrace(planner):
  """The shared jitted function has traced once; new values of a weight must not trace it
  again (``assert_max_traces`` raises)."""
  spec, ctx, fn, params, counted = planner
  counted(params, *inputs())
  if spec.defaults:
    name = sorted(spec.defaults)[0]
    changed = params.replace(planner=dict(params.planner, **{name: params.planner[name] * 0.5}))
  else:
    changed = params.replace(r_max=params.r_max * 0.75)
  counted(changed, *inputs())  # a second trace raises


def test_every_planner_is_documented_and_its_settings_are_static():
  for name in planner_names():
    spec = base.get_planner(name)
    assert spec.summary, f"planner {name} has no summary"
    assert spec.plan.__doc__ or spec.summary
    hash(spec.settings)  # static settings are a jit cache key
    for weight, value in spec.defaults.items():
      assert np.isfinite(float(value)), (name, weight)
