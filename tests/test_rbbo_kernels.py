"""Grassmann and fidelity kernels (rbbo.kernels) and the GP built on them (rbbo.gp)."""

import re

import numpy as np
import pytest
from scipy.stats import ortho_group
from sklearn.base import clone
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, WhiteKernel

from rbbo import grassmann as gr
from rbbo.gp import GPHyperparameters, GrassmannGP
from rbbo.kernels import FidelityKernel, GrassmannKernel

M, C = 7, 2


def _x(rng, n=12, fidelity=False):
    x = gr.flatten(gr.random_points(M, C, n, rng))
    return np.column_stack([x, rng.uniform(size=n)]) if fidelity else x


def _numeric_gradient(kernel, x, eps=1e-6):
    theta = kernel.theta
    grads = []
    for i in range(len(theta)):
        step = np.zeros_like(theta)
        step[i] = eps
        hi = kernel.clone_with_theta(theta + step)(x)
        lo = kernel.clone_with_theta(theta - step)(x)
        grads.append((hi - lo) / (2 * eps))
    return np.stack(grads, axis=-1)


@pytest.mark.parametrize(
    "kernel",
    [
        GrassmannKernel(M, C, length_scale=0.7),
        FidelityKernel(length_scale=0.3),
        ConstantKernel(2.0) * GrassmannKernel(M, C, 1.3) * FidelityKernel(0.5) + WhiteKernel(0.1),
    ],
    ids=["grassmann", "fidelity", "product+white"],
)
def test_kernel_gradient_matches_finite_differences(kernel, rng):
    x = _x(rng, fidelity=True)
    k, grad = kernel(x, eval_gradient=True)
    np.testing.assert_allclose(k, kernel(x), rtol=1e-12)
    assert grad.shape == (len(x), len(x), len(kernel.theta))
    np.testing.assert_allclose(grad, _numeric_gradient(kernel, x), rtol=1e-5, atol=1e-8)


def test_fixed_length_scale_has_no_gradient(rng):
    x = _x(rng)
    _, grad = GrassmannKernel(M, C, 1.0, "fixed")(x, eval_gradient=True)
    assert grad.shape == (len(x), len(x), 0)


def test_kernel_is_invariant_under_rotations_of_each_basis(rng):
    bases = gr.random_points(M, C, 10, rng)
    rotated = np.stack([b @ ortho_group.rvs(C, random_state=i) for i, b in enumerate(bases)])
    kernel = GrassmannKernel(M, C, 0.8)
    np.testing.assert_allclose(kernel(gr.flatten(bases)), kernel(gr.flatten(rotated)), atol=1e-12)
    other = gr.flatten(gr.random_points(M, C, 3, rng))
    np.testing.assert_allclose(
        kernel(gr.flatten(bases), other), kernel(gr.flatten(rotated), other), atol=1e-12
    )


@pytest.mark.parametrize("length_scale", [0.1, 1.0, 10.0])
def test_gram_matrices_are_positive_semidefinite(length_scale, rng):
    x = _x(rng, n=40, fidelity=True)
    for kernel in (
        GrassmannKernel(M, C, length_scale),
        GrassmannKernel(M, C, length_scale) * FidelityKernel(0.4),
    ):
        k = kernel(x)
        np.testing.assert_allclose(k, k.T, atol=1e-14)
        assert np.linalg.eigvalsh(k).min() > -1e-10
        np.testing.assert_array_equal(kernel.diag(x), np.ones(len(x)))


def test_kernel_values_follow_projection_distance(rng):
    a, b = gr.random_points(M, C, 2, rng)
    d = gr.projection_distance(a, b)
    k = GrassmannKernel(M, C, 0.9)(gr.flatten(a), gr.flatten(b))[0, 0]
    assert k == pytest.approx(np.exp(-(d**2) / (2 * 0.9**2)))


def test_kernel_works_with_sklearn_clone_and_bounds():
    kernel = GrassmannKernel(M, C, 2.0, (0.1, 10.0))
    copy = clone(kernel)
    assert copy.get_params() == kernel.get_params()
    np.testing.assert_allclose(kernel.bounds, np.log([[0.1, 10.0]]))
    assert [h.name for h in kernel.hyperparameters] == ["length_scale"]


