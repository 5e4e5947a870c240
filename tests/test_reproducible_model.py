"""The reduced model does not depend on the machine that builds it: eigenvector signs and
degenerate eigenspaces get one basis, cubature ties one order, whatever the BLAS kernel's last
bits (a B_c found on one machine must mean the same actuation on another)."""

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from softrom_gym.rom.cubature import _ranked
from softrom_gym.rom.eigen import reference_fields
from softrom_gym.rom.subspace import canonical_eigenvectors


def _problem(rng, n=30):
    """A generalised eigenbasis (M-orthonormal) with eigenvalues 1, 2, 2, 2, 3, 5, 5."""
    mass3 = rng.uniform(0.5, 2.0, n)
    lam = np.array([1.0, 2.0, 2.0, 2.0, 3.0, 5.0, 5.0])
    x = np.linalg.qr(rng.standard_normal((n, len(lam))))[0]
    return lam, x / np.sqrt(mass3)[:, None], mass3


def test_sign_flips_and_rotations_inside_an_eigenspace_give_one_basis(rng):
    lam, vec, mass3 = _problem(rng)
    reference = canonical_eigenvectors(lam, vec, mass3, keep=5)
    # What another eigensolver may return: flipped signs, any basis of the triple eigenspace.
    rot = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    other = vec.copy()
    other[:, 1:4] = vec[:, 1:4] @ rot
    other[:, [0, 4]] *= -1.0
    again = canonical_eigenvectors(lam, other, mass3, keep=5)
    np.testing.assert_allclose(again, reference, atol=1e-12)
    # the same span, M-orthonormal
    np.testing.assert_allclose(reference.T @ (mass3[:, None] * reference), np.eye(5), atol=1e-12)
    overlap = vec[:, :5].T @ (mass3[:, None] * reference)
    np.testing.assert_allclose(np.linalg.svd(overlap, compute_uv=False), 1.0, atol=1e-12)


def test_a_cut_inside_a_degenerate_eigenspace_keeps_the_same_part_of_it(rng):
    lam, vec, mass3 = _problem(rng)
    kept = canonical_eigenvectors(lam, vec, mass3, keep=3)  # 2 of the triple eigenspace
    rot = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    other = vec.copy()
    other[:, 1:4] = vec[:, 1:4] @ rot
    np.testing.assert_allclose(canonical_eigenvectors(lam, other, mass3, keep=3), kept,
                               atol=1e-12)  # fmt: skip
    # a cluster that runs to the last eigenpair given may be larger than what was computed
    with pytest.raises(ValueError, match="compute more eigenpairs"):
        canonical_eigenvectors(lam, vec, mass3, keep=6)


def test_cubature_ranking_orders_ties_by_index():
    score = np.array([0.5, 1.0, 1.0 + 1e-12, -np.inf, 1.0 - 1e-12, 0.9])
    np.testing.assert_array_equal(_ranked(score)[:4], [1, 2, 4, 5])
    np.testing.assert_array_equal(_ranked(score[::-1].copy())[:4], [1, 3, 4, 0])


_BUILD = """
import numpy as np, sys
from softrom_gym.robots import cross
from softrom_gym.rom import build_subspace, train_cubature
robot = cross()
sub = build_subspace(robot, 12, cache=False)
rule = train_cubature(robot, sub, num_poses=40, cache=False)
np.savez(sys.argv[1], basis=sub.basis, elements=rule.elements, weights=rule.weights)
"""


def _openblas_kernels() -> bool:
    if platform.system() != "Linux" or platform.machine() != "x86_64":
        return False
    with open("/proc/cpuinfo") as f:
        flags = f.read()
    return " avx2" in flags and "openblas" in str(np.__config__.CONFIG).lower()


@pytest.mark.skipif(not _openblas_kernels(), reason="needs OpenBLAS on x86-64 with AVX2")
def test_the_same_model_from_two_blas_kernels(tmp_path):
    """OpenBLAS's Sandybridge and Haswell kernels round differently; before the canonical
    bases the cross (a symmetric body) got a B_r with flipped columns and another cubature rule."""
    out = {}
    for core in ("Sandybridge", "Haswell"):
        env = {**os.environ, "OPENBLAS_CORETYPE": core, "OMP_NUM_THREADS": "1"}
        path = tmp_path / f"{core}.npz"
        subprocess.run([sys.executable, "-c", _BUILD, str(path)], env=env, check=True)
        out[core] = np.load(path)
    a, b = out["Sandybridge"], out["Haswell"]
    np.testing.assert_allclose(a["basis"], b["basis"], atol=1e-9)
    np.testing.assert_array_equal(a["elements"], b["elements"])
    np.testing.assert_allclose(a["weights"], b["weights"], rtol=1e-6)


def _m_orthonormal(n, k, seed=0):
    rng = np.random.default_rng(seed)
    mass3 = rng.uniform(0.2, 5.0, n)  # far from uniform: the M inner product matters
    q, _ = np.linalg.qr(rng.standard_normal((n, k)))
    return mass3, q / np.sqrt(mass3)[:, None]


def test_eigenvalues_within_a_relative_gap_form_one_cluster():
    """rel_gap is relative: two eigenvalues of 1e4 that differ by 1e-7 of themselves (1e-3
    absolute) are one eigenspace, whose canonical basis does not depend on the basis the
    solver gave of it. An absolute gap of 1e-6 split them and passed every test."""
    mass3, vec = _m_orthonormal(12, 5)
    lam = np.array([1e4, 1e4 * (1 + 1e-7), 2e4, 3e4, 4e4])
    c, s = np.cos(0.3), np.sin(0.3)
    turned = vec.copy()
    turned[:, :2] = vec[:, :2] @ np.array([[c, -s], [s, c]])
    turned[:, 2] *= -1.0
    np.testing.assert_allclose(canonical_eigenvectors(lam, turned, mass3, keep=4),
                               canonical_eigenvectors(lam, vec, mass3, keep=4),
                               rtol=0, atol=1e-12)  # fmt: skip


def test_the_canonical_basis_is_the_mass_projection_of_the_reference_fields():
    """The documented choice, which every recorded B_r fingerprint depends on: a simple
    eigenvalue's eigenvector has w_1^T M u > 0, and a degenerate eigenspace's first column is
    the M-projection of w_1 onto it, M-normalised, w_1 being the first reference field
    whatever the cluster's size. Projecting with the Euclidean inner product, or reference
    fields whose first column changes with their count, still gave bases invariant to the
    solver's choices, and passed every test while changing every robot's modes."""
    n = 12
    mass3, vec = _m_orthonormal(n, 5, seed=1)
    lam = np.array([1e4, 2e4, 2e4, 3e4, 4e4])
    out = canonical_eigenvectors(lam, vec, mass3, keep=3)
    w = reference_fields(n, 1)[:, 0]
    np.testing.assert_array_equal(reference_fields(n, 3)[:, :1], reference_fields(n, 1))
    sign = np.sign(w @ (mass3 * vec[:, 0]))
    np.testing.assert_allclose(out[:, 0], sign * vec[:, 0], rtol=0, atol=1e-12)
    block = vec[:, 1:3]
    p = block @ (block.T @ (mass3 * w))
    p /= np.sqrt(p @ (mass3 * p))
    np.testing.assert_allclose(out[:, 1], p, rtol=0, atol=1e-12)
    gram = out.T @ (mass3[:, None] * out)
    np.testing.assert_allclose(gram, np.eye(3), atol=1e-12)
