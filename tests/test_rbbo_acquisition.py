"""GP-UCB gradients and its maximisation on Gr(M, C) (rbbo.acquisition, rbbo.optimizers)."""

import numpy as np
import pytest
from pymanopt.manifolds import Grassmann
from pymanopt.optimizers import ConjugateGradient

from rbbo import grassmann as gr
from rbbo.acquisition import (
    UCBAcquisition,
    make_problem,
    maximize_on_grassmann,
    ucb_beta,
)
from rbbo.gp import GrassmannGP
from rbbo.optimizers import LRBFGS

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
