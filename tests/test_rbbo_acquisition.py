"""GP-UCB gradients and its maximisation on Gr(M, C) (rbbo.acquisition, rbbo.optimizers)."""

import subprocess
import sys

import numpy as np
import pymanopt
import pytest
from pymanopt.manifolds import Euclidean, Grassmann
from pymanopt.optimizers import ConjugateGradient

from rbbo import grassmann as gr
from rbbo.acquisition import (
    UCBAcquisition,
    make_problem,
    maximize_on_grassmann,
    perturb,
    ucb_beta,
)
from rbbo.gp import GrassmannGP
from rbbo.optimizers import LRBFGS
from rbbo.optimizers.lrbfgs import _Metric

M, C = 8, 3


class TraceQuadratic:
    """mu(B) = tr(B^T A B): its maximisers span the top-C eigenspace of A."""

    def __init__(self, a):
        self.a = a

    def value_and_gradient(self, b):
        ab = self.a @ b
        return float(np.sum(b * ab)), 2.0 * ab

    def values(self, bases):
        return np.einsum("nmc,mk,nkc->n", bases, self.a, bases)


def _symmetric(rng, m=M):
    a = rng.standard_normal((m, m))
    return a + a.T


@pytest.fixture(scope="module")
def gp():
    rng = np.random.default_rng(7)
    bases = gr.random_points(M, C, 20, rng)
    z = rng.uniform(size=20)
    y = np.sum(bases[:, :C, :] ** 2, axis=(1, 2)) + 0.5 * z + 0.05 * rng.standard_normal(20)
    return GrassmannGP(M, C, fidelity=True, random_state=0).fit(bases, y, z)


@pytest.mark.parametrize("optimizer", ["lrbfgs", "cg"])
def test_maximiser_finds_top_eigenspace(optimizer, rng):
    a = _symmetric(rng)
    eigval, eigvec = np.linalg.eigh(a)
    top = eigvec[:, -C:]
    result = maximize_on_grassmann(
        TraceQuadratic(a), M, C, rng=rng, optimizer=optimizer, n_random=16, n_starts=2,
        max_iterations=500,
    )  # fmt: skip
    assert result.value == pytest.approx(eigval[-C:].sum(), rel=1e-8)
    assert gr.projection_distance(result.basis, top) < 1e-4
    assert not result.fallback_used
    assert all("Terminated" in r.stopping_criterion for r in result.results)


def test_lrbfgs_matches_conjugate_gradient_and_needs_fewer_iterations(rng):
    a = _symmetric(rng, 20)
    problem = make_problem(TraceQuadratic(a), 20, C)
    x0 = gr.random_points(20, C, rng=rng)
    kwargs = {"max_iterations": 1000, "min_gradient_norm": 1e-6, "verbosity": 0}
    quasi_newton = LRBFGS(**kwargs).run(problem, initial_point=x0)
    cg = ConjugateGradient(**kwargs).run(problem, initial_point=x0)
    assert quasi_newton.cost == pytest.approx(cg.cost, rel=1e-9)
    assert "min grad norm" in quasi_newton.stopping_criterion
    assert quasi_newton.iterations < cg.iterations


def test_lrbfgs_reports_its_stopping_reason(rng):
    problem = make_problem(TraceQuadratic(_symmetric(rng)), M, C)
    x0 = gr.random_points(M, C, rng=rng)
    result = LRBFGS(max_iterations=3).run(problem, initial_point=x0)
    assert result.iterations == 3
    assert "max iterations" in result.stopping_criterion
    gr.validate_basis(result.point, M, C)
    with pytest.raises(ValueError, match="memory must be a positive integer, got 0"):
        LRBFGS(memory=0)
    with pytest.raises(ValueError, match="need 0 < c1 < c2 < 1"):
        LRBFGS(c1=0.5, c2=0.1)
    # (0 trials: every run stopped at its start, "line search failed"; 2.5 ran 2)
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match=f"max_line_search must be a positive integer, "
                                             f"got {bad}"):  # fmt: skip
            LRBFGS(max_line_search=bad)
    with pytest.raises(ValueError, match="memory must be a positive integer, got True"):
        LRBFGS(memory=True)


