"""``experiments/bench_lockstep_variants.py``: each variant is a setting passed to the engine (no
module patched) that changes what it says, and its comparison of final states tells bit for bit
from a changed leaf. (A candidate that wins on a GPU moves into the package with its checks
against the engine: see tests/test_mapping.py.)"""

import functools
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import EAGER_AND_JIT, box_world

from jaxplore import sim
from jaxplore.config import config_for, make_params

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import bench_lockstep_variants as variants  # noqa: E402


def _config(planner="nearest_frontier"):
  grid = box_world(20, 24, res=0.1)
  params = make_params(res=0.1, r_robot=0.15, r_max=1.0)
  return grid, params, config_for(grid.shape, grid.res, params, max_steps=8, planner=planner,
                                  strategy="lockstep")


def test_each_variant_is_a_setting_of_the_engine_passed_in():
  """``tile_loop`` turns the lockstep whole-grid belief update off, ``coarse_ladder`` leaves
  only chunks of 4 and 16 below a round's own, ``fixed_chunks`` none, ``fixed_leftovers`` takes
  the whole-grid round after a window out of them, ``obs32`` and ``chunk*`` set the observation
  buffer's dtype and the smallest planning chunk; head is the engine as it is."""
  _, _, config = _config()
  assert variants.adjust("head")(config) == config
  expected = {"tile_loop": {"lockstep_whole_grid_update": False},
              "coarse_ladder": {"lockstep_small_chunks": (4, 16)},
              "fixed_chunks": {"lockstep_small_chunks": ()},
              "fixed_leftovers": {"lockstep_leftovers_by_need": False},
              "obs32": {"observation_dtype": "int32"},
              "chunk16": {"lockstep_min_chunk": 16}, "chunk4": {"lockstep_min_chunk": 4}}
  for name, fields in expected.items():
    adjusted = variants.adjust(name)(config)
    assert adjusted != config and hash(adjusted) != hash(config)  # a program of its own
    assert {field: getattr(adjusted, field) for field in fields} == fields
    assert adjusted.planner == config.planner
  with pytest.raises(SystemExit, match="li2020"):
    variants.adjust("visible_by_depth")(config)


def test_the_belief_update_variants_reach_the_traced_scan():
  """The whole-grid update has no loop over tiles (``tile_loop`` brings one back), and the
  observation buffer is int8 (int32 with ``obs32``): in the program of a batch's reset scan."""
  grid, params, config = _config()
  world = sim.make_world(grid, 0.15)
  params = sim.broadcast_params(params, 2)
  keys = jax.random.split(jax.random.PRNGKey(0), 2)
  starts = jnp.asarray([[0.5, 0.6, 0.0], [1.0, 0.6, 0.0]])
  program = lambda config: str(jax.make_jaxpr(
      lambda p, k, s: sim.reset_batch(config, world, p, k, s))(params, keys, starts))
  head = program(config)
  tile_loop = program(variants.adjust("tile_loop")(config))
  assert tile_loop.count("while[") > head.count("while[")
  buffer = f"[{-(-grid.shape[0] // 16) * -(-grid.shape[1] // 16) * 16 * 16 + 1}]"
  obs32 = program(variants.adjust("obs32")(config))
  assert "i8" + buffer in head and "i32" + buffer not in head
  assert "i32" + buffer in obs32 and "i8" + buffer not in obs32


def test_the_visible_variants_run_li2020s_visible_region_with_its_sums_passed_in():
  from jaxplore.planners import li2020
  _, _, config = _config("li2020")
  assert config.planner.settings.region == "beams"
  visible = variants.adjust("visible")(config)
  by_depth = variants.adjust("visible_by_depth")(config)
  assert visible.planner.settings == by_depth.planner.settings
  assert visible.planner.settings.region == "visible"
  assert visible.planner.plan is li2020.plan_li2020
  assert isinstance(by_depth.planner.plan, functools.partial)
  assert by_depth.planner.plan.func is li2020.plan_li2020
  assert by_depth.planner.plan.keywords == {"visible_sums": variants._visible_by_depth}
  assert variants.COMPARED_WITH["visible_by_depth"] == "visible"


def test_compare_tells_bit_for_bit_from_a_changed_leaf(tmp_path):
  state = {".logodds": np.arange(6, dtype=np.float32), ".entropy": np.float32([100.0, 200.0])}
  np.savez(tmp_path / "a.npz", **state)
  np.savez(tmp_path / "same.npz", **state)
  np.savez(tmp_path / "rounding.npz", **dict(state, **{".entropy": np.float32([100.0001, 200.0])}))
  np.savez(tmp_path / "entropy.npz", **dict(state, **{".entropy": np.float32([101.0, 200.0])}))
  np.savez(tmp_path / "logodds.npz", **dict(state, **{".logodds": np.float32([0, 1, 2, 3, 4, 5.5])}))
  verdict = lambda name: variants.compare(tmp_path / "a.npz", tmp_path / f"{name}.npz")
  assert verdict("same") == "bit for bit"
  assert verdict("rounding").startswith(".entropy within")
  assert "beyond" in verdict("entropy")
  assert ".logodds DIFFERS" in verdict("logodds")


@pytest.mark.parametrize("radius, block", [(3.0, 4), (5.5, 64)])
@EAGER_AND_JIT
def test_visible_gains_by_depth_are_the_packages_to_float_summation_order(radius, block,
                                                                          transform):
  """The GPU candidate sums what ``li2020.visible_gains`` sums (itself checked against a NumPy
  ray caster in tests/planners/test_li2020.py), a depth's rows as a batch: the same up to
  float rounding, on walls that cut sight lines and squeeze diagonals."""
  from jaxplore.planners import li2020
  from visible_by_depth import visible_gains_by_depth
  rng = np.random.default_rng(3)
  occupied = jnp.asarray(rng.random((14, 19)) < 0.25)
  gains = jnp.asarray(rng.random((2, 14, 19)), jnp.float32)
  expected = li2020.visible_gains(gains, occupied, radius, 2)
  got = transform(lambda g, o: visible_gains_by_depth(g, o, radius, block))(gains, occupied)
  for want, have in zip(expected, got):
    np.testing.assert_allclose(np.asarray(have), np.asarray(want), rtol=1e-5, atol=1e-5)
  # Not a copy of the disc's plain sums: some sight lines are blocked on this map.
  blind = li2020.visible_gains(gains, jnp.zeros_like(occupied), radius, 2)[0]
  assert not np.allclose(np.asarray(blind), np.asarray(got[0]))
