"""Planners, one module per paper, all behind :mod:`jaxplore.planners.base`'s interface.

Each module defines its planners as :class:`PlannerSpec` objects (``li2020.LI2020``, ...);
:data:`BUILT_IN` lists them, and only this list puts them under their names (``--planner``).
A planner object may also be passed to the engine without being registered.
"""

from jaxplore.planners import ahmed, frontier, godoy2023, gpbo, li2020, reg
from jaxplore.planners.base import (
  BeliefView,
  Plan,
  PlannerSpec,
  RobotView,
  get_planner,
  planner,
  planner_names,
  register,
)

BUILT_IN: tuple[PlannerSpec, ...] = (
    frontier.NEAREST_FRONTIER, frontier.FD, godoy2023.FRT, godoy2023.IG, li2020.LI2020,
    ahmed.AHMED, ahmed.AGS, gpbo.GPBO, reg.EREG, reg.REG, reg.SRG, reg.SRT)

for _spec in BUILT_IN:
  register(_spec)

__all__ = ["BUILT_IN", "BeliefView", "Plan", "PlannerSpec", "RobotView", "get_planner", "planner",
           "planner_names", "register"]
