"""Simulation space B_r and cubature (softrom_gym.rom)."""

import io

import numpy as np
import pytest
import trimesh

import cpp_sim
from softrom_gym.robots import beam, from_mesh
from softrom_gym.rom import build_subspace, cache_dir, sample_poses, train_cubature
from softrom_gym.rom.cubature import _greedy_nnls
from softrom_gym.transfer import map_control_basis


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
    # B_r holds the modal derivatives of Barbič & James, K Phi_ij = -(dK/dq_i) psi_j, of the
    # pairs of modes with the lowest lambda_i lambda_j (M // 3 = 6 columns: the first pairs
    # at least): recomputed here with another difference step and another regularisation of
    # K's rigid null space, the first three lie in span B_r to the truncation error of the
    # package's own differences (measured: 3e-7 of their M-norm; 1e-5 leaves a margin of 30).
    fem = robot.fem_model()
    m3 = np.repeat(fem.mass, 3)
    k0 = fem.stiffness(robot.nodes).toarray()
    rigid = subspace.basis[:, :6]
    mr = m3[:, None] * rigid
    modes = subspace.deformation[:, : subspace.num_modes]
    lam = subspace.frequencies[: subspace.num_modes] ** 2
    pairs = sorted(((i, j) for i in range(4) for j in range(i, 4)),
                   key=lambda p: lam[p[0]] * lam[p[1]])[:3]  # fmt: skip
    assert pairs[0] == (0, 0)
    b, size = subspace.basis, np.ptp(robot.nodes, axis=0).max()
    for i, j in pairs:
        eps = 1e-5 * size / np.abs(modes[:, i]).max()  # 8 um where the mode moves most
        u = modes[:, i].reshape(-1, 3)
        dk = fem.stiffness(robot.nodes + eps * u) - fem.stiffness(robot.nodes - eps * u)
        rhs = -(dk @ modes[:, j]) / (2 * eps)
        rhs -= mr @ (rigid.T @ rhs)
        phi = np.linalg.solve(k0 + 7.0 * mr @ mr.T, rhs)
        phi -= rigid @ (mr.T @ phi)
        outside = phi - b @ (b.T @ (m3 * phi))
        ratio = np.sqrt(outside @ (m3 * outside) / (phi @ (m3 * phi)))
        assert ratio < 1e-5, ((i, j), ratio)


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


def test_the_mapping_s_residual_is_the_mass_norm_share_the_target_cannot_hold(robot, subspace):
    # Guards: the residual's denominator |B B_c|_M taken without the mass (sqrt(C) exactly,
    # B being mass-orthonormal), and C == target_dim refused as "more than target_dim".
    import re

    from softrom_gym import map_control_basis

    b_c = np.linalg.qr(np.random.default_rng(4).normal(size=(20, 3)))[0]
    small = build_subspace(robot, 8).deformation
    m3 = np.repeat(robot.fem_model().mass, 3)
    field = subspace.deformation @ b_c
    lost = field - small @ (small.T @ (m3[:, None] * field))
    expected = np.sqrt(np.sum(m3[:, None] * lost**2)) / np.sqrt(3)
    with pytest.raises(ValueError, match="relative residual") as error:
        map_control_basis(b_c, robot, 20, 8)
    reported = float(re.search(r"relative residual (\S+) >", str(error.value)).group(1))
    assert reported == pytest.approx(expected, rel=2e-3)
    np.testing.assert_array_equal(map_control_basis(np.eye(3), robot, 3, 3), np.eye(3))


