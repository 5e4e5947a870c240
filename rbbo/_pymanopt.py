"""pymanopt, imported without its automatic-differentiation backends.

pymanopt 2.2 imports torch, tensorflow, jax and autograd eagerly when any of its modules is
imported (each guarded by ``try: import ... except ImportError``). RBBO supplies its
gradients by hand and uses only the numpy backend, and torch alone costs 1-3 s of start-up
where it is installed (it is, for the RL extra). So those four are hidden from the import
system while pymanopt loads, unless something has imported them already, and are importable
normally afterwards.
"""

from __future__ import annotations

import sys

_AUTODIFF = ("torch", "tensorflow", "jax", "autograd")

if "pymanopt" not in sys.modules:
    _hidden = [name for name in _AUTODIFF if name not in sys.modules]
    for _name in _hidden:
        sys.modules[_name] = None  # type: ignore[assignment]  # makes "import torch" fail
    try:
        import pymanopt
    finally:
        for _name in _hidden:
            if sys.modules.get(_name, 0) is None:
                del sys.modules[_name]

import pymanopt  # noqa: E402
from pymanopt.manifolds import Grassmann  # noqa: E402
from pymanopt.optimizers import ConjugateGradient  # noqa: E402
from pymanopt.optimizers.optimizer import Optimizer, OptimizerResult  # noqa: E402
from pymanopt.tools import printer  # noqa: E402

__all__ = ["ConjugateGradient", "Grassmann", "Optimizer", "OptimizerResult", "printer", "pymanopt"]