def test_lrbfgs_prints_as_pymanopts_optimizers_do(rng, capsys):
    problem = make_problem(TraceQuadratic(_symmetric(rng)), M, C)
    x0 = gr.random_points(M, C, rng=rng)
    LRBFGS(max_iterations=3, verbosity=2).run(problem, initial_point=x0)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "Optimizing..." and "Gradient norm" in lines[1]
    rows = [line.split() for line in lines if line.split() and line.split()[0].isdigit()]
    assert [int(r[0]) for r in rows] == [0, 1, 2, 3]  # a row per iteration
    assert "max iterations" in lines[-1]
    LRBFGS(max_iterations=3, verbosity=1).run(problem, initial_point=x0)
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "Optimizing..." and len(out) == 2
    LRBFGS(max_iterations=3).run(problem, initial_point=x0)
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("z", [1.0, 0.3])
def test_ucb_euclidean_gradient_matches_finite_differences(gp, z, rng):
    acq = UCBAcquisition(gp, beta=2.0, z=z)
    b = gr.random_points(M, C, rng=rng)
    _, grad = acq.value_and_gradient(b)
    # the Euclidean gradient in the ambient R^(M x C): B need not be orthonormal for this
    direction = rng.standard_normal((M, C))
    eps = 1e-6
    hi, _ = acq.value_and_gradient(b + eps * direction)
    lo, _ = acq.value_and_gradient(b - eps * direction)
    assert np.sum(grad * direction) == pytest.approx((hi - lo) / (2 * eps), rel=1e-6)


def test_ucb_batch_values_match_pointwise(gp, rng):
    acq = UCBAcquisition(gp, beta=3.0)
    bases = gr.random_points(M, C, 6, rng)
    pointwise = [acq.value_and_gradient(b)[0] for b in bases]
    np.testing.assert_allclose(acq.values(bases), pointwise, rtol=1e-10)
    for bad in (-1.0, np.inf, np.nan):
        with pytest.raises(ValueError, match=f"beta must be a finite number >= 0, got {bad}"):
            UCBAcquisition(gp, beta=bad)


def test_ucb_riemannian_gradient_passes_pymanopt_style_check(gp, rng):
    """pymanopt's check_gradient test, without its plot (pymanopt 2.2.1's own
    check_directional_derivative fails under numpy 2: a 1-element array is stored into a
    float slot): the first-order Taylor error of the cost along a retraction curve falls
    with slope 2 in log h, and the Riemannian gradient is tangent."""
    problem = make_problem(UCBAcquisition(gp, beta=2.0), M, C)
    manifold = problem.manifold
    x = gr.random_points(M, C, rng=rng)
    d = manifold.projection(x, rng.standard_normal((M, C)))
    d /= np.linalg.norm(d)
    grad = problem.riemannian_gradient(x)
    f0, df0 = problem.cost(x), manifold.inner_product(x, grad, d)
    h = np.logspace(-5, -2, 7)
    error = [abs(problem.cost(manifold.retraction(x, t * d)) - f0 - t * df0) for t in h]
    slope = np.polyfit(np.log10(h), np.log10(error), 1)[0]
    assert slope == pytest.approx(2.0, abs=0.1)
    assert np.linalg.norm(x.T @ grad) < 1e-12
    assert Grassmann(M, C).norm(x, grad) > 0


def test_ucb_maximiser_beats_every_start(gp, rng):
    acq = UCBAcquisition(gp, beta=ucb_beta(20, gr.dimension(M, C)))
    incumbents = gp.bases_[np.argsort(-gp.ys_)[:2]]
    result = maximize_on_grassmann(acq, M, C, incumbents=incumbents, rng=rng, n_random=32)
    starts = np.concatenate([gr.random_points(M, C, 256, rng), incumbents])
    assert result.value >= acq.values(starts).max() - 1e-9
    assert result.value == pytest.approx(acq.value_and_gradient(result.basis)[0])


