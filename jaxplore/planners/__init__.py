"""Planners, one module per paper, all behind :mod:`jaxplore.planners.base`'s interface."""

from jaxplore.planners import frontier  # noqa: F401  (registers nearest_frontier)
from jaxplore.planners import li2020  # noqa: F401  (registers li2020)
from jaxplore.planners import godoy2023  # noqa: F401  (registers frt, ig, fd)
from jaxplore.planners import ahmed  # noqa: F401  (registers ahmed, ags)
from jaxplore.planners.base import (BeliefView, Plan, PlannerSpec, RobotView, get_planner,
                                    planner_names, register)

__all__ = ["BeliefView", "Plan", "PlannerSpec", "RobotView", "get_planner", "planner_names",
           "register"]
