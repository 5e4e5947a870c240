"""softrom_gym: Gymnasium environments of soft robots simulated in a reduced space.

Importing the package registers the environments: ``softrom_gym/CrossSwim-v0``,
``CrossWalk-v0``, ``BeamWalk-v0``, ``QuadrupedWalk-v0``, ``TripodWalk-v0`` and the generic
``softrom_gym/SoftRobot-v0`` (any robot, task and direction).
"""

from .export import export_trajectory
from .registration import BENCHMARKS, register_envs
from .transfer import map_control_basis

register_envs()

__all__ = ["BENCHMARKS", "export_trajectory", "map_control_basis", "register_envs"]
