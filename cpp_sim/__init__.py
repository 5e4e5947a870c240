"""softrom's compiled simulation core.

The extension module ``cpp_sim._core`` is built from ``cpp_sim/src`` by the package's
scikit-build-core build; this package re-exports its public classes.
"""

from ._core import (
    FEMModel,
    ReducedConfig,
    ReducedModel,
    ReducedState,
    kernel_instruction_set,
    reduced_element_forces,
)

__all__ = [
    "FEMModel",
    "ReducedConfig",
    "ReducedModel",
    "ReducedState",
    "kernel_instruction_set",
    "reduced_element_forces",
]
