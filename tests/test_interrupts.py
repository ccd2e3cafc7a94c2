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
from conftest import REPO, subprocess_env



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
