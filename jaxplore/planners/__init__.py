"""Planners, one module per paper, all behind :mod:`jaxplore.planners.base`'s interface."""

from jaxplore.planners import frontier  # noqa: F401  (registers nearest_frontier, fd)
from jaxplore.planners import li2020  # noqa: F401  (registers li2020)
from jaxplore.planners import godoy2023  # noqa: F401  (registers frt, ig)
from jaxplore.planners import gpbo  # noqa: F401  (registers gpbo)
from jaxplore.planners import reg  # noqa: F401  (registers ereg, reg, srg, srt)
from jaxplore.planners import ahmed  # noqa: F401  (registers ahmed, ags)
from jaxplore.planners.base import (BeliefView, Plan, PlannerSpec, RobotView, get_planner,
                                    planner_names, register)

__all__ = ["BeliefView", "Plan", "PlannerSpec", "RobotView", "get_planner", "planner_names",
           "register"]
