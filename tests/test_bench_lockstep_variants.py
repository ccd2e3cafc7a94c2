"""``experiments/bench_lockstep_variants.py``: its variants patch what they say, and its
comparison of final states tells bit for bit from a changed leaf. (A candidate that wins on a
GPU moves into the package with its checks against the engine: see tests/test_mapping.py.)"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import EAGER_AND_JIT

from jaxplore import mapping
from test_mapping import _observation_case

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import bench_lockstep_variants as variants  # noqa: E402


def test_the_variants_undo_what_landed(monkeypatch):
  """``tile_loop`` brings the belief update's loop over tiles back under the lockstep strategy,
  ``coarse_ladder`` only chunks of 4 and 16 below a round's own, ``fixed_chunks`` the planning
  chunks that ignore how many robots need a plan, ``fixed_leftovers`` them for the whole-grid
  round after a window."""
  from jaxplore import planning
  monkeypatch.setattr(mapping, "integrate_observation", mapping.integrate_observation)
  monkeypatch.setattr(planning, "LOCKSTEP_SMALL_CHUNKS", planning.LOCKSTEP_SMALL_CHUNKS)
  params, logodds, _, tiles, reachable = _observation_case((37, 50), seed=7)
  args = (jnp.asarray(logodds), 2, jnp.asarray(tiles), jnp.asarray(reachable), params)
  loops = lambda: str(jax.make_jaxpr(
      lambda *a: mapping.integrate_observation(*a, whole_grid=True))(*args)).count("while[")
  assert loops() == 0
  variants._patch("tile_loop")
  assert loops() == 1
  assert len(planning.LOCKSTEP_SMALL_CHUNKS) > 2
  variants._patch("coarse_ladder")
  assert planning.LOCKSTEP_SMALL_CHUNKS == (4, 16)
  variants._patch("fixed_chunks")
  assert planning.LOCKSTEP_SMALL_CHUNKS == ()
  monkeypatch.setattr(planning, "_plan_where_needed_lockstep", planning._plan_where_needed_lockstep)
  engine = planning._plan_where_needed_lockstep
  variants._patch("fixed_leftovers")
  assert planning._plan_where_needed_lockstep.func is variants._plan_where_needed_fixed_leftovers
  assert planning._plan_where_needed_lockstep.args == (engine,)


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


def test_the_visible_by_depth_variant_replaces_lockstep_visible_gains(monkeypatch):
  from jaxplore.planners import li2020
  from visible_by_depth import visible_gains_by_depth
  monkeypatch.setattr(li2020, "visible_gains", li2020.visible_gains)
  variants._patch("visible_by_depth")
  gains, occupied = jnp.ones((1, 9, 9)), jnp.zeros((9, 9), bool).at[4, 6].set(True)
  patched = li2020.visible_gains(gains, occupied, 3.0, 8)
  candidate = visible_gains_by_depth(gains, occupied, 3.0)
  assert all(np.array_equal(a, b) for a, b in zip(patched, candidate))
