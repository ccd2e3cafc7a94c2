"""The batched exploration engine: the rollout of a batch of robots on one world.

The layers, one module each: :mod:`jaxplore.world` (the truth and where robots start, host side),
:mod:`jaxplore.robot` (one robot's state, reset and motion step), :mod:`jaxplore.planning` (which
robots plan before a step, and how), and this module, which composes them over time: an
:func:`epoch` is ``replan_every`` steps of the whole batch, each preceded by the plans it needs;
:func:`advance` scans epochs; :func:`rollout` is a whole episode in one compiled call. The names
callers use from the layers are re-exported here.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from jaxplore.config import ConfigError, Params, SimConfig
from jaxplore.planners.base import get_planner
from jaxplore.planning import (
  belief_view,
  crop_maps,
  needs_plan,
  plan,
  plan_where_needed,
  uses_window,
)
from jaxplore.robot import (
  COMPLETE,
  EXHAUSTED,
  REASONS,
  RUNNING,
  TIMEOUT,
  Record,
  State,
  planner_context,
  record,
  reset,
  robot_view,
  step,
)
from jaxplore.world import World, cell_centre, cell_of, make_world, sample_start, to_cells


def config_record(config: SimConfig) -> dict:
  """``config`` in JSON form (``config.json``'s ``sim_config``): every field, the planner and the
  sensor as their names and the planner's static settings as ``planner_settings`` (None for a
  planner without any)."""
  values = {f.name: getattr(config, f.name) for f in dataclasses.fields(SimConfig)}
  settings = config.planner.settings
  values["planner"] = config.planner.name
  values["sensor"] = config.sensor.name
  values["planner_settings"] = None if settings is None else dataclasses.asdict(settings)
  return values


def config_from_dict(recorded: dict) -> SimConfig:
  """The :class:`SimConfig` a results folder recorded (:func:`config_record`), the planner looked
  up by its name and given its recorded settings.

  Folders written before R_e became static recorded ``gain_radius_cells`` (R_e in cells); those
  written before li2020 kept its entropy map recorded ``r_e``, ``dpi_min`` and
  ``max_update_radius_cells`` with the engine's settings: they go to the planner's settings
  where it has them.
  """
  values = dict(recorded)
  if "gain_radius_cells" in values:
    values["r_e"] = float(values.pop("gain_radius_cells")) * float(values["res"])
  spec = get_planner(values.get("planner", SimConfig.planner))
  settings = dict(values.get("planner_settings") or {})
  fields = {f.name for f in dataclasses.fields(spec.settings)} if spec.settings else set()
  for name in ("r_e", "dpi_min", "max_update_radius_cells"):
    if name in values and name in fields and name not in settings:
      settings[name] = values[name]
  values["planner"] = spec.with_settings(**settings)
  known = {f.name for f in dataclasses.fields(SimConfig)}
  return SimConfig(**{k: v for k, v in values.items() if k in known})


def epoch(config: SimConfig, world: World, params: Params, state: State):
  """``replan_every`` motion steps of the whole batch, each preceded by the plans it needs.

  ``params`` and ``state`` carry a leading batch axis; ``world`` is shared.
  """
  step_batch = jax.vmap(lambda p, s: step(config, world, p, s))

  def body(s, _):
    s = plan_where_needed(config, world, params, s)
    return step_batch(params, s)

  return jax.lax.scan(body, state, None, length=config.replan_every)


def advance_unjitted(config: SimConfig, world: World, params: Params, state: State, n_epochs: int):
  """``n_epochs * replan_every`` steps for a batch; records stacked as
  [n_epochs * replan_every, B]."""
  def body(s, _):
    return epoch(config, world, params, s)

  state, records = jax.lax.scan(body, state, None, length=n_epochs)
  records = jax.tree.map(lambda r: r.reshape((-1,) + r.shape[2:]), records)
  return state, records


advance = jax.jit(advance_unjitted, static_argnames=("config", "n_epochs"))


@functools.partial(jax.jit, static_argnames=("config",))
def reset_batch(config: SimConfig, world: World, params: Params, keys, start_poses=None):
  """``reset`` for a batch: ``params`` and ``keys`` batched; ``start_poses`` f32[B, 3] or None."""
  if start_poses is None:
    return jax.vmap(lambda p, k: reset(config, world, p, k))(params, keys)
  return jax.vmap(lambda p, k, s: reset(config, world, p, k, s))(params, keys, start_poses)


def broadcast_params(params: Params, batch: int) -> Params:
  """Gives every leaf a leading batch axis (scalars are repeated; batched leaves are checked)."""
  def expand(leaf):
    leaf = jnp.asarray(leaf, jnp.float32)
    if leaf.ndim == 0:
      return jnp.broadcast_to(leaf, (batch,))
    if leaf.shape[0] != batch:
      raise ConfigError(f"a batched parameter has {leaf.shape[0]} values for {batch} robots")
    return leaf
  return jax.tree.map(expand, params)


def rollout(config: SimConfig, world: World, params: Params, keys, start_poses=None):
  """The whole episode for a batch in one compiled call (no early exit, no progress bar).

  :func:`jaxplore.run.run` is the user-facing loop that stops early and shows progress; this is
  the minimal pure form (for tests and embedding).
  Returns (final state, records with leaves [max_steps, B]).
  """
  state = reset_batch(config, world, params, keys, start_poses)
  state, records = advance(config, world, params, state, config.n_epochs)
  records = jax.tree.map(lambda r: r[: config.max_steps], records)
  return state, records


__all__ = [
    "World", "State", "Record", "make_world", "reset", "step", "record", "plan", "needs_plan",
    "plan_where_needed", "uses_window", "belief_view", "crop_maps", "robot_view",
    "planner_context", "epoch", "advance", "advance_unjitted", "reset_batch", "rollout",
    "broadcast_params", "config_from_dict", "config_record", "cell_of", "cell_centre", "to_cells",
    "sample_start",
    "REASONS", "RUNNING", "COMPLETE", "EXHAUSTED", "TIMEOUT",
]