def test_beta_schedule_grows_logarithmically():
    b = [ucb_beta(t, 51) for t in (1, 10, 100)]
    assert b[0] < b[1] < b[2]
    assert b[2] - b[1] == pytest.approx(b[1] - b[0])  # 0.4 * 2 log(10) per decade
    assert b[1] - b[0] == pytest.approx(0.8 * np.log(10.0), rel=1e-12)
    # beta_t = 0.2 * 2 log(d t^2 pi^2 / (6 delta)), delta = 0.1 (rbbo.acquisition's
    # docstring), and the values it quotes for d = 51 at t = 6, 40 and 300
    assert b[0] == pytest.approx(0.4 * np.log(51 * np.pi**2 / 0.6), rel=1e-12)
    assert [round(ucb_beta(t, 51), 2) for t in (6, 40, 300)] == [4.13, 5.64, 7.26]
    assert ucb_beta(0, 51) == b[0]  # fewer than one observation counts as one
    assert ucb_beta(1, 51, delta=0.5, scale=1.0) == pytest.approx(
        2.0 * np.log(51 * np.pi**2 / 3.0), rel=1e-12
    )
    with pytest.raises(ValueError, match="delta must be in"):
        ucb_beta(1, 3, delta=2.0)


def test_bad_optimizer_name(rng):
    with pytest.raises(ValueError, match=r"unknown optimizer 'bfgs'; valid: \['lrbfgs', 'cg'\]"):
        maximize_on_grassmann(TraceQuadratic(np.eye(M)), M, C, optimizer="bfgs")


def test_incumbents_of_another_shape_or_off_the_manifold_are_refused(rng):
    f = TraceQuadratic(np.eye(M))
    wrong = gr.random_points(6, 4, 3, rng)  # 72 numbers: a reshape to (-1, 8, 3) took them
    assert (M, C) == (8, 3)
    with pytest.raises(ValueError, match=rf"incumbents must have shape \(n, {M}, {C}\)"):
        maximize_on_grassmann(f, M, C, incumbents=wrong, rng=0, n_random=4)
    with pytest.raises(ValueError, match=r"incumbents\[0\] is not orthonormal"):
        maximize_on_grassmann(f, M, C, incumbents=2 * gr.identity_basis(M, C), rng=0)
    result = maximize_on_grassmann(f, M, C, incumbents=gr.identity_basis(M, C), rng=0, n_random=0)
    gr.validate_basis(result.basis, M, C)  # one (M, C) incumbent is a stack of one


@pytest.mark.parametrize("failure", ["raises", "non-finite"])
def test_a_failing_lrbfgs_run_is_redone_with_conjugate_gradient(rng, monkeypatch, failure):
    """The documented fallback: a start whose L-RBFGS run fails still yields its optimum."""

    def failing(self, problem, *, initial_point=None):
        if failure == "raises":
            raise np.linalg.LinAlgError("singular")
        return type("Result", (), {"cost": np.nan, "point": initial_point})()

    monkeypatch.setattr(LRBFGS, "run", failing)
    a = _symmetric(rng)
    result = maximize_on_grassmann(TraceQuadratic(a), M, C, rng=rng, n_random=16, n_starts=2,
                                   max_iterations=500)  # fmt: skip
    assert result.fallback_used and result.optimizer == "lrbfgs"
    assert len(result.results) == 2
    assert result.value == pytest.approx(np.linalg.eigvalsh(a)[-C:].sum(), rel=1e-8)
    with pytest.raises(ValueError, match="no starts: give incumbents or n_random > 0"):
        maximize_on_grassmann(TraceQuadratic(a), M, C, n_random=0)


