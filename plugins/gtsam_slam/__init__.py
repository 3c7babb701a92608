"""``gtsam`` SLAM backend: semantic factor graph on iSAM2, semantic loop closure, information gain.

See :mod:`.backend` (the graph), :mod:`.slc` (eqs. 2–6 registration), :mod:`.information`
(eq. 10 by low-rank updates) and docs/slam.md.
"""

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_slam_backends():
    return {"gtsam": Deferred("amslam.plugins.gtsam_slam.backend:GtsamSlam")}