def test_kernel_rejects_bad_input(rng):
    with pytest.raises(ValueError, match=r"X must have shape \(n, >= M \* C\) = \(n, >= 14\)"):
        GrassmannKernel(M, C)(np.ones((3, 5)))
    with pytest.raises(ValueError, match="length_scale must be a positive finite scalar, got -1"):
        GrassmannKernel(M, C, -1.0)(_x(rng))
    with pytest.raises(ValueError, match="length_scale must be a positive finite scalar, got inf"):
        GrassmannKernel(M, C, np.inf)(_x(rng))
    with pytest.raises(ValueError, match="length_scale must be a positive finite scalar, got nan"):
        FidelityKernel(np.nan).information_gap(np.array([0.5]))
    for column in (1.0, True, "1"):
        with pytest.raises(ValueError, match=f"column must be an integer, got {column!r}"):
            FidelityKernel(column=column)(np.ones((2, 3)))
    np.testing.assert_allclose(
        FidelityKernel(column=np.int64(0))(np.eye(2)), FidelityKernel(column=0)(np.eye(2))
    )
    with pytest.raises(ValueError, match="control_dim = 9 exceeds sim_dim = 7"):
        GrassmannKernel(M, 9)(_x(rng))
    with pytest.raises(ValueError, match="Gradient can only be evaluated when Y is None"):
        GrassmannKernel(M, C)(_x(rng), _x(rng), eval_gradient=True)


def test_gp_posterior_matches_sklearn(rng):
    bases = gr.random_points(M, C, 15, rng)
    z = rng.uniform(size=15)
    y = np.sum((bases[:, :C, :]) ** 2, axis=(1, 2)) + 0.3 * z + 0.01 * rng.standard_normal(15)
    gp = GrassmannGP(M, C, fidelity=True, random_state=0).fit(bases, y, z)
    hp = gp.hyperparameters
    assert hp.noise_variance > 0 and hp.fidelity_length_scale is not None

    x = np.column_stack([gr.flatten(bases), z])
    ys = (y - gp.y_mean_) / gp.y_std_
    ref = GaussianProcessRegressor(gp.kernel_, optimizer=None, alpha=1e-10).fit(x, ys)
    query = gr.random_points(M, C, 5, rng)
    mu_ref, sd_ref = ref.predict(np.column_stack([gr.flatten(query), np.ones(5)]), True)
    mu, sd = gp.predict_standardized(query, 1.0)
    np.testing.assert_allclose(mu, mu_ref, atol=1e-7)
    # sklearn's predictive sd includes the WhiteKernel noise; ours is the latent sd
    np.testing.assert_allclose(sd**2 + hp.noise_variance, sd_ref**2, atol=1e-7)
    mu_orig, sd_orig = gp.predict(query, 1.0)
    np.testing.assert_allclose(mu_orig, gp.y_mean_ + gp.y_std_ * mu)
    np.testing.assert_allclose(sd_orig, gp.y_std_ * sd)


def test_gp_fantasy_shrinks_uncertainty(rng):
    bases = gr.random_points(M, C, 8, rng)
    y = rng.standard_normal(8)
    gp = GrassmannGP(M, C, random_state=0).fit(bases, y)
    pending = gr.random_points(M, C, rng=rng)
    mu0, sd0 = gp.predict(pending)
    fantasy = gp.conditioned_on(pending[None], mu0)
    mu1, sd1 = fantasy.predict(pending)
    assert sd1[0] < sd0[0]
    np.testing.assert_allclose(mu1, mu0, atol=1e-8)
    # One more observation at the query point with noise variance n (standardised units,
    # plus the 1e-10 jitter) leaves the variance s^2 n / (s^2 + n) there, s^2 the variance
    # before it (measured: 7e-13 apart; 1e-6 leaves room for a less well-conditioned fit).
    s2 = (sd0[0] / gp.y_std_) ** 2
    n = gp.hyperparameters.noise_variance + 1e-10
    assert (sd1[0] / gp.y_std_) ** 2 == pytest.approx(s2 * n / (s2 + n), rel=1e-6)
    # the fantasy is a copy: the GP it came from predicts as before, on its 8 points
    assert gp.n_observations == 8 and fantasy.n_observations == 9
    np.testing.assert_array_equal(gp.predict(pending), (mu0, sd0))


