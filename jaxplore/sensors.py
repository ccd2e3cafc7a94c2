"""Range sensors as objects: what a robot's scan measures, behind one seam.

A sensor is a static, hashable object (``SimConfig.sensor``; ``--set sensor=NAME`` picks one
of :data:`SENSORS`, a preset may too, and from Python a user's own subclass of
:class:`RaySensor` is passed as it is). The engine asks it for two things, and treats every sensor
alike from there on (the cells a scan marks, localisation, the SLAM model's keyframes):

- :meth:`RaySensor.offsets`: the directions of its ``n_beams`` rays in the robot's frame;
- :meth:`RaySensor.measure`: what each ray reports against the truth, a
  :class:`jaxplore.sensor.Scan` (a beam with no return, ``hit`` False and range 0, marks
  nothing; one that hit nothing within ``r_max`` reports ``r_max`` and marks free cells to it).

Its numbers are :class:`jaxplore.config.Params` leaves (traced: a sweep over them compiles
once): ``r_max``, ``fov``, ``range_noise``, ``min_range``, each sensor reading them as its
docstring says. :meth:`RaySensor.buffer_bytes` is its part of the memory guard's estimate.

Two sensors: :class:`Lidar` (the papers' planar lidar) and :class:`DepthCone` (a depth camera's
narrow cone: no return nearer than ``min_range``, an error growing with the square of the depth).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxplore import sensor


@dataclasses.dataclass(frozen=True)
class RaySensor:
  """A planar sensor of ``n_beams`` rays spread evenly over ``params.fov`` about the heading,
  each reporting the distance to the first occupied cell within ``params.r_max``."""

  name = "ray"
  summary = ""

  def offsets(self, params, n_beams: int):
    """f32[n_beams]: the rays' angles in the robot's frame (rad)."""
    return sensor.beam_angles(jnp.float32(0.0), params.fov, n_beams)

  def angles(self, heading, params, n_beams: int):
    """The rays' absolute angles from a robot with ``heading`` (rad)."""
    return sensor.beam_angles(heading, params.fov, n_beams)

  def measure(self, truth_framed, shape, u0, v0, angles, params, res: float, n_cross: int, key,
              active, dirs) -> sensor.Scan:
    """The scan from ``(u0, v0)`` (cell units) against the framed truth
    (:func:`jaxplore.sensor.measure`'s arguments; ``params``: this robot's)."""
    raise NotImplementedError

  def buffer_bytes(self, n_beams: int, max_range_cells: int) -> int:
    """Bytes of one robot's scan buffers, for the memory guard (the traversal's crossings)."""
    return n_beams * (4 * max_range_cells + 2) * 4 * 6


@dataclasses.dataclass(frozen=True)
class Lidar(RaySensor):
  """A planar lidar: each range with a Gaussian error of std ``range_noise`` (m), clipped to
  ``[0, r_max]``; returns nearer than ``min_range`` are dropped."""

  name = "lidar"
  summary = "planar lidar: Gaussian range error of std range_noise"

  def measure(self, truth_framed, shape, u0, v0, angles, params, res: float, n_cross: int, key,
              active, dirs) -> sensor.Scan:
    scan = sensor.measure(truth_framed, shape, u0, v0, angles, params.r_max / res, n_cross,
                          key=key, noise_cells=params.range_noise / res, active=active, dirs=dirs)
    return _drop_near(scan, params.min_range / res)


@dataclasses.dataclass(frozen=True)
class DepthCone(RaySensor):
  """A depth camera's cone (a RealSense-like stereo or structured-light sensor seen in the
  plane): no return nearer than ``min_range`` (the camera's minimum depth), and a depth error
  that grows with the square of the depth, ``σ(z) = range_noise · z²`` with z in metres
  (``range_noise``: the error's std at 1 m), as stereo depth's does (the disparity's error is
  constant, the depth ``z ∝ 1/disparity``). Its narrow ``fov`` and short ``r_max`` come from the
  ``depth_camera`` preset or the user."""

  name = "depth_cone"
  summary = "depth camera cone: no return nearer than min_range, error std range_noise * z^2"

  def measure(self, truth_framed, shape, u0, v0, angles, params, res: float, n_cross: int, key,
              active, dirs) -> sensor.Scan:
    scan = sensor.measure(truth_framed, shape, u0, v0, angles, params.r_max / res, n_cross,
                          active=active, dirs=dirs)
    if key is not None:
      depth_m = scan.true_ranges * res
      noise = params.range_noise * depth_m**2 / res * jax.random.normal(key, depth_m.shape)
      r_max = params.r_max / res
      scan = scan._replace(ranges=jnp.where(scan.hit, jnp.clip(scan.true_ranges + noise, 0.0,
                                                               r_max), scan.ranges))
    return _drop_near(scan, params.min_range / res)


def _drop_near(scan: sensor.Scan, min_cells):
  """Beams whose obstacle is nearer than ``min_cells`` report no return (range 0, no hit): the
  sensor saw nothing along them, neither the obstacle nor free space."""
  near = scan.hit & (scan.true_ranges < min_cells)
  return scan._replace(ranges=jnp.where(near, 0.0, scan.ranges), hit=scan.hit & ~near)


SENSORS: dict[str, RaySensor] = {s.name: s for s in (Lidar(), DepthCone())}


def get_sensor(sensor_or_name) -> RaySensor:
  """The sensor registered under a name (a sensor object is returned as it is)."""
  from jaxplore.errors import ConfigError
  if isinstance(sensor_or_name, RaySensor):
    return sensor_or_name
  if sensor_or_name not in SENSORS:
    raise ConfigError(f"unknown sensor {sensor_or_name!r}; valid sensors: "
                      f"{', '.join(sorted(SENSORS))}")
  return SENSORS[sensor_or_name]


__all__ = ["DepthCone", "Lidar", "RaySensor", "SENSORS", "get_sensor"]
