"""Gymnasium environments of the softrom benchmarks."""

from .control_space import set_control_basis
from .soft_robot_env import TASKS, SoftRobotEnv
from .vector_env import SoftRobotVectorEnv

__all__ = ["TASKS", "SoftRobotEnv", "SoftRobotVectorEnv", "set_control_basis"]
