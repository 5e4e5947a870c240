"""Riemannian optimisers for the acquisition (pymanopt ``Optimizer`` subclasses)."""

from .lrbfgs import LRBFGS

__all__ = ["LRBFGS"]
