"""A robot's SLAM: scan matching against its own belief, pose-graph optimisation, trajectory and
map accuracy.

* :mod:`jaxplore.slam.scan_matching`: correlative scan matching (Olson 2009) as Karto does it.
* :mod:`jaxplore.slam.optimiser`: SE(2) pose-graph optimisation.
* :mod:`jaxplore.slam.accuracy`: absolute trajectory and relative pose error, map error.
"""