def test_subspace_is_cached_on_disk(robot, subspace, monkeypatch):
    files = list(cache_dir().glob("subspace-*.npz"))
    assert files, "no cache file written"
    # A cached subspace is read back, not recomputed: the eigensolvers must not run.
    import softrom_gym.rom.eigen as module

    def no_eigensolve(*args, **kwargs):
        raise AssertionError("the cached subspace was recomputed")

    with monkeypatch.context() as patch:
        patch.setattr(module.spla, "eigsh", no_eigensolve)
        patch.setattr(module, "dense_eigh", no_eigensolve)
        again = build_subspace(robot, 20)
    np.testing.assert_array_equal(again.basis, subspace.basis)
    # a numpy integer is the same M (its repr, np.int64(20), was hashed: a second entry)
    with monkeypatch.context() as patch:
        patch.setattr(module.spla, "eigsh", no_eigensolve)
        patch.setattr(module, "dense_eigh", no_eigensolve)
        numpy_m = build_subspace(robot, np.int64(20), num_derivatives=np.int32(20 // 3))
    assert type(numpy_m.M) is int
    np.testing.assert_array_equal(numpy_m.basis, subspace.basis)
    # A corrupt cache entry is rebuilt, not fatal, and said so. (Only this one: the cache is
    # the session's, and other tests' entries, corrupted, would warn there.)
    from softrom_gym.rom.cache import mesh_key

    entry = cache_dir() / f"subspace-{mesh_key(robot, 20, 20 // 3)}.npz"
    assert entry in files
    entry.write_bytes(b"not a zip file")
    with pytest.warns(RuntimeWarning, match="corrupt cache entry .* it is rebuilt"):
        rebuilt = build_subspace(robot, 20)
    np.testing.assert_allclose(rebuilt.basis, subspace.basis, atol=1e-8)


def _saved(save, *args, **kwargs) -> bytes:
    """The bytes np.save / np.savez writes."""
    buf = io.BytesIO()
    save(buf, *args, **kwargs)
    return buf.getvalue()


def test_a_truncated_or_foreign_cache_entry_is_rebuilt_with_a_warning(tmp_path):
    small = beam(resolution=6)
    sub = build_subspace(small, 6, cache=tmp_path)
    rule = train_cubature(small, sub, num_poses=8, cache=tmp_path)
    entry = next(tmp_path.glob("subspace-*.npz"))
    data = entry.read_bytes()
    other = build_subspace(small, 7, cache=False)
    for name, write in (
        # a truncated zip once left its file open (a ResourceWarning) and was rebuilt silently
        ("truncated", lambda f: f.write_bytes(data[: len(data) // 2])),
        # a bare .npy crashed with a TypeError (an array is no context manager)
        ("npy", lambda f: f.write_bytes(_saved(np.save, np.zeros(3)))),
        # a readable entry of another shape was returned as this robot's B_r
        ("shape", lambda f: f.write_bytes(_saved(np.savez, basis=other.basis,
                                                  frequencies=other.frequencies, num_modes=4))),
    ):  # fmt: skip
        write(entry)
        with pytest.warns(RuntimeWarning, match="corrupt cache entry"):
            again = build_subspace(small, 6, cache=tmp_path)
        np.testing.assert_array_equal(again.basis, sub.basis, err_msg=name)
        assert np.array_equal(np.load(entry)["basis"], sub.basis), name  # written anew
    cub = next(tmp_path.glob("cubature-*.npz"))
    cub.write_bytes(_saved(np.savez, elements=np.array([small.num_tets]), weights=np.ones(1),
                           training_error=0.0))  # fmt: skip
    with pytest.warns(RuntimeWarning, match=r"element index outside \[0, 36\)"):
        again = train_cubature(small, sub, num_poses=8, cache=tmp_path)
    np.testing.assert_array_equal(again.elements, rule.elements)


def test_two_threads_writing_one_entry_do_not_share_a_temporary_file(tmp_path, monkeypatch):
    import threading

    import softrom_gym.rom.cache as module

    seen, barrier = [], threading.Barrier(2)
    savez = np.savez

    def slow_savez(file, **arrays):
        seen.append(str(file))
        barrier.wait(timeout=10)  # both writers are mid-write together
        savez(file, **arrays)

    monkeypatch.setattr(module.np, "savez", slow_savez)
    path = tmp_path / "entry.npz"
    threads = [threading.Thread(target=module.save_entry, args=(path,), kwargs={"a": np.ones(9)})
               for _ in range(2)]  # fmt: skip
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(seen)) == 2, seen
    np.testing.assert_array_equal(np.load(path)["a"], np.ones(9))
    assert [p.name for p in tmp_path.iterdir()] == ["entry.npz"]  # no temporary left behind


def test_cache_dir_is_user_settable(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTROM_CACHE_DIR", str(tmp_path))
    assert cache_dir() == tmp_path
    # a quoted "~/..." (no shell expanded it) is the home folder, not a folder named "~"
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("SOFTROM_CACHE_DIR", "~/softrom-cache")
    assert cache_dir() == tmp_path / "softrom-cache"


def test_too_many_modes_raise(robot):
    small = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 2)
    with pytest.raises(ValueError, match=r"M = 500 deformation modes requested, but the robot"):
        build_subspace(small, 500, cache=False)
    with pytest.raises(TypeError, match="M must be an integer"):
        build_subspace(robot, 2.5, cache=False)
    for m in (0, -3):  # were "M = 0 deformation modes requested, but the robot has only 78"
        with pytest.raises(ValueError, match=f"M must be >= 1 deformation mode, got {m}"):
            build_subspace(small, m, cache=False)
    with pytest.raises(ValueError, match="num_derivatives must be in"):
        build_subspace(robot, 10, num_derivatives=10, cache=False)
    # Found by passing num_derivatives a float and a bool: 1.5 was "slice indices must be
    # integers" from deep in the build, '1' a '<=' TypeError, True silently one derivative.
    for bad in (1.5, True, "1"):
        with pytest.raises(TypeError, match=f"num_derivatives must be an integer, got {bad!r}"):
            build_subspace(small, 6, num_derivatives=bad, cache=False)


def test_the_largest_simulation_space_of_a_small_mesh_is_all_its_vibration_modes():
    small = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 2)
    largest = 3 * small.num_nodes - 6
    full = build_subspace(small, largest, num_derivatives=0, cache=False)
    mass3 = np.repeat(small.fem_model().mass, 3)
    gram = full.basis.T @ (mass3[:, None] * full.basis)
    np.testing.assert_allclose(gram, np.eye(largest + 6), atol=1e-9)


def test_a_small_mesh_s_modes_from_the_dense_solver_solve_the_eigenproblem():
    # Guards: dense_eigh (3N <= 600, every small mesh) returning the eigenvectors of
    # M^-1/2 K M^-1/2 without mapping them back by M^-1/2 (the benchmark robots take ARPACK).
    with pytest.warns(UserWarning, match="times the mesh's volume"):  # 0.1 m in 2 voxels
        small = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 3)
    assert 3 * small.num_nodes <= 600
    sub = build_subspace(small, 6, num_derivatives=0, cache=False)
    fem = small.fem_model()
    k, m3 = fem.stiffness(small.nodes), np.repeat(fem.mass, 3)
    for j in range(6):
        u = sub.deformation[:, j]
        residual = k @ u - sub.frequencies[j] ** 2 * m3 * u
        assert np.linalg.norm(residual) < 1e-6 * np.linalg.norm(k @ u)


def _cubature_errors(robot, subspace, rule, poses):
    """Each pose's relative error of the rule's reduced elastic force."""
    g = cpp_sim.reduced_element_forces(robot.fem_model(), subspace.elastic, poses)
    exact = g.sum(axis=1)
    approx = np.einsum("pem,e->pm", g[:, rule.elements], rule.weights)
    return np.linalg.norm(approx - exact, axis=1) / np.linalg.norm(exact, axis=1)


def test_cubature_matches_exact_forces_on_held_out_poses(robot, subspace):
    rule = train_cubature(robot, subspace)
    assert len(rule) < robot.num_tets // 5
    assert np.all(rule.weights > 0)
    # The training error it reports is the RMS over its 100 training poses (seed 0) of each
    # pose's relative force error, and it met the default target, 0.005.
    training = _cubature_errors(
        robot, subspace, rule, sample_poses(robot, subspace, 100, np.random.default_rng(0))
    )
    assert rule.training_error == pytest.approx(np.sqrt(np.mean(training**2)), rel=1e-9)
    assert rule.training_error <= 0.005
    # On unseen poses a few times the training error: measured 0.017 at most (0.048 for a
    # rule trained only to 0.02), so 0.03 holds a margin and still sees a rule twice as rough.
    poses = sample_poses(robot, subspace, 30, np.random.default_rng(2024))  # unseen seed
    rel = _cubature_errors(robot, subspace, rule, poses)
    assert rel.max() < 0.03, rel.max()


def test_training_poses_scale_each_deformation_column_by_its_inverse_frequency(robot, subspace):
    # Guards: sample_poses multiplying by omega_j instead of dividing (stiff columns would
    # dominate the training poses). Every pose's coefficients share one scale factor, so
    # |c_j| omega_j has the same distribution for every column j.
    poses = sample_poses(robot, subspace, 400, np.random.default_rng(0))
    spread = np.median(np.abs(poses[:, 3:]), axis=0) * subspace.frequencies
    assert spread.max() < 1.4 * spread.min()


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


def test_the_cubature_cap_is_honoured_and_checked():
    small = beam(resolution=6)
    sub = build_subspace(small, 6, cache=False)
    # greedy NNLS added four candidates a round, so max_elements=1 gave three elements
    for cap in (1, 2, 5):
        assert 1 <= len(train_cubature(small, sub, max_elements=cap, cache=False)) <= cap
    # -1 gave an empty rule (a body without elasticity), 0 silently the default cap
    for cap in (0, -1):
        with pytest.raises(ValueError, match=f"max_elements must be >= 1, got {cap}"):
            train_cubature(small, sub, max_elements=cap, cache=False)
    with pytest.raises(TypeError, match="max_elements must be an integer, got 2.5"):
        train_cubature(small, sub, max_elements=2.5, cache=False)


def test_mapping_names_bad_dimensions_and_takes_an_env(robot, subspace):
    """The argument checks of map_control_basis beyond its shape and orthonormality, and the
    two shortcuts a user takes: an env for its robot, and the same M (a copy, not a view)."""
    import gymnasium as gym

    from softrom_gym import map_control_basis

    b_c = np.eye(20)[:, :3]
    for source, target, name, value in ((0, 40, "source_dim", "0"), (20, True, "target_dim",
                                         "True"), (20, 24.0, "target_dim", "24.0")):  # fmt: skip
        with pytest.raises(ValueError, match=f"{name} must be a positive integer, got {value}"):
            map_control_basis(b_c, robot, source, target)
    bad = b_c.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="control_basis contains non-finite values"):
        map_control_basis(bad, robot, 20, 40)
    with pytest.raises(ValueError, match="control_basis has C = 3 columns, more than "
                       "target_dim = 2"):  # fmt: skip
        map_control_basis(b_c, robot, 20, 2)
    same = map_control_basis(b_c, robot, 20, 20)
    np.testing.assert_array_equal(same, b_c)
    assert not np.shares_memory(same, b_c)
    env = gym.make("softrom_gym/BeamWalk-v0")
    np.testing.assert_array_equal(map_control_basis(b_c, env, 20, 40),
                                  map_control_basis(b_c, robot, 20, 40))  # fmt: skip


def test_an_unwritable_cache_costs_only_speed(tmp_path, monkeypatch):
    """save_entry's OSError path: a cache folder that cannot be made (a file in its way), and
    a write that fails after its temporary file was made (a full disk). Each is said once per
    folder (a new robot's model is then rebuilt, minutes, every time it is made)."""
    small = beam(resolution=6)
    blocked = tmp_path / "file"
    blocked.write_text("")
    with pytest.warns(
        RuntimeWarning,
        match=r"cannot write the cache entry .*file/cache/.* it "
        "is built again each time it is needed; set SOFTROM_CACHE_DIR",
    ) as said:
        sub = build_subspace(small, 6, cache=blocked / "cache")
        rule = train_cubature(small, sub, num_poses=8, cache=blocked / "cache")
    assert len([w for w in said if "cannot write" in str(w.message)]) == 1
    np.testing.assert_array_equal(sub.basis, build_subspace(small, 6, cache=False).basis)
    assert len(rule) >= 1
    assert [p.name for p in tmp_path.iterdir()] == ["file"]  # no temporary left behind
    from softrom_gym.rom import cache

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(cache.os, "replace", full_disk)
    with pytest.warns(RuntimeWarning, match="No space left on device"):
        np.testing.assert_array_equal(build_subspace(small, 6, cache=tmp_path / "full").basis,
                                      sub.basis)  # fmt: skip
    assert list((tmp_path / "full").iterdir()) == []  # its temporary was removed


def test_cache_entries_missing_arrays_or_with_bad_weights_are_rebuilt(tmp_path):
    small = beam(resolution=6)
    sub = build_subspace(small, 6, cache=tmp_path)
    rule = train_cubature(small, sub, num_poses=8, cache=tmp_path)
    entry = next(tmp_path.glob("subspace-*.npz"))
    entry.write_bytes(_saved(np.savez, basis=sub.basis, num_modes=sub.num_modes))
    with pytest.warns(RuntimeWarning, match="no 'frequencies' array"):
        np.testing.assert_array_equal(build_subspace(small, 6, cache=tmp_path).basis, sub.basis)
    cub = next(tmp_path.glob("cubature-*.npz"))
    for arrays, problem in (
        ({"elements": rule.elements, "weights": rule.weights}, "missing arrays"),
        ({"elements": rule.elements.astype(float), "weights": rule.weights,
          "training_error": 0.0}, "not matching index and weight vectors"),
        ({"elements": rule.elements, "weights": -rule.weights, "training_error": 0.0},
         "a negative or non-finite weight"),
    ):  # fmt: skip
        cub.write_bytes(_saved(np.savez, **arrays))
        with pytest.warns(RuntimeWarning, match=f"corrupt cache entry .*{problem}"):
            again = train_cubature(small, sub, num_poses=8, cache=tmp_path)
        np.testing.assert_array_equal(again.weights, rule.weights)


def test_cache_dir_defaults_to_the_users_cache(monkeypatch, tmp_path):
    import sys

    monkeypatch.setenv("SOFTROM_CACHE_DIR", "")  # set but empty: as if unset (not the cwd)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    if sys.platform == "darwin":
        assert cache_dir().parts[-3:] == ("Library", "Caches", "softrom")
    else:
        assert cache_dir() == tmp_path / "softrom"
        monkeypatch.delenv("XDG_CACHE_HOME")  # the XDG default, ~/.cache
        monkeypatch.setenv("HOME", str(tmp_path))
        assert cache_dir() == tmp_path / ".cache" / "softrom"


def test_model_and_cubature_arguments_are_named(robot, subspace):
    from softrom_gym.robots import quadruped
    from softrom_gym.rom import build_reduced_model

    with pytest.raises(ValueError, match="forces must be 'cubature' or 'exact', got 'fast'"):
        build_reduced_model(robot, 20, subspace=subspace, forces="fast")
    with pytest.raises(ValueError, match=r"subspace basis has \d+ rows, robot has 3N = \d+"):
        build_reduced_model(quadruped(), 20, subspace=subspace)
    # Found by passing M with a prebuilt subspace: M=5 built the subspace's 20-mode model.
    with pytest.raises(ValueError, match="M = 5 but the subspace has M = 20 deformation"):
        build_reduced_model(robot, 5, subspace=subspace, forces="exact")
    assert build_reduced_model(robot, subspace=subspace, forces="exact").M == subspace.M
    with pytest.raises(ValueError, match="num_poses must be >= 1, got 0"):
        train_cubature(robot, subspace, num_poses=0)
    for tolerance in (0.0, 1.0):
        with pytest.raises(ValueError, match=rf"tolerance must be in \(0, 1\), got {tolerance}"):
            train_cubature(robot, subspace, tolerance=tolerance)
    # Found by passing each argument a wrong type: num_poses=2.5 was "'float' object cannot be
    # interpreted as an integer", tolerance='0.1' a '<' TypeError, seed=-1 numpy's "expected
    # non-negative integer" (none naming the argument), and seed=True silently seeded 1.
    for kwargs, error, match in (
        ({"num_poses": 2.5}, TypeError, "num_poses must be an integer, got 2.5"),
        ({"num_poses": True}, TypeError, "num_poses must be an integer, got True"),
        ({"tolerance": "0.1"}, TypeError, "tolerance must be a real number, got '0.1'"),
        ({"seed": True}, TypeError, "seed must be an integer, got True"),
        ({"seed": 1.5}, TypeError, "seed must be an integer, got 1.5"),
        ({"seed": -1}, ValueError, "seed must be >= 0, got -1"),
    ):
        with pytest.raises(error, match=match):
            train_cubature(robot, subspace, cache=False, **kwargs)


def test_cubature_training_ends_when_no_candidate_improves_the_fit(monkeypatch):
    """A round whose picks NNLS all pruned left the selection as it was, and the next round
    picked them again, forever: near-duplicate elements (mirror images) and an error the
    rule cannot reach stalled 131 of 200 such problems (a review, session 54)."""
    import softrom_gym.rom.cubature as cubature

    real, calls = cubature.nnls, [0]

    def counted(*args, **kwargs):
        calls[0] += 1
        if calls[0] > 1000:
            raise RuntimeError("the training stalled: over 1,000 NNLS rounds")
        return real(*args, **kwargs)

    monkeypatch.setattr(cubature, "nnls", counted)
    rng = np.random.default_rng(0)
    for _ in range(20):
        calls[0] = 0
        a = rng.random((30, 12))
        a[:, 6:] = a[:, :6] * (1 + 1e-15 * rng.standard_normal((1, 6)))
        b = a[:, :6] @ rng.random(6) + 0.3 * rng.standard_normal(30)  # not reachable exactly
        selected, weights, err = cubature._greedy_nnls(a, b, 1e-6, 12, False)
        assert err > 1e-6 and np.all(weights > 0) and len(set(selected)) == len(selected)
        residual = np.linalg.norm(b - a[:, selected] @ weights) / np.linalg.norm(b)
        assert residual == pytest.approx(err)


def test_rotation_columns_are_the_documented_rotations_in_order_and_sign():
    """Columns 3..5 are the infinitesimal rotations w x (X - c) about e_x, e_y, e_z,
    mass-orthonormalised in that order: column 3 + k is a combination of the first k + 1
    rotations with a positive coefficient on its own. The existing test checks the span only:
    (X - c) x w in place of w x (X - c) flips every column and passed (caught only by a
    1.10e-5 > 1e-5 drift in a chaotic contact test). Subspace.signature(), which RBBO runs
    record, depends on these signs."""
    robot = beam()
    sub = build_subspace(robot, 6, cache=False)
    mass = robot.fem_model().mass
    r = robot.nodes - mass @ robot.nodes / mass.sum()
    a = np.column_stack([np.cross(e, r).ravel() for e in np.eye(3)])
    coef, *_ = np.linalg.lstsq(a, sub.rotations, rcond=None)
    np.testing.assert_allclose(a @ coef, sub.rotations, atol=1e-12)
    np.testing.assert_allclose(np.tril(coef, -1), 0.0, atol=1e-9 * np.abs(coef).max())
    assert np.all(np.diag(coef) > 0)


def test_modal_derivatives_are_those_of_the_lowest_eigenvalue_products():
    """Barbic & James: the derivative columns are Phi_ij = -K^-1 (dK/dq_i) psi_j for the
    pairs of low modes with the lowest lambda_i lambda_j first. The existing tests check only
    properties any derivative columns have (stiffer than the modes, mass-orthonormal), so
    ranking the pairs by eigenvalues shifted by one (lam[5:] for lam[6:], a rigid lambda ~ 0
    for mode 0's) changed the last four columns of the beam's B_r entirely and was caught
    only as a contact stagger that stopped converging in tests/test_solver.py."""
    from softrom_gym.rom.subspace import _mass_gram_schmidt, _modal_derivatives

    robot, m = beam(), 20
    sub = build_subspace(robot, m, cache=False)
    fem = robot.fem_model()
    mass3 = np.repeat(fem.mass, 3)
    k0 = fem.stiffness(robot.nodes)
    rigid, modes = sub.basis[:, :6], sub.deformation[:, : sub.num_modes]
    lam = sub.frequencies[: sub.num_modes] ** 2
    nd = m - sub.num_modes
    base = min(sub.num_modes, max(2, int(np.ceil(np.sqrt(2 * nd))) + 1))
    unit = lam[0] * lam[0]

    def rank(p):
        return float(np.round(lam[p[0]] * lam[p[1]] / unit, 6)), p

    ranked = sorted(((i, j) for i in range(base) for j in range(i, base)), key=rank)
    pairs = ranked[: 2 * nd]
    phis = _modal_derivatives(fem, robot.nodes, modes, pairs, k0, rigid, mass3)
    expected = np.column_stack(_mass_gram_schmidt(list(modes.T) + phis, mass3, rigid)[:m])
    # the same span as B_r's deformation columns (mass inner product)
    overlap = expected.T @ (mass3[:, None] * sub.deformation)
    np.testing.assert_allclose(np.linalg.svd(overlap, compute_uv=False), 1.0, atol=1e-6)


def test_a_control_basis_off_orthonormal_by_more_than_1e_8_is_refused():
    """The documented tolerance is the env's, 1e-8: a B_c 1e-6 off orthonormal is refused
    (before any simulation space is built). The existing test uses a far-off basis, so a
    tolerance of 1e-4 passed it."""
    basis = np.eye(6)[:, :2]
    basis[0, 0] += 1e-6
    with pytest.raises(ValueError, match=r"not orthonormal: max \|B_c\^T B_c - I\| = 2e-06"):
        map_control_basis(basis, beam(), 6, 8)


def test_the_greedy_pick_is_the_element_most_aligned_with_the_residual():
    """An, Kim & James's greedy step scores each element by the cosine of its column with the
    residual, a_j . r / |a_j|: not by a_j . r (large columns win), a_j . r / |a_j|^2 (small
    columns win) or an L1-normalised product. Here column 0 is parallel to b, columns 1 and 2
    are at cosine 0.9 with norms 100 and 0.01, and column 3 (e_0) at cosine 0.87 has the
    larger L1 score."""
    b = np.array([3.0, 1.0, 1.0, 1.0])
    unit = b / np.linalg.norm(b)
    side1 = np.array([0.0, 1.0, -1.0, 0.0]) / np.sqrt(2.0)
    side2 = np.array([0.0, 1.0, 1.0, -2.0]) / np.sqrt(6.0)
    assert abs(side1 @ b) < 1e-15 and abs(side2 @ b) < 1e-15
    tilt = np.sqrt(1.0 - 0.9**2)
    a = np.column_stack([unit, 100.0 * (0.9 * unit + tilt * side1),
                         0.01 * (0.9 * unit + tilt * side2), np.eye(4)[0]])  # fmt: skip
    selected, weights, err = _greedy_nnls(a, b, 1e-9, 1, False)
    assert selected.tolist() == [0]
    assert weights == pytest.approx([np.linalg.norm(b)]) and err < 1e-12


def test_training_turns_move_a_node_coordinate_by_up_to_5_percent_of_the_size():
    """sample_poses: the linearised rotation's largest coordinate displacement is uniform on
    [0, 5 %] of the robot's size (its largest extent). Dropping that scaling (unit Gaussian
    rotation coordinates), a 10x range, the norm for the largest coordinate, or a turn in
    metres rather than in sizes all passed the tests of sample_poses and train_cubature."""
    robot = beam()
    subspace = build_subspace(robot, 20)
    size = float(np.ptp(robot.nodes, axis=0).max())
    poses = sample_poses(robot, subspace, 400, np.random.default_rng(0))
    turn = np.abs(poses[:, :3] @ subspace.rotations.T).max(axis=1) / size
    assert turn.max() <= 0.05 * (1 + 1e-12)
    assert turn.max() > 0.048  # reaches the top of its range ...
    assert turn.mean() == pytest.approx(0.025, abs=0.003)  # ... uniform over it
