"""The planner interface shared by every paper's planner, and the registry.

A planner is a pure function ``plan(config, view, robot, params, key) -> Plan`` for ONE robot
(the engine batches it). It sees the belief, never the truth. The simulator knows nothing about
any one paper: it calls the planner named in ``SimConfig.planner``.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import chex
import jax
import jax.numpy as jnp

from jaxplore import mapping
from jaxplore.config import ConfigError


@chex.dataclass(frozen=True)
class BeliefView:
  """What a planner may look at (one robot).

  Attributes:
    logodds: f32[H, W] occupancy belief.
    entropy_map: f32[H, W] Li's smoothed entropy map I_e (Eq 3).
    free, occupied, unknown: bool[H, W] belief classes.
    inflated: bool[H, W] cells within the robot radius of a believed-occupied cell.
    traversable: bool[H, W] free cells clear of occupied cells by the robot radius.
    frontier: bool[H, W] free cells next to unknown ones (see :func:`mapping.frontier`).
    blacklist: bool[H, W] goals the engine found unresolvable for this robot.
  """

  logodds: chex.Array
  entropy_map: chex.Array
  free: chex.Array
  occupied: chex.Array
  unknown: chex.Array
  inflated: chex.Array
  traversable: chex.Array
  frontier: chex.Array
  blacklist: chex.Array


@chex.dataclass(frozen=True)
class RobotView:
  """The robot as it believes itself to be: estimated pose (m, rad), its cell, covariance Σ."""

  pose: chex.Array  # f32[3]
  cell: chex.Array  # i32[2] (row, col)
  cov: chex.Array  # f32[3, 3]


@chex.dataclass(frozen=True)
class Plan:
  """A planner's answer for one robot.

  Attributes:
    waypoints: i32[L, 2] cells (row, col) from the robot's cell on; only ``length`` are valid.
    length: i32, number of valid waypoints (0 = no plan).
    goal: i32[2], the cell the plan is for (for bookkeeping: blacklist, figures).
    look_at: i32[2], a cell to face once the last waypoint is reached (e.g. the unknown cell
      behind a frontier), so narrow field-of-view sensors see what the goal was chosen for.
    valid: bool, a candidate was found.
    gain: f32, the planner's utility of the chosen candidate (planner-defined units).
    cost: f32, path cost of the chosen candidate (m, weighted by the planner's edge weights).
    n_candidates: i32, how many candidates the planner scored.
  """

  waypoints: chex.Array
  length: chex.Array
  goal: chex.Array
  look_at: chex.Array
  valid: chex.Array
  gain: chex.Array
  cost: chex.Array
  n_candidates: chex.Array


PlanFn = Callable[..., Plan]


@dataclasses.dataclass(frozen=True)
class PlannerSpec:
  """A registered planner.

  Attributes:
    name: registry name (command line ``--planner``).
    plan: the plan function.
    defaults: default weights (traced leaves of ``Params.planner``).
    summary: one line for listings.
    blacklist_on_arrival: the engine blacklists a goal once the robot has reached the end of
      the path to it (Ahmed's FD), so it is never chosen again.
    validate: optional host-side check of the resolved weights and config,
      ``validate(weights: dict[str, array], params, config) -> None``, raising ``ConfigError``.
    windowed: the planner picks the candidate with the smallest path cost over unit node costs
      (``Plan.cost`` in metres, each step costing at least its length), so a plan made on a
      window around the robot is the whole grid's plan when its cost is below the distance to
      the window's edge (:func:`jaxplore.sim.plan_where_needed` then skips the whole grid).
  """

  name: str
  plan: PlanFn
  defaults: dict
  summary: str
  blacklist_on_arrival: bool = False
  validate: Callable | None = None
  windowed: bool = False


_REGISTRY: dict[str, PlannerSpec] = {}


def register(name: str, defaults: dict | None = None, summary: str = "",
             blacklist_on_arrival: bool = False, validate: Callable | None = None,
             windowed: bool = False):
  """Decorator adding a plan function to the registry under ``name``."""

  def wrap(fn):
    _REGISTRY[name] = PlannerSpec(name, fn, dict(defaults or {}), summary, blacklist_on_arrival,
                                  validate, windowed)
    return fn

  return wrap


def get_planner(name: str) -> PlannerSpec:
  if name not in _REGISTRY:
    raise ConfigError(f"unknown planner {name!r}; valid planners: {', '.join(sorted(_REGISTRY))}")
  return _REGISTRY[name]


def planner_names() -> list[str]:
  return sorted(_REGISTRY)


def no_plan(capacity: int, robot: RobotView) -> Plan:
  """An invalid plan that keeps the robot where it is."""
  return Plan(waypoints=jnp.broadcast_to(robot.cell, (capacity, 2)).astype(jnp.int32),
              length=jnp.int32(0), goal=robot.cell, look_at=robot.cell, valid=jnp.bool_(False),
              gain=jnp.float32(0), cost=jnp.float32(jnp.inf), n_candidates=jnp.int32(0))


def unknown_neighbour(cell, unknown, occupied):
  """An unknown 8-neighbour of ``cell`` that is not sealed off by two occupied cells, else ``cell``.

  Used as a look-at point: facing it lets a narrow field of view observe what made ``cell`` a
  frontier.
  """
  h, w = unknown.shape
  get = lambda grid, r, c, fill: grid.at[r, c].get(mode="fill", fill_value=fill)
  best = cell
  found = jnp.bool_(False)
  for di, dj in mapping.NEIGHBOURS_8:
    r, c = cell[0] + di, cell[1] + dj
    ok = get(unknown, r, c, False)
    if di != 0 and dj != 0:
      ok = ok & ~(get(occupied, cell[0] + di, cell[1], True) & get(occupied, cell[0], cell[1] + dj, True))
    take = ok & ~found
    best = jnp.where(take, jnp.stack([r, c]).astype(jnp.int32), best)
    found = found | ok
  return best
