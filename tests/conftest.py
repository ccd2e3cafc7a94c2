"""Shared test setup: silent rank promotion is an error (STYLE.md practice 12); tiny worlds."""

from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")

SHARED_MAPS = Path(__file__).resolve().parents[1].parent / "shared" / "maps"

# Run kernels eagerly and compiled on the same inputs (STYLE.md practice 11).
EAGER_AND_JIT = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["eager", "jit"])


def box_world(h=40, w=60, res=0.1, walls=()):
  """A walled rectangle; ``walls`` = ((r0, r1, c0, c1), ...) extra occupied blocks."""
  from jaxplore.maps.grid import GridMap
  occ = np.zeros((h, w), bool)
  occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
  for r0, r1, c0, c1 in walls:
    occ[r0:r1, c0:c1] = True
  return GridMap(occ, res, (0.0, 0.0), "box")
