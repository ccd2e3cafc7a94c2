"""Grid graph algorithms: shortest paths with predecessors, and path extraction."""

from jaxplore.graph.dijkstra import ShortestPaths
from jaxplore.graph.dijkstra import batching
from jaxplore.graph.dijkstra import default_max_sweeps
from jaxplore.graph.dijkstra import extract_path
from jaxplore.graph.dijkstra import shortest_paths
from jaxplore.graph.dijkstra import shortest_paths_batched

__all__ = [
    "ShortestPaths",
    "batching",
    "default_max_sweeps",
    "extract_path",
    "shortest_paths",
    "shortest_paths_batched",
]
