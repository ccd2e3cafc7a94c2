"""The command line as a user meets it: whole help texts, and bad input or an unwritable output
refused before any compute with a message and exit code 2 (1 where results could not be written
after the compute), never a traceback."""

import os
import types

import pandas as pd
import pytest

from jaxplore import cli, results
from jaxplore.errors import ConfigError, OutputError, check_writable
from jaxplore.planners import planner_names

RUN = ["run", "--world", "open", "--res", "0.5", "--robots", "1", "--max-steps", "8",
       "--set", "r_max=2", "--devices", "1", "--no-progress"]


def test_the_help_is_whole_and_run_help_lists_every_planner(capsys):
  with pytest.raises(SystemExit) as exited:
    cli.main(["--help"])
  text = capsys.readouterr().out
  assert exited.value.code == 0 and "``" not in text and "for each command." in text
  for command in ("run", "sweep"):
    with pytest.raises(SystemExit):
      cli.main([command, "--help"])
    text = capsys.readouterr().out
    assert "planners (--planner NAME):" in text
    assert all(f"  {name} " in text for name in planner_names())


@pytest.mark.parametrize("flags, says", [
    (["--set", "r_max"], "--set takes NAME=VALUE, got 'r_max'"),
    (["--set", "r_max=0"], "parameter r_max must be > 0, got 0"),  # named r_e before
    (["--planner-set", "k1"], "--planner-set takes NAME=VALUE"),
    # both ran silently wrong: 0 m driven at 1e6 m/s (dt became 1e-7 s), 1,000 s per metre
    (["--set", "v_max=1e6"], "steps to turn half a circle, more than its 8 and 1000"),
    (["--set", "dt=100"], "v_max * dt = 25 m per step, more than a cell's diagonal (0.707 m)")])
def test_bad_flags_exit_2_naming_the_problem(capsys, flags, says):
  assert cli.main(RUN + flags) == 2
  err = capsys.readouterr().err
  assert err.startswith("jaxplore: error: ") and says in err, err


def test_toml_values_of_the_wrong_type_are_refused_by_name(tmp_path, capsys):
  for text, says in (("max_steps = true", "max_steps must be a positive integer, got True"),
                     ("robots = true", "robots must be a positive integer, got True"),
                     ("[set]\nr_max = true", "[set] r_max must be a number, got True")):
    path = tmp_path / "run.toml"
    path.write_text(text + "\n")
    assert cli.main(RUN[:1] + ["--config", str(path), "--no-progress"]) == 2, text
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err, err


@pytest.mark.parametrize("args, says", [
    (["--render", "lab", "--res", "0"], "res must be a positive number of metres per cell"),
    (["--render", "lab", "--out", "lab.txt"], "the rendering is a PNG; give a .png file"),
    (["--render", "lab", "--out", "afile/lab.png"], "afile' is a file, not a folder")])
def test_maps_render_refuses_bad_input(tmp_path, monkeypatch, capsys, args, says):
  monkeypatch.chdir(tmp_path)
  (tmp_path / "afile").write_text("")
  assert cli.main(["maps"] + args) == 2
  assert says in capsys.readouterr().err


def test_an_output_under_a_file_or_unwritable_is_refused_before_compute(tmp_path, monkeypatch,
                                                                          capsys):
  (tmp_path / "afile.txt").write_text("")
  assert cli.main(RUN + ["--out", str(tmp_path / "afile.txt" / "sub")]) == 2
  assert "afile.txt' is a file, not a folder" in capsys.readouterr().err
  # a read-only filesystem (root may write anywhere else: access() is what says EROFS)
  real = os.access
  monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(tmp_path)
                      else real(p, mode))
  with pytest.raises(ConfigError, match="is not writable"):
    check_writable(tmp_path / "new" / "run", "--out")
  assert cli.main(["plot", str(tmp_path)]) == 2
  assert "is not writable" in capsys.readouterr().err


def test_a_disk_that_fills_up_keeps_what_was_written_and_says_what_is_missing(tmp_path,
                                                                             monkeypatch, capsys):
  """Results that could not be written after the compute: what was written stays, the message
  says what is missing, the command exits 1 without a traceback (it lost the run)."""
  def full(*args, **kwargs):
    raise OSError(28, "No space left on device")

  monkeypatch.setattr(results, "write_maps", full)
  out = tmp_path / "run"
  episodes = pd.DataFrame({"robot": [0], "coverage": [0.5]})
  write = lambda: results.write_run(out, {"sim_config": {}}, {"run_s": 1.0}, episodes,
                                    episodes.assign(step=1), None,
                                    types.SimpleNamespace(logodds=None, memory=None))
  with pytest.raises(OutputError) as error:
    write()
  text = str(error.value)
  assert "could not write maps.npz" in text and "No space left on device" in text, text
  assert "written: config.json, timing.json, episodes.parquet, curves.parquet" in text
  assert "missing: maps.npz, memory.npz, the figures" in text
  pd.testing.assert_frame_equal(pd.read_parquet(out / "episodes.parquet"), episodes)
  result, code = cli._reporting_errors(write)
  err = capsys.readouterr().err
  assert result is None and code == 1 and "jaxplore: error: could not write maps.npz" in err


