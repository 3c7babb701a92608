"""How a tree node receives the runtime services it uses (``setup(**services)``, see :mod:`amslam.robot`)."""

from __future__ import annotations

import py_trees


def require_services(behaviour: py_trees.behaviour.Behaviour, uses: tuple[str, ...], services: dict) -> None:
    """Give ``behaviour`` the services it uses, or refuse naming the missing ones."""
    missing = [key for key in uses if services.get(key) is None]
    if missing:
        wanted = ", ".join(f"{key}=..." for key in missing)
        raise KeyError(
            f"behaviour {behaviour.name!r} needs setup({wanted}): the runtime's services (see amslam.robot)"
        )
    for key in uses:
        setattr(behaviour, key, services[key])
