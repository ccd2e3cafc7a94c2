"""``jaxplore animate``: the replay reproduces the recorded run, the GIF has frames, bad input is refused."""

import json
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from conftest import tiny_office
from PIL import Image

import jaxplore
from jaxplore import animate, cli, sweeps
from jaxplore.config import ConfigError

# Two rooms and a door, so paths bend. The shapes and settings are those of the quickstart
# notebook's tiny run (tests/test_notebooks.py) and of tests/test_runner.py's, so one process
# compiles the run only once (conftest.tiny_office); the seed differs (a traced value).
WORLD = tiny_office()
SETTINGS = dict(robots=2, seed=3, max_steps=40, replan_every=5, params={"r_max": 3.0},
                progress=False, quiet=True)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
  out = tmp_path_factory.mktemp("anim_run")
  jaxplore.run(world=WORLD, out=out, **SETTINGS)
  return out


def test_replay_reproduces_the_recorded_trajectory(run_dir):
  curves = pd.read_parquet(run_dir / "curves.parquet")
  replay = animate.resimulate(run_dir, (1, 0), progress=False)
  assert replay.robots == (1, 0)
  for j, robot in enumerate(replay.robots):
    curve = curves[curves.robot == robot].sort_values("step")
    n = len(curve)
    assert n > 10 and curve.distance.iloc[-1] > 0.5  # the robot really moved
    np.testing.assert_allclose(replay.x[:n, j], curve.x.to_numpy(), rtol=0, atol=1e-6)
    np.testing.assert_allclose(replay.y[:n, j], curve.y.to_numpy(), rtol=0, atol=1e-6)
  assert replay.max_deviation_m <= 1e-6
  # Frames start at the reset, then one per planning round (the default keeps them all here).
  assert [f["step"] for f in replay.frames] == list(range(0, 41, 5))
  first, last = replay.frames[0], replay.frames[-1]
  assert np.count_nonzero(last["logodds"]) > np.count_nonzero(first["logodds"])  # the map grew
  # The path drawn at a frame is the rest of the one being followed: it starts at the robot's cell.
  planned = 0
  for frame in replay.frames:
    for j in range(2):
      if frame["planned"][j]:
        planned += 1
        x, y = frame["pose"][j][:2]
        cell = (int((y - replay.origin[1]) // replay.res), int((x - replay.origin[0]) // replay.res))
        assert tuple(frame["waypoints"][j][0]) == cell
        assert 1 <= frame["path_len"][j] <= frame["waypoints"].shape[1]
  assert planned >= len(replay.frames)  # most frames show a plan for both robots
  assert not last["planned"].any()  # both robots timed out: nothing left to plan


def test_animate_writes_a_gif_with_frames(run_dir, tmp_path):
  out = animate.animate(run_dir, robots="0,1", out=tmp_path / "anim.gif", every=10, progress=False)
  assert out == tmp_path / "anim.gif" and out.is_file()
  assert not list(tmp_path.glob("*.tmp*"))
  with Image.open(out) as gif:
    assert gif.format == "GIF"
    # every=10 steps = every 2nd planning round of 5 steps: steps 0, 10, 20, 30, 40.
    assert gif.n_frames == 5
    gif.seek(0)
    start = np.asarray(gif.convert("RGB"), np.int16)
    gif.seek(gif.n_frames - 1)
    end = np.asarray(gif.convert("RGB"), np.int16)
  assert np.abs(start - end).sum() > 0  # the picture changes over time


def test_a_tampered_trajectory_is_refused(run_dir, tmp_path):
  copy = tmp_path / "copy"
  shutil.copytree(run_dir, copy)
  curves = pd.read_parquet(copy / "curves.parquet")
  curves.loc[(curves.robot == 1) & (curves.step > 20), "x"] += 0.05
  curves.to_parquet(copy / "curves.parquet", index=False)
  with pytest.raises(ConfigError, match="robot 1 leaves the recorded trajectory at step 21"):
    animate.resimulate(copy, (0, 1), progress=False)


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory, run_dir):
  """A two-setting sweep with the run's shapes (so its compiled program is the run's)."""
  out = tmp_path_factory.mktemp("anim_sweep")
  jaxplore.sweep({"r_max": [2.0, 3.0]}, seeds=[5], world=WORLD, planner="nearest_frontier",
                 max_steps=40, replan_every=5, out=out, quiet=True, progress=False)
  return out


@pytest.mark.slow  # a whole sweep in subprocesses or through the CLI: `pytest -m slow`
def test_replay_of_sweep_rows_reproduces_them(sweep_dir):
  curves = pd.read_parquet(sweep_dir / "curves.parquet")
  replay = animate.resimulate(sweep_dir, (1, 0), progress=False)
  assert replay.planner == "nearest_frontier" and replay.world == "tiny_office"
  for j, robot in enumerate((1, 0)):
    curve = curves[curves.robot == robot].sort_values("step")
    assert len(curve) > 10
    np.testing.assert_allclose(replay.x[:len(curve), j], curve.x.to_numpy(), rtol=0, atol=1e-6)
    np.testing.assert_allclose(replay.y[:len(curve), j], curve.y.to_numpy(), rtol=0, atol=1e-6)
  # Same seed, same start, different ranges: the rows really ran different settings.
  episodes = pd.read_parquet(sweep_dir / "episodes.parquet").set_index("robot")
  assert episodes.r_max[0] == 2.0 and episodes.r_max[1] == 3.0
  assert replay.x[0, 0] == replay.x[0, 1] and replay.y[0, 0] == replay.y[0, 1]
  entropy = [curves[curves.robot == r].entropy.to_numpy() for r in (0, 1)]
  assert not np.allclose(entropy[0], entropy[1])


@pytest.mark.slow  # a whole sweep in subprocesses or through the CLI: `pytest -m slow`
def test_sweep_robots_of_different_groups_are_refused(sweep_dir, tmp_path):
  copy = tmp_path / "copy"
  shutil.copytree(sweep_dir, copy)
  made = json.loads((copy / sweeps.SCHEDULE_FILE).read_text())
  group = made["groups"][0]
  made["groups"] = [dict(group, rows=group["rows"][:1]),
                    dict(group, planner="frt", rows=group["rows"][1:])]
  (copy / sweeps.SCHEDULE_FILE).write_text(json.dumps(made))
  with pytest.raises(ConfigError, match="different world x planner groups.*robot 1: tiny_office / frt"):
    animate.resimulate(copy, (0, 1), progress=False)


def test_cli_animate_writes_the_default_file(run_dir, capsys):
  assert cli.main(["animate", str(run_dir), "--robots", "0,1", "--every", "20", "--no-progress"]) == 0
  path = run_dir / "animation_0-1.gif"
  assert f"wrote {path}" in capsys.readouterr().out
  with Image.open(path) as gif:
    assert gif.n_frames == 3  # steps 0, 20, 40


@pytest.mark.parametrize("make_args, match", [
    (lambda d, t: [str(t / "nowhere")], "does not exist"),
    (lambda d, t: [str(t)], "config.json.*missing"),
    (lambda d, t: [str(d), "--robots", "0,2"], "robot index 2 is out of range: the run has 2 robots"),
    (lambda d, t: [str(d), "--robots", "-1"], "robot index -1 is out of range"),
    (lambda d, t: [str(d), "--robots", "0,x"], "comma-separated integers"),
    (lambda d, t: [str(d), "--robots", "1,1"], "repeat"),
    (lambda d, t: [str(d), "--out", str(t / "a.avi")], r"must end in \.gif or \.mp4"),
    (lambda d, t: [str(d), "--every", "0"], "every must be a positive"),
    (lambda d, t: [str(d), "--fps", "0"], "fps must be a positive"),
])
def test_bad_input_is_refused_with_a_clear_error(run_dir, tmp_path, capsys, make_args, match):
  assert cli.main(["animate", *make_args(run_dir, tmp_path), "--no-progress"]) == 2
  err = capsys.readouterr().err
  assert err.startswith("jaxplore: error: ")
  assert re.search(match, err), err


def test_mp4_without_ffmpeg_is_refused(run_dir, tmp_path, monkeypatch):
  from matplotlib import animation as mpl_animation
  monkeypatch.setattr(mpl_animation.FFMpegWriter, "isAvailable", classmethod(lambda cls: False))
  with pytest.raises(ConfigError, match="needs ffmpeg"):
    animate.animate(run_dir, (0,), out=tmp_path / "a.mp4", progress=False)
