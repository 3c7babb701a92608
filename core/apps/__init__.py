"""Applications: what sits on top of the kernel and the plugins and plugs into the kernel's hooks.

The ``amslam`` subcommands (:mod:`.commands`, :mod:`.characterise`), experiments
(:mod:`.experiments`, :mod:`.multirobot`), the replay viewer (:mod:`.viewer`), the compact object
map (:mod:`.objectmap`) and the detector's training tools (:mod:`.detector_training`). They
register through the ``amslam`` entry points exactly as a third party's would; an application may
import plugins, never the other way round.
"""
