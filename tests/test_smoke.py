"""Every registered planner runs a few robots to the end on the default devices.

The command line makes one host device per core; CI has two cores, so two devices here. Three
planners (gpbo, ahmed, ags) used to hang forever at four robots there (two per device: jaxlib's
batched LAPACK kernels deadlocked XLA:CPU's thread pool, see ``jaxplore.linalg``); the nine
others finished. A hang fails this test at its time limit instead of stalling CI.

The suite's default run takes the planners whose runs hung (gpbo; ahmed, whose code ags shares)
and nearest_frontier (the default planner: its process also checks, with its compiled program,
that a batch that does not divide over the devices is padded, not run on fewer); every other
planner runs under ``pytest -m slow``, in two processes (a test class each: xdist hands them to
both workers at once, each with its own time limit). Each planner costs ~15-20 s of compile here,
and every planner's batched program is checked for the hang's cause (a batched LAPACK call) in
``tests/planners/test_conformance.py``. The active-SLAM planners run on the oracle SLAM model
here but one (``OWN_SLAM``), which runs on its own (scan_matching).

LLVM optimises the programs at level 0 here, and XLA's fusions are emitted without its MLIR
fusion emitters (the suite's ``conftest.CODEGEN_FLAG``, where this jaxlib knows it): the compile is
~20 % shorter at level 0 (li2020: 9.8 s against 12.2 s) and half that again without the MLIR
emitters (reset and chunk: 9.5 -> 3.5 s for nearest_frontier, 11.4 -> 6.4 s for gpbo; the tables
and final states bit for bit the same). What can hang is the runtime's threading, the same under
both: the code before the fix hung gpbo under these flags too (jaxplore.linalg's batched calls
put back, jaxlib 0.10.2).
"""

import subprocess
import sys
import textwrap

import pytest

from conftest import REPO, subprocess_env

from jaxplore.planners import planner_names

PLANNERS = textwrap.dedent("""
    import sys, time
    from jaxplore import cli
    for name in sys.argv[1:]:
      t0 = time.perf_counter()
      own_slam = [] if name in {own_slam!r} else ["--slam", "oracle"]
      code = cli.main(["run", "--world", "open", "--res", "0.5", "--planner", name, "--robots",
                       "4", "--seed", "5", "--max-steps", "40", "--no-progress", *own_slam])
      print(f"SMOKE {name} exit {code} in {time.perf_counter() - t0:.1f} s", flush=True)
      if code:
        sys.exit(code)
    if "nearest_frontier" not in sys.argv[1:]:
      sys.exit(0)

    # 3 robots on 2 devices run as 2 + 2 (a copy of the last robot, its results dropped), not on
    # one device: their tables, state and robot-step count are the first 3 robots' of a batch of
    # 4 (a robot's run does not depend on the others), from the same compiled program.
    import jax, pandas as pd, jaxplore
    settings = dict(world="open", res=0.5, planner="nearest_frontier", seed=5, max_steps=40,
                    progress=False, quiet=True)
    three = jaxplore.run(robots=3, **settings)
    four = jaxplore.run(robots=4, **settings)
    assert three.config["sharded_over"] == 2, three.config["sharded_over"]
    for leaf in jax.tree.leaves(three.state):
      assert leaf.shape[0] == 3, leaf.shape
    pd.testing.assert_frame_equal(three.episodes, four.episodes.iloc[:3], check_exact=True)
    pd.testing.assert_frame_equal(three.curves, four.curves[four.curves.robot < 3],
                                  check_exact=True)
    assert three.timing["robot_steps"] == int(four.state.steps[:3].sum())
    print("PADDED ok", flush=True)
""")
# Every planner runs on the oracle SLAM model but these, on their own (PlannerSpec.slam): ahmed
# reads the scan_matching pose graph, and runs on it by default. The SLAM step is the engine's,
# the same under every planner, and it compiles for ~15 s more at each run: on their own models,
# the seven active-SLAM planners took the test from 68 to 209 s.
OWN_SLAM = {"ahmed"}
PLANNERS = PLANNERS.replace("{own_slam!r}", repr(OWN_SLAM))


# The planners of the default run: the two whose code hung (ags is ahmed's with other weights)
# and the default planner.
HUNG_ONCE = ("ahmed", "gpbo", "nearest_frontier")


def halves():
  """Every other registered planner, in two halves: alternate names, so that the four of the REG
  family (the slowest to compile) go two and two."""
  names = sorted(set(planner_names()) - set(HUNG_ONCE))
  return names[0::2], names[1::2]


def run_four_robots_on_two_host_devices(names):
  # no program of this process is compiled by another: none is written to the suite's cache
  env = subprocess_env(XLA_FLAGS="--xla_force_host_platform_device_count=2 "
                                 "--xla_backend_optimization_level=0",
                       JAX_ENABLE_COMPILATION_CACHE="false")
  try:
    proc = subprocess.run([sys.executable, "-c", PLANNERS, *names], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=540)
  except subprocess.TimeoutExpired as hung:
    done = [line for line in (hung.stdout or b"").decode().splitlines() if "SMOKE" in line]
    raise AssertionError(f"hung after {len(done)} planners: {done}") from None
  finished = [line for line in proc.stdout.splitlines() if line.startswith("SMOKE")]
  assert proc.returncode == 0, (finished, proc.stderr[-3000:])
  assert [line.split()[1] for line in finished] == list(names), finished
  assert "on 2 x cpu" in proc.stdout  # sharded over both devices
  if "nearest_frontier" in names:
    assert "PADDED ok" in proc.stdout


def test_the_planners_that_hung_run_four_robots_on_two_host_devices():
  run_four_robots_on_two_host_devices(HUNG_ONCE)


@pytest.mark.slow
class TestFirstHalf:
  def test_every_other_planner_runs_four_robots_on_two_host_devices(self):
    run_four_robots_on_two_host_devices(halves()[0])


@pytest.mark.slow
class TestSecondHalf:
  def test_every_other_planner_runs_four_robots_on_two_host_devices(self):
    run_four_robots_on_two_host_devices(halves()[1])


def test_the_runs_cover_every_planner():
  first, second = halves()
  assert sorted(first + second + list(HUNG_ONCE)) == sorted(planner_names())
  assert len(planner_names()) >= 12 and min(len(first), len(second)) >= 4
