"""The planning scheduler: which robots plan before a step, on what part of the grid, and how
their answers are written back into the batch.

A robot plans when it needs to (:func:`needs_plan`): when its last step was idle (its path is
done or blocked and it already faces its look-at cell, or it never planned), or when
``replan_every`` steps have passed since its last plan, unless its planner commits to its goal.
Planning is by far the most expensive part of a step, and ``lax.cond`` under ``vmap`` would run
it for every robot, so :func:`plan_where_needed` gathers the robots that need a plan, plans them
a few at a time and scatters the answers back; the others cost nothing.

The planner sees a :class:`~jaxplore.planners.base.BeliefView` of one robot's belief (never the
truth) and a :class:`~jaxplore.planners.base.PlannerContext`; a planner with memory gets and
returns its ``State.memory``.
"""

from __future__ import annotations

import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import mapping, pytrees
from jaxplore.config import Params, SimConfig, window_margin
from jaxplore.graph import labels
from jaxplore.planners import base as planners_base
from jaxplore.planners import window as planning_window
from jaxplore.robot import EXHAUSTED, State, planner_context, robot_view
from jaxplore.world import World, cell_of


def unexplored(config: SimConfig, unknown):
  """The unknown cells that are unexplored space: all of them, but for the specks of at most
  ``config.map_hole_cells`` cells enclosed by known ones. Under pose error a wall drawn a cell
  off by one keyframe and passed through by the beams of another ends with evidence both ways
  (neither free nor occupied), and such a hole would be a frontier that no look resolves:
  seen again, the wall flickers elsewhere (Karto's grid keeps such cells occupied instead, as
  a cell hit in more than 10 % of the beams through it)."""
  if not config.map_hole_cells:
    return unknown
  return unknown & ~labels.enclosed_specks(unknown, config.map_hole_cells)


# Points sampled on each segment of the keyframe trajectory (:func:`trail_cells`): 16 keep them
# about half a cell apart on a segment of 8 cells (keyframes are ``kf_dist``, 0.3 m by default,
# apart: 1.5 cells at 0.2 m, 6 at 0.05 m); a longer segment's cells may have gaps.
TRAIL_SAMPLES = 16


def trail_cells(config: SimConfig, world: World, state: State):
  """The cells of one robot's keyframe trajectory as it now estimates it: segments from each
  keyframe's pose to the next and from the last to the current estimate, i32[N * S, 2] (row,
  col); the samples of unused keyframe slots are (-1, -1), which no grid holds.

  The robot's centre has been in these cells (up to its pose error), so they are a route it can
  drive again although the belief may draw a wall within its radius of them; taken from the
  pose graph, the trail follows every correction of the poses (a loop closure moves it with the
  map rebuilt from the same keyframes)."""
  graph = state.graph
  index = jnp.arange(graph.poses.shape[0])
  start = graph.poses[:, :2]
  stop = jnp.where((index + 1 < graph.n_nodes)[:, None], jnp.roll(start, -1, axis=0),
                   state.pose_est[None, :2])
  t = jnp.linspace(0.0, 1.0, TRAIL_SAMPLES)
  points = start[:, None] + t[None, :, None] * (stop - start)[:, None]  # [N, S, 2] (x, y)
  cells = jnp.moveaxis(cell_of(jnp.moveaxis(points, -1, 0), world.origin, config.res), 0, -1)
  cells = jnp.where((index < graph.n_nodes)[:, None, None], cells, -1)
  return cells.reshape(-1, 2)