def test_gp_rejects_bad_data(rng):
    bases = gr.random_points(M, C, 4, rng)
    with pytest.raises(ValueError, match="y must hold 4 finite values"):
        GrassmannGP(M, C).fit(bases, [1.0, 2.0, np.nan, 0.0])
    with pytest.raises(ValueError, match=r"bases must have shape \(n, 7, 2\)"):
        GrassmannGP(M, C).fit(bases[:, :5], np.zeros(4))
    with pytest.raises(ValueError, match="pass z"):
        GrassmannGP(M, C, fidelity=True).fit(bases, np.zeros(4))
    with pytest.raises(ValueError, match=r"n >= 1, got \(0, 7, 2\)"):
        GrassmannGP(M, C).fit(bases[:0], np.zeros(0))
    with pytest.raises(ValueError, match=r"bases\[0\] .*orthonormal"):
        GrassmannGP(M, C).fit(3.0 * bases, np.zeros(4))
    gp = GrassmannGP(M, C)
    with pytest.raises(RuntimeError, match="fit the GP before predicting"):
        gp.ucb_and_gradient(bases[0], 1.0)
    gp.fit(bases, rng.normal(size=4))
    with pytest.raises(ValueError, match=r"bases must have shape \(n, 7, 2\) or \(7, 2\)"):
        gp.predict(bases[:, :5])
    # a basis the kernel cannot read (its span is read through B B^T) is named, not
    # predicted far off (2 B gave a mean of -2e6 for R in [-2, 2])
    with pytest.raises(ValueError, match=r"bases\[1\] is not orthonormal"):
        gp.predict(np.stack([bases[0], 2.0 * bases[1]]))
    for call in (lambda b: gp.predict(b), lambda b: GrassmannGP(M, C).fit(b, np.zeros(4))):
        with pytest.raises(TypeError, match="bases must be real, got a complex128 array"):
            call(bases + 1e-3j)


@pytest.mark.parametrize(
    "name", ["length_scale_bounds", "fidelity_length_scale_bounds", "noise_bounds",
             "signal_bounds"],
)  # fmt: skip
def test_gp_names_bad_hyperparameter_bounds_when_made(name):
    """They reached scikit-learn's kernels unchecked: a reversed pair failed the fit with "An
    upper bound is less than the corresponding lower bound" (which one, not said), "free" with
    numpy's "ufunc 'log' not supported", and a zero low bound with a divide-by-zero."""
    pins = name in ("noise_bounds", "signal_bounds")  # (low = high pins those two)
    relation = "<=" if pins else "<"
    for bounds, match in (
        ((1.0, 0.5), rf"must satisfy 0 < low {relation} high < inf, got \(1.0, 0.5\)"),
        ((0.0, 1.0), rf"must satisfy 0 < low {relation} high < inf, got \(0.0, 1.0\)"),
        ("free", r"must be a \(low, high\) pair or 'fixed', got 'free'"),
    ):
        with pytest.raises(ValueError, match=f"{name} {match}"):
            GrassmannGP(M, C, fidelity=True, **{name: bounds})
    # "fixed" holds the hyperparameter at its start, as scikit-learn's kernels take it
    bases = gr.random_points(M, C, 6, np.random.default_rng(0))
    gp = GrassmannGP(M, C, fidelity=True, random_state=0, **{name: "fixed"})
    gp.fit(bases, np.arange(6.0), z=np.linspace(0.0, 1.0, 6))
    if name == "length_scale_bounds":
        assert gp.hyperparameters.length_scale == 1.0
    if pins:  # equal bounds fit with the hyperparameter held at that value
        gp = GrassmannGP(M, C, fidelity=True, random_state=0, **{name: (0.25, 0.25)})
        gp.fit(bases, np.arange(6.0), z=np.linspace(0.0, 1.0, 6))
        fitted = gp.hyperparameters
        value = fitted.noise_variance if name == "noise_bounds" else fitted.signal_variance
        assert value == pytest.approx(0.25)
    else:
        with pytest.raises(ValueError, match=rf"{name} must satisfy 0 < low < high < inf"):
            GrassmannGP(M, C, fidelity=True, **{name: (0.25, 0.25)})


