"""Planners, one module per paper, all behind :mod:`jaxplore.planners.base`'s interface."""

from jaxplore.planners import (
  ahmed,  # noqa: F401  (registers ahmed, ags)
  frontier,  # noqa: F401  (registers nearest_frontier, fd)
  godoy2023,  # noqa: F401  (registers frt, ig)
  gpbo,  # noqa: F401  (registers gpbo)
  li2020,  # noqa: F401  (registers li2020)
  reg,  # noqa: F401  (registers ereg, reg, srg, srt)
)
from jaxplore.planners.base import (
  BeliefView,
  Plan,
  PlannerSpec,
  RobotView,
  get_planner,
  planner_names,
  register,
)

__all__ = ["BeliefView", "Plan", "PlannerSpec", "RobotView", "get_planner", "planner_names",
           "register"]
