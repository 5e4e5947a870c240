"""Gymnasium environments of the softrom benchmarks."""

from .soft_robot_env import TASKS, SoftRobotEnv
from .vector_env import SoftRobotVectorEnv

__all__ = ["TASKS", "SoftRobotEnv", "SoftRobotVectorEnv"]
