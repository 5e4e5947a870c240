"""Simulation space B_r and cubature (softrom_gym.rom)."""

import numpy as np
import pytest
import trimesh

import cpp_sim
from softrom_gym.robots import beam, from_mesh
from softrom_gym.rom import build_subspace, cache_dir, sample_poses, train_cubature


@pytest.fixture(scope="module")
def robot():
    return beam()


@pytest.fixture(scope="module")
def subspace(robot):
    return build_subspace(robot, 20)


def test_basis_is_mass_orthonormal_with_exact_translations(robot, subspace):
    b = subspace.basis
    mass = robot.fem_model().mass
    m3 = np.repeat(mass, 3)
    assert b.shape == (3 * robot.num_nodes, 26) and subspace.M == 20
    np.testing.assert_allclose(b.T @ (m3[:, None] * b), np.eye(26), atol=1e-10)
    for k in range(3):
        t = np.zeros((robot.num_nodes, 3))
        t[:, k] = 1.0 / np.sqrt(mass.sum())
        np.testing.assert_allclose(b[:, k], t.ravel(), atol=1e-14)
    # Columns 3..5 span the infinitesimal rotations about the centre of mass.
    r = robot.nodes - mass @ robot.nodes / mass.sum()
    a = np.column_stack([np.cross(e, r).ravel() for e in np.eye(3)])
    fit, *_ = np.linalg.lstsq(a, subspace.rotations, rcond=None)
    np.testing.assert_allclose(a @ fit, subspace.rotations, atol=1e-12)
    # ... and are zero-energy at rest: K annihilates them.
    k = robot.fem_model().stiffness(robot.nodes)
    assert np.abs(k @ subspace.rotations).max() < 1e-8 * np.abs(k @ subspace.deformation).max()


def test_lowest_modes_solve_the_eigenproblem(robot, subspace):
    fem = robot.fem_model()
    k = fem.stiffness(robot.nodes)
    m3 = np.repeat(fem.mass, 3)
    for j in range(subspace.num_modes):
        u = subspace.deformation[:, j]
        lam = subspace.frequencies[j] ** 2
        residual = k @ u - lam * m3 * u
        assert np.linalg.norm(residual) < 1e-6 * np.linalg.norm(k @ u)
    # Sorted, positive, and rigid motions excluded.
    f = subspace.frequencies[: subspace.num_modes]
    assert np.all(np.diff(f) >= -1e-9) and f[0] > 0.1


def test_modal_derivatives_span_quadratic_deformation(robot, subspace):
    # A modal derivative column is far stiffer than the linear modes around it.
    assert subspace.frequencies[subspace.num_modes :].min() > subspace.frequencies[0]


def test_a_larger_simulation_space_contains_the_smaller(robot, subspace):
    # What comparing M = 20 with M = 40 rests on (benchmarks/check_m_convergence.py): the
    # larger B_r is a richer Galerkin space of the same robot, with the same first modes, so
    # the same actions are the same forces.
    larger = build_subspace(robot, 40)
    m3 = np.repeat(robot.fem_model().mass, 3)
    small, big = subspace.basis, larger.basis
    outside = small - big @ (big.T @ (m3[:, None] * small))
    assert np.sqrt(np.sum(m3[:, None] * outside**2, axis=0)).max() < 1e-8
    np.testing.assert_allclose(big[:, : 6 + 3], small[:, : 6 + 3], atol=1e-8)


def test_a_control_basis_maps_to_the_same_actuation_in_a_larger_space(robot, subspace):
    from softrom_gym import map_control_basis

    big = build_subspace(robot, 40).deformation
    b_c = np.linalg.qr(np.random.default_rng(3).normal(size=(20, 3)))[0]
    mapped = map_control_basis(b_c, robot, 20, 40)
    assert mapped.shape == (40, 3)
    np.testing.assert_allclose(mapped.T @ mapped, np.eye(3), atol=1e-10)
    # the full-space force field M B B_c f_c is the same in both models
    np.testing.assert_allclose(big @ mapped, subspace.deformation @ b_c, atol=1e-8)
    np.testing.assert_allclose(map_control_basis(mapped, robot, 40, 20), b_c, atol=1e-10)
    # the first C modes coincide, so the identity maps to the exact zero-padded identity
    np.testing.assert_array_equal(map_control_basis(np.eye(20)[:, :3], robot, 20, 40),
                                  np.eye(40)[:, :3])  # fmt: skip
    outside = np.linalg.qr(np.random.default_rng(4).normal(size=(40, 3)))[0]
    with pytest.raises(ValueError, match=r"cannot represent .* relative residual 0\.\d+"):
        map_control_basis(outside, robot, 40, 20)
    with pytest.raises(ValueError, match=r"shape \(20, 3\), expected \(source_dim, C\) = \(40"):
        map_control_basis(b_c, robot, 40, 60)
    with pytest.raises(TypeError, match="expected a Robot or a softrom_gym env, got str"):
        map_control_basis(b_c, "beam", 20, 40)
    with pytest.raises(ValueError, match="control_basis is not orthonormal"):
        map_control_basis(2.0 * b_c, robot, 20, 40)
    for atol in (float("nan"), -1.0):
        with pytest.raises(ValueError, match="atol must be a number >= 0"):
            map_control_basis(outside, robot, 40, 20, atol=atol)


