"""Gymnasium environments of the softrom benchmarks."""

from .control_space import set_control_basis
from .observations import LINEARISED_TURN_LIMIT
from .soft_robot_env import TASKS, SoftRobotEnv
from .vector_env import SoftRobotVectorEnv

__all__ = [
    "LINEARISED_TURN_LIMIT",
    "TASKS",
    "SoftRobotEnv",
    "SoftRobotVectorEnv",
    "set_control_basis",
]
