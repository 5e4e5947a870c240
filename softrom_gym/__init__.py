"""softrom_gym: Gymnasium environments of soft robots simulated in a reduced space.

Importing the package registers the environments: ``softrom_gym/CrossSwim-v0``,
``CrossWalk-v0``, ``BeamWalk-v0``, ``QuadrupedWalk-v0``, ``TripodWalk-v0`` and the generic
``softrom_gym/SoftRobot-v0`` (any robot, task and direction).
"""

from .export import export_trajectory
from .registration import BENCHMARKS, register_envs
from .transfer import map_control_basis

register_envs()

__all__ = [
    "BENCHMARKS",
    "export_trajectory",
    "map_control_basis",
    "register_envs",
    "simulator_build",
]


def simulator_build() -> dict[str, str]:
    """What simulates: the compiled core's file and the SIMD kernel set it runs here
    (``"x86-64-v3"`` or ``"baseline"``; ``SOFTROM_KERNELS`` may force the baseline), so a
    record of a run can name them. Results differ across kernel sets by round-off only."""
    import cpp_sim
    import cpp_sim._core

    return {"kernels": cpp_sim.kernel_instruction_set(), "core": str(cpp_sim._core.__file__)}
