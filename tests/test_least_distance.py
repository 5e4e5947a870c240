"""The contact solve's normal half, the least-distance programme min |x| s.t. E x >= f, solved
by NNLS (Lawson & Hanson ch. 23.4): against its optimality conditions and scipy's NNLS, on
sequences of right-hand sides as staggering produces them (warm starts; with the fast solver
the Gram factor carried from call to call, grown, downdated and its forward solve kept)."""

import numpy as np
import pytest
from scipy.optimize import nnls as scipy_nnls

import cpp_sim


def contact_like(k: int, m: int, seed: int, clusters: int = 0) -> np.ndarray:
    """k constraint rows in m coordinates, each with a positive component along e_0 (moving
    up is feasible, as for a ground plane); with ``clusters``, rows come in nearly coplanar
    groups, as the nodes of a foot or of the cross's arms do in a reduced space."""
    rng = np.random.default_rng(seed)
    if clusters:
        centres = rng.standard_normal((clusters, m))
        e = centres[rng.integers(clusters, size=k)] + 1e-3 * rng.standard_normal((k, m))
    else:
        e = rng.standard_normal((k, m))
    e[:, 0] = np.abs(e[:, 0]) + 0.5
    return e


def scipy_least_distance(e: np.ndarray, f: np.ndarray) -> np.ndarray:
    m = e.shape[1]
    g = np.vstack([e.T, f[None, :]])
    d = np.zeros(m + 1)
    d[m] = 1.0
    u, _ = scipy_nnls(g, d, maxiter=50 * g.shape[1])
    r = g @ u - d
    return -r[:m] / r[m]


def sequence(f0: np.ndarray, steps: int, seed: int, jump_every: int = 5) -> np.ndarray:
    """Right-hand sides drifting by small changes, with a larger one every few calls."""
    rng = np.random.default_rng(seed)
    fs = [f0]
    for s in range(1, steps):
        scale = 0.3 if s % jump_every == 0 else 1e-3
        fs.append(fs[-1] + scale * rng.standard_normal(f0.size))
    return np.array(fs)


@pytest.mark.parametrize("clusters", [0, 6])
@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_least_distance_meets_its_optimality_conditions(solver, clusters):
    k, m = 120, 20
    e = contact_like(k, m, seed=1, clusters=clusters)
    rng = np.random.default_rng(2)
    fs = sequence(rng.standard_normal(k), 30, seed=3)
    results = cpp_sim._core._least_distance_sequence(e, fs, solver)
    for f, (x, lam, feasible, converged) in zip(fs, results, strict=True):
        assert feasible and converged
        scale = np.abs(f).max() + np.abs(e).max() * np.linalg.norm(x)
        slack = e @ x - f
        assert slack.min() > -1e-10 * scale  # primal feasible
        assert lam.min() >= 0.0  # dual feasible
        np.testing.assert_allclose(x, e.T @ lam, atol=1e-10 * max(1.0, np.abs(x).max()))
        assert np.abs(lam * slack).max() < 1e-10 * scale * max(1.0, lam.max())  # complementary
        # The minimiser is unique even where the multipliers are not (clustered rows).
        np.testing.assert_allclose(x, scipy_least_distance(e, f), atol=1e-8 * scale)


def test_fast_and_reference_least_distance_agree_along_a_sequence():
    k, m = 185, 26  # the cross walker's candidates and coordinates
    e = contact_like(k, m, seed=4, clusters=8)
    rng = np.random.default_rng(5)
    fs = sequence(rng.standard_normal(k) - 1.0, 40, seed=6, jump_every=7)
    fast = cpp_sim._core._least_distance_sequence(e, fs, "fast")
    ref = cpp_sim._core._least_distance_sequence(e, fs, "reference")
    for (x_fast, *_), (x_ref, *_) in zip(fast, ref, strict=True):
        np.testing.assert_allclose(x_fast, x_ref, atol=1e-9 * max(1.0, np.abs(x_ref).max()))


def test_least_distance_sequence_validates_its_input():
    e = contact_like(10, 4, seed=0)
    with pytest.raises(ValueError, match="fs .* 3 x 9"):
        cpp_sim._core._least_distance_sequence(e, np.zeros((3, 9)))
    with pytest.raises(ValueError, match="solver must be 'fast' or 'reference', got 'qr'"):
        cpp_sim._core._least_distance_sequence(e, np.zeros((1, 10)), "qr")


@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_least_distance_sequence_gives_no_x_for_an_infeasible_programme(solver):
    # x >= 1 and -x >= 1 have no solution; x >= 0.5, x <= 2 has x = 0.5. An infeasible call's
    # x was the buffer's leftover (the last feasible x, or uninitialised memory at the start).
    e = np.array([[1.0], [-1.0]])
    fs = np.array([[1.0, 1.0], [0.5, -2.0], [1.0, 1.0]])
    results = cpp_sim._core._least_distance_sequence(e, fs, solver)
    assert [feasible for _, _, feasible, _ in results] == [False, True, False]
    assert np.isnan(results[0][0]).all() and np.isnan(results[2][0]).all()
    np.testing.assert_allclose(results[1][0], [0.5])


@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_a_programme_whose_multipliers_fall_below_the_floor_returns_zero(solver):
    # A resting block's normal solve in a mass unit 1e20-1e40 times a kilogram's: every
    # multiplier falls below NNLS's absolute 1e-14 floor and is dropped, and the reference
    # solver's QR of the emptied passive set read an empty vector's maximum (a review,
    # session 55: SIGSEGV). Such units are far outside any robot's (1e-10 to 1e10 agree with
    # kilograms to ~3e-6; README), but a crash is never the answer.
    from softrom_gym.robots.robot import Robot
    from softrom_gym.robots.voxel import voxels_to_tets
    from softrom_gym.rom import build_reduced_model, build_subspace

    nodes, tets = voxels_to_tets(np.ones((4, 4, 2), dtype=bool), 0.05)
    robot = Robot("block", nodes, tets, youngs_modulus=1e6)
    sub = build_subspace(robot, 12)
    model = build_reduced_model(robot, subspace=sub)
    m = sub.basis.shape[1]
    a = np.eye(m)
    a[3:, 3:] += (model.dt**2 + model.dt * model.damping_beta) * model.elastic_stiffness(
        np.zeros(m - 3)
    )
    surface = np.array(robot.surface_nodes)
    bottom = surface[robot.nodes[surface, 2] < 1e-9]
    e = np.linalg.solve(np.linalg.cholesky(a), sub.basis[3 * bottom + 2].T).T  # J_n L^-T
    rng = np.random.default_rng(0)
    fs = 9.81 * model.dt * (1 + 0.05 * rng.standard_normal((4, len(bottom))))
    for scale in (1e-20, 1e-30, 1e-40):
        for x, lam, feasible, _ in cpp_sim._core._least_distance_sequence(
            e / np.sqrt(scale), fs, solver
        ):
            assert feasible and np.all(np.isfinite(x)) and np.all(lam >= 0.0)
