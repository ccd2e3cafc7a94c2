"""Ground-truth worlds: map files, procedural generators and named built-in worlds."""

from __future__ import annotations

from jaxplore.maps.grid import GridMap, MapError
from jaxplore.maps.io import load_map, resample, save_map
from jaxplore.maps.worlds import (
    WORLDS,
    WorldSpec,
    get_world,
    largest_component,
    load_world,
    reachable_mask,
    render_png,
    world_table,
)

__all__ = [
    "GridMap",
    "MapError",
    "WORLDS",
    "WorldSpec",
    "get_world",
    "largest_component",
    "load_map",
    "load_world",
    "reachable_mask",
    "render_png",
    "resample",
    "save_map",
    "world_table",
]