def test_gp_predict_names_a_bad_fidelity():
    """predict(bases, z=nan) returned NaN, and a z per basis of another count raised numpy's
    "operands could not be broadcast together"."""
    bases = gr.random_points(M, C, 6, np.random.default_rng(0))
    gp = GrassmannGP(M, C, fidelity=True, random_state=0)
    gp.fit(bases, np.arange(6.0), z=np.linspace(0.0, 1.0, 6))
    for z in (np.nan, [0.1, 0.2, 0.3], [[0.5, 0.5]]):
        with pytest.raises(ValueError, match=r"z must be one finite fidelity or one per basis "
                           r"\(2\)"):  # fmt: skip
            gp.predict(bases[:2], z)
    mu, _ = gp.predict(bases[:2], [0.5, 1.0])
    assert mu[1] == pytest.approx(gp.predict(bases[1], 1.0)[0][0], rel=1e-12)


def test_gp_names_a_bad_restart_count_when_made():
    """n_restarts reached scikit-learn as int(n_restarts): -1 failed the first fit of three or
    more points with the message of GaussianProcessRegressor's 'n_restarts_optimizer' (and
    passed a fit of two), 2.7 ran 2 restarts, and 'a' raised int()'s "invalid literal"."""
    for value in (-1, 2.7, "a", True, None):
        with pytest.raises(ValueError, match=rf"n_restarts must be an integer >= 0, got "
                           rf"{re.escape(repr(value))}"):  # fmt: skip
            GrassmannGP(M, C, n_restarts=value)
    assert GrassmannGP(M, C, n_restarts=np.int64(0)).n_restarts == 0


def test_information_gap_is_zero_at_the_target_and_grows_as_z_over_h():
    """BOCA's xi(z) = sqrt(1 - k(z, 1)^2), a public method no test evaluated."""
    kernel = FidelityKernel(length_scale=0.5)
    z = np.array([1.0, 0.999, 0.5, 0.0])
    xi = kernel.information_gap(z)
    k = np.exp(-0.5 * (z - 1.0) ** 2 / 0.25)
    np.testing.assert_allclose(xi, np.sqrt(1.0 - k**2), rtol=1e-12)
    assert xi[0] == 0.0
    assert xi[1] == pytest.approx(0.001 / 0.5, rel=1e-3)  # |z - 1| / h near the target
    assert np.all(np.diff(xi) > 0)
    assert kernel.information_gap(0.5, z_target=0.5) == 0.0


def test_gram_matrix_diagonal_is_exactly_one(rng):
    """k(B, B) = 1 to the bit, as ``diag`` says, though 2 C - 2 ||B^T B||_F^2 rounds to a few
    1e-15 (without the exact diagonal about a third of these entries are 1 - 1e-15)."""
    x = _x(rng, n=40)
    k = GrassmannKernel(M, C, 0.3)(x)
    np.testing.assert_array_equal(np.diag(k), np.ones(len(x)))


def test_kernels_name_bad_length_scales_and_bounds(rng):
    """Each was checked for neither kernel: l = 0 divides by zero, an infinite upper bound
    reaches scikit-learn's log, a triple is read as its first two numbers."""
    x = _x(rng, fidelity=True)
    for make in (lambda ls: GrassmannKernel(M, C, ls), FidelityKernel):
        with pytest.raises(ValueError, match="length_scale must be a positive finite scalar, "
                                             "got 0.0"):  # fmt: skip
            make(0.0)(x)
    for bounds in ((0.1, np.inf), (0.1, 1.0, 2.0), (0.0, 1.0)):
        for kernel in (GrassmannKernel(M, C, 1.0, bounds), FidelityKernel(1.0, bounds)):
            with pytest.raises(ValueError, match=r"length_scale_bounds must satisfy 0 < low < "
                                                 r"high < inf"):  # fmt: skip
                kernel(x)
    with pytest.raises(ValueError, match="length_scale_bounds must satisfy"):
        GrassmannGP(M, C, length_scale_bounds=(0.1, np.inf))


