"""Contract test kits that plugin authors run with pytest against their own backends.

One kit per backend kind, each a class of ``test_*`` methods to subclass in a test module with
``make_backend()`` overridden (and ``make_params()`` to tune parameters):

* :class:`amslam.testing.platform.PlatformContract` — clock, take-off, setpoints, frames, landing;
* :class:`amslam.testing.mapping.MappingContract` — occupancy, frontiers, viewpoints, paths, save/load;
* :class:`amslam.testing.slam.SlamContract` — key poses, drift correction, landmarks;
* :class:`amslam.testing.detector.DetectorContract` — valid 3-D detections of a known scene;
* :class:`amslam.testing.planner.PlannerContract` — tours of reachable stops from the request.

The built-in backends run the same kits (``tests/plugins/*/test_contract.py``).
"""
