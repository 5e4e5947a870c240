"""scikit-learn kernels for RBBO: an RBF on Gr(M, C) and an RBF on the fidelity T.

The GP of the paper's Sec. "RBBO Algorithm" models the reward R(B_c) with the radial kernel of
the extrinsic distance d(B_i, B_j) = ||B_i B_i^T - B_j B_j^T||_F, and with multi-fidelity
(BOCA) R(B_c, T) with the separable kernel k(d(B_i, B_j)) k(|T_i - T_j|). Both kernels here
are ordinary scikit-learn kernels with declared hyperparameters and analytic gradients with
respect to log(theta), so they compose with ``ConstantKernel``, ``WhiteKernel``, ``*`` and
``+`` and are fitted by ``GaussianProcessRegressor``'s marginal-likelihood optimiser::

    kernel = ConstantKernel() * GrassmannKernel(M, C) * FidelityKernel() + WhiteKernel()

Rows of ``X`` hold a basis B_c flattened row-major (:func:`rbbo.grassmann.flatten`, M * C
numbers), optionally followed by the normalised fidelity z = (T - T_min) / (T_max - T_min);
:class:`GrassmannKernel` reads the first M * C columns and :class:`FidelityKernel` one column
(the last by default).
"""

from __future__ import annotations

import numpy as np
from sklearn.gaussian_process.kernels import Hyperparameter, Kernel, NormalizedKernelMixin

from .grassmann import _check_dims, projection_sq_distances, unflatten

__all__ = ["FidelityKernel", "GrassmannKernel"]


def _check_length_scale(value: float) -> None:
    # (bool(): numpy's isscalar would narrow value to types that `> 0` does not take)
    # (inf passes `> 0` but makes k = 1 everywhere: a GP that cannot tell points apart)
    if not (bool(np.isscalar(value)) and 0 < value < np.inf):
        raise ValueError(f"length_scale must be a positive finite scalar, got {value!r}")


def _check_bounds(name: str, bounds, allow_equal: bool = False) -> None:
    """``bounds`` is "fixed" or (low, high) with 0 < low < high < inf (low <= high with
    ``allow_equal``: equal bounds pin a hyperparameter at that value), else a ValueError
    naming ``name``."""
    if isinstance(bounds, str):
        if bounds != "fixed":
            raise ValueError(f"{name} must be a (low, high) pair or 'fixed', got {bounds!r}")
        return
    b = np.asarray(bounds, dtype=float)
    ordered = b.shape == (2,) and 0 < b[0] and b[1] < np.inf
    ordered = ordered and (b[0] <= b[1] if allow_equal else b[0] < b[1])
    if not ordered:
        relation = "<=" if allow_equal else "<"
        raise ValueError(f"{name} must satisfy 0 < low {relation} high < inf, got {bounds!r}")


class GrassmannKernel(NormalizedKernelMixin, Kernel):
    r"""Radial kernel on Gr(M, C) with the projection distance.

    .. math::
        k(B_i, B_j) = \exp\left(-\frac{\|B_i B_i^T - B_j B_j^T\|_F^2}{2 l^2}\right)
                    = \exp\left(-\frac{C - \|B_i^T B_j\|_F^2}{l^2}\right)

    Positive definite on Gr(M, C) (a Gaussian kernel of a Euclidean embedding) and invariant
    under B -> B Q for orthogonal Q.

    Parameters
    ----------
    sim_dim : int
        M, the number of rows of B_c.
    control_dim : int
        C, the number of columns of B_c.
    length_scale : float
        l, in the units of the projection distance (which lies in [0, sqrt(2 C)]).
    length_scale_bounds : pair of floats or "fixed"
        Bounds of l for the marginal-likelihood fit.
    """

    def __init__(
        self,
        sim_dim: int,
        control_dim: int,
        length_scale: float = 1.0,
        length_scale_bounds=(1e-2, 1e2),
    ):
        self.sim_dim = sim_dim
        self.control_dim = control_dim
        self.length_scale = length_scale
        self.length_scale_bounds = length_scale_bounds

    @property
    def hyperparameter_length_scale(self) -> Hyperparameter:
        return Hyperparameter("length_scale", "numeric", self.length_scale_bounds)

    def _validate(self) -> None:
        _check_dims(self.sim_dim, self.control_dim)
        _check_length_scale(self.length_scale)
        _check_bounds("length_scale_bounds", self.length_scale_bounds)

    def __call__(self, X, Y=None, eval_gradient: bool = False):
        """Kernel matrix k(X, Y) and, if asked, its gradient w.r.t. log(length_scale).

        Parameters
        ----------
        X : ndarray of shape (n_X, >= M * C)
        Y : ndarray of shape (n_Y, >= M * C), optional (default: X)
        eval_gradient : bool
            Also return dK/dlog(l), shape (n_X, n_X, 1) (or (n_X, n_X, 0) if l is fixed);
            only when Y is None.
        """
        self._validate()
        bx = unflatten(np.atleast_2d(X), self.sim_dim, self.control_dim)
        if Y is None:
            sq = projection_sq_distances(bx, control_dim=self.control_dim)
        else:
            if eval_gradient:
                raise ValueError("Gradient can only be evaluated when Y is None.")
            by = unflatten(np.atleast_2d(Y), self.sim_dim, self.control_dim)
            sq = projection_sq_distances(bx, by, control_dim=self.control_dim)
        scaled = sq / self.length_scale**2
        k = np.exp(-0.5 * scaled)
        if Y is None:
            np.fill_diagonal(k, 1.0)  # exact, whatever the round-off in the overlaps
        if not eval_gradient:
            return k
        if self.hyperparameter_length_scale.fixed:
            return k, np.empty((k.shape[0], k.shape[0], 0))
        # d k / d log l = k * d^2 / l^2
        return k, (k * scaled)[:, :, None]

    def is_stationary(self) -> bool:
        # Stationary on Gr(M, C) in the embedded sense, but not in the flattened coordinates
        # scikit-learn sees; nothing in GaussianProcessRegressor relies on it.
        return False

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(sim_dim={self.sim_dim}, control_dim={self.control_dim}, "
            f"length_scale={self.length_scale:.3g})"
        )