SWEEP = ["sweep", "--res", "0.5", "--seeds", "1", "--max-steps", "8", "--devices", "1", "--quiet"]


@pytest.mark.parametrize("flags, says", [
    (["--world", "open", "open"], "worlds repeat: ['open', 'open']"),
    (["--world", "open", "--grid", "range_noise=0.1,0.1"], "grid 'range_noise' repeats a value"),
    (["--world", "open", "--planner", "li2020", "--random", "k1=0.2:0.2", "--samples", "2"],
     "low 0.2 is not below high 0.2 (one value"),
    (["--world", "open", "--planner", "li2020", "--random", "k1=0:0.5", "--samples", "2",
      "--random-seed", "-1"], "random_seed must be an integer in [0, 2**32), got -1")])
def test_a_sweep_refuses_repeats_empty_ranges_and_bad_seeds(capsys, flags, says):
  """Repeated planners and seeds were refused, but repeated worlds and grid values gave
  duplicate rows, an empty random range one row recorded as two samples, and a negative random
  seed a NumPy traceback."""
  assert cli.main(SWEEP + flags) == 2
  err = capsys.readouterr().err
  assert says in err and "Traceback" not in err, err


def test_distributed_without_a_coordinator_says_what_to_set():
  import subprocess
  import sys
  from conftest import REPO, subprocess_env
  env = {k: v for k, v in subprocess_env().items() if not k.startswith("JAX_")}
  proc = subprocess.run([sys.executable, "-m", "jaxplore"] + SWEEP + ["--world", "open",
                                                                      "--distributed"],
                        cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
  assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
  assert "--distributed" in proc.stderr and "JAX_COORDINATOR_ADDRESS" in proc.stderr


@pytest.mark.parametrize("planner, setting, says", [
    ("ahmed", "max_candidates=0", "'ahmed': setting max_candidates must be"),
    ("gpbo", "n_beams=1000000000", "'gpbo': setting n_beams must be"),
    ("gpbo", "n_train=2.5", "setting n_train must be"),
    ("ereg", "nodes=1000000000", "mostly for the planner's memory (ereg's settings)")])
def test_a_planner_setting_that_cannot_work_is_refused_before_the_compile(capsys, planner,
                                                                         setting, says):
  """These failed inside the compiler (a gather from an empty array), after a 13 s compile, or
  asked XLA for 2e18 bytes: the memory guard now counts the planner's memory."""
  assert cli.main(RUN + ["--planner", planner, "--planner-set", setting]) == 2
  err = capsys.readouterr().err
  assert says in err, err


def test_memory_is_checked_before_the_worlds_preparation_and_a_sweeps_listing(monkeypatch,
                                                                             capsys):
  """A 20000 x 20000 map at its own resolution grew past 12 GB in the world's preparation
  (distance transforms) before the run's memory guard looked; a 5.5e9-setting sweep grid was
  killed by the kernel while its rows were listed. Both are refused first, with the numbers."""
  from jaxplore import memory, sim
  monkeypatch.setattr(memory, "available_bytes", lambda: 64 << 20)

  def never(*args, **kwargs):
    raise AssertionError("the world was prepared before the memory guard")

  monkeypatch.setattr(sim, "make_world", never)
  assert cli.main(RUN) == 2
  assert "one robot on a 40x40 grid with max_steps=8 needs about" in capsys.readouterr().err
  monkeypatch.setattr(memory, "available_bytes", lambda: 300 << 20)  # one robot's run fits
  k1 = ",".join(str(k / 600) for k in range(300))
  alpha = ",".join(str(1 + k / 300) for k in range(300))
  assert cli.main(SWEEP + ["--world", "open", "--planner", "li2020", "--grid", f"k1={k1}",
                           f"alpha={alpha}"]) == 2
  err = capsys.readouterr().err
  assert "the sweep has 9e+04 robot-episodes; listing them takes about 0.343 GiB" in err, err
