"""The host loop around the engine: reset, compile once, advance until every robot is done.

``jaxplore run`` and every chunk of a sweep go through :func:`reset`, :func:`compile_advance`
and :func:`drive`. The batch advances in chunks of planning rounds (one compiled call each, the
granularity of progress and early stop) and stops once every robot is done or the step budget is
spent. The batch is sharded over local devices with ``shard_map`` (robots are independent, so
sharding does not change a number).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import time
from typing import Callable

import jax
import numpy as np

from jaxplore import interrupts, sim
from jaxplore.config import ConfigError, SimConfig

# The event JAX's monitoring reports once per XLA backend compile, with its duration.
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


def default_chunk_epochs(config: SimConfig) -> int:
  """Planning rounds per compiled call: about 500 steps, the granularity of progress and early
  stop."""
  return max(1, min(config.n_epochs, 2000 // config.replan_every // 4 or 1))


def shard_count(robots: int, devices: int) -> int:
  """Devices a batch of ``robots`` is sharded over: ``devices``, or the largest divisor of
  ``robots`` it shares with ``devices`` (every device holds as many robots)."""
  return devices if robots % devices == 0 else math.gcd(devices, robots)


def local_devices(requested: int | None) -> int:
  """``requested`` local devices (default all), at most what there is; a count below 1 (or not
  a whole number) is refused."""
  if requested is not None and (isinstance(requested, bool)
                                or not isinstance(requested, (int, np.integer)) or requested < 1):
    raise ConfigError(f"devices must be a positive integer, got {requested!r}")
  n_local = len(jax.local_devices())
  return n_local if requested is None else min(int(requested), n_local)


@functools.lru_cache(maxsize=32)
def compiled_advance(config: SimConfig, n_epochs: int, n_devices: int):
  """The chunk function ``(world, params, state) -> (state, records)``, jitted once per
  (config, chunk length, device count); the batch is sharded over ``n_devices`` local devices."""
  fn = functools.partial(sim.advance_unjitted, config, n_epochs=n_epochs)
  if n_devices <= 1:
    return jax.jit(fn)
  from jax.sharding import Mesh, PartitionSpec as P
  mesh = Mesh(np.array(jax.local_devices()[:n_devices]), ("robots",))
  sharded = jax.shard_map(fn, mesh=mesh, in_specs=(P(), P("robots"), P("robots")),
                          out_specs=(P("robots"), P(None, "robots")), check_vma=False)
  return jax.jit(sharded)


def reset(config: SimConfig, world: sim.World, batch) -> sim.State:
  """The batch at its starts after the first scan (``batch``: a
  :class:`jaxplore.resolve.Batch`)."""
  state = sim.reset_batch(config, world, batch.params, batch.keys, batch.starts)
  return jax.block_until_ready(state)


def compile_advance(config: SimConfig, n_epochs: int, n_devices: int, world, params, state):
  """The chunk function compiled ahead of time for these inputs' shapes."""
  return compiled_advance(config, n_epochs, n_devices).lower(world, params, state).compile()


@dataclasses.dataclass
class Rollout:
  """What :func:`drive` leaves: the state and records of the last *finished* chunk.

  Attributes:
    state: the final state (NumPy leaves, batch first).
    records: per-step records stacked [T, B] (NumPy), T <= the step budget; None if no chunk
      finished.
    steps: motion steps advanced (the lockstep count, finished robots included).
    interrupted: Ctrl-C stopped the loop; ``state`` and ``records`` are those of the last chunk
      that finished before it, consistent with each other.
    run_s: wall-clock seconds of the loop.
  """

  state: sim.State
  records: sim.Record | None
  steps: int
  interrupted: bool
  run_s: float


def drive(compiled, world, params, state, max_steps: int, *, interruptible: bool = False,
          on_chunk: Callable | None = None) -> Rollout:
  """Advances the batch chunk by chunk until every robot is done or ``max_steps`` are spent.

  Args:
    compiled: the chunk function (:func:`compile_advance`).
    interruptible: on Ctrl-C, return what the finished chunks gave (``interrupted=True``)
      instead of raising. Within :func:`jaxplore.interrupts.deferred`, Ctrl-C stops the loop
      once the chunk in flight has finished (it is kept).
    on_chunk: called after every finished chunk with its records (NumPy) and the done flags.
  """
  records, steps, interrupted = [], 0, False
  t0 = time.perf_counter()
  try:
    while steps < max_steps:
      new_state, rec = compiled(world, params, state)
      rec = jax.tree.map(np.asarray, rec)
      done = np.asarray(jax.block_until_ready(new_state).done)
      n = rec.done.shape[0]
      # One statement with no call in it publishes the chunk: an interrupt lands before it (the
      # chunk is dropped; the state and records of the chunks before stay together) or after it.
      state, records, steps = new_state, records + [rec], steps + n
      if on_chunk is not None:
        on_chunk(rec, done)
      if done.all():
        break
      if interrupts.requested():
        raise KeyboardInterrupt
  except KeyboardInterrupt:
    if not interruptible:
      raise
    interrupted = True
  run_s = time.perf_counter() - t0
  stacked = (jax.tree.map(lambda *xs: np.concatenate(xs, axis=0)[:max_steps], *records)
             if records else None)
  return Rollout(jax.tree.map(np.asarray, state), stacked, steps, interrupted, run_s)


_COMPILE_EVENTS: list[tuple[str, float]] = []
_LISTENING = False


def _listen_to_compiles():
  """Records every XLA backend compile through JAX's monitoring hook (installed once)."""
  global _LISTENING
  if _LISTENING:
    return
  import jax.monitoring

  def on_event(event, duration, **kwargs):
    if event == COMPILE_EVENT:
      _COMPILE_EVENTS.append((str(kwargs.get("fun_name", "?")), float(duration)))

  jax.monitoring.register_event_duration_secs_listener(on_event)
  _LISTENING = True


@contextlib.contextmanager
def count_compiles(tally: dict):
  """Adds the XLA compiles inside the block to ``tally``: ``count``, ``seconds`` and ``names``."""
  _listen_to_compiles()
  first = len(_COMPILE_EVENTS)
  try:
    yield tally
  finally:
    events = _COMPILE_EVENTS[first:]
    tally["count"] = tally.get("count", 0) + len(events)
    tally["seconds"] = tally.get("seconds", 0.0) + sum(d for _, d in events)
    tally["names"] = tally.get("names", []) + [name for name, _ in events]


__all__ = ["COMPILE_EVENT", "Rollout", "compile_advance", "compiled_advance", "count_compiles",
           "default_chunk_epochs", "drive", "local_devices", "reset", "shard_count"]