def test_fidelity_column_takes_every_index_of_x_and_names_one_past_it():
    """Python's range for a column of X, -n_columns .. n_columns - 1; one past it is named
    (not numpy's IndexError)."""
    x = np.array([[0.0, 1.0, 0.2], [1.0, 0.0, 0.7]])
    np.testing.assert_array_equal(
        FidelityKernel(0.5, column=-3)(x), FidelityKernel(0.5, column=0)(x)
    )
    np.testing.assert_array_equal(FidelityKernel(0.5, column=2)(x), FidelityKernel(0.5)(x))
    for column in (3, -4):
        with pytest.raises(ValueError, match=rf"column {column} is out of range for X of shape "
                                             r"\(2, 3\)"):  # fmt: skip
            FidelityKernel(column=column)(x)


def test_fidelity_kernel_gradient_only_on_x_and_none_when_fixed(rng):
    """As scikit-learn's kernels: no gradient of k(X, Y), an (n, n, 0) one for a fixed h."""
    x = _x(rng, n=5, fidelity=True)
    with pytest.raises(ValueError, match="Gradient can only be evaluated when Y is None"):
        FidelityKernel(0.5)(x, x[:3], eval_gradient=True)
    k, grad = FidelityKernel(0.5, "fixed")(x, eval_gradient=True)
    np.testing.assert_array_equal(k, FidelityKernel(0.5)(x))
    assert grad.shape == (5, 5, 0)


def test_gp_fantasy_with_fidelity_matches_sklearn_on_all_the_data(rng):
    """Kriging-believer fantasies under BOCA: conditioned_on appends bases, z and y in the same
    order, so the posterior is the fitted kernel's on the old and the new data together (the
    fantasy test above has no fidelity, where z's order cannot show)."""
    bases = gr.random_points(M, C, 10, rng)
    z = rng.uniform(size=10)
    y = np.sum(bases[:, :C, :] ** 2, axis=(1, 2)) + 0.3 * z + 0.01 * rng.standard_normal(10)
    gp = GrassmannGP(M, C, fidelity=True, random_state=0).fit(bases, y, z)
    new, z_new, y_new = gr.random_points(M, C, 3, rng), np.array([0.0, 0.5, 1.0]), y[:3] + 1.0
    fantasy = gp.conditioned_on(new, y_new, z_new)
    x = np.column_stack([gr.flatten(np.concatenate([bases, new])), np.concatenate([z, z_new])])
    ys = (np.concatenate([y, y_new]) - gp.y_mean_) / gp.y_std_
    ref = GaussianProcessRegressor(gp.kernel_, optimizer=None, alpha=1e-10).fit(x, ys)
    query = np.concatenate([new, gr.random_points(M, C, 3, rng)])
    mu_ref, sd_ref = ref.predict(np.column_stack([gr.flatten(query), np.full(6, 0.7)]), True)
    mu, sd = fantasy.predict_standardized(query, 0.7)
    np.testing.assert_allclose(mu, mu_ref, atol=1e-7)
    np.testing.assert_allclose(sd**2 + gp.hyperparameters.noise_variance, sd_ref**2, atol=1e-7)


def test_gp_log_marginal_likelihood_is_that_of_the_model_it_predicts_with(rng):
    """The fit's marginal likelihood is the kernel's with the 1e-10 jitter the posterior adds
    (a larger alpha in the fit would choose the noise of another model)."""
    bases = gr.random_points(M, C, 12, rng)
    y = np.sum(bases[:, :C, :] ** 2, axis=(1, 2)) + 0.01 * rng.standard_normal(12)
    gp = GrassmannGP(M, C, random_state=0).fit(bases, y)
    ys = (y - gp.y_mean_) / gp.y_std_
    ref = GaussianProcessRegressor(gp.kernel_, optimizer=None, alpha=1e-10)
    ref.fit(gr.flatten(bases), ys)
    assert gp.log_marginal_likelihood_ == pytest.approx(ref.log_marginal_likelihood_value_,
                                                        rel=1e-9)  # fmt: skip


@pytest.mark.parametrize("value", [3.0, -1e-200, 1e200])
def test_gp_of_constant_observations_predicts_that_constant(rng, value):
    """y without spread is scaled by max |y| alone (dividing by its zero std would give NaN
    everywhere), whatever its size; y = 0 keeps y_std = 1."""
    bases = gr.random_points(M, C, 5, rng)
    gp = GrassmannGP(M, C, random_state=0).fit(bases, np.full(5, value))
    assert gp.y_std_ == abs(value)
    mu, sd = gp.predict(gr.random_points(M, C, 4, rng))
    np.testing.assert_allclose(mu, value, rtol=1e-6)
    assert np.all(np.isfinite(sd))
    assert GrassmannGP(M, C).fit(bases, np.zeros(5)).y_std_ == 1.0