class FidelityKernel(NormalizedKernelMixin, Kernel):
    r"""Radial kernel on the fidelity coordinate z (one column of X): BOCA's k(|T_i - T_j|).

    .. math:: k(z_i, z_j) = \exp\left(-\frac{(z_i - z_j)^2}{2 h^2}\right)

    Parameters
    ----------
    length_scale : float
        h, in units of z (RBBO uses z = (T - T_min) / (T_max - T_min) in [0, 1]).
    length_scale_bounds : pair of floats or "fixed"
    column : int
        The column of X that holds z (default: the last).
    """

    def __init__(self, length_scale: float = 1.0, length_scale_bounds=(1e-2, 1e2), column=-1):
        self.length_scale = length_scale
        self.length_scale_bounds = length_scale_bounds
        self.column = column

    @property
    def hyperparameter_length_scale(self) -> Hyperparameter:
        return Hyperparameter("length_scale", "numeric", self.length_scale_bounds)

    def _column(self, X) -> np.ndarray:
        # (a float or bool column would index by truncation or as 0/1: refuse it by name)
        if isinstance(self.column, bool) or not isinstance(self.column, (int, np.integer)):
            raise ValueError(f"column must be an integer, got {self.column!r}")
        x = np.atleast_2d(np.asarray(X, dtype=float))
        if not -x.shape[1] <= self.column < x.shape[1]:
            raise ValueError(f"column {self.column} is out of range for X of shape {x.shape}")
        return x[:, self.column]

    def __call__(self, X, Y=None, eval_gradient: bool = False):
        """Kernel matrix k(z_X, z_Y) and, if asked, its gradient w.r.t. log(h)."""
        _check_length_scale(self.length_scale)
        _check_bounds("length_scale_bounds", self.length_scale_bounds)
        zx = self._column(X)
        if Y is not None and eval_gradient:
            raise ValueError("Gradient can only be evaluated when Y is None.")
        zy = zx if Y is None else self._column(Y)
        scaled = (zx[:, None] - zy[None, :]) ** 2 / self.length_scale**2
        k = np.exp(-0.5 * scaled)
        if not eval_gradient:
            return k
        if self.hyperparameter_length_scale.fixed:
            return k, np.empty((k.shape[0], k.shape[0], 0))
        return k, (k * scaled)[:, :, None]

    def information_gap(self, z: np.ndarray, z_target: float = 1.0) -> np.ndarray:
        """BOCA's information gap xi(z) = sqrt(1 - k(z, z_target)^2) (Kandasamy et al. 2017).

        About |z - z_target| / h near the target; 0 at the target fidelity itself.
        """
        _check_length_scale(self.length_scale)
        z = np.asarray(z, dtype=float)
        phi = np.exp(-0.5 * (z - z_target) ** 2 / self.length_scale**2)
        return np.sqrt(np.maximum(1.0 - phi**2, 0.0))

    def is_stationary(self) -> bool:
        return True

    def __repr__(self) -> str:
        return f"{type(self).__name__}(length_scale={self.length_scale:.3g}, column={self.column})"