@pytest.mark.parametrize("beta", [0.0, 4.0])
def test_ucb_is_the_posterior_mean_plus_root_beta_times_its_sd(gp, rng, beta):
    """gamma = mu + beta^(1/2) sigma with mu, sigma the GP's latent posterior at z (the tests
    above compare the acquisition with itself: values, gradient, maximiser); beta = 0, pure
    exploitation, is a valid weight."""
    acq = UCBAcquisition(gp, beta=beta, z=0.6)
    bases = gr.random_points(M, C, 5, rng)
    mu, sd = gp.predict_standardized(bases, 0.6)
    np.testing.assert_allclose(acq.values(bases), mu + np.sqrt(beta) * sd, rtol=1e-12)
    for b, mu_b, sd_b in zip(bases, mu, sd, strict=True):
        _, _, mu_1, sd_1 = gp.ucb_and_gradient(b, np.sqrt(beta), 0.6)
        assert (mu_1, sd_1) == pytest.approx((mu_b, sd_b), rel=1e-10)
        value = acq.value_and_gradient(b)[0]
        assert value == pytest.approx(mu_b + np.sqrt(beta) * sd_b, rel=1e-10)


def test_beta_schedule_names_a_dimension_or_delta_out_of_range():
    with pytest.raises(ValueError, match="dim must be >= 1, got 0"):
        ucb_beta(5, 0)
    for delta in (0.0, 1.0):
        with pytest.raises(ValueError, match=rf"delta must be in \(0, 1\), got {delta}"):
            ucb_beta(5, 3, delta=delta)


def test_perturb_moves_the_subspace_by_the_tangent_step_it_is_given(rng):
    """A tangent step of norm s moves span(B) by sqrt(2) s to first order; a step with a part
    inside span(B) (not projected out) would move it less."""
    b = gr.random_points(M, C, rng=rng)
    for scale in (1e-4, 1e-3):
        moved = perturb(b, scale, rng)
        gr.validate_basis(moved, M, C, tol=1e-12)
        assert gr.projection_distance(b, moved) == pytest.approx(np.sqrt(2.0) * scale, rel=1e-5)


class _Counting(TraceQuadratic):
    def __init__(self, a):
        super().__init__(a)
        self.batches = []

    def values(self, bases):
        self.batches.append(len(bases))
        return super().values(bases)


def test_starts_are_the_random_points_the_incumbents_and_their_perturbations(rng):
    """n_random Haar points, each incumbent and n_perturbations perturbations of each: the
    first batch the function rates holds exactly those; an incumbent is a start itself."""
    a = _symmetric(rng)
    top = np.linalg.eigh(a)[1][:, -C:]
    incumbents = np.stack([top, gr.random_points(M, C, rng=rng)])
    for n_random, n_perturbations, expected in ((1, 3, 1 + 2 * 4), (0, 0, 2), (5, 1, 5 + 2 * 2)):
        f = _Counting(a)
        result = maximize_on_grassmann(
            f, M, C, incumbents=incumbents, rng=rng, n_random=n_random,
            n_perturbations=n_perturbations, max_iterations=0,
        )  # fmt: skip
        assert f.batches[0] == expected
        assert result.value >= f.values(top[None])[0] - 1e-12  # (the top eigenspace is kept)


def test_pymanopt_loads_without_the_autodiff_backends_and_leaves_them_importable():
    """rbbo._pymanopt hides torch, tensorflow, jax and autograd while pymanopt loads (torch
    alone costs seconds) and unhides them: none is loaded, and none is left as the None entry
    of sys.modules that makes its import fail. (A fresh interpreter: here pymanopt is loaded.)"""
    code = ("import sys, rbbo.acquisition; names = ('torch', 'tensorflow', 'jax', 'autograd'); "
            "print('pymanopt' in sys.modules, [n in sys.modules for n in names])")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "[False,", "False,", "False,", "False]"]


def _quadratic_problem(a, b):
    """f(x) = x^T A x / 2 - b^T x on R^n."""
    manifold = Euclidean(len(b))

    @pymanopt.function.numpy(manifold)
    def cost(x):
        return float(0.5 * x @ a @ x - b @ x)

    @pymanopt.function.numpy(manifold)
    def gradient(x):
        return a @ x - b

    return pymanopt.Problem(manifold, cost, euclidean_gradient=gradient)


def _with_metric(manifold, **kwargs):
    """An LRBFGS whose private steps can be called outside run() (which sets the metric)."""
    opt = LRBFGS(**kwargs)
    opt._inner = _Metric(manifold)
    return opt


