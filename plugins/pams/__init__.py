"""Planner plugin ``pams``: perception-aware viewpoint planning around known objects (paper 2, §IV-D).

Being built for issue #9; it registers no backend yet.
"""
