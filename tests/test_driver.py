"""The host loop (``jaxplore.driver.drive``): early stop, the step budget, and Ctrl-C leaving the
state and records of the same chunks. A stand-in chunk function replaces the engine, so the
loop's bookkeeping is tested without compiling anything."""

import os
import signal
import threading
import time

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplore import driver, interrupts
from jaxplore.config import ConfigError


@chex.dataclass(frozen=True)
class State:
  steps: chex.Array  # i32[B]
  done: chex.Array  # bool[B]


@chex.dataclass(frozen=True)
class Record:
  step: chex.Array  # [T, B]
  done: chex.Array


class Interrupt:
  """A record leaf whose conversion to NumPy is where Ctrl-C lands (the host waits there for
  the chunk to finish)."""

  def __array__(self, *args, **kwargs):
    raise KeyboardInterrupt


def chunks(chunk_steps=4, robots=2, finish_at=None, interrupt_at=None):
  """A chunk function advancing every robot ``chunk_steps`` steps; robot ``b`` is done from
  step ``finish_at[b]`` on; the ``interrupt_at``-th call's records cannot be read."""
  calls = []

  def compiled(world, params, state):
    calls.append(1)
    steps = state.steps[0] + jnp.arange(1, chunk_steps + 1)
    limit = jnp.asarray(finish_at if finish_at is not None else [10**9] * robots)
    done = steps[:, None] >= limit[None, :]
    record = Record(step=jnp.broadcast_to(steps[:, None], (chunk_steps, robots)), done=done)
    if len(calls) == interrupt_at:
      record = record.replace(step=Interrupt())
    return State(steps=state.steps + chunk_steps, done=done[-1]), record

  return compiled, calls


def start(robots=2):
  return State(steps=jnp.zeros(robots, jnp.int32), done=jnp.zeros(robots, bool))


def test_stops_once_every_robot_is_done_and_keeps_the_budget():
  compiled, calls = chunks(finish_at=[5, 9])
  rollout = driver.drive(compiled, None, None, start(), max_steps=100)
  assert len(calls) == 3 and rollout.steps == 12 and not rollout.interrupted
  assert rollout.state.done.all() and rollout.records.step.shape == (12, 2)
  np.testing.assert_array_equal(rollout.records.step[:, 0], np.arange(1, 13))
  # the budget cuts the records of the last chunk
  compiled, calls = chunks()
  rollout = driver.drive(compiled, None, None, start(), max_steps=10)
  assert len(calls) == 3 and rollout.records.step.shape == (10, 2)


def test_ctrl_c_keeps_the_state_and_records_of_the_same_finished_chunks():
  seen = []
  compiled, calls = chunks(interrupt_at=3)
  rollout = driver.drive(compiled, None, None, start(), max_steps=100, interruptible=True,
                         on_chunk=lambda rec, done: seen.append(rec.step.shape[0]))
  assert len(calls) == 3 and rollout.interrupted and seen == [4, 4]
  # The third chunk ran but its records never arrived: the state is the second chunk's.
  assert rollout.steps == 8 and rollout.records.step.shape == (8, 2)
  np.testing.assert_array_equal(rollout.state.steps, [8, 8])
  assert rollout.records.step[-1, 0] == rollout.state.steps[0]


def test_ctrl_c_before_the_first_chunk_keeps_the_reset_state():
  compiled, _ = chunks(interrupt_at=1)
  rollout = driver.drive(compiled, None, None, start(), max_steps=100, interruptible=True)
  assert rollout.interrupted and rollout.records is None and rollout.steps == 0
  np.testing.assert_array_equal(rollout.state.steps, [0, 0])


def test_ctrl_c_propagates_unless_interruptible():
  compiled, _ = chunks(interrupt_at=2)
  with pytest.raises(KeyboardInterrupt):
    driver.drive(compiled, None, None, start(), max_steps=100)


def test_shard_count_divides_the_batch():
  assert driver.shard_count(16, 2) == 2 and driver.shard_count(9, 2) == 1
  assert driver.shard_count(6, 4) == 2 and driver.shard_count(3, 3) == 3


@pytest.mark.parametrize("requested", [0, -2, 1.5, True, "2"])
def test_a_device_count_below_one_or_not_whole_is_refused(requested):
  """``devices=0`` used to run silently on one device (and the CLI's --devices 0 set the host
  device count to the cores first); every bad count is now refused naming it."""
  with pytest.raises(ConfigError, match="devices must be a positive integer"):
    driver.local_devices(requested)
  assert driver.local_devices(None) == len(jax.local_devices())
  assert driver.local_devices(10**6) == len(jax.local_devices())  # at most what there is


