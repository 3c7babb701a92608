"""The library layer: algorithms that more than one plugin or application uses.

Layers (arrows point down only; ``tests/test_import_contract.py`` checks them)::

    applications   amslam.apps       cli commands, experiments, multi-robot, viewer, characterisation
    plugins        amslam.plugins.*  backends; amslam.trees: behaviours and mission trees
    library        amslam.lib        this package
    kernel         amslam            types, geometry, interfaces, hookspecs, registry, mission, runtime

What is here, one concept a module: the voxel lattice and log-odds model (:mod:`.voxel_grid`),
the storage-independent voxel map (:mod:`.voxel_map`), frontiers and viewpoints
(:mod:`.frontiers`), collision checks and free-space search (:mod:`.free_space`), object shapes
(:mod:`.shapes`) and their factors (:mod:`.shape_factors`), tours over cost matrices
(:mod:`.tours`), camera back-projection (:mod:`.camera`), viewing angles of objects
(:mod:`.viewing`), and the characterised uncertainty models against range and viewing angle
(:mod:`.uncertainty`). A plugin that needs another plugin's code needs it moved here.
"""
