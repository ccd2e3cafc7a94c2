"""Shared test setup: silent rank promotion is an error (STYLE.md practice 12); tiny worlds."""

import functools
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")

# The checkout a test's subprocess runs from (the package it imports is this one).
REPO = Path(__file__).resolve().parents[1]


def subprocess_env(drop=("XLA_FLAGS",), **extra):
  """The environment of a test's Python subprocess: this one's without the variables whose names
  start with ``drop`` (the parent's XLA flags are not the child's), the checkout first on
  ``PYTHONPATH``, then ``extra``; XLA_FLAGS get the suite's fusion-emitter flag
  (:data:`CODEGEN_FLAG`) unless they set it."""
  env = {k: v for k, v in os.environ.items() if not k.startswith(tuple(drop))}
  env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
  cache = jax.config.jax_compilation_cache_dir  # the suite's (shared_compilation_cache)
  if cache:  # a program another test's process compiled is loaded, not compiled again
    env["JAX_COMPILATION_CACHE_DIR"] = str(cache)
    env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"
  env.update(extra)
  if CODEGEN_FLAG and "xla_cpu_use_fusion_emitters" not in env.get("XLA_FLAGS", ""):
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {CODEGEN_FLAG}".strip()  # the suite's codegen
  return env


# XLA:CPU's MLIR fusion emitters (jaxlib's default) take about half of a compile of the engine's
# programs, and the suite is compile-bound; XLA's other fusion emitters, with this flag, compile
# the same fusions in about half the time (a run's chunk program: 10.5 -> 5.1 s, li2020 on 2 host
# devices) and gave the same numbers in every check made (tables and final states bit for bit; the
# suite's oracles and bit-for-bit checks pass under both). The suite's processes, and the
# subprocesses its tests start (subprocess_env), compile with it; XLA_FLAGS that set
# xla_cpu_use_fusion_emitters themselves (``=true``: jaxlib's default codegen) are kept instead,
# for both. XLA refuses to start with a flag its version does not know, so it is used only where
# a probe finds it known.
FAST_COMPILE_FLAG = "--xla_cpu_use_fusion_emitters=false"


@functools.cache
def fast_compile_flags() -> str:
  """:data:`FAST_COMPILE_FLAG` if this jaxlib knows it (a probe process starts its CPU client with
  it, ~1 s), else ``""``."""
  env = dict(os.environ, XLA_FLAGS=FAST_COMPILE_FLAG, JAX_PLATFORMS="cpu")
  probe = subprocess.run([sys.executable, "-c", "import jax; jax.devices()"], env=env,
                         capture_output=True, timeout=120)
  return FAST_COMPILE_FLAG if probe.returncode == 0 else ""


def _codegen_flag() -> str:
  """The fusion-emitter flag of the suite's processes: the one XLA_FLAGS gives (an xdist worker
  inherits the controller's), else :func:`fast_compile_flags`; put in XLA_FLAGS here, before
  JAX starts its CPU client."""
  flags = os.environ.get("XLA_FLAGS", "")
  given = [f for f in flags.split() if f.startswith("--xla_cpu_use_fusion_emitters")]
  if given:
    return given[-1]
  fast = fast_compile_flags()
  if fast:
    os.environ["XLA_FLAGS"] = f"{flags} {fast}".strip()
  return fast


CODEGEN_FLAG = _codegen_flag()


def pytest_collection_modifyitems(items):
  """The order xdist hands modules out in (``--no-loadscope-reorder``): the smoke tests first
  (a minute or more in a process of their own; under ``-m slow`` two halves more, one to each
  worker: last, they kept one worker busy while the other idled), then the modules with most
  tests first, as xdist's own order was."""
  sizes: dict = {}
  for item in items:
    sizes[item.module.__name__] = sizes.get(item.module.__name__, 0) + 1
  items.sort(key=lambda item: (item.module.__name__.rsplit(".", 1)[-1] != "test_smoke",
                               -sizes[item.module.__name__]))


SHARED_MAPS = (Path(__file__).resolve().parents[1].parent / "shared" / "maps").resolve()
# The public maps are read from beside the checkout and never copied into the project; a checkout
# without them (a lone clone) skips the few tests that read them, naming the folder.
needs_shared_maps = pytest.mark.skipif(
    not SHARED_MAPS.is_dir(),
    reason=f"reads the public maps at {SHARED_MAPS}, beside the checkout (never copied into the "
           f"project); not present here")

def lapack_calls(program_text: str) -> list[tuple[str, str]]:
  """(kernel, number of batch dimensions) of each LAPACK call in a lowered program's text
  (``jax.jit(f).lower(...).as_text()``): a batched call deadlocks two host devices
  (:mod:`jaxplore.linalg`)."""
  return re.findall(r"custom_call @(lapack_\w+).*?num_batch_dims = \"(\d+)\"", program_text)


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


def tiny_office():
  """Two rooms and a door at 0.2 m (8 x 6 m): the world of the quickstart notebook's tiny run.
  tests/test_animate.py, test_runner.py and test_interrupts.py run 2 robots on it for 40 steps
  (replanning every 5, a 3 m lidar): one engine program for them all, compiled by whichever runs
  first and loaded from the suite's compilation cache by the others."""
  from jaxplore.maps import generate
  return generate.office(8.0, 6.0, res=0.2, seed=0, name="tiny_office")


@pytest.fixture(scope="session", autouse=True)
def shared_compilation_cache(tmp_path_factory):
  """The suite is compile-bound and several modules compile the same programs (the same small
  worlds and settings behind jit wrappers of their own, on either xdist worker): a compilation
  cache shared by the run's workers loads those instead of compiling them again (with
  loadscope: 506 -> 467-542 s over four runs of the suite on 2 cores). It lives in the run's
  temporary folder (an xdist worker's is a subfolder of it), which pytest prunes with its old
  runs."""
  base = tmp_path_factory.getbasetemp()
  folder = (base.parent if base.name.startswith("popen-gw") else base) / "jax_compilation_cache"
  jax.config.update("jax_compilation_cache_dir", str(folder))
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
  yield
  jax.config.update("jax_compilation_cache_dir", None)
