"""The Gaussian process R(B_c) ~ GP, or R(B_c, T) ~ GP with BOCA's fidelity kernel.

Hyperparameters (signal variance, Grassmann length scale l, fidelity length scale h, noise
variance) are fitted by scikit-learn's ``GaussianProcessRegressor`` (marginal likelihood,
analytic kernel gradients). The posterior used by the acquisition is then computed here from
those hyperparameters, because GP-UCB needs mu and sigma *and their gradients with respect to
B_c* many times per proposal; with the flattened projectors P_i = vec(B_i B_i^T) both come
from two matrix-vector products with the (n, M^2) matrix of P_i:

    k_i(B) = s^2 exp(-(C - <P_i, vec(B B^T)>) / l^2) k_T(z_i, z)
    d k_i / d B = (2 / l^2) k_i P_i B

The latent-function posterior is returned (the WhiteKernel noise models MPC seed noise, and
the acquisition should not reward it). Its variance is read from the lower Cholesky factor
L of K (K = L L^T, the noise on its diagonal), as scikit-learn does,

    sigma^2(B) = s^2 - ||L^-1 k(B)||^2,

and never through an explicit K^-1: with the noise at its floor (1e-6) and a long length
scale K reaches cond ~1e9, where s^2 - k^T K^-1 k with a formed inverse was off by up to
half of sigma, and jagged along a line (steps of 1e-5 moved the UCB by ~1e-4 where its
slope was ~0.3), which the acquisition's line search read as slope.
Observations are standardised (zero mean, unit variance) before fitting;
:meth:`GrassmannGP.predict` returns original units.
"""

from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve, cholesky, solve_triangular
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, WhiteKernel
from threadpoolctl import threadpool_limits

from .grassmann import _check_dims, flatten, projectors, validate_basis
from .kernels import FidelityKernel, GrassmannKernel, _check_bounds

__all__ = ["GPHyperparameters", "GrassmannGP", "single_threaded_blas"]


def single_threaded_blas():
    """Context manager: BLAS/LAPACK on one thread.

    The GP's matrices are small (n up to a few hundred); a multi-threaded OpenBLAS spends
    more on waking threads than on the work (a 35-point fit measured 2.1 s with threads on a
    loaded 2-core machine, 0.08 s without), and the cores are better left to the evaluation
    workers.
    """
    return threadpool_limits(limits=1, user_api="blas")


@dataclass(frozen=True)
class GPHyperparameters:
    """Fitted hyperparameters on the standardised scale.

    Attributes
    ----------
    signal_variance : float
        s^2 of the ConstantKernel factor.
    length_scale : float
        l of the Grassmann kernel (projection-distance units).
    fidelity_length_scale : float or None
        h of the fidelity kernel (units of z), None without fidelity.
    noise_variance : float
        The WhiteKernel noise level (observation noise, e.g. MPC seed noise).
    """

    signal_variance: float
    length_scale: float
    fidelity_length_scale: float | None
    noise_variance: float


def _real_bases(bases) -> np.ndarray:
    if np.iscomplexobj(bases):  # (float() would drop the imaginary part with a warning only)
        raise TypeError(f"bases must be real, got a {np.asarray(bases).dtype} array")
    return np.asarray(bases, dtype=float)


