"""Soft robots as tetrahedral meshes: the paper's four benchmark bodies and user meshes.

>>> from softrom_gym.robots import quadruped, from_mesh
>>> quadruped().num_nodes
1412
"""

from .mesh_import import from_mesh
from .procedural import beam, cross, quadruped, tripod
from .robot import Robot

ROBOTS = {"cross": cross, "beam": beam, "quadruped": quadruped, "tripod": tripod}


def make_robot(name: str, **kwargs) -> Robot:
    """Build a benchmark robot by name (one of :data:`ROBOTS`)."""
    try:
        factory = ROBOTS[name]
    except KeyError:
        raise ValueError(f"unknown robot {name!r}; valid robots: {sorted(ROBOTS)}") from None
    return factory(**kwargs)


__all__ = ["ROBOTS", "Robot", "beam", "cross", "from_mesh", "make_robot", "quadruped", "tripod"]