def belief_view(config: SimConfig, params: Params, state: State, robot_cell, trail=None,
                inflate: bool = True) -> planners_base.BeliefView:
  """The planner's view of one robot's belief (masks computed once per planning round).

  Traversable cells are free cells clear of believed walls by the robot radius, plus an escape
  route: the free cells of the inflated zone that the robot reaches within
  ``max_inflation_cells + 1`` steps without ever stepping closer to a believed wall, so a robot
  that newly mapped walls inside its radius can drive out of the inflated zone but never deeper
  into it (with any escape cell traversable, goals near walls pulled the robot a few cells
  further into a narrowing notch at each plan until it stood where no plan led out). With
  ``trail`` (cells, i32[K, 2], in the view's coordinates: :func:`trail_cells`), the free cells
  the robot has driven through are traversable too: under SLAM a wall drawn a cell off by a
  keyframe's few centimetres of pose error closes a passage of three or four cells to the
  inflated belief, and a robot that went through one could otherwise never come back. Without
  ``inflate`` every free cell is traversable (the last recovery, :func:`_recover`).
  """
  free, occupied, unknown = mapping.classify(state.logodds, params)
  wall_distance_sq = mapping.distance_sq_within(occupied, config.max_inflation_cells)
  inflated = mapping.within_radius(wall_distance_sq.astype(jnp.float32),
                                   params.r_robot / config.res if inflate else 0.0)
  escape_zone = free & inflated
  # A cell off the grid (an estimate beyond the edge) starts no route: dropped, not wrapped.
  escape = jnp.zeros(free.shape, bool).at[robot_cell[0], robot_cell[1]].set(
      True, mode="drop", wrap_negative_indices=False) & escape_zone
  framed_distance = mapping.frame(wall_distance_sq, -1)

  def widen(_, escape):
    # A cell joins from a neighbour on the route that is no farther from the walls than it is.
    framed = mapping.frame(escape, False)
    joins = jnp.zeros(free.shape, bool)
    for di, dj in mapping.NEIGHBOURS_8:
      joins = joins | (mapping.shifted(framed, di, dj)
                       & (mapping.shifted(framed_distance, di, dj) <= wall_distance_sq))
    return escape | (joins & escape_zone)

  # A loop, not unrolled: XLA would fuse each step into the next one's 8 neighbour reads.
  escape = jax.lax.fori_loop(0, config.max_inflation_cells + 1, widen, escape)
  traversable = (free & ~inflated) | escape
  if trail is not None:
    on_trail = jnp.zeros(free.shape, bool).at[trail[:, 0], trail[:, 1]].set(
        True, mode="drop", wrap_negative_indices=False)
    traversable = traversable | (free & on_trail)
  return planners_base.BeliefView(
      logodds=state.logodds, free=free, occupied=occupied,
      unknown=unknown, inflated=inflated, traversable=traversable,
      frontier=mapping.frontier(free, unexplored(config, unknown), occupied),
      blacklist=state.blacklist,
      pose_graph=(state.graph if config.planner.needs_pose_graph
                  else None))