def test_lrbfgs_direction_is_minus_the_bfgs_inverse_hessian_times_the_gradient(rng):
    """The two-loop recursion against the BFGS update it stands for, on R^n:
    H <- V^T H V + rho s s^T with V = I - rho y s^T over the pairs, oldest first, from
    H_0 = <s, y> / <y, y> I of the newest pair."""
    n = 6
    manifold = Euclidean(n)
    opt = _with_metric(manifold)
    a = rng.standard_normal((n, n))
    a = a @ a.T + n * np.eye(n)
    pairs = []
    for _ in range(3):
        s = rng.standard_normal(n)
        pairs.append((s, a @ s, 1.0 / (s @ a @ s)))
    grad = rng.standard_normal(n)
    s, y, _ = pairs[-1]
    h = (s @ y) / (y @ y) * np.eye(n)
    for s, y, rho in pairs:
        v = np.eye(n) - rho * np.outer(y, s)
        h = v.T @ h @ v + rho * np.outer(s, s)
    x = np.zeros(n)
    np.testing.assert_allclose(opt._direction(manifold, x, grad, pairs), -h @ grad, rtol=1e-10)
    np.testing.assert_array_equal(opt._direction(manifold, x, grad, []), -grad)


def test_lrbfgs_line_search_returns_a_weak_wolfe_step():
    """f(x) = x^2 from x = 1 along d = -1.99999 (df0 = -3.99998): t = 1 lowers f, but not by
    c1 t |df0|, and overshoots; the search halves to t = 1/2, which meets both conditions."""
    problem = _quadratic_problem(np.array([[2.0]]), np.array([0.0]))
    opt = _with_metric(problem.manifold)
    x, d = np.array([1.0]), np.array([-1.99999])
    df0 = float(2.0 * x @ d)
    t, new_x, new_cost, new_grad, evaluations = opt._line_search(problem, x, 1.0, d, df0, 1.0, 12)
    assert new_cost <= 1.0 + 1e-4 * t * df0  # Armijo
    assert float(new_grad @ d) >= 0.9 * df0  # curvature
    assert t == 0.5 and evaluations == 2
    np.testing.assert_allclose(new_x, x + t * d)


def test_lrbfgs_line_search_keeps_an_armijo_point_when_curvature_is_out_of_reach():
    """On f(x) = -x the slope never rises: after its trials (t = 1, 2, 4) the search keeps the
    last point that met the Armijo condition rather than failing."""
    manifold = Euclidean(1)

    @pymanopt.function.numpy(manifold)
    def cost(x):
        return float(-x[0])

    @pymanopt.function.numpy(manifold)
    def gradient(x):
        return -np.ones(1)

    problem = pymanopt.Problem(manifold, cost, euclidean_gradient=gradient)
    t, new_x, _, new_grad, evaluations = _with_metric(manifold)._line_search(
        problem, np.zeros(1), 0.0, np.ones(1), -1.0, 1.0, 3
    )
    assert (t, evaluations) == (4.0, 3) and new_grad is not None
    np.testing.assert_array_equal(new_x, [4.0])


def test_lrbfgs_reports_the_length_of_its_last_step(rng):
    """step_size (pymanopt's min_step_size criterion reads it) is the length t ||d|| of the
    last step: on R^n the distance between the last two iterates."""
    n = 5
    a = rng.standard_normal((n, n))
    problem = _quadratic_problem(a @ a.T + np.eye(n), rng.standard_normal(n))
    x0 = rng.standard_normal(n)
    one = LRBFGS(max_iterations=1).run(problem, initial_point=x0)
    two = LRBFGS(max_iterations=2).run(problem, initial_point=x0)
    assert one.step_size == pytest.approx(np.linalg.norm(one.point - x0), rel=1e-12)
    assert two.step_size == pytest.approx(np.linalg.norm(two.point - one.point), rel=1e-12)


