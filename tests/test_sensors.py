"""Sensors as objects (jaxplore.sensors): the lidar is the traversal it always was, the depth
cone drops near returns and its depth error grows with the square of the depth, and the engine
scans with whichever sensor the config holds."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import EAGER_AND_JIT, box_world
from jaxplore import sensor, sim
from jaxplore.config import ConfigError, SimConfig, config_for, make_params, validate_params
from jaxplore.sensors import SENSORS, DepthCone, Lidar, get_sensor

RES = 0.1


def corridor():
  """A 30 x 60 room: the robot at (5.5, 20.5) cells (col, row), a wall 3 cells to its left."""
  occupied = np.zeros((30, 60), bool)
  occupied[[0, -1], :] = occupied[:, [0, -1]] = True
  occupied[:, 2] = True
  return occupied, sensor.frame_truth(jnp.asarray(occupied))


def scan_of(sensor_object, params, angles, key=None, u0=5.5, v0=20.5):
  occupied, truth = corridor()
  return sensor_object.measure(truth, occupied.shape, jnp.float32(u0), jnp.float32(v0), angles,
                               params, RES, 61, key, jnp.bool_(True), sensor.directions(angles))


@EAGER_AND_JIT
def test_the_lidar_is_the_plain_traversal_with_gaussian_range_noise(transform):
  params = make_params(res=RES, r_max=4.0, range_noise=0.05)
  angles = sensor.beam_angles(jnp.float32(0.3), params.fov, 64)
  key = jax.random.PRNGKey(7)
  got = transform(lambda a, k: scan_of(Lidar(), params, a, k))(angles, key)
  occupied, truth = corridor()
  want = sensor.measure(truth, occupied.shape, jnp.float32(5.5), jnp.float32(20.5), angles,
                        4.0 / RES, 61, key=key, noise_cells=0.05 / RES)
  for name in want._fields:
    np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


def test_the_depth_cone_reports_nothing_nearer_than_its_minimum_range():
  params = make_params(res=RES, r_max=4.0, min_range=0.4)
  angles = jnp.linspace(-math.pi, math.pi, 90, endpoint=False, dtype=jnp.float32)
  plain = scan_of(Lidar(), make_params(res=RES, r_max=4.0), angles)
  for cone in (DepthCone(), Lidar()):  # min_range is every sensor's
    scan = scan_of(cone, params, angles)
    near = np.asarray(plain.hit) & (np.asarray(plain.true_ranges) * RES < 0.4)
    assert near.any() and (~near & np.asarray(plain.hit)).any()
    assert not np.asarray(scan.hit)[near].any()
    np.testing.assert_array_equal(np.asarray(scan.ranges)[near], 0.0)
    np.testing.assert_array_equal(np.asarray(scan.ranges)[~near], np.asarray(plain.ranges)[~near])
    np.testing.assert_array_equal(np.asarray(scan.hit)[~near], np.asarray(plain.hit)[~near])


def test_the_depth_cones_error_grows_with_the_square_of_the_depth():
  """The spread of the measured depths over many keys is ``range_noise * z**2`` (z in m): a plain
  NumPy estimate of each beam's standard deviation against the stereo model."""
  params = make_params(res=RES, r_max=6.0, range_noise=0.005)  # clipped at r_max: 4.6σ away
  angles = jnp.asarray([math.pi, math.pi * 0.75, 0.0, 0.4, -0.5 * math.pi], jnp.float32)
  keys = jax.random.split(jax.random.PRNGKey(0), 4000)
  scans = jax.jit(jax.vmap(lambda k: scan_of(DepthCone(), params, angles, k)))(keys)
  true_m = np.asarray(scans.true_ranges[0], np.float64) * RES
  hit = np.asarray(scans.hit[0])
  assert hit.all() and true_m.max() / true_m.min() > 4  # beams at several depths
  error_m = (np.asarray(scans.ranges, np.float64) - np.asarray(scans.true_ranges)) * RES
  np.testing.assert_allclose(error_m.std(axis=0), 0.005 * true_m**2, rtol=0.06)
  np.testing.assert_allclose(error_m.mean(axis=0), 0.0, atol=4 * 0.005 * true_m.max()**2 / 60)


def test_the_sensor_is_a_static_setting_and_a_preset_may_choose_it():
  params = make_params(res=RES)
  config = config_for((30, 60), RES, params)
  assert config.sensor == Lidar() and SENSORS["lidar"] is get_sensor("lidar")
  cone = dataclasses.replace(config, sensor="depth_cone")
  assert cone.sensor == DepthCone() and cone != config  # another compiled program
  assert sim.config_record(cone)["sensor"] == "depth_cone"
  assert sim.config_from_dict(sim.config_record(cone)) == cone
  preset = "depth_camera"
  camera = config_for((30, 60), RES, make_params(preset, res=RES), preset=preset)
  assert camera.sensor == DepthCone() and camera.n_beams == 160
  with pytest.raises(ConfigError, match="sensor must be one of"):
    dataclasses.replace(config, sensor="sonar")
  with pytest.raises(ConfigError, match="min_range .* is not below r_max"):
    validate_params(make_params(res=RES, r_max=2.0, min_range=2.0), config)


def test_the_engine_scans_with_the_configs_sensor():
  """A reset's first scan with a narrow depth cone facing +x marks cells only inside the cone and
  beyond its minimum range; the lidar, from the same pose, marks cells all around."""
  grid = box_world(40, 60, res=RES)
  start = jnp.asarray([3.0, 2.0, 0.0], jnp.float32)
  seen = {}
  for name, fov in (("depth_cone", math.radians(60.0)), ("lidar", 2 * math.pi)):
    params = make_params(res=RES, r_max=2.0, fov=fov, min_range=0.3, r_robot=0.1)
    config = config_for(grid.shape, grid.res, params, max_steps=8, n_beams=90, sensor=name)
    world = sim.make_world(grid, 0.1)
    state = jax.jit(lambda p, k, s, c=config, w=world: sim.reset(c, w, p, k, s))(
        params, jax.random.PRNGKey(0), start)
    seen[name] = np.asarray(state.logodds) != 0
  rows, cols = np.nonzero(seen["depth_cone"])
  dx, dy = (cols + 0.5) * RES - 3.0, (rows + 0.5) * RES - 2.0
  bearing, distance = np.arctan2(dy, dx), np.hypot(dx, dy)
  assert len(rows) > 50
  # inside the cone (half a cell's slack at the edges) and, but for the robot's own cell, beyond
  # the minimum range where the beams start
  assert (np.abs(bearing) <= math.radians(30.0) + RES / np.maximum(distance, RES)).all()
  assert seen["lidar"].sum() > 4 * seen["depth_cone"].sum()
  assert (dx < -0.5).sum() == 0 and (seen["lidar"][:, :25]).any()