def stuck_after(chunks_before, sleep_s=30.0):
  """A chunk function whose call number ``chunks_before + 1`` waits ``sleep_s`` inside the
  compiled program without using CPU (a host callback that sleeps), as a deadlocked runtime does;
  the calls before it are :func:`chunks`' own."""
  compiled, calls = chunks()

  def sleep(x):
    time.sleep(sleep_s)
    return x

  blocked = jax.jit(lambda s: jax.pure_callback(sleep, s, s))

  def chunk(world, params, state):
    new_state, record = compiled(world, params, state)
    if len(calls) > chunks_before:
      new_state = new_state.replace(steps=blocked(new_state.steps))
    return new_state, record

  return chunk, calls


def test_a_chunk_that_makes_no_progress_is_reported_and_the_finished_ones_kept():
  chunk, calls = stuck_after(2)
  t0 = time.monotonic()
  rollout = driver.drive(chunk, None, None, start(), max_steps=100, interruptible=True,
                         watchdog=driver.Watchdog(idle_s=1.0))
  assert time.monotonic() - t0 < 10
  assert "chunk 3 (from step 8) is stuck" in rollout.stalled and "no CPU" in rollout.stalled
  assert not rollout.interrupted and rollout.steps == 8 and rollout.records.step.shape == (8, 2)
  np.testing.assert_array_equal(rollout.state.steps, [8, 8])
  chunk, _ = stuck_after(0)
  with pytest.raises(driver.Stalled, match="chunk 1 .* is stuck"):
    driver.drive(chunk, None, None, start(), max_steps=100, watchdog=driver.Watchdog(idle_s=1.0))


def test_a_chunk_far_slower_than_the_ones_before_is_reported_on_any_device():
  chunk, _ = stuck_after(1, sleep_s=5.0)
  rollout = driver.drive(chunk, None, None, start(), max_steps=100, interruptible=True,
                         watchdog=driver.Watchdog(idle_s=1e9, slow_factor=10.0, min_s=0.5))
  assert "chunk 2 (from step 4) is stuck: it has run" in rollout.stalled and rollout.steps == 4


def test_the_first_ctrl_c_ends_a_stuck_chunk_within_the_grace_period():
  chunk, _ = stuck_after(1)
  threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT)).start()
  t0 = time.monotonic()
  with interrupts.deferred():
    rollout = driver.drive(chunk, None, None, start(), max_steps=100, interruptible=True,
                           watchdog=driver.Watchdog(idle_s=1e9, grace_s=0.5))
  assert time.monotonic() - t0 < 5
  assert rollout.interrupted and rollout.stalled is None and rollout.steps == 4
  assert driver.dropped_call_running()  # the dropped call still sleeps: a command exits at once


def test_a_chunk_longer_than_the_budget_is_cut_to_it():
  from jaxplore.config import SimConfig
  config = SimConfig(height=10, width=10, res=0.1, max_steps=200, replan_every=8)
  assert driver.chunk_epochs_for(config, 100000) == 25 == config.n_epochs
  assert driver.chunk_epochs_for(config, 3) == 3
  assert driver.chunk_epochs_for(config, None) == driver.default_chunk_epochs(config)


SUSPENDED = """
import sys, time
from jaxplore import driver

def busy():  # a call that computes (keeps a core busy) for 2 s of the clock
  t0 = time.monotonic()
  while time.monotonic() - t0 < 2.0:
    sum(range(1000))
  return "done"

print("ready", flush=True)
out = driver.call_watched(busy, stage="chunk 1", watchdog=driver.Watchdog(idle_s=1.0,
                                                                          suspended_s=0.5))
print(out, flush=True)
"""


def test_a_process_suspended_and_resumed_is_not_judged_deadlocked():
  """Ctrl-Z then ``fg`` (here SIGSTOP, 3 s, SIGCONT) in the middle of a call: the process used
  no CPU while it lay still, which the watchdog must not take for a wedged program."""
  import subprocess
  import sys

  from conftest import REPO, subprocess_env
  proc = subprocess.Popen([sys.executable, "-c", SUSPENDED], cwd=REPO, env=subprocess_env(),
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
  assert proc.stdout.readline().strip() == "ready"
  time.sleep(0.5)
  proc.send_signal(signal.SIGSTOP)
  time.sleep(3.0)
  proc.send_signal(signal.SIGCONT)
  out, err = proc.communicate(timeout=60)
  assert proc.returncode == 0, err[-2000:]
  assert out.strip() == "done"
