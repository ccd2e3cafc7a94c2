"""``jaxplore sweep --distributed`` for real: two JAX processes on the loopback address (CPU
backend, one device each) split a sweep, one of them is killed, and the sweep is resumed.

Every run is a ``jaxplore`` command in a subprocess with the same environment, so the tables are
compared bit for bit. The processes share a persistent compilation cache and compile without
XLA's backend optimisations: the first run compiles, the others load (a 20 x 20 world, 20 steps).
"""

import signal
import socket
import subprocess
import sys
import textwrap
import time

import pandas as pd
import pytest

from conftest import REPO, subprocess_env

# Four rows (two sensor ranges x two seeds), one per chunk: process 0 runs chunks 0 and 2,
# process 1 chunks 1 and 3. Every row differs, so a row written under another's name shows.
SWEEP = ["sweep", "--world", "open", "--res", "1.0", "--planner", "nearest_frontier",
         "--max-steps", "20", "--replan-every", "4", "--grid", "r_max=1.5,2.5", "--seeds", "2",
         "--chunk-size", "1", "--devices", "1", "--no-progress", "--quiet"]
CHUNKS = 4
TIMEOUT_S = 300

# jaxplore's command, killed (SIGKILL, by itself) halfway through writing its second chunk:
# the first chunk is finished, the second leaves a torn temporary file.
DIES_IN_SECOND_CHUNK = textwrap.dedent("""
    import os, signal, sys
    import pandas as pd
    from jaxplore import cli
    real, writes = pd.DataFrame.to_parquet, []
    def to_parquet(self, path, *args, **kwargs):
      real(self, path, *args, **kwargs)
      if os.path.basename(str(path)).startswith("chunk_"):
        writes.append(path)
        if len(writes) == 3:  # chunk A's curves and episodes, then chunk B's curves
          os.kill(os.getpid(), signal.SIGKILL)
    pd.DataFrame.to_parquet = to_parquet
    sys.exit(cli.main(sys.argv[1:]))
""")


@pytest.fixture(scope="module")
def env(tmp_path_factory):
  cache = tmp_path_factory.mktemp("jax_cache")
  return subprocess_env(
      drop=("XLA_", "JAX_"), XLA_FLAGS="--xla_backend_optimization_level=0", JAX_PLATFORMS="cpu",
      JAX_COMPILATION_CACHE_DIR=str(cache), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
      JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")


@pytest.fixture(scope="module")
def one_process(env, tmp_path_factory):
  """The sweep run by one process (and the compile every later run loads from the cache)."""
  out = tmp_path_factory.mktemp("one") / "sweep"
  done = subprocess.run([sys.executable, "-m", "jaxplore.cli", *SWEEP, "--out", str(out)],
                        cwd=REPO, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
  assert done.returncode == 0, done.stderr[-3000:]
  return out


def _free_port() -> int:
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


def _start(env, argv, port, process, script=None):
  env = dict(env, JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}", JAX_NUM_PROCESSES="2",
             JAX_PROCESS_ID=str(process))
  program = ["-c", script] if script else ["-m", "jaxplore.cli"]
  return subprocess.Popen([sys.executable, *program, *argv, "--distributed"], cwd=REPO, env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _finish(procs):
  """Waits for every process; returns their outputs (and kills them all on a timeout)."""
  deadline = time.monotonic() + TIMEOUT_S
  try:
    return [p.communicate(timeout=max(1.0, deadline - time.monotonic()))[0] for p in procs]
  except subprocess.TimeoutExpired:
    for p in procs:
      p.kill()
    pytest.fail("a process of the sweep hung:\n" + "\n".join(p.communicate()[0][-2000:] for p in procs))


def _tables(out):
  return pd.read_parquet(out / "episodes.parquet"), pd.read_parquet(out / "curves.parquet")


def _chunk_done(out, k):
  return (out / "chunks" / f"chunk_{k:05d}.parquet").exists()


def test_two_processes_split_a_sweep_and_resume_after_one_is_killed(env, one_process, tmp_path):
  out = tmp_path / "sweep"
  argv = [*SWEEP, "--out", str(out)]

  # Process 1 dies writing its second chunk (3); process 0 finishes its own (0, 2) and waits
  # for process 1 at the closing barrier, where the test kills it like a job scheduler would.
  port = _free_port()
  survivor = _start(env, argv, port, 0)
  dying = _start(env, argv, port, 1, script=DIES_IN_SECOND_CHUNK)
  deadline = time.monotonic() + TIMEOUT_S
  while not (_chunk_done(out, 0) and _chunk_done(out, 2)) or dying.poll() is None:
    if survivor.poll() not in (None, 0) or time.monotonic() > deadline:
      break
    time.sleep(0.05)
  if survivor.poll() is None:
    survivor.send_signal(signal.SIGKILL)
  logs = _finish([survivor, dying])
  assert dying.returncode == -signal.SIGKILL, logs[1][-3000:]
  assert [_chunk_done(out, k) for k in range(CHUNKS)] == [True, True, True, False], logs
  assert list((out / "chunks").glob("chunk_00003*.tmp")), "the torn write should be left behind"
  assert not (out / "episodes.parquet").exists()

  # Both processes resume: only chunk 3 is left, process 1's; process 0 assembles the tables.
  port = _free_port()
  resumed = [_start(env, ["sweep", "--resume", str(out), "--devices", "1", "--no-progress",
                          "--quiet"], port, i) for i in range(2)]
  logs = _finish(resumed)
  assert [p.returncode for p in resumed] == [0, 0], "\n".join(log[-3000:] for log in logs)
  assert "0 of 4 chunks run here" in logs[0] and "1 of 4 chunks run here" in logs[1], logs
  assert not list((out / "chunks").glob("*.tmp"))
  for mine, theirs in zip(_tables(out), _tables(one_process)):
    pd.testing.assert_frame_equal(mine, theirs, check_exact=True)
  assert sorted(_tables(out)[0].r_max.unique()) == [1.5, 2.5]
