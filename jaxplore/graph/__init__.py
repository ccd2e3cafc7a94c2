"""Grid graph algorithms: shortest paths with predecessors, and path extraction."""

from jaxplore.graph.dijkstra import (
  STRATEGY_BATCHING,
  ShortestPaths,
  default_max_sweeps,
  extract_path,
  shortest_paths,
  shortest_paths_batched,
)

__all__ = [
    "STRATEGY_BATCHING",
    "ShortestPaths",
    "default_max_sweeps",
    "extract_path",
    "shortest_paths",
    "shortest_paths_batched",
]
