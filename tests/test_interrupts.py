"""Ctrl-C at safe points (``jaxplore.interrupts``): a SIGINT within ``deferred`` only sets a flag,
the host loop stops after the chunk in flight (keeping it), and ``jaxplore run`` interrupted while
compiling exits 130 with a message instead of crashing on exit (segmentation fault) or going on."""

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from jaxplore import driver, interrupts
from tests.test_driver import chunks, start
from conftest import REPO, subprocess_env, tiny_office



def test_sigint_within_deferred_sets_a_flag_and_check_raises_there():
  before = signal.getsignal(signal.SIGINT)
  with interrupts.deferred():
    with interrupts.deferred():  # nested blocks share one handler
      assert not interrupts.requested()
      interrupts.check("not yet")  # nothing pressed: no raise
      os.kill(os.getpid(), signal.SIGINT)
      assert interrupts.requested()  # noted, not raised mid-statement
    with pytest.raises(KeyboardInterrupt, match="stop here"):
      interrupts.check("stop here")
  assert signal.getsignal(signal.SIGINT) is before and not interrupts.requested()


def test_sigterm_is_taken_as_ctrl_c_with_its_own_exit_code(capsys):
  """SIGTERM (kill, a batch scheduler's stop) during a run exited 143 with nothing written; it
  now stops at the next safe point like Ctrl-C, and the command exits 143."""
  before = signal.getsignal(signal.SIGTERM)
  with interrupts.deferred():
    os.kill(os.getpid(), signal.SIGTERM)
    assert interrupts.requested() and interrupts.exit_code() == 143
    assert "SIGTERM received: stopping at the next safe point" in capsys.readouterr().err
    chunk, calls = chunks()
    rollout = driver.drive(chunk, None, None, start(), max_steps=100, interruptible=True)
  assert rollout.interrupted and len(calls) == 1 and rollout.steps == 4
  assert signal.getsignal(signal.SIGTERM) is before


def pressed_during_second_chunk():
  compiled, calls = chunks()

  def chunk(world, params, state):
    if len(calls) == 1:
      os.kill(os.getpid(), signal.SIGINT)  # lands while the second chunk runs
    return compiled(world, params, state)

  return chunk, calls


def test_drive_stops_after_the_chunk_in_flight_and_keeps_it():
  chunk, calls = pressed_during_second_chunk()
  with interrupts.deferred():
    rollout = driver.drive(chunk, None, None, start(), max_steps=100, interruptible=True)
  assert len(calls) == 2 and rollout.interrupted and rollout.steps == 8
  assert rollout.records.step.shape == (8, 2)
  assert rollout.records.step[-1, 0] == rollout.state.steps[0] == 8
  chunk, calls = pressed_during_second_chunk()
  with interrupts.deferred(), pytest.raises(KeyboardInterrupt):
    driver.drive(chunk, None, None, start(), max_steps=100)
  assert len(calls) == 2


# jaxplore run with Ctrl-C pressed (SIGINT to itself) as the first JAX program (the reset) compiles.
PRESSED_IN_COMPILE = textwrap.dedent("""
    import os, signal, sys
    from jaxplore import cli, driver
    real = driver.reset
    def pressed(*args, **kwargs):
      os.kill(os.getpid(), signal.SIGINT)
      return real(*args, **kwargs)
    driver.reset = pressed
    sys.exit(cli.main(sys.argv[1:]))
""")


def test_ctrl_c_while_compiling_exits_130_and_writes_nothing(tmp_path):
  out = tmp_path / "run"
  env = subprocess_env()
  proc = subprocess.run(
      [sys.executable, "-c", PRESSED_IN_COMPILE, "run", "--world", "open", "--res", "0.5",
       "--robots", "1", "--max-steps", "20", "--set", "r_max=2", "--devices", "1",
       "--no-progress", "--out", str(out)],
      cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
  assert proc.returncode == interrupts.EXIT_CODE, proc.stderr[-3000:]
  assert "interrupted before the first step" in proc.stderr, proc.stderr[-3000:]
  assert "Traceback" not in proc.stderr and not out.exists()


# jaxplore run whose second chunk never finishes and uses no CPU (a host callback that sleeps
# 10 minutes, as a deadlocked runtime waits): the watchdog or the first Ctrl-C must end it, with
# the finished chunk's results written.
STUCK_SECOND_CHUNK = textwrap.dedent("""
    import os, signal, sys, threading, time
    import jax
    from jaxplore import cli, driver
    # Ctrl-C's grace period alone ends the run in the Ctrl-C cases: the watchdog's idle time,
    # were it as short, could judge the chunk stuck first (both at ~2 s in, on a loaded machine).
    watching = os.environ["STUCK_MODE"] == "watchdog"
    driver.drive.__kwdefaults__["watchdog"] = driver.Watchdog(idle_s=2.0 if watching else 60.0,
                                                              grace_s=1.0)
    real = driver.compile_advance

    def sleep(x):
      time.sleep(600)
      return x

    blocked = jax.jit(lambda s: jax.pure_callback(sleep, s, s))

    class Stuck:
      def __init__(self, compiled):
        self.compiled, self.calls = compiled, 0
      def __getattr__(self, name):
        return getattr(self.compiled, name)
      def __call__(self, world, params, state):
        self.calls += 1
        new_state, rec = self.compiled(world, params, state)
        if self.calls == 2:
          if os.environ["STUCK_MODE"] != "watchdog":
            sent = getattr(signal, os.environ["STUCK_MODE"].upper())
            threading.Timer(1.0, os.kill, (os.getpid(), sent)).start()
          new_state = new_state.replace(steps=blocked(new_state.steps))
        return new_state, rec

    driver.compile_advance = lambda *args, **kwargs: Stuck(real(*args, **kwargs))
    sys.exit(cli.main(sys.argv[1:]))
""")


@pytest.mark.parametrize("mode, code, says", [
    ("watchdog", 3, "chunk 2 (from step 5) is stuck: the process has used no CPU"),
    ("sigint", interrupts.EXIT_CODE, "chunk 2 (from step 5) was still running 1 s after Ctrl-C")])
def test_a_stuck_run_ends_in_seconds_and_keeps_the_finished_chunk(tmp_path, mode, code, says):
  # The world, robots and settings of tests/test_animate.py's run (conftest.tiny_office), one
  # planning round a chunk as its replay runs them: that module's programs, loaded from the
  # suite's compilation cache instead of compiled again (~15 s).
  from jaxplore.maps import save_map
  world = tmp_path / "tiny_office.yaml"
  save_map(tiny_office(), world)
  out = tmp_path / "run"
  proc = subprocess.run(
      [sys.executable, "-c", STUCK_SECOND_CHUNK, "run", "--world", str(world),
       "--robots", "2", "--max-steps", "40", "--set", "r_max=3", "--devices", "1",
       "--chunk-epochs", "1", "--replan-every", "5", "--no-progress", "--out", str(out)],
      cwd=REPO, env=subprocess_env(STUCK_MODE=mode), capture_output=True, text=True, timeout=240)
  assert proc.returncode == code, proc.stderr[-3000:]
  assert says in proc.stderr and "partial results kept" in proc.stderr, proc.stderr[-3000:]
  assert "Traceback" not in proc.stderr
  import pandas as pd
  curves = pd.read_parquet(out / "curves.parquet")
  assert curves.step.max() == 5  # the first chunk's steps, written
