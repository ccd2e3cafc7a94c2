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
import threading
import time
from collections.abc import Callable

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


def chunk_epochs_for(config: SimConfig, requested: int | None) -> int:
  """Planning rounds per compiled call: ``requested`` (default :func:`default_chunk_epochs`), cut
  to the rounds the step budget needs (a longer chunk would only simulate past it)."""
  return min(requested or default_chunk_epochs(config), config.n_epochs)


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
  from jax.sharding import Mesh
  from jax.sharding import PartitionSpec as P
  mesh = Mesh(np.array(jax.local_devices()[:n_devices]), ("robots",))
  sharded = jax.shard_map(fn, mesh=mesh, in_specs=(P(), P("robots"), P("robots")),
                          out_specs=(P("robots"), P(None, "robots")), check_vma=False)
  return jax.jit(sharded)


def reset(config: SimConfig, world: sim.World, batch) -> sim.State:
  """The batch at its starts after the first scan (``batch``: a
  :class:`jaxplore.resolve.Batch`)."""
  return call_watched(sim.reset_batch, config, world, batch.params, batch.keys, batch.starts,
                      stage="the reset (every robot's first scan)", watchdog=Watchdog())


def compile_advance(config: SimConfig, n_epochs: int, n_devices: int, world, params, state):
  """The chunk function compiled ahead of time for these inputs' shapes."""
  return compiled_advance(config, n_epochs, n_devices).lower(world, params, state).compile()


class Stalled(RuntimeError):
  """A compiled call made no progress (see :class:`Watchdog`); the message names the stage."""


@dataclasses.dataclass(frozen=True)
class Watchdog:
  """When the host stops waiting for a compiled call.

  Attributes:
    idle_s: on CPU devices, the call is stuck once the process has used no CPU time (less than
      ``idle_share`` of one core) for this long: a computing program always keeps a core busy,
      so an idle process that waits is deadlocked (e.g. XLA's thread pool wedged).
    slow_factor, min_s: on any device, the call is stuck once it has run ``slow_factor`` times
      as long as the slowest call that finished before it, and at least ``min_s``.
    grace_s: after Ctrl-C, how long the call in flight is still waited for before it is dropped
      (the calls finished before it are kept).
    poll_s: how often the host looks.
    suspended_s: a look that comes this much later than asked finds a process that was
      suspended (Ctrl-Z, SIGSTOP, a machine put to sleep): the time it lay still is neither idle
      nor running, and both clocks start again from there.
  """

  idle_s: float = 60.0
  idle_share: float = 0.05
  slow_factor: float = 20.0
  min_s: float = 300.0
  grace_s: float = 5.0
  poll_s: float = 0.05
  suspended_s: float = 10.0


def call_watched(fn, *args, stage: str, watchdog: Watchdog, slowest_s: float | None = None):
  """``fn(*args)`` (a compiled call) and its outputs computed, watching for a stall and Ctrl-C.

  The call is made from a helper thread: XLA runs some programs on the calling thread, and a
  main thread inside the runtime could neither look at the clock nor take Ctrl-C.

  Raises:
    Stalled: the :class:`Watchdog` judged the call stuck; the message names ``stage`` and why.
    KeyboardInterrupt: Ctrl-C (within :func:`jaxplore.interrupts.deferred`) and the call still
      unfinished ``grace_s`` later; or Ctrl-C outside it.
  """
  box = {}

  def call():
    try:
      box["out"] = fn(*args)
    except BaseException as error:  # handed to the caller's thread
      box["error"] = error

  thread = threading.Thread(target=call, name=f"jaxplore: {stage}", daemon=True)

  def finished():
    if thread.is_alive():
      return False
    return "error" in box or all(leaf.is_ready() for leaf in jax.tree.leaves(box["out"])
                                 if hasattr(leaf, "is_ready"))

  on_cpu = jax.default_backend() == "cpu"
  start = last_busy = sample_t = time.monotonic()
  sample_cpu = time.process_time()
  interrupted_at, poll = None, 1e-4
  thread.start()
  try:
    looked = start
    while not finished():
      time.sleep(poll)
      poll = min(2 * poll, watchdog.poll_s)  # a short call is not held up by the polling
      now = time.monotonic()
      if now - looked > poll + watchdog.suspended_s:  # the process lay still: not a stall
        start += now - looked
        last_busy = sample_t = now
        sample_cpu = time.process_time()
      looked = now
      if now - sample_t >= 1.0:  # CPU use over the last second or so
        if time.process_time() - sample_cpu > watchdog.idle_share * (now - sample_t):
          last_busy = now
        sample_t, sample_cpu = now, time.process_time()
      if interrupts.requested():
        interrupted_at = interrupted_at or now
        if now - interrupted_at > watchdog.grace_s:
          raise KeyboardInterrupt(f"{stage} was still running {watchdog.grace_s:g} s after "
                                  "Ctrl-C; it was dropped")
      if on_cpu and now - last_busy > watchdog.idle_s:
        raise Stalled(f"{stage} is stuck: the process has used no CPU for {now - last_busy:.0f} "
                      f"s while waiting for it ({now - start:.0f} s in all): the compiled "
                      "program is deadlocked, not computing")
      if slowest_s is not None and now - start > max(watchdog.min_s,
                                                     watchdog.slow_factor * slowest_s):
        raise Stalled(f"{stage} is stuck: it has run {now - start:.0f} s, more than "
                      f"{watchdog.slow_factor:g} times the slowest chunk before it "
                      f"({slowest_s:.1f} s)")
  except (Stalled, KeyboardInterrupt):
    _DROPPED[:] = [finished]
    raise
  if "error" in box:
    raise box["error"]
  return box["out"]