def test_gp_names_bad_data_wherever_it_is(rng):
    """Every basis is validated (not only the first), z's length too; an unfitted GP says so
    when conditioned and counts no observations."""
    bases = gr.random_points(M, C, 4, rng)
    bad = bases.copy()
    bad[2] *= 2.0
    with pytest.raises(ValueError, match=r"bases\[2\] is not orthonormal"):
        GrassmannGP(M, C).fit(bad, np.zeros(4))
    with pytest.raises(ValueError, match="z must hold 4 finite values"):
        GrassmannGP(M, C, fidelity=True).fit(bases, np.zeros(4), np.zeros(3))
    gp = GrassmannGP(M, C)
    assert gp.n_observations == 0
    with pytest.raises(RuntimeError, match="fit the GP before conditioning it on more data"):
        gp.conditioned_on(bases, np.zeros(4))
    gp.fit(bases, np.arange(4.0))
    assert gp.n_observations == 4


def _ill_conditioned_gp(seed=2):
    """A GP whose K has cond 4.5e8: 40 of its 45 bases within 0.4 of one subspace W, the noise
    at the default floor (1e-6) and the length scale at the default upper bound (20), as a
    fit on a noiseless objective ends up (the hyperparameters pinned here, not fitted)."""
    rng = np.random.default_rng(seed)
    w = gr.random_points(M, C, rng=rng)
    near = []
    for _ in range(40):
        near.append(_retract(w, _tangent(w, rng), rng.uniform(0.02, 0.4)))
    bases = np.concatenate([gr.random_points(M, C, 5, rng), np.stack(near)])
    y = np.linalg.norm(np.swapaxes(bases, 1, 2) @ w, axis=(1, 2)) ** 2
    gp = GrassmannGP(M, C, length_scale_bounds="fixed", noise_bounds="fixed",
                     signal_bounds="fixed")  # fmt: skip
    gp.hyperparameters = GPHyperparameters(10.0, 20.0, None, 1e-6)  # (held by "fixed")
    return gp.fit(bases, y), w, rng


def _tangent(b, rng):
    """A unit tangent direction of Gr(M, C) at b."""
    d = rng.standard_normal(b.shape)
    d -= b @ (b.T @ d)
    return d / np.linalg.norm(d)


def _retract(b, d, t):
    u, _, vt = np.linalg.svd(b + t * d, full_matrices=False)
    return u @ vt


def test_gp_sd_is_accurate_where_the_covariance_is_ill_conditioned():
    """sigma = (s^2 - ||L^-1 k||^2)^(1/2) against 40-digit arithmetic on the same float64 K and
    k: within 1e-6 relative (measured 8e-9). s^2 - k^T K^-1 k with an explicit K^-1 was off by
    up to 30 % here (28-54 % at n = 115-200 with M = 20, C = 3)."""
    import mpmath  # (the test extra's)

    gp, _, _ = _ill_conditioned_gp()
    hp = gp.hyperparameters
    query = gp.bases_[-10:]
    _, sd = gp.predict_standardized(query)

    # K and k as the GP forms them, then sigma in 40 digits (a Cholesky solve as well: its
    # rounding, ~1e-40 cond(K), is far below the tolerance)
    k = hp.signal_variance * np.exp(-(C - gp.proj_ @ gp.proj_.T) / hp.length_scale**2)
    k[np.diag_indices_from(k)] += hp.noise_variance + 1e-10
    kq = hp.signal_variance * np.exp(-(C - gp.proj_ @ gr.projectors(query).T) / 400.0)
    assert np.linalg.cond(k) > 1e8  # (what makes the explicit inverse lose sigma)
    mpmath.mp.dps = 40
    chol = mpmath.cholesky(mpmath.matrix(k.tolist()))
    reference = []
    for col in kq.T:
        u: list = []  # L^-1 k, by forward substitution
        for i, ki in enumerate(col):
            u.append((ki - sum(chol[i, j] * u[j] for j in range(i))) / chol[i, i])
        reference.append(float(mpmath.sqrt(hp.signal_variance - sum(x * x for x in u))))
    np.testing.assert_allclose(sd, reference, rtol=1e-6)
    # ucb_and_gradient's sigma (the acquisition's), and BOCA's through predict_standardized
    sd_ucb = [gp.ucb_and_gradient(b, 2.0)[3] for b in query]
    np.testing.assert_allclose(sd_ucb, reference, rtol=1e-6)


