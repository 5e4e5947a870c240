"""softrom's compiled simulation core.

The extension module ``cpp_sim._core`` is built from ``cpp_sim/src`` by the package's
scikit-build-core build; this package re-exports its public classes.
"""

import os

_KERNELS = os.environ.get("SOFTROM_KERNELS", "")
if _KERNELS not in ("", "auto", "baseline"):
    # The C++ core reads it on first use; an unknown value must not be silently ignored.
    raise ValueError(
        f"SOFTROM_KERNELS={_KERNELS!r} is not understood: set 'baseline' (the x86-64 baseline "
        "kernels on any machine) or 'auto' (AVX2 + FMA where the CPU has it), or leave it unset"
    )

from ._core import (  # noqa: E402
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