_DROPPED: list = []  # whether the last call given up on (Ctrl-C or a stall) has finished


def dropped_call_running() -> bool:
  """Whether a compiled call that :func:`call_watched` gave up on is still running: the
  interpreter would wait for it at exit, so a command ends the process at once instead."""
  return any(not finished() for finished in _DROPPED)


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
    stalled: why the loop stopped waiting for a chunk that made no progress (:class:`Stalled`),
      or None; ``state`` and ``records`` are those of the chunks finished before it.
    dropped: after Ctrl-C, what was given up on (a chunk still running after the grace period),
      or "".
  """

  state: sim.State
  records: sim.Record | None
  steps: int
  interrupted: bool
  run_s: float
  stalled: str | None = None
  dropped: str = ""


def drive(compiled, world, params, state, max_steps: int, *, interruptible: bool = False,
          on_chunk: Callable | None = None, watchdog: Watchdog = Watchdog()) -> Rollout:
  """Advances the batch chunk by chunk until every robot is done or ``max_steps`` are spent.

  Args:
    compiled: the chunk function (:func:`compile_advance`).
    interruptible: on Ctrl-C or a stall, return what the finished chunks gave
      (``interrupted=True`` or ``stalled``) instead of raising. Within
      :func:`jaxplore.interrupts.deferred`, Ctrl-C stops the loop once the chunk in flight has
      finished (it is kept), or ``watchdog.grace_s`` later if it has not (it is dropped).
    on_chunk: called after every finished chunk with its records (NumPy) and the done flags.
    watchdog: when a chunk counts as stuck (:class:`Watchdog`).
  Raises:
    Stalled: a chunk made no progress (unless ``interruptible``).
  """
  records: list[sim.Record] = []
  steps, interrupted, stalled, dropped = 0, False, None, ""
  slowest = None
  t0 = time.perf_counter()
  try:
    while steps < max_steps:
      t_chunk = time.monotonic()
      new_state, rec = call_watched(compiled, world, params, state, watchdog=watchdog,
                                    stage=f"chunk {len(records) + 1} (from step {steps})",
                                    slowest_s=slowest)
      slowest = max(slowest or 0.0, time.monotonic() - t_chunk)
      rec = jax.tree.map(np.asarray, rec)
      done = np.asarray(new_state.done)
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
  except KeyboardInterrupt as error:
    if not interruptible:
      raise
    interrupted, dropped = True, str(error)
  except Stalled as error:
    if not interruptible:
      raise
    stalled = str(error)
  run_s = time.perf_counter() - t0
  stacked = (jax.tree.map(lambda *xs: np.concatenate(xs, axis=0)[:max_steps], *records)
             if records else None)
  return Rollout(jax.tree.map(np.asarray, state), stacked, steps, interrupted, run_s, stalled,
                 dropped)


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


__all__ = ["COMPILE_EVENT", "Rollout", "Stalled", "Watchdog", "call_watched", "chunk_epochs_for",
           "compile_advance", "compiled_advance", "count_compiles", "default_chunk_epochs", "drive",
           "dropped_call_running", "local_devices", "reset", "shard_count"]