def test_subspace_is_cached_on_disk(robot, subspace, monkeypatch):
    files = list(cache_dir().glob("subspace-*.npz"))
    assert files, "no cache file written"
    # A cached subspace is read back, not recomputed: the eigensolvers must not run.
    import softrom_gym.rom.subspace as module

    def no_eigensolve(*args, **kwargs):
        raise AssertionError("the cached subspace was recomputed")

    with monkeypatch.context() as patch:
        patch.setattr(module.spla, "eigsh", no_eigensolve)
        patch.setattr(module, "_dense_eigh", no_eigensolve)
        again = build_subspace(robot, 20)
    np.testing.assert_array_equal(again.basis, subspace.basis)
    # A corrupt cache entry is rebuilt, not fatal.
    for f in files:
        f.write_bytes(b"not a zip file")
    rebuilt = build_subspace(robot, 20)
    np.testing.assert_allclose(rebuilt.basis, subspace.basis, atol=1e-8)


def test_cache_dir_is_user_settable(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTROM_CACHE_DIR", str(tmp_path))
    assert cache_dir() == tmp_path


def test_too_many_modes_raise(robot):
    small = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 2)
    with pytest.raises(ValueError, match=r"M = 500 deformation modes requested, but the robot"):
        build_subspace(small, 500, cache=False)
    with pytest.raises(TypeError, match="M must be an integer"):
        build_subspace(robot, 2.5, cache=False)
    with pytest.raises(ValueError, match="num_derivatives must be in"):
        build_subspace(robot, 10, num_derivatives=10, cache=False)


def test_the_largest_simulation_space_of_a_small_mesh_is_all_its_vibration_modes():
    small = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 2)
    largest = 3 * small.num_nodes - 6
    full = build_subspace(small, largest, num_derivatives=0, cache=False)
    mass3 = np.repeat(small.fem_model().mass, 3)
    gram = full.basis.T @ (mass3[:, None] * full.basis)
    np.testing.assert_allclose(gram, np.eye(largest + 6), atol=1e-9)


def test_cubature_matches_exact_forces_on_held_out_poses(robot, subspace):
    rule = train_cubature(robot, subspace)
    assert len(rule) < robot.num_tets // 5
    assert np.all(rule.weights > 0)
    poses = sample_poses(robot, subspace, 30, np.random.default_rng(2024))  # unseen seed
    g = cpp_sim.reduced_element_forces(robot.fem_model(), subspace.elastic, poses)
    exact = g.sum(axis=1)
    approx = np.einsum("pem,e->pm", g[:, rule.elements], rule.weights)
    rel = np.linalg.norm(approx - exact, axis=1) / np.linalg.norm(exact, axis=1)
    assert rel.max() < 0.05, rel.max()


def test_reduced_element_forces_sum_to_projected_full_forces(robot, subspace):
    poses = sample_poses(robot, subspace, 2, np.random.default_rng(0))
    fem = robot.fem_model()
    g = cpp_sim.reduced_element_forces(fem, subspace.elastic, poses)
    for p in range(2):
        x = robot.nodes + (subspace.elastic @ poses[p]).reshape(-1, 3)
        projected = subspace.elastic.T @ fem.forces(x).ravel()
        np.testing.assert_allclose(g[p].sum(axis=0), projected, rtol=1e-9, atol=1e-9)


def test_cubature_cache_is_keyed_on_the_frequencies_that_scale_its_poses(tmp_path):
    from softrom_gym.rom import Subspace

    small = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 2)
    sub = build_subspace(small, 6, cache=False)
    stiffer = Subspace(sub.basis, 2.0 * sub.frequencies, sub.num_modes)
    train_cubature(small, sub, num_poses=8, cache=tmp_path)
    train_cubature(small, stiffer, num_poses=8, cache=tmp_path)
    # Same basis, other frequencies: a second entry, not the first one read back.
    assert len(list(tmp_path.glob("cubature-*.npz"))) == 2