def test_lrbfgs_solves_an_ill_conditioned_quadratic_as_l_bfgs_does(rng):
    """Condition number 100 on R^20: scipy's L-BFGS-B (memory 10) took 71 iterations on
    such a problem, this one 74; steepest descent needs hundreds."""
    n = 20
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    a = q @ np.diag(np.logspace(0, 2, n)) @ q.T
    b = rng.standard_normal(n)
    result = LRBFGS(max_iterations=300, min_gradient_norm=1e-8).run(
        _quadratic_problem(a, b), initial_point=np.zeros(n)
    )
    np.testing.assert_allclose(result.point, np.linalg.solve(a, b), rtol=1e-6)
    assert result.iterations < 100


def _recording_pairs(opt):
    """Wrap opt._direction to record (x, pairs) at each call."""
    seen = []
    direction = opt._direction

    def recording(manifold, x, grad, pairs):
        seen.append((np.array(x), [(np.array(s), np.array(y), rho) for s, y, rho in pairs]))
        return direction(manifold, x, grad, pairs)

    opt._direction = recording
    return seen


def test_lrbfgs_pairs_are_steps_and_gradient_changes(rng):
    """s_k = t d_k (the step taken, not the direction) and y_k the change of gradient: on a
    quadratic y = A s for every stored pair, with rho = 1 / <s, y>."""
    n = 8
    a = rng.standard_normal((n, n))
    a = a @ a.T + np.eye(n)
    problem = _quadratic_problem(a, rng.standard_normal(n))
    opt = LRBFGS(max_iterations=6, memory=4)
    seen = _recording_pairs(opt)
    opt.run(problem, initial_point=rng.standard_normal(n))
    assert max(len(pairs) for _, pairs in seen) == 4
    for _, pairs in seen:
        for s, y, rho in pairs:
            np.testing.assert_allclose(y, a @ s, rtol=1e-9, atol=1e-12)
            assert rho == pytest.approx(1.0 / (s @ y), rel=1e-12)


def test_lrbfgs_pairs_live_in_the_tangent_space_of_the_current_point(rng):
    """On Gr(M, C) (tangent vectors V: X^T V = 0) every pair the two-loop recursion uses was
    transported to x_k, the gradient change y_k = grad f(x_k) - T(grad f(x_k-1)) included."""
    m, c = 10, 3
    problem = make_problem(TraceQuadratic(_symmetric(rng, m)), m, c)
    opt = LRBFGS(max_iterations=8)
    seen = _recording_pairs(opt)
    opt.run(problem, initial_point=gr.random_points(m, c, rng=rng))
    assert sum(len(pairs) for _, pairs in seen) > 10
    for x, pairs in seen:
        for s, y, rho in pairs:
            assert np.abs(x.T @ s).max() < 1e-12 and np.abs(x.T @ y).max() < 1e-12
            assert rho > 0


def test_lrbfgs_drops_a_pair_whose_curvature_the_transport_turns_negative():
    """Grassmann's transport is a projection: <s, y> > 0 at x can be <= 0 at the new point,
    and such a pair would make H indefinite."""
    manifold = Grassmann(3, 1)
    x, new_x = np.eye(3)[:, :1], np.eye(3)[:, 1:2]
    s = np.array([[0.0], [1.0], [1.0]])
    ys = (np.array([[0.0], [1.0], [2.0]]), np.array([[0.0], [3.0], [-1.0]]))
    pairs = [(s, y, 1.0 / float(np.vdot(s, y))) for y in ys]
    assert all(rho > 0 for _, _, rho in pairs)
    moved = _with_metric(manifold)._transport_pairs(manifold, x, new_x, pairs)
    assert len(moved) == 1
    ts, ty, rho = moved[0]
    np.testing.assert_array_equal(ts, [[0.0], [0.0], [1.0]])
    np.testing.assert_array_equal(ty, [[0.0], [0.0], [2.0]])
    assert rho == 0.5


def test_lrbfgs_needs_c1_strictly_below_c2():
    with pytest.raises(ValueError, match="need 0 < c1 < c2 < 1, got c1 = 0.5, c2 = 0.5"):
        LRBFGS(c1=0.5, c2=0.5)


