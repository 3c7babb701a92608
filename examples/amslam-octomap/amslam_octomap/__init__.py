"""amslam-octomap: an OctoMap mapping backend for amslam, shipped as its own distribution.

Install it next to amslam (``pip install ./examples/amslam-octomap``) and select it in a mission::

    mapping: {plugin: octomap, global_voxel: 0.25}

amslam finds this module through the ``amslam`` entry-point group (see ``pyproject.toml``) and calls
the hook below once at start-up.
"""

import amslam
from amslam_octomap.backend import FrontierParams, OctomapMapping, OctomapParams

__version__ = "0.1.0"
__all__ = ["FrontierParams", "OctomapMapping", "OctomapParams"]


@amslam.hookimpl
def amslam_mapping_backends():
    """The ``octomap`` mapping backend."""
    return {"octomap": OctomapMapping}