def test_gp_ucb_gradient_matches_finite_differences_where_the_covariance_is_ill_conditioned():
    """Along a geodesic-like curve from bases near W the UCB is smooth and its slope the
    gradient's (central differences at h = 1e-5: within 9e-7 relative). With the explicit
    K^-1 the UCB was jagged at that scale (differences 0.4-11 times off, of either sign):
    noise that the acquisition's line search reads as slope."""
    gp, w, rng = _ill_conditioned_gp()
    h = 1e-5
    for _ in range(4):
        b = _retract(w, _tangent(w, rng), 0.2)
        d = _tangent(b, rng)
        _, grad, _, _ = gp.ucb_and_gradient(b, 2.0)
        hi = gp.ucb_and_gradient(_retract(b, d, h), 2.0)[0]
        lo = gp.ucb_and_gradient(_retract(b, d, -h), 2.0)[0]
        assert (hi - lo) / (2 * h) == pytest.approx(np.sum(grad * d), rel=1e-4, abs=1e-6)


@pytest.mark.parametrize("scale", [1e-13, 1e200, -1e300])
def test_gp_predictions_scale_with_y_whatever_its_size(rng, scale):
    """y is standardised after dividing by max |y|: y.std() of |y| > ~1e154 overflowed (NaN
    predictions), and y ~ 1e-13 counted as a constant (its std below an absolute 1e-12)."""
    bases = gr.random_points(M, C, 8, rng)
    y = rng.standard_normal(8)
    query = gr.random_points(M, C, 4, rng)
    mu, sd = GrassmannGP(M, C, random_state=0).fit(bases, y).predict(query)
    mu_s, sd_s = GrassmannGP(M, C, random_state=0).fit(bases, scale * y).predict(query)
    np.testing.assert_allclose(mu_s / scale, mu, rtol=1e-6)
    np.testing.assert_allclose(sd_s / abs(scale), sd, rtol=1e-6)


def test_gp_names_observations_beyond_float64_on_its_scale(rng):
    """y near the float64 limit fit (their mean overflowed); a fantasy whose distance to their
    mean is beyond float64 is named, not conditioned on as inf."""
    bases = gr.random_points(M, C, 4, rng)
    gp = GrassmannGP(M, C, random_state=0).fit(bases[:3], [1.0e308, 1.1e308, 1.2e308])
    mu, _ = gp.predict(bases[:3])
    np.testing.assert_allclose(mu, [1.0e308, 1.1e308, 1.2e308], rtol=1e-2)  # (noise fitted)
    with pytest.raises(ValueError, match=r"y = array\(\[-1.5e\+308\]\) is beyond float64"):
        gp.conditioned_on(bases[3:], [-1.5e308])


def test_gp_names_a_fidelity_outside_0_1_and_a_stack_given_as_one_basis(rng):
    """z = 7 was fitted (a trajectory seven times past T_max to the fidelity kernel), and
    ucb_and_gradient given three bases used the first."""
    bases = gr.random_points(M, C, 5, rng)
    y = rng.standard_normal(5)
    for z in (np.full(5, 7.0), np.array([0.0, 0.5, 1.0, -0.1, 1.0])):
        with pytest.raises(ValueError, match=r"z must hold 5 finite values in \[0, 1\], got"):
            GrassmannGP(M, C, fidelity=True).fit(bases, y, z)
    gp = GrassmannGP(M, C, fidelity=True, random_state=0).fit(bases, y, np.linspace(0, 1, 5))
    with pytest.raises(ValueError, match=r"z must hold 1 finite values in \[0, 1\]"):
        gp.conditioned_on(bases[:1], [0.0], [1.5])
    with pytest.raises(ValueError, match=r"takes one basis \(7, 2\), got shape \(3, 7, 2\)"):
        gp.ucb_and_gradient(bases[:3], 1.0)
    assert gp.ucb_and_gradient(bases[:1], 1.0)[0] == gp.ucb_and_gradient(bases[0], 1.0)[0]
