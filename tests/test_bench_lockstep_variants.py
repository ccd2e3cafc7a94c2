"""``experiments/bench_lockstep_variants.py``: its variants patch what they say, and its
comparison of final states tells bit for bit from a changed leaf. (A candidate that wins on a
GPU moves into the package with its checks against the engine: see tests/test_mapping.py.)"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxplore import mapping
from test_mapping import _observation_case

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import bench_lockstep_variants as variants  # noqa: E402


def test_the_variants_undo_what_landed(monkeypatch):
  """``tile_loop`` brings the belief update's loop over tiles back under the lockstep strategy,
  ``fixed_chunks`` the planning chunks that ignore how many robots need a plan."""
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
  assert planning.LOCKSTEP_SMALL_CHUNKS
  variants._patch("fixed_chunks")
  assert planning.LOCKSTEP_SMALL_CHUNKS == ()


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
