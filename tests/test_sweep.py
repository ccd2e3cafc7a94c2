"""``jaxplore sweep``: chunks, one compile, resume after an interruption or ``kill -9``, sharding,
TOML files, random search, several planners, the memory guard and clear refusals.

Every compute here is a 40 x 40 world (``open`` at 0.5 m) for 30 steps; the settings of
``SETTINGS`` are shared so that in-process sweeps reuse one compiled program.
"""

import dataclasses
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import jaxplore
from jaxplore import cli, memory, runner, sim, sweeps
from jaxplore.resolve import resolve
from jaxplore.runspec import RunSpec
from jaxplore.sweeps import execute, schedule, settings
from jaxplore.config import ConfigError
from conftest import REPO, subprocess_env

RUNSPEC_FIELDS = {f.name for f in dataclasses.fields(RunSpec)}
# On the oracle SLAM model (li2020's own is scan_matching): these tests are of the sweep's
# bookkeeping, which is the same under both, and the oracle's programs compile faster.
SETTINGS = dict(world="open", res=0.5, planner="li2020", max_steps=30, replan_every=5,
                params={"r_max": 2.0}, slam="oracle", progress=False, quiet=True, devices=1)
# A sensor setting and a planner weight: the field of view changes the very first scan, so every
# setting's coverage differs (li2020 follows its first path for all 30 steps, so alpha and k1
# alone may not show within them).
GRID = {"fov": [3.0, 6.0], "k1": [0.0, 0.3]}
CLI_ARGS = ["sweep", "--world", "open", "--res", "0.5", "--planner", "li2020", "--max-steps", "30",
            "--replan-every", "5", "--set", "r_max=2", "--slam", "oracle", "--grid", "fov=3,6", "k1=0,0.3",
            "--seeds", "2", "--chunk-size", "3", "--devices", "1", "--no-progress", "--quiet"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
  """The uninterrupted sweep: 8 rows in chunks of 3 (the last padded), compiles counted by a
  JAX monitoring listener of the test's own."""
  import jax.monitoring
  compiled = []

  def listener(event, duration, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
      compiled.append(str(kwargs.get("fun_name")))

  jax.monitoring.register_event_duration_secs_listener(listener)
  out = tmp_path_factory.mktemp("sweep") / "reference"
  try:
    result = jaxplore.sweep(GRID, seeds=2, out=out, chunk_size=3, **SETTINGS)
  finally:
    jax.monitoring.unregister_event_duration_listener(listener)
  return result, out, compiled


def _tables(out):
  return pd.read_parquet(out / "episodes.parquet"), pd.read_parquet(out / "curves.parquet")


def test_chunks_share_one_compiled_program_and_tables_cover_every_row(reference):
  result, out, compiled = reference
  advance = [name for name in compiled if "advance" in name]
  assert len(advance) == 1, compiled  # three chunks, one compile of the engine
  assert result.timing["compiles"] == 1 and result.timing["chunks"] == 3
  plan = json.loads((out / sweeps.SCHEDULE_FILE).read_text())
  assert plan["groups"][0]["chunk_size"] == 3 and plan["n_chunks"] == 3
  assert [r["row"] for r in plan["groups"][0]["rows"]] == list(range(8))
  for k in range(3):
    assert (out / "chunks" / f"chunk_{k:05d}.parquet").exists()
    assert (out / "chunks" / f"chunk_{k:05d}.curves.parquet").exists()
  assert not list((out / "chunks").glob("*.tmp"))
  for name in ("config.json", "timing.json", "episodes.parquet", "curves.parquet", "sweep.png",
               "map.png", "coverage_time.png"):
    assert (out / name).exists(), name
  episodes, curves = _tables(out)
  pd.testing.assert_frame_equal(episodes, result.episodes)
  # one row per robot-episode (the padding of the last chunk dropped), every swept value a column
  assert episodes.robot.tolist() == list(range(8))
  assert sorted(set(zip(episodes.fov, episodes.k1, episodes.seed))) == sorted(
      (a, k, s) for a in (3.0, 6.0) for k in (0.0, 0.3) for s in (0, 1))
  assert set(curves.robot) == set(range(8))
  assert (episodes.world == "open").all() and (episodes.planner == "li2020").all()
  # common random numbers: seed s starts where PRNGKey(s) puts a robot, in every setting (the
  # first recorded pose is one motion step, which may differ by setting, from the start)
  first = curves[curves.step == 1].set_index("robot")
  resolved = resolve(RunSpec(**{k: v for k, v in SETTINGS.items() if k in RUNSPEC_FIELDS}))
  one_step = float(resolved.params.v_max * resolved.params.dt)
  starts = {}
  for s in (0, 1):
    pose = sim.reset(resolved.config, resolved.world, resolved.params, jax.random.PRNGKey(s)).pose
    starts[s] = np.asarray(pose[:2])
    for robot in episodes.robot[episodes.seed == s]:
      moved = np.hypot(*(first.loc[robot, ["x", "y"]].to_numpy(float) - starts[s]))
      assert moved <= one_step + 1e-5, (s, robot, moved)
  assert np.hypot(*(starts[0] - starts[1])) > 2 * one_step  # the check tells the seeds apart
  # the settings differ (the sweep is not running one setting eight times): each seed's coverage
  # depends on its field of view
  for s in (0, 1):
    mine = episodes[episodes.seed == s]
    assert mine[mine.fov == 3.0].coverage.max() != mine[mine.fov == 6.0].coverage.max()
  config = json.loads((out / "config.json").read_text())
  assert config["sweep"]["grid"] == {"fov": [3.0, 6.0], "k1": [0.0, 0.3]}
  assert config["groups"][0]["sim_config"]["max_steps"] == 30
  # jaxplore plot DIR redraws every figure of a sweep folder, sweep.png included
  (out / "sweep.png").unlink()
  assert cli.main(["plot", str(out)]) == 0
  assert (out / "sweep.png").exists()


# The engine's own parameters and li2020's weights (its entropy map's among them); every
# planner's weights alone are checked by tests/planners/test_conformance.py. The batch is this
# module's (SETTINGS, a chunk of 3 robots, the chunk's planning rounds): the engine program the
# reference sweep compiles (this test asks for it, so it is built first, in this process) is
# loaded from the suite's compilation cache, not compiled again (~13 s on 2 idle cores; it was
# in tests/test_sim.py, on the other xdist worker, and compiled its own while this module's
# was not yet there); a retrace is counted by this test's own jit all the same.
@pytest.mark.parametrize("planner", ["li2020"])
def test_changing_a_traced_parameter_does_not_retrace(planner, reference):
  from jaxplore import driver
  resolved = resolve(RunSpec(world="open", res=0.5, planner=planner, max_steps=30, replan_every=5,
                             params={"r_max": 2.0}, robots=3))
  config, world = resolved.config, resolved.world
  params = resolved.batch().params
  keys = jax.random.split(jax.random.PRNGKey(1), 3)
  state = sim.reset_batch(config, world, params, keys)
  chex.clear_trace_counter()
  advance = jax.jit(chex.assert_max_traces(sim.advance_unjitted, n=1),
                    static_argnames=("config", "n_epochs"))
  n_epochs = driver.chunk_epochs_for(config, None)
  advance(config, world, params, state, n_epochs=n_epochs)
  # All at once: any one of them compiled in as a constant would make this call retrace.
  changes = {"v_max": 0.4, "r_max": 1.5, "l_free": -0.5}
  changed = params.replace(**{name: jnp.full((3,), value, jnp.float32)
                              for name, value in changes.items()},
                           planner={name: value * 0.5 for name, value in params.planner.items()})
  out, _ = advance(config, world, changed, state, n_epochs=n_epochs)
  jax.block_until_ready(out)


def _interrupt_second_chunk(monkeypatch):
  """Makes the sweep's second chunk raise KeyboardInterrupt (as Ctrl-C would); returns the real
  ``run_chunk`` to put back."""
  real = execute.run_chunk
  calls = []

  def interrupt_second_chunk(*args, **kwargs):
    calls.append(1)
    if len(calls) == 2:
      raise KeyboardInterrupt
    return real(*args, **kwargs)

  monkeypatch.setattr(execute, "run_chunk", interrupt_second_chunk)
  return real


def test_interrupted_sweep_resumes_to_the_same_table(reference, tmp_path, monkeypatch):
  _, ref_out, _ = reference
  out = tmp_path / "cut"
  real = _interrupt_second_chunk(monkeypatch)
  with pytest.raises(KeyboardInterrupt, match="--resume"):
    jaxplore.sweep(GRID, seeds=2, out=out, chunk_size=3, **SETTINGS)
  monkeypatch.setattr(execute, "run_chunk", real)
  assert (out / "chunks" / "chunk_00000.parquet").exists()
  assert not (out / "chunks" / "chunk_00001.parquet").exists()
  assert not (out / "episodes.parquet").exists()
  (out / "chunks" / "chunk_00001.parquet.tmp").write_bytes(b"torn write")  # as if killed mid-write

  resumed = jaxplore.sweep(resume=out, progress=False, quiet=True, devices=1)
  assert resumed.timing["chunks_skipped"] == 1 and resumed.timing["chunks_run"] == 2
  assert not list((out / "chunks").glob("*.tmp"))
  for mine, theirs in zip(_tables(out), _tables(ref_out)):
    pd.testing.assert_frame_equal(mine, theirs)

  # the same command again on the finished folder computes nothing and gives the same table
  again = jaxplore.sweep(GRID, seeds=2, out=out, chunk_size=3, **SETTINGS)
  assert again.timing["chunks_run"] == 0
  pd.testing.assert_frame_equal(again.episodes, _tables(ref_out)[0])


def test_a_folder_of_the_older_layout_resumes(reference, tmp_path):
  """Folders written before the schedule was renamed hold ``sweep_plan.json`` (its run settings
  without the newer ones): they resume into the same tables."""
  _, ref_out, _ = reference
  old = tmp_path / "old"
  shutil.copytree(ref_out, old)
  made = json.loads((old / sweeps.SCHEDULE_FILE).read_text())
  made["format"] = "jaxplore-sweep-plan"
  del made["spec"]["run"]["plan_window"]
  (old / sweeps.LEGACY_FILE).write_text(json.dumps(made))
  (old / sweeps.SCHEDULE_FILE).unlink()
  for path in [old / "episodes.parquet", old / "curves.parquet", *old.glob("chunks/chunk_00002*")]:
    path.unlink()
  resumed = jaxplore.sweep(resume=old, progress=False, quiet=True, devices=1)
  assert resumed.timing["chunks_run"] == 1 and resumed.timing["chunks_skipped"] == 2
  for mine, theirs in zip(_tables(old), _tables(ref_out)):
    pd.testing.assert_frame_equal(mine, theirs)


KILLABLE = textwrap.dedent("""
    # jaxplore sweep, with the second chunk held back so that SIGKILL lands while it is pending
    import sys, time
    from jaxplore import cli
    from jaxplore.sweeps import execute
    real, calls = execute.run_chunk, []
    def held(*args, **kwargs):
      calls.append(1)
      if len(calls) == 2:
        time.sleep(600)
      return real(*args, **kwargs)
    execute.run_chunk = held
    sys.exit(cli.main(sys.argv[1:]))
""")


@pytest.mark.slow  # a whole sweep in subprocesses or through the CLI: `pytest -m slow`
def test_kill_9_then_resume_gives_the_uninterrupted_table(reference, tmp_path):
  _, ref_out, _ = reference
  out = tmp_path / "killed"
  proc = subprocess.Popen([sys.executable, "-c", KILLABLE, *CLI_ARGS, "--out", str(out)],
                          cwd=REPO, env=subprocess_env(), stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT)
  first_chunk = out / "chunks" / "chunk_00000.parquet"
  deadline = time.monotonic() + 240
  while not first_chunk.exists():
    if proc.poll() is not None or time.monotonic() > deadline:
      proc.kill()
      pytest.fail(f"sweep ended or hung before its first chunk:\n{proc.communicate()[0].decode()}")
    time.sleep(0.05)
  os.kill(proc.pid, signal.SIGKILL)
  proc.wait(timeout=30)
  assert proc.returncode == -signal.SIGKILL
  assert not (out / "chunks" / "chunk_00001.parquet").exists()
  assert not (out / "episodes.parquet").exists()

  assert cli.main(["sweep", "--resume", str(out), "--devices", "1", "--no-progress", "--quiet"]) == 0
  for mine, theirs in zip(_tables(out), _tables(ref_out)):
    pd.testing.assert_frame_equal(mine, theirs)


SHARDED = textwrap.dedent("""
    import sys, jax, jaxplore
    assert len(jax.devices()) == 2, jax.devices()
    result = jaxplore.sweep({"fov": [3.0, 6.0], "k1": [0.0, 0.3]}, seeds=2, world="open", res=0.5,
                            planner="li2020", max_steps=30, replan_every=5, params={"r_max": 2.0},
                            slam="oracle", progress=False, quiet=True, devices=2, chunk_size=4)
    assert result.timing["compiles"] == 1 and result.timing["sharded_over"] == 2, result.timing
    result.episodes.to_parquet(sys.argv[1] + "/episodes.parquet")
    result.curves.to_parquet(sys.argv[1] + "/curves.parquet")
""")


@pytest.mark.slow  # a whole sweep in subprocesses or through the CLI: `pytest -m slow`
def test_sharded_sweep_equals_unsharded_bit_for_bit(reference, tmp_path):
  """Two host devices, chunks of 4 sharded 2 + 2, against one device and chunks of 3: the same
  rows land in different chunks, positions and devices, and every number is identical."""
  _, ref_out, _ = reference
  done = subprocess.run([sys.executable, "-c", SHARDED, str(tmp_path)], cwd=REPO, capture_output=True,
                        env=subprocess_env(XLA_FLAGS="--xla_force_host_platform_device_count=2"),
                        timeout=300)
  assert done.returncode == 0, done.stderr.decode()[-3000:]
  for mine, theirs in zip(_tables(tmp_path), _tables(ref_out)):
    pd.testing.assert_frame_equal(mine, theirs, check_exact=True)


@pytest.mark.slow  # a whole episode or CLI run: `pytest -m slow` (see README)
def test_toml_random_search_and_several_planners(reference, tmp_path):
  toml = tmp_path / "sweep.toml"
  toml.write_text(textwrap.dedent(f"""
      world = "open"
      planners = ["li2020", "nearest_frontier"]
      seeds = [0, 1]
      res = 0.5
      max_steps = 30
      replan_every = 5
      chunk_size = 3
      out = "{tmp_path / 'toml'}"

      [set]
      r_max = 2.0

      [planner_set]
      k2 = 0.8

      [random]
      samples = 2
      seed = 7
      alpha = {{ low = 1.0, high = 2.0 }}
      k1 = {{ low = 0.01, high = 0.3, log = true }}
  """))
  result = jaxplore.sweep(config=toml, progress=False, quiet=True, devices=1)
  episodes = result.episodes
  li, nf = episodes[episodes.planner == "li2020"], episodes[episodes.planner == "nearest_frontier"]
  assert len(li) == 2 * 2 and len(nf) == 2 * 2  # 2 random points x 2 seeds for each planner
  assert li.alpha.between(1.0, 2.0).all() and li.k1.between(0.01, 0.3).all()
  assert li.alpha.nunique() == 2 and li.k1.nunique() == 2
  assert nf.k1.isna().all() and nf.alpha.isna().all()  # li2020's weights, not nearest_frontier's
  assert episodes.robot.tolist() == list(range(8))
  assert result.timing["compiles"] <= 2  # one program per planner (li2020's may be cached)
  config = json.loads((tmp_path / "toml" / "config.json").read_text())
  assert config["groups"][0]["fixed_planner_params"]["k2"] == pytest.approx(0.8)
  assert (tmp_path / "toml" / "sweep.png").exists()
  # the points come from the seed: the same file plans the same points
  again = sweeps.make_spec(None, sweeps.load_config(toml)["random"], 2, 7, [0], "open", "li2020")
  drawn = settings.random_samples(again.random, 2, 7)
  assert sorted(li.alpha.unique()) == sorted(a for a, _ in drawn)


@pytest.mark.parametrize("text, match", [
    ("gird = 1", "unknown key 'gird'"),
    ("samples = 4", "unknown key 'samples'.*\\[random\\]"),
    ("[grid]\nalpha = []", "sweep grid for 'alpha' is empty"),
    ("[grid]\nfov = ['a']", "must be a number"),
    ("[random]\nalpha = {low = 1, high = 2}", "samples"),
    ("[random]\nsamples = 2\nalpha = {low = 1, hi = 2}", "unknown key.*'hi'"),
    ("[random]\nsamples = 2\nk1 = {low = 0, high = 1, log = true}", "log range needs low > 0"),
    ("seeds = 'many'", "seeds must be"),
    ("world = 'open'\nworlds = ['lab']", "either world or worlds"),
    ("chunk_size = 0", "chunk_size must be a positive integer"),
    ("max_steps = = 3", "not valid TOML"),
])
def test_bad_toml_is_refused_naming_the_key(tmp_path, text, match):
  path = tmp_path / "bad.toml"
  path.write_text(text)
  with pytest.raises(ConfigError, match=match):
    jaxplore.sweep(config=path, progress=False)


def test_cli_errors_are_one_clear_line(tmp_path, capsys):
  bad = tmp_path / "bad.toml"
  bad.write_text("gird = 1\n")
  assert cli.main(["sweep", "--config", str(bad), "--devices", "1", "--no-progress"]) == 2
  err = capsys.readouterr().err
  assert err.startswith("jaxplore: error:") and "gird" in err
  assert cli.main(["sweep", "--resume", str(tmp_path / "nowhere"), "--devices", "1"]) == 2
  assert "cannot resume" in capsys.readouterr().err
  assert cli.main(["sweep", "--resume", str(tmp_path), "--grid", "alpha=1", "--devices", "1"]) == 2
  assert "do not give grid" in capsys.readouterr().err
  assert cli.main(["sweep", "--random", "alpha=1", "--samples", "2", "--devices", "1"]) == 2
  assert "NAME=LOW:HIGH" in capsys.readouterr().err


def test_resume_refuses_a_missing_or_corrupt_plan(tmp_path):
  with pytest.raises(ConfigError, match=f"holds no {sweeps.SCHEDULE_FILE}"):
    jaxplore.sweep(resume=tmp_path, progress=False)
  (tmp_path / sweeps.SCHEDULE_FILE).write_text("{not json")
  with pytest.raises(ConfigError, match="corrupt"):
    jaxplore.sweep(resume=tmp_path, progress=False)
  (tmp_path / sweeps.SCHEDULE_FILE).write_text(json.dumps({"format": schedule.SCHEDULE_FORMAT,
                                                             "version": 1}))
  with pytest.raises(ConfigError, match="corrupt"):
    jaxplore.sweep(resume=tmp_path, progress=False)


def test_a_folder_holding_another_sweep_or_other_files_is_refused(reference, tmp_path):
  _, ref_out, _ = reference
  other = tmp_path / "other"
  other.mkdir()
  shutil.copy(ref_out / sweeps.SCHEDULE_FILE, other / sweeps.SCHEDULE_FILE)
  with pytest.raises(ConfigError, match=r"different sweep.*grid.*--resume"):
    jaxplore.sweep({"alpha": [1.0, 3.0]}, seeds=2, out=other, **SETTINGS)
  with pytest.raises(ConfigError, match="different sweep.*seeds"):
    jaxplore.sweep(GRID, seeds=3, out=other, **SETTINGS)
  busy = tmp_path / "busy"
  busy.mkdir()
  (busy / "notes.txt").write_text("mine")
  with pytest.raises(ConfigError, match="not empty and holds no sweep schedule"):
    jaxplore.sweep(GRID, seeds=2, out=busy, **SETTINGS)
  with pytest.raises(ConfigError, match="is a file"):
    jaxplore.sweep(GRID, seeds=2, out=busy / "notes.txt", **SETTINGS)


def test_memory_guard_shrinks_a_chunk_or_refuses_with_the_numbers(monkeypatch, capsys):
  _, config, _, _ = runner.prepare("open", "li2020", 8, res=0.5, max_steps=30, replan_every=5,
                                   params={"r_max": 2.0})
  one, eight = memory.estimate_bytes(config, 1), memory.estimate_bytes(config, 8)
  # room for a chunk of two robots but not eight
  room = int(memory.estimate_bytes(config, 2) / sweeps.MEMORY_FRACTION) + 1
  monkeypatch.setattr(memory, "available_bytes", lambda: room)
  assert memory.estimate_bytes(config, 3) > sweeps.MEMORY_FRACTION * room
  assert sweeps.fit_chunk(config, 8) == 2
  err = capsys.readouterr().err
  assert "chunk of 8 robots" in err and "40x40" in err and f"({eight} bytes)" in err
  assert "running chunks of 2 robots instead" in err
  with pytest.raises(ConfigError, match="the schedule's chunks of 8"):
    sweeps.fit_chunk(config, 8, fixed=True)
  # not even one robot: refused before any compute, naming bytes, grid and robots
  monkeypatch.setattr(memory, "available_bytes", lambda: one)
  with pytest.raises(ConfigError, match=rf"one robot on a 40x40 grid .*\({one} bytes\).*available"):
    jaxplore.sweep(GRID, seeds=2, **SETTINGS)
  with pytest.raises(ConfigError, match="one robot"):
    jaxplore.sweep(GRID, seeds=2, chunk_size=10_000_000, **SETTINGS)


def test_a_chunk_program_that_compiles_too_large_is_refused_then_resumes(reference, tmp_path,
                                                                        monkeypatch):
  """The memory model passes the chunk, the compiled program's own numbers do not: refused
  before the chunk runs, naming the numbers; the sweep resumes once there is room."""
  _, ref_out, _ = reference
  out = tmp_path / "too_large"
  with monkeypatch.context() as patch:
    patch.setattr(memory, "estimate_bytes", lambda config, robots: 0)
    patch.setattr(memory, "available_bytes", lambda: 1 << 10)
    with pytest.raises(ConfigError, match="3 robots on a 40x40 grid .* allocates .*smaller chunks"):
      jaxplore.sweep(GRID, seeds=2, out=out, chunk_size=3, **SETTINGS)
  assert not list((out / "chunks").glob("*.parquet"))
  resumed = jaxplore.sweep(resume=out, progress=False, quiet=True, devices=1)
  assert resumed.timing["chunks_run"] == 3
  for mine, theirs in zip(_tables(out), _tables(ref_out)):
    pd.testing.assert_frame_equal(mine, theirs)


def test_bad_sweep_arguments_are_refused_before_compute():
  with pytest.raises(ConfigError, match="cannot sweep 'gamma'"):
    jaxplore.sweep({"gamma": [1.0]}, seeds=1, **SETTINGS)
  with pytest.raises(ConfigError, match="both in the grid and in the random search"):
    jaxplore.sweep({"alpha": [1.0]}, random={"alpha": (1.0, 2.0)}, samples=2, **SETTINGS)
  with pytest.raises(ConfigError, match="samples is given"):
    jaxplore.sweep({"alpha": [1.0]}, samples=2, **SETTINGS)
  with pytest.raises(ConfigError, match="unknown setting.*'robots'"):
    jaxplore.sweep({"alpha": [1.0]}, robots=3, **SETTINGS)
  with pytest.raises(ConfigError, match="chunk_size must be a positive integer"):
    jaxplore.sweep({"alpha": [1.0]}, chunk_size=0, **SETTINGS)
  with pytest.raises(ConfigError, match="k1 < k2"):
    jaxplore.sweep({"k1": [0.2, 0.95]}, seeds=1, **SETTINGS)


def test_r_e_fixes_a_shape_so_each_value_is_its_own_group():
  """A batch takes one r_e (li2020's gain kernel's shape); the schedule splits its values."""
  spec = sweeps.make_spec({"r_e": [0.5, 1.0], "alpha": [1.0, 2.0]}, None, None, 0, [0, 1], "open",
                          ["li2020", "nearest_frontier"], RunSpec(res=0.5, max_steps=30))
  groups = schedule.split_groups(spec)
  # r_e and alpha are li2020's: nearest_frontier runs once per seed, with neither.
  assert [(g.planner, len(g.rows)) for g in groups] == [("li2020", 4), ("li2020", 4),
                                                         ("nearest_frontier", 2)]
  assert [r.row for g in groups for r in g.rows] == list(range(10))
  for g in groups[:2]:
    assert len({r.values[0] for r in g.rows}) == 1  # one r_e per group
  for g in groups:
    schedule.resolve_group(spec, g, None, {})  # validates: each group is a legal batch
  mixed = dataclasses.replace(groups[0], rows=groups[0].rows + groups[1].rows)
  with pytest.raises(ConfigError, match="r_e"):
    schedule.resolve_group(spec, mixed, None, {})


def test_resume_recomputes_a_zero_byte_or_missing_chunk_file(reference, tmp_path, capsys):
  _, ref_out, _ = reference
  out = tmp_path / "damaged"
  shutil.copytree(ref_out, out)
  (out / "episodes.parquet").unlink()
  (out / "chunks" / "chunk_00001.parquet").write_bytes(b"")  # a full disk, a torn copy
  (out / "chunks" / "chunk_00002.curves.parquet").unlink()
  resumed = jaxplore.sweep(resume=out, progress=False, quiet=True, devices=1)
  assert resumed.timing["chunks_run"] == 2 and resumed.timing["chunks_skipped"] == 1
  err = capsys.readouterr().err
  assert "chunk 1 of" in err and "chunk 2 of" in err and "computing it again" in err
  for mine, theirs in zip(_tables(out), _tables(ref_out)):
    pd.testing.assert_frame_equal(mine, theirs)


def test_a_second_sweep_into_a_busy_folder_is_refused_before_touching_it(reference, tmp_path):
  import fcntl
  _, ref_out, _ = reference
  out = tmp_path / "busy"
  shutil.copytree(ref_out, out)
  stray = out / "chunks" / "chunk_00002.parquet.tmp"
  stray.write_bytes(b"the other sweep's chunk, being written")
  with open(out / sweeps.LOCK_FILE, "a") as other:  # as the sweep running in there holds it
    fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
    with pytest.raises(ConfigError, match="in use by another jaxplore sweep"):
      jaxplore.sweep(resume=out, progress=False, quiet=True, devices=1)
    with pytest.raises(ConfigError, match="in use by another jaxplore sweep"):
      jaxplore.sweep(GRID, seeds=2, out=out, chunk_size=3, **SETTINGS)
  assert stray.exists()  # its temporaries were left alone
  # once it is released, the same sweep takes the folder (finished: nothing to compute)
  again = jaxplore.sweep(GRID, seeds=2, out=out, chunk_size=3, **SETTINGS)
  assert again.timing["chunks_run"] == 0


def test_plot_on_a_missing_or_empty_folder_is_one_clear_line(tmp_path, capsys):
  (tmp_path / "empty").mkdir()
  for folder, match in ((tmp_path / "missing", "is not a folder"),
                        (tmp_path / "empty", "holds no finished jaxplore results")):
    assert cli.main(["plot", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxplore: error: ") and match in err and "Traceback" not in err


def test_a_word_valued_setting_is_a_grid_axis(reference, tmp_path, monkeypatch):
  """li2020's ``region`` swept by its words: a group (a compiled program) per word, the words in
  the table and in each group's resolved settings, and an interrupted sweep resumes from its
  schedule (words kept through its JSON) to the uninterrupted table. (Groups of 3 rows: the
  ``beams`` group is the reference's program, only ``disc`` compiles.)"""
  grid = {"region": ["beams", "disc"]}
  out = tmp_path / "cut"
  real = _interrupt_second_chunk(monkeypatch)
  with pytest.raises(KeyboardInterrupt, match="--resume"):
    jaxplore.sweep(grid, seeds=3, out=out, chunk_size=3, **SETTINGS)
  monkeypatch.setattr(execute, "run_chunk", real)
  resumed = jaxplore.sweep(resume=out, progress=False, quiet=True, devices=1)
  assert resumed.timing["chunks_skipped"] == 1 and resumed.timing["chunks_run"] == 1

  episodes = pd.read_parquet(out / "episodes.parquet")
  assert list(episodes.region) == ["beams"] * 3 + ["disc"] * 3
  groups = json.loads((out / "config.json").read_text())["groups"]
  assert [g["sim_config"]["planner_settings"]["region"] for g in groups] == ["beams", "disc"]
  whole = jaxplore.sweep(grid, seeds=3, out=tmp_path / "whole", chunk_size=3, **SETTINGS)
  pd.testing.assert_frame_equal(episodes, whole.episodes)


def test_grid_words_are_refused_where_a_number_is_meant():
  """Words only for a planner's word-valued setting, never mixed with numbers, each once, and
  each one the planner knows: refused before any compute, naming the setting."""
  with pytest.raises(ConfigError, match="grid value of 'alpha' must be a number"):
    jaxplore.sweep({"alpha": ["high"]}, seeds=1, **SETTINGS)
  with pytest.raises(ConfigError, match="mixes words and numbers"):
    jaxplore.sweep({"region": ["disc", 1.0]}, seeds=1, **SETTINGS)
  with pytest.raises(ConfigError, match="repeats a value"):
    jaxplore.sweep({"region": ["disc", "disc"]}, seeds=1, **SETTINGS)
  with pytest.raises(ConfigError, match="region must be one of beams, visible, disc, got 'cube'"):
    jaxplore.sweep({"region": ["disc", "cube"]}, seeds=1, **SETTINGS)
  assert settings.normalise_grid({"region": "disc"}) == {"region": ("disc",)}


def test_cli_grid_takes_words_for_a_word_valued_setting(monkeypatch):
  """``--grid region=disc,visible`` reaches the sweep as words (numbers stay numbers)."""
  class Called(Exception):
    pass

  def capture(grid=None, **kwargs):
    raise Called(grid)

  monkeypatch.setattr(sweeps, "sweep", capture)
  with pytest.raises(Called) as called:
    cli.main(["sweep", "--world", "open", "--planner", "li2020", "--grid", "region=disc,visible",
              "alpha=1,2", "--no-progress", "--quiet"])
  assert called.value.args[0] == {"region": ["disc", "visible"], "alpha": [1.0, 2.0]}


class Scheduled(Exception):
  """Raised where a sweep would start computing (the README examples' tests stop there)."""


@pytest.fixture
def stop_at_compute(tmp_path, monkeypatch):
  """Runs in ``tmp_path``; a sweep raises :class:`Scheduled` instead of computing, its schedule
  and resolved groups kept in the returned list."""
  monkeypatch.chdir(tmp_path)
  scheduled = []

  def stop(made, group_runs, *args):
    scheduled.append((made, group_runs))
    raise Scheduled

  monkeypatch.setattr(execute, "execute", stop)
  return scheduled


def test_the_readme_sweep_command_schedules_without_an_error(stop_at_compute):
  """The user guide's `jaxplore sweep` command line passes every check before compute."""
  line = re.search(r"^jaxplore sweep .*$", (REPO / "docs" / "user-guide.md").read_text(), re.M).group(0)
  with pytest.raises(Scheduled):
    cli.main(shlex.split(line)[1:] + ["--no-progress", "--devices", "1"])
  made, group_runs = stop_at_compute[0]
  assert [g.planner for g in made.groups] == ["li2020"]
  assert len(made.groups[0].rows) == 3 * 3 * 2 * 8  # alpha x k1 x k2 x seeds


def test_the_readme_toml_example_schedules_without_an_error(tmp_path, stop_at_compute):
  """The user guide's TOML sweep, as a user would save it, goes through every check a sweep makes
  before compute (settings, worlds, planners' weights, memory) and is scheduled; the compute
  itself (2 worlds x 2 planners x 96 settings x 8 seeds) is left out."""
  block = re.search(r"```toml\n(.*?)```", (REPO / "docs" / "user-guide.md").read_text(), re.S).group(1)
  (tmp_path / "sweep.toml").write_text(block)
  with pytest.raises(Scheduled):
    jaxplore.sweep(config="sweep.toml", progress=False, quiet=True, devices=1)
  made, group_runs = stop_at_compute[0]
  assert {(g.world, g.planner) for g in made.groups} == {
      (w, p) for w in (0, 1) for p in ("li2020", "nearest_frontier")}  # worlds by index
  assert {r.resolved.grid.name for r in group_runs} == {"lab", "office"}
  assert all(r.resolved.config.res == 0.2 for r in group_runs)
  assert (tmp_path / "runs" / "sweep_toml" / sweeps.SCHEDULE_FILE).exists()


def test_the_slam_model_is_a_grid_axis():
  """``slam`` is a word-valued static setting of the simulator: ``--grid
  slam=oracle,scan_matching`` makes a group (a compiled program) per model, each resolving to its
  SLAM model; a word no model has is refused before any compute."""
  from jaxplore.sweeps import schedule
  spec = settings.make_spec(grid={"slam": ["oracle", "scan_matching"], "r_max": [1.5, 2.0]},
                            seeds=[0], worlds=["open"], planners=["nearest_frontier"],
                            base=RunSpec.create(res=0.5, max_steps=30))
  groups = schedule.split_groups(spec)
  assert len(groups) == 2 and [len(g.rows) for g in groups] == [2, 2]
  configs = [schedule.resolve_group(spec, g, None, {}).config for g in groups]
  assert [c.slam for c in configs] == ["oracle", "scan_matching"]
  assert [c.map_hole_cells for c in configs] == [0, 4] and configs[1].graph_nodes > 0
  with pytest.raises(ConfigError, match="grid value of 'slam' must be one of oracle, "
                     "scan_matching, got 'lidar'"):
    jaxplore.sweep({"slam": ["oracle", "lidar"]}, seeds=1, **SETTINGS)


def test_set_names_a_weight_of_the_swept_planner(stop_at_compute):
  """``--set k1=0.3`` on a li2020 sweep: the weight goes to the planner's table (the sweep's
  shared spec names no planner, so the sweep routes it by its planners), into every row."""
  with pytest.raises(Scheduled):
    cli.main(["sweep", "--world", "open", "--res", "0.5", "--planner", "li2020", "--set",
              "k1=0.3", "--grid", "alpha=1,2", "--seeds", "1", "--max-steps", "10",
              "--no-progress", "--quiet", "--devices", "1"])
  made, group_runs = stop_at_compute[0]
  assert dict(made.spec.base.planner_params) == {"k1": 0.3}
  assert "k1" not in made.spec.base.params
