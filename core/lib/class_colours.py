"""The colour of each object class: one palette for every picture of a class.

The simulator paints its objects with it (their albedo), and the apps draw classes with it: the
rerun scene and the MCAP export's markers, the report's ``top_view.png``. A chair is the same red
in the simulated camera image, in rerun, in Foxglove and on the report's map. Classes without a
fixed colour get a stable one hashed from their name, so a class keeps its colour across runs and
tools.
"""

from __future__ import annotations

import hashlib

import numpy as np

#: RGB in [0, 1] of the classes the procedural worlds use, and of the building's surfaces
CLASS_COLOURS: dict[str, tuple[float, float, float]] = {
    "chair": (0.78, 0.22, 0.18),
    "table": (0.55, 0.36, 0.18),
    "shelf": (0.22, 0.38, 0.68),
    "sofa": (0.28, 0.58, 0.30),
    "wall": (0.82, 0.80, 0.76),
    "floor": (0.52, 0.47, 0.42),
    "ceiling": (0.93, 0.93, 0.92),
}
#: map voxels that belong to no landmark (``map.ply``'s class ``none``)
NO_CLASS_RGB = (150, 150, 150)


def class_colour(name: str) -> np.ndarray:
    """RGB in [0, 1] of a class: the fixed colour of a known class, a stable hashed one otherwise."""
    if name in CLASS_COLOURS:
        return np.array(CLASS_COLOURS[name])
    digest = hashlib.sha1(name.encode()).digest()
    return 0.25 + 0.6 * np.frombuffer(digest[:3], dtype=np.uint8) / 255.0


def class_rgb(name: str) -> tuple[int, int, int]:
    """RGB 0-255 of a class (:func:`class_colour`); ``none`` (no landmark) grey."""
    if name == "none":
        return NO_CLASS_RGB
    r, g, b = (int(round(255 * c)) for c in class_colour(name))
    return r, g, b


def class_hex(name: str) -> str:
    """``#rrggbb`` of a class (:func:`class_rgb`), for matplotlib and web pages."""
    return "#{:02x}{:02x}{:02x}".format(*class_rgb(name))
