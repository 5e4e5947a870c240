"""Gymnasium environments of the softrom benchmarks."""

from .soft_robot_env import TASKS, SoftRobotEnv

__all__ = ["TASKS", "SoftRobotEnv"]