def _standardise(y: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(y_mean, y_std, (y - y_mean) / y_std) of finite observations y, robust to their scale.

    y is divided by a = max |y| first: y.std() of |y| > ~1e154 overflowed (NaN predictions),
    and 1e-300-sized y lost their digits. y whose spread is at most 1e-12 of a (rounding) is
    a constant: y_std = a (1 where y = 0), and the standardised y are ~0, not NaN.
    """
    a = float(np.max(np.abs(y)))
    if a == 0.0:
        return 0.0, 1.0, np.zeros_like(y)
    u = y / a  # |u| <= 1: the mean and the std below cannot overflow
    u_mean, u_std = float(u.mean()), float(u.std())
    # (relative to a: an absolute 1e-12 took y ~ 1e-13 with std 1.4e-14 for a constant)
    if u_std <= 1e-12:
        u_std = 1.0
    y_mean, y_std = a * u_mean, a * u_std
    if not (np.isfinite(y_mean) and 0.0 < y_std < np.inf):  # (only subnormal y get here)
        raise ValueError(f"y = {y!r} has a spread (std {a * u_std!r}) that float64 cannot "
                         "standardise")  # fmt: skip
    return y_mean, y_std, (u - u_mean) / u_std


def _parts(kernel):
    params = kernel.get_params(deep=True)
    found = {}
    for value in params.values():
        for cls in (ConstantKernel, GrassmannKernel, FidelityKernel, WhiteKernel):
            if isinstance(value, cls):
                found[cls] = value
    return found


class GrassmannGP:
    """GP posterior over the reward R(B_c) (or R(B_c, z) with fidelity).

    Parameters
    ----------
    sim_dim, control_dim : int
        M and C.
    fidelity : bool
        Model the fidelity z in [0, 1] with BOCA's product kernel.
    n_restarts : int
        Extra random restarts (>= 0) of the marginal-likelihood optimiser (the previous fit
        is always the first start).
    length_scale_bounds, fidelity_length_scale_bounds, noise_bounds, signal_bounds
        Hyperparameter bounds on the standardised scale: (low, high) with
        0 < low < high < inf (low = high allowed for the noise and the signal, pinning it),
        or "fixed" (held at its start); a ValueError names a bad one.
    random_state : int or None
        Seeds the restarts.
    """

    def __init__(
        self,
        sim_dim: int,
        control_dim: int,
        *,
        fidelity: bool = False,
        n_restarts: int = 1,
        length_scale_bounds=(0.05, 20.0),
        fidelity_length_scale_bounds=(0.05, 20.0),
        noise_bounds=(1e-6, 10.0),
        signal_bounds=(1e-2, 1e2),
        random_state: int | None = None,
    ):
        self.sim_dim, self.control_dim = _check_dims(sim_dim, control_dim)
        # named here: scikit-learn's kernels take them unchecked and fail the fit unhelpfully
        _check_bounds("length_scale_bounds", length_scale_bounds)
        _check_bounds("fidelity_length_scale_bounds", fidelity_length_scale_bounds)
        # (equal bounds pin the noise or the signal, as scikit-learn's own kernels allow)
        _check_bounds("noise_bounds", noise_bounds, allow_equal=True)
        _check_bounds("signal_bounds", signal_bounds, allow_equal=True)
        self.fidelity = bool(fidelity)
        # (int() took 2.7 as 2 and -1 as far as scikit-learn's fit, which named its own
        # 'n_restarts_optimizer')
        if (
            isinstance(n_restarts, bool)
            or not isinstance(n_restarts, (int, np.integer))
            or n_restarts < 0
        ):
            raise ValueError(f"n_restarts must be an integer >= 0, got {n_restarts!r}")
        self.n_restarts = int(n_restarts)
        self.length_scale_bounds = length_scale_bounds
        self.fidelity_length_scale_bounds = fidelity_length_scale_bounds
        self.noise_bounds = noise_bounds
        self.signal_bounds = signal_bounds
        self.random_state = random_state
        self.hyperparameters: GPHyperparameters | None = None
        self.kernel_ = None

    def _fitted(self) -> GPHyperparameters:
        """The hyperparameters, of a GP its caller knows to be fitted."""
        hp = self.hyperparameters
        assert hp is not None, "the GP is not fitted"
        return hp

    # -- fitting --------------------------------------------------------------------------
    def _initial_kernel(self):
        hp = self.hyperparameters
        k = ConstantKernel(hp.signal_variance if hp else 1.0, self.signal_bounds)
        k = k * GrassmannKernel(
            self.sim_dim,
            self.control_dim,
            hp.length_scale if hp else 1.0,
            self.length_scale_bounds,
        )
        if self.fidelity:
            h = hp.fidelity_length_scale if hp and hp.fidelity_length_scale else 1.0
            k = k * FidelityKernel(h, self.fidelity_length_scale_bounds)
        return k + WhiteKernel(hp.noise_variance if hp else 1e-2, self.noise_bounds)

    def _check_data(self, bases, y, z):
        b = _real_bases(bases)
        if b.ndim != 3 or b.shape[1:] != (self.sim_dim, self.control_dim) or b.shape[0] < 1:
            raise ValueError(
                f"bases must have shape (n, {self.sim_dim}, {self.control_dim}), n >= 1, got "
                f"{b.shape}"
            )
        for i, basis in enumerate(b):  # the kernel reads spans through B B^T: orthonormal B
            validate_basis(basis, name=f"bases[{i}]")
        y = np.asarray(y, dtype=float).ravel()
        if y.shape[0] != b.shape[0] or not np.all(np.isfinite(y)):
            raise ValueError(f"y must hold {b.shape[0]} finite values, got {y!r}")
        if self.fidelity:
            if z is None:
                raise ValueError("this GP models fidelity: pass z (one value per basis)")
            z = np.asarray(z, dtype=float).ravel()
            # (the fidelity kernel would take z = 7 and model a trajectory longer than T_max)
            if z.shape[0] != b.shape[0] or not np.all((z >= 0.0) & (z <= 1.0)):
                raise ValueError(f"z must hold {b.shape[0]} finite values in [0, 1], got {z!r}")
        else:
            z = np.ones(b.shape[0])
        return b, y, z

    def _x(self, bases, z):
        x = flatten(bases)
        return np.column_stack([x, z]) if self.fidelity else x

    def fit(self, bases: np.ndarray, y: np.ndarray, z: np.ndarray | None = None) -> GrassmannGP:
        """Fit hyperparameters by marginal likelihood and condition on (bases, z, y).

        Parameters
        ----------
        bases : (n, M, C) orthonormal B_c
        y : (n,) observed R
        z : (n,) fidelities in [0, 1] (only with ``fidelity=True``)
        """
        with single_threaded_blas():
            return self._fit(*self._check_data(bases, y, z))

    def _fit(self, b, y, z) -> GrassmannGP:
        self.y_mean_, self.y_std_, ys = _standardise(y)
        gpr = GaussianProcessRegressor(
            self._initial_kernel(),
            alpha=1e-10,
            normalize_y=False,
            n_restarts_optimizer=self.n_restarts if b.shape[0] > 2 else 0,
            random_state=self.random_state,
        )
        with warnings.catch_warnings():
            # Hyperparameters at a bound (e.g. the noise floor on noiseless synthetic data)
            # are an expected outcome here, not a fault.
            warnings.simplefilter("ignore", ConvergenceWarning)
            gpr.fit(self._x(b, z), ys)
        self.kernel_ = gpr.kernel_
        parts = _parts(gpr.kernel_)
        self.hyperparameters = GPHyperparameters(
            signal_variance=float(parts[ConstantKernel].constant_value),
            length_scale=float(parts[GrassmannKernel].length_scale),
            fidelity_length_scale=(
                float(parts[FidelityKernel].length_scale) if self.fidelity else None
            ),
            noise_variance=float(parts[WhiteKernel].noise_level),
        )
        self.log_marginal_likelihood_ = float(gpr.log_marginal_likelihood_value_)
        self._condition(b, z, ys)
        return self

    def _fidelity_factor(self, z_a, z_b) -> np.ndarray:
        if not self.fidelity:
            return np.ones((np.size(z_a), np.size(z_b)))
        h = self._fitted().fidelity_length_scale
        assert h is not None  # (a fidelity GP fits h)
        za, zb = np.atleast_1d(z_a), np.atleast_1d(z_b)
        return np.exp(-0.5 * (za[:, None] - zb[None, :]) ** 2 / h**2)

    def _condition(self, b, z, ys) -> None:
        hp = self._fitted()
        c = self.control_dim
        self.bases_, self.z_, self.ys_ = b, z, ys
        self.proj_ = projectors(b)
        overlap = self.proj_ @ self.proj_.T
        k = hp.signal_variance * np.exp(-(c - overlap) / hp.length_scale**2)
        k *= self._fidelity_factor(z, z)
        k[np.diag_indices_from(k)] += hp.noise_variance + 1e-10
        jitter = 0.0
        for _ in range(6):
            try:
                # (cholesky, not cho_factor: its upper triangle is zero, not K's)
                factor = cholesky(k + jitter * np.eye(len(k)), lower=True)
                break
            except np.linalg.LinAlgError:
                jitter = max(10 * jitter, 1e-8)
        else:  # pragma: no cover - the noise floor keeps K well conditioned
            raise np.linalg.LinAlgError("GP covariance is not positive definite")
        # L alone (no K^-1): sigma^2 = s^2 - ||L^-1 k||^2 keeps its accuracy at cond(K) ~1e9
        self.chol_ = factor
        self.alpha_ = cho_solve((factor, True), ys)

    def conditioned_on(self, bases: np.ndarray, y: np.ndarray, z=None) -> GrassmannGP:
        """A copy with the same hyperparameters, conditioned on more data (original units).

        Used for kriging-believer fantasies: pending B_c with y = their posterior mean.
        """
        if self.hyperparameters is None:
            raise RuntimeError("fit the GP before conditioning it on more data")
        b, y, z = self._check_data(bases, y, z)
        out = copy.copy(self)
        with np.errstate(over="ignore"):  # (checked below, naming the values)
            ys = (y - self.y_mean_) / self.y_std_
        if not np.all(np.isfinite(ys)):
            raise ValueError(f"y = {y!r} is beyond float64 on the GP's scale (y_mean = "
                             f"{self.y_mean_!r}, y_std = {self.y_std_!r})")  # fmt: skip
        with single_threaded_blas():
            out._condition(
                np.concatenate([self.bases_, b]),
                np.concatenate([self.z_, z]),
                np.concatenate([self.ys_, ys]),
            )
        return out

    # -- posterior ------------------------------------------------------------------------
    def _cross(self, bases, z) -> np.ndarray:
        hp = self._fitted()
        q = projectors(bases)
        overlap = self.proj_ @ q.T
        k = hp.signal_variance * np.exp(-(self.control_dim - overlap) / hp.length_scale**2)
        return k * self._fidelity_factor(self.z_, z)

    def _query(self, bases: np.ndarray) -> np.ndarray:
        """Query bases as (m, M, C), or an error naming what is wrong (or that it is unfitted)."""
        if self.hyperparameters is None:
            raise RuntimeError("fit the GP before predicting")
        b = _real_bases(bases)
        if b.ndim == 2:
            b = b[None]
        if b.ndim != 3 or b.shape[1:] != (self.sim_dim, self.control_dim):
            m, c = self.sim_dim, self.control_dim
            raise ValueError(f"bases must have shape (n, {m}, {c}) or ({m}, {c}), got "
                             f"{np.shape(bases)}")  # fmt: skip
        return b

    def predict_standardized(self, bases: np.ndarray, z: float | np.ndarray = 1.0):
        """Latent posterior mean and standard deviation on the standardised scale.

        The bases are not checked for orthonormality (the acquisition's hot path; use
        :meth:`predict` for bases from elsewhere).
        """
        b = self._query(bases)
        zq = np.broadcast_to(np.asarray(z, dtype=float), (b.shape[0],))
        k = self._cross(b, zq)
        mu = self.alpha_ @ k
        # one triangular solve for all m queries: O(n^2 m); (unchecked: a NaN query gives NaN)
        u = solve_triangular(self.chol_, k, lower=True, check_finite=False)
        var = self._fitted().signal_variance - np.sum(u * u, axis=0)
        return mu, np.sqrt(np.maximum(var, 1e-14))

    def predict(self, bases: np.ndarray, z: float | np.ndarray = 1.0):
        """Posterior mean and standard deviation of R (latent, original units).

        Parameters
        ----------
        bases : (m, M, C) or (M, C)
        z : fidelity in [0, 1] (ignored without fidelity)

        Each basis must be orthonormal (the kernel reads its span through B B^T): one that
        is not is refused, as by :meth:`fit`, instead of predicted far off.
        """
        query = self._query(bases)
        for i, basis in enumerate(query):
            validate_basis(basis, name=f"bases[{i}]")
        # (a NaN z predicted NaN, and one z per basis of another count numpy's broadcast error)
        zq = np.asarray(z, dtype=float)
        if zq.ndim > 1 or zq.size not in (1, len(query)) or not np.all(np.isfinite(zq)):
            raise ValueError(f"z must be one finite fidelity or one per basis ({len(query)}), "
                             f"got {z!r}")  # fmt: skip
        mu, sd = self.predict_standardized(bases, z)
        return self.y_mean_ + self.y_std_ * mu, self.y_std_ * sd

    def ucb_and_gradient(self, basis: np.ndarray, sqrt_beta: float, z: float = 1.0):
        """GP-UCB mu + beta^(1/2) sigma at one B_c and its Euclidean gradient (standardised).

        Parameters
        ----------
        basis : (M, C) or (1, M, C)
            B_c (not checked for orthonormality: the acquisition's hot path).
        sqrt_beta : float
            beta^(1/2).
        z : float
            Fidelity in [0, 1] (ignored without fidelity).

        Returns
        -------
        value : float
        gradient : (M, C) ndarray, d value / d B_c in the ambient R^(M x C)
        mu, sigma : floats (standardised)
        """
        query = self._query(basis)
        if len(query) != 1:  # (a stack of bases used its first and dropped the rest)
            raise ValueError(f"ucb_and_gradient takes one basis ({self.sim_dim}, "
                             f"{self.control_dim}), got shape {np.shape(basis)}")  # fmt: skip
        b = query[0]
        hp = self._fitted()
        q = (b @ b.T).ravel()
        overlap = self.proj_ @ q
        k = hp.signal_variance * np.exp(-(self.control_dim - overlap) / hp.length_scale**2)
        if self.fidelity:
            h = hp.fidelity_length_scale
            assert h is not None  # (a fidelity GP fits h)
            k = k * np.exp(-0.5 * (self.z_ - z) ** 2 / h**2)
        mu = float(k @ self.alpha_)
        u = solve_triangular(self.chol_, k, lower=True, check_finite=False)  # L^-1 k
        sigma = float(np.sqrt(max(hp.signal_variance - float(u @ u), 1e-14)))
        # K^-1 k = L^-T (L^-1 k): the gradient's, from the solve above (O(n^2), no inverse)
        v = solve_triangular(self.chol_, u, lower=True, trans="T", check_finite=False)
        # d mu = alpha . dk ;  d sigma = -(K^-1 k) . dk / sigma ;  dk_i = (2 / l^2) k_i P_i B
        w = k * (self.alpha_ - (sqrt_beta / sigma) * v)
        m = self.sim_dim
        grad = (2.0 / hp.length_scale**2) * (w @ self.proj_).reshape(m, m) @ b
        return mu + sqrt_beta * sigma, grad, mu, sigma

    @property
    def n_observations(self) -> int:
        return 0 if self.hyperparameters is None else len(self.ys_)