class _Broken(TraceQuadratic):
    """tr(B^T A B), A = diag(0, 1, ..., M - 1), but where (B B^T)[0, 0] > 0.5 (B near e_0) its
    value is NaN (``part="value"``) or its gradient is (``part="gradient"``)."""

    def __init__(self, part):
        super().__init__(np.diag(np.arange(M, dtype=float)))
        self.part = part

    def value_and_gradient(self, b):
        value, grad = super().value_and_gradient(b)
        if (b @ b.T)[0, 0] > 0.5:
            return (np.nan, grad) if self.part == "value" else (value, np.full_like(grad, np.nan))
        return value, grad

    def values(self, bases):
        return np.array([self.value_and_gradient(b)[0] for b in bases])


def _near_e0(rng):
    return gr.orthonormalize(np.eye(M)[:, :C] + 0.3 * rng.standard_normal((M, C)))


def test_a_start_of_nan_value_does_not_hide_the_finite_optimum_its_run_finds(rng):
    """The best value so far started at the best start's: a NaN there compared as no better
    than every finite optimum, and a NaN was returned; non-finite starts now rank last."""
    top = float(np.sum(np.arange(M)[-C:]))  # (A's C largest eigenvalues)
    start = _near_e0(rng)
    assert np.isnan(_Broken("value").values(start[None])[0])
    result = maximize_on_grassmann(_Broken("value"), M, C, incumbents=start, n_random=0,
                                   n_perturbations=0, rng=0)  # fmt: skip
    assert result.value == pytest.approx(top, rel=1e-8)
    # a finite start ranks above a NaN one (n_starts = 1: the one run is from the other)
    other = gr.identity_basis(M, C)[::-1].copy()  # (rows reversed: the span of e_(M-C)..)
    result = maximize_on_grassmann(_Broken("value"), M, C, incumbents=np.stack([start, other]),
                                   n_random=0, n_perturbations=0, n_starts=1)  # fmt: skip
    assert result.value == pytest.approx(top, rel=1e-8)
    everywhere_nan = type("NaN", (TraceQuadratic,), {
        "value_and_gradient": lambda self, b: (np.nan, np.zeros_like(b)),
        "values": lambda self, bases: np.full(len(bases), np.nan),
    })(None)  # fmt: skip
    with pytest.raises(ValueError, match="no start and no local run reached a finite value"):
        maximize_on_grassmann(everywhere_nan, M, C, n_random=4, rng=0)


def test_a_nan_gradient_is_named_and_its_start_passed_over(rng):
    """A NaN gradient reached the retraction's SVD ("SVD did not converge", from the
    ConjugateGradient fallback too): it is a ValueError now, and a start whose runs both end
    in one is passed over."""
    start = _near_e0(rng)
    problem = make_problem(_Broken("gradient"), M, C)
    with pytest.raises(ValueError, match="gradient is not finite at a point where its value"):
        problem.riemannian_gradient(start)
    result = maximize_on_grassmann(_Broken("gradient"), M, C, incumbents=start, n_random=8,
                                   n_starts=9, rng=0)  # fmt: skip
    assert result.fallback_used
    assert result.value == pytest.approx(float(np.sum(np.arange(M)[-C:])), rel=1e-8)
    # only the start there: nothing improves on it, and it is returned
    result = maximize_on_grassmann(_Broken("gradient"), M, C, incumbents=start, n_random=0,
                                   n_perturbations=0)  # fmt: skip
    assert result.results == [] and np.array_equal(result.basis, start)


def test_maximiser_names_a_bad_start_count_or_perturbation_scale(rng):
    """n_random = -1 was taken as 0, and a NaN perturbation scale reached numpy's SVD."""
    f = TraceQuadratic(_symmetric(rng))
    inc = gr.identity_basis(M, C)
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match=rf"n_random must be an integer >= 0, got {bad}"):
            maximize_on_grassmann(f, M, C, incumbents=inc, n_random=bad)
    for bad in (np.nan, np.inf, -0.1):
        with pytest.raises(ValueError, match=rf"perturbation_scale must be a finite number >= "
                                             rf"0, got {bad}"):  # fmt: skip
            maximize_on_grassmann(f, M, C, incumbents=inc, perturbation_scale=bad)
