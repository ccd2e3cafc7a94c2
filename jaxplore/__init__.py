"""jaxplore: a JAX-vectorised, batched simulator for autonomous exploration and active SLAM.

``jaxplore.run(...)`` runs a batch of robots on a world and returns the tables (see
:func:`jaxplore.runner.run`); ``jaxplore.sweep(...)`` runs worlds × planners × parameter settings
× seeds in resumable chunks (see :func:`jaxplore.sweeps.sweep`); both take the settings of
:class:`jaxplore.runspec.RunSpec`. Submodules: the engine (``maps``, ``sensor``, ``mapping``,
``motion``, ``graph``, ``planners``, ``sim``, ``metrics``) and the host layer around it
(``runspec``, ``resolve``, ``driver``, ``results``, ``memory``, ``runner``, ``sweeps``,
``animate``, ``plot``, ``cli``).

Importing jaxplore does not import JAX, so the command line can set ``XLA_FLAGS`` (host device
count) first; the heavy modules load on first use.
"""

__version__ = "0.1.0"


def __getattr__(name):
  if name in ("run", "sweep"):
    from jaxplore import runner
    return getattr(runner, name)
  if name == "RunResult":
    from jaxplore.runner import RunResult
    return RunResult
  if name == "SweepResult":
    from jaxplore.sweeps import SweepResult
    return SweepResult
  raise AttributeError(f"module 'jaxplore' has no attribute {name!r}")


__all__ = ["run", "sweep", "RunResult", "SweepResult", "__version__"]