def _window_origin(config: SimConfig, cell, side: int):
  """Top-left cell of the ``side``-wide window centred on ``cell``, shifted to lie in the grid."""
  return jnp.stack([jnp.clip(cell[0] - side // 2, 0, config.height - side),
                    jnp.clip(cell[1] - side // 2, 0, config.width - side)]).astype(jnp.int32)


_MAP_FIELDS = ("logodds", "blacklist")


def _small_fields() -> tuple[str, ...]:
  """The state's fields a planning round reads whole and writes back (all but the maps)."""
  return tuple(f.name for f in dataclasses.fields(State) if f.name not in _MAP_FIELDS)


def crop_maps(state: State, origin, shape) -> State:
  """``state`` with its maps cut to the ``shape`` region at ``origin`` (what a window plans on)."""
  crop = lambda grid: None if grid is None else jax.lax.dynamic_slice(
      grid, (origin[0], origin[1]), shape)
  return state.replace(**{name: crop(getattr(state, name)) for name in _MAP_FIELDS})


def _propose(config: SimConfig, params: Params, state: State, robot, origin, key, trail=None,
             inflate: bool = True):
  """The planner's plan on the region of the grid that ``state``'s maps hold, at ``origin``.

  Returns (plan in grid coordinates, new memory, certified). The region is the whole grid (a
  plan there is always certified) or a window around the robot
  (:mod:`jaxplore.planners.window`).
  """
  spec = config.planner
  shape = state.logodds.shape
  ctx = planner_context(config, shape)
  cell = robot.cell - origin
  view = belief_view(config, params, state, cell, None if trail is None else trail - origin[None],
                     inflate)
  whole_grid = shape == (config.height, config.width)
  if not whole_grid:
    view, edge = planning_window.restrict(view, cell, origin, (config.height, config.width),
                                          window_margin(config.max_inflation_cells))
  local = robot.replace(cell=cell, position=None if robot.position is None else
                        robot.position - origin.astype(robot.position.dtype))
  result, memory = spec.propose(ctx, view, local, params, key, state.memory)
  certified = jnp.bool_(True) if whole_grid else planning_window.certified(result, edge, config.res)
  return planning_window.to_grid(result, origin), memory, certified


# explore_lite (m-explore, ``explore.cpp``'s ``goalOnBlacklist``) takes a goal within 5 cells
# of a blacklisted one, along both axes, for the blacklisted goal itself: its neighbouring
# frontier cells would otherwise be chosen next, one after another.
STALL_BLACKLIST_CELLS = 5
_STALL_BOX = np.stack(np.meshgrid(
    np.arange(-STALL_BLACKLIST_CELLS, STALL_BLACKLIST_CELLS + 1),
    np.arange(-STALL_BLACKLIST_CELLS, STALL_BLACKLIST_CELLS + 1), indexing="ij"),
    axis=-1).reshape(-1, 2).astype(np.int32)


@pytrees.dataclass(frozen=True)
class PlanOutcome:
  """What one planning round changes in one robot's state.

  Attributes:
    state: the robot's state with its new plan; its map leaves are not meaningful (a round
      reads the maps of a region of the grid and writes nothing but ``marks`` to them).
    marks: i32[2 + S, 2] goal cells to blacklist (the goal the robot arrived at, a stuck goal,
      the S cells around the goal of a stalled robot).
    mark: bool[2 + S] which of ``marks`` apply.
    certified: bool; False when a window could not certify its plan: then nothing changes.
  """

  state: State
  marks: chex.Array
  mark: chex.Array
  certified: chex.Array


def _plan_round(config: SimConfig, world: World, params: Params, state: State, origin,
                recovery: int = 0) -> PlanOutcome:
  """One robot's planning round on the region of the grid that ``state``'s maps hold.

  ``state`` is one robot's state whose map leaves are the whole grid (``origin`` = (0, 0)) or,
  for a ``windowed`` planner, a window at ``origin`` (:func:`crop_maps`). A robot whose planner
  finds no candidate ends ``exhausted`` (unless already complete). A goal chosen twice in a row
  while the robot already stands on it cannot be resolved from here and is blacklisted, so no
  robot waits on it forever; so are the cells around the goal of a robot that has stalled
  (driven ``stall_m`` without leaving ``stall_span`` or gaining a free cell:
  :func:`jaxplore.robot._watch_stall`), as explore_lite blacklists a goal with a tolerance of
  :data:`STALL_BLACKLIST_CELLS` cells. ``recovery`` (:func:`_recover`): 1, the robot may plan
  along its keyframe trajectory (:func:`belief_view`); 2, and through every free cell of its
  belief, its radius ignored.
  """
  spec = config.planner
  key, k_plan = jax.random.split(state.key)
  running = ~state.done
  arrival_goal = state.goal
  arrived = jnp.bool_(False)
  if spec.blacklist_on_arrival:
    arrived = running & (state.path_len > 0) & (state.path_idx >= state.path_len)
    local_goal = state.goal - origin
    state = state.replace(blacklist=state.blacklist.at[local_goal[0], local_goal[1]].max(
        arrived, mode="drop", wrap_negative_indices=False))
  stalled = running & (params.stall_m > 0) & (state.stall_m >= params.stall_m) & jnp.all(
      state.goal >= 0)
  stall_cells = state.goal[None] + _STALL_BOX
  local = stall_cells - origin[None]
  state = state.replace(
      blacklist=state.blacklist.at[local[:, 0], local[:, 1]].max(
          stalled, mode="drop", wrap_negative_indices=False),
      stall_m=jnp.where(stalled, 0.0, state.stall_m))
  robot = robot_view(config, world, state)
  trail = trail_cells(config, world, state) if recovery else None
  result, memory, certified = _propose(config, params, state, robot, origin, k_plan, trail,
                                       inflate=recovery < 2)
  stuck = running & result.valid & (result.length <= 1) & jnp.all(result.goal == state.last_goal)
  exhausted = running & ~result.valid
  install = running & result.valid
  state = state.replace(
      key=key, since_plan=jnp.int32(0),
      waypoints=jnp.where(install, result.waypoints, state.waypoints),
      path_len=jnp.where(install, result.length, 0),
      path_idx=jnp.where(install, jnp.minimum(1, result.length), 0),
      goal=jnp.where(install, result.goal, state.goal),
      look_at=jnp.where(install, result.look_at, robot.cell),
      last_goal=jnp.where(install, result.goal, state.last_goal),
      on_trail=jnp.where(install, recovery > 0, state.on_trail),
      done=state.done | exhausted,
      reason=jnp.where(exhausted, EXHAUSTED, state.reason),
      memory=jax.tree.map(lambda new, old: jnp.where(running, new, old), memory, state.memory))
  return PlanOutcome(
      state=state, marks=jnp.concatenate([jnp.stack([arrival_goal, result.goal]), stall_cells]),
      mark=jnp.concatenate([jnp.stack([arrived, stuck]),
                            jnp.broadcast_to(stalled, (len(_STALL_BOX),))]),
      certified=certified)


def _apply_plans(state: State, robots, outcome: PlanOutcome) -> State:
  """Writes the outcomes of robots ``robots`` (i32[C], a batch of outcomes) into the batched
  ``state``: the small leaves of certified outcomes, and their blacklist marks."""
  ok = outcome.certified

  def write(old, new):
    keep = ok.reshape(ok.shape + (1,) * (new.ndim - 1))
    return old.at[robots].set(jnp.where(keep, new, old[robots]))

  small = {name: jax.tree.map(write, getattr(state, name), getattr(outcome.state, name))
           for name in _small_fields()}
  mark = outcome.mark & ok[:, None]
  rows, cols = outcome.marks[..., 0], outcome.marks[..., 1]
  blacklist = state.blacklist.at[robots[:, None], rows, cols].max(
      mark, mode="drop", wrap_negative_indices=False)
  return state.replace(blacklist=blacklist, **small)


# The recoveries a robot that found nothing on its belief tries before it gives up
# (:func:`_recover`): its keyframe trail, then every free cell its radius ignored.
RECOVERIES = (1, 2)


def _recover(config: SimConfig, outcome: PlanOutcome, was_done, replan,
             recoveries: tuple[int, ...] = RECOVERIES) -> PlanOutcome:
  """``outcome``, but where a robot ended ``exhausted`` (found nothing on its belief), the
  outcome of ``replan(recovery)`` for each of :data:`RECOVERIES` in turn until one finds a plan
  (``config.trail``; :func:`_plan_round`), as a navigation stack's recoveries clear its costmap
  before it gives up: the same round along the robot's keyframe trail, then through every free
  cell of its belief, its radius ignored (under SLAM a wall drawn a cell off narrows a door of
  three or four cells to nothing once inflated; the robot's collisions with the true walls
  still stop it). ``was_done``: the robots' ``done`` before the round. Only a round with such a
  robot runs ``replan`` (a batch-level ``cond``). A window's round tries the trail only: a
  window without a frontier is no reason to squeeze through its narrow places, the whole grid
  is planned next (with every free cell in a window, robots on `intel` took the narrow way to
  the nearest frontier again and again, and ten of sixteen ended shut in, against one)."""
  if not config.trail:
    return outcome
  for recovery in recoveries:
    retry = outcome.state.done & ~was_done & (outcome.state.reason == EXHAUSTED)
    pick = lambda new, old, retry=retry: jnp.where(
        retry.reshape(retry.shape + (1,) * (new.ndim - retry.ndim)), new, old)
    outcome = jax.lax.cond(jnp.any(retry),
                           lambda recovery=recovery, outcome=outcome, pick=pick: jax.tree.map(
                               pick, replan(recovery), outcome),
                           lambda outcome=outcome: outcome)
  return outcome


def plan(config: SimConfig, world: World, params: Params, state: State) -> State:
  """One robot's planning round on the whole grid: ask the planner, install the path, handle
  no-op goals (see :func:`_plan_round`; with ``config.trail``, :func:`_recover`)."""
  origin = jnp.zeros((2,), jnp.int32)
  outcome = _recover(config, _plan_round(config, world, params, state, origin), state.done,
                     lambda recovery: _plan_round(config, world, params, state, origin, recovery))
  batch = lambda tree: jax.tree.map(lambda x: x[None], tree)
  new = _apply_plans(batch(state), jnp.zeros((1,), jnp.int32), batch(outcome))
  return jax.tree.map(lambda x: x[0], new)


def needs_plan(config: SimConfig, state: State):
  """Whether a robot plans before its next step: it is running, and its last step was idle or
  ``replan_every`` steps have passed since its last plan (never, for a planner that commits to
  its goal: it plans again when its path is done or blocked)."""
  if config.planner.commits:
    return ~state.done & ~state.busy
  return ~state.done & (~state.busy | (state.since_plan >= config.replan_every))


def uses_window(config: SimConfig) -> bool:
  """Whether planning tries a window first (a ``windowed`` planner, a window smaller than the
  grid)."""
  return (config.planner.windowed and
          0 < config.plan_window < min(config.height, config.width))


def _plan_robots(config: SimConfig, world: World, params: Params, state: State, need, window: int,
                 chunk: int):
  """:func:`plan` for the robots with ``need`` set, ``chunk`` at a time, on the window of
  ``window`` cells around each (0 = the whole grid). Returns the new state and which robots got
  their plan (all of them on the whole grid; with a window, those whose plan was certified: the
  others keep their state).

  Each robot's maps are read straight from the batch, cropped to its window; a round writes
  back only its small leaves and blacklist marks (:func:`_apply_plans`), never whole maps.
  """
  batch = need.shape[0]
  chunk = min(chunk, batch)
  n_need = jnp.sum(need.astype(jnp.int32))
  order = jnp.nonzero(need, size=batch + chunk, fill_value=-1)[0]
  # A last partial chunk is filled with copies of its own last robot: they plan from the same
  # state and write the same result. (A robot of an earlier chunk would plan a second time,
  # from its new state, and its key would advance twice: the noise it draws next, and so its
  # run, would depend on the batch around it.)
  order = jnp.where(order < 0, order[jnp.maximum(n_need - 1, 0)], order)
  n_chunks = (n_need + chunk - 1) // chunk
  shape = (window, window) if window else (config.height, config.width)

  def plan_chunk(k, carry):
    state, planned = carry
    robots = jax.lax.dynamic_slice(order, (k * chunk,), (chunk,))

    def plan_one(p, robot, recovery=0):
      one = {name: jax.tree.map(lambda x: x[robot], getattr(state, name))
             for name in _small_fields()}
      cell = cell_of(one["pose_est"][:2], world.origin, config.res)
      origin = _window_origin(config, cell, window) if window else jnp.zeros((2,), jnp.int32)
      corner = (robot, origin[0], origin[1])
      crop = lambda grid: None if grid is None else jax.lax.dynamic_slice(
          grid, corner, (1,) + shape)[0]
      maps = {name: crop(getattr(state, name)) for name in _MAP_FIELDS}
      return _plan_round(config, world, p, State(**one, **maps), origin, recovery)

    chunk_params = jax.tree.map(lambda x: x[robots], params)
    outcome = _recover(
        config, jax.vmap(plan_one)(chunk_params, robots), state.done[robots],
        lambda recovery: jax.vmap(functools.partial(plan_one, recovery=recovery))(chunk_params,
                                                                                 robots),
        RECOVERIES[:1] if window else RECOVERIES)
    return _apply_plans(state, robots, outcome), planned.at[robots].set(outcome.certified)

  return jax.lax.fori_loop(0, n_chunks, plan_chunk, (state, jnp.zeros_like(need)))


def lockstep_plan_chunk(config: SimConfig, batch: int) -> int:
  """Robots planned together in the lockstep window round (or, without a window, on the whole
  grid): those expected to plan at one step, ``1 / replan_every`` of the batch, at least
  ``config.lockstep_min_chunk``, at most the batch.

  One chunk's shortest paths are solved together by relaxation. Planning the whole batch at
  every step (about 1 in ``replan_every`` robots needs to) spent most of its time in the
  whole-grid solves that a few robots needed; gathering those into chunks of at least 64 ran
  several times faster on a GPU (``experiments/results/bench_accelerator_gpu.md``, "Gathered
  planning chunks"), and smaller floors gained little there
  (``bench_lockstep_variants_gpu.md``: ``chunk4``)."""
  return min(batch, max(config.lockstep_min_chunk, -(-batch // config.replan_every)))


def _plan_robots_by_need(config: SimConfig, world: World, params: Params, state: State, need,
                         chunk: int):
  """:func:`_plan_robots` on the whole grid in the smallest of ``config.lockstep_small_chunks``
  that holds every robot with ``need`` set, else in chunks of ``chunk`` as before.

  A planner that replans only when its path is done (li2020) has a robot or two of 64
  planning at a typical step, and a chunk pays for all its rows, copies included. The planner is
  compiled once per size (``lax.switch``); each call is never larger, nor are there more of them.
  The default sizes are a ladder of factor 4 (4, 16, 64, ...), so a round pays for at most 4
  times the rows it needs: chunks by need beat fixed chunks for li2020 on ``lab`` on a GPU, at
  more compile time, and the full ladder beat 4 and 16 alone on a CPU with lockstep forced while
  a GPU showed no difference (``experiments/results/bench_lockstep_variants_gpu.md``,
  ``bench_lockstep_ladder_cpu.md``). A chunk's size never changes a plan, so the results are
  the same bit for bit.
  """
  chunk = min(chunk, need.shape[0])
  sizes = sorted({size for size in config.lockstep_small_chunks if size < chunk} | {chunk})
  rounds = [functools.partial(_plan_robots, config, world, params, need=need, window=0,
                              chunk=size) for size in sizes]
  if len(rounds) == 1:
    return rounds[0](state)
  n_need = jnp.sum(need.astype(jnp.int32))
  branch = sum((n_need > size).astype(jnp.int32) for size in sizes[:-1])
  return jax.lax.switch(branch, rounds, state)


def _plan_where_needed_lockstep(config: SimConfig, world: World, params: Params, state: State
                                ) -> State:
  """:func:`plan_where_needed` for an accelerator: the robots that need a plan are gathered in
  chunks (the last filled with copies of its own last robot), each chunk one set of kernels, its
  shortest paths solved by relaxation (:data:`jaxplore.graph.STRATEGY_BATCHING`). The window
  round takes the robots expected to plan at one step (:func:`lockstep_plan_chunk`) as one
  chunk: a planner whose work is a long loop of small kernels (li2020's visible gains) pays per
  chunk, not per robot. The whole-grid round after it, for the few plans the window could not
  certify, takes chunks of ``config.lockstep_min_chunk``, or a smaller chunk when one holds them
  all (:func:`_plan_robots_by_need`; ``config.lockstep_leftovers_by_need``): a whole-grid solve
  costs per row, and chunks by need ran faster on a CPU with lockstep forced, no slower on a GPU
  (``experiments/results/bench_lockstep_leftovers_cpu.md``,
  ``bench_lockstep_variants_gpu.md``). A planner without a window plans on the whole grid in
  the window round's chunks, or in a smaller one by need likewise. The results are
  :func:`plan_where_needed`'s."""
  need = needs_plan(config, state)
  batch = need.shape[0]
  per_step = lockstep_plan_chunk(config, batch)
  if not uses_window(config):
    return _plan_robots_by_need(config, world, params, state, need, per_step)[0]
  state, certified = _plan_robots(config, world, params, state, need, config.plan_window,
                                  per_step)
  leftovers = min(batch, config.lockstep_min_chunk)
  if not config.lockstep_leftovers_by_need:
    return _plan_robots(config, world, params, state, need & ~certified, 0, leftovers)[0]
  return _plan_robots_by_need(config, world, params, state, need & ~certified, leftovers)[0]


def plan_where_needed(config: SimConfig, world: World, params: Params, state: State) -> State:
  """:func:`plan` for the robots of a batch that need it (:func:`needs_plan`).

  ``params`` and ``state`` carry a leading batch axis. The robots that plan are gathered in
  chunks of ``config.plan_chunk``, planned with ``vmap`` (a chunk of 4 plans about twice as fast
  per robot as one robot alone: the shortest-path sweeps vectorise across the chunk) and
  scattered back in place; robots that do not plan cost nothing, where a batched ``lax.cond``
  would run the planner for all of them. A last partial chunk is filled with repeats of its own
  last robot (its copies compute and write the same result); on the whole grid, the robots
  left over after full chunks plan one at a time instead.

  With a planning window (:func:`uses_window`), every robot first plans on the window around
  it, and only those whose answer the window cannot certify plan again on the whole grid: the
  work follows the distance to the nearest candidate instead of the grid's size.

  With the ``lockstep`` strategy (``SimConfig.strategy``, an accelerator's default) the chunks
  are larger and the shortest paths are solved by relaxation
  (:func:`_plan_where_needed_lockstep`).
  """
  if config.strategy == "lockstep":
    return _plan_where_needed_lockstep(config, world, params, state)
  need = needs_plan(config, state)
  if uses_window(config):
    state, certified = _plan_robots(config, world, params, state, need, config.plan_window,
                                    config.plan_chunk)
    need = need & ~certified
  # Whole-grid plans are few and dear: the robots left over after full chunks plan one by one
  # rather than in a chunk padded with copies, which was faster, the more so the more robots
  # are beyond their window (experiments/results/plan_window.md).
  chunk = min(config.plan_chunk, need.shape[0])
  if chunk == 1:
    return _plan_robots(config, world, params, state, need, 0, 1)[0]
  rank = jnp.cumsum(need.astype(jnp.int32)) - 1
  in_full_chunks = rank < (rank[-1] + 1) // chunk * chunk
  state, _ = _plan_robots(config, world, params, state, need & in_full_chunks, 0, chunk)
  state, _ = _plan_robots(config, world, params, state, need & ~in_full_chunks, 0, 1)
  return state


