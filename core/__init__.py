"""amslam — active metric-semantic SLAM for aerial robots.

Plugins import :data:`hookimpl` from here to implement the hooks of :mod:`amslam.hookspecs`.
"""

import pluggy

__version__ = "0.2.0"

hookimpl = pluggy.HookimplMarker("amslam")

__all__ = ["hookimpl", "__version__"]
