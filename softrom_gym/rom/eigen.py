"""Generalised eigenpairs K u = lambda M u of a robot at rest, the lowest ones, in a basis that
does not depend on the eigensolver's arbitrary choices (sign, and the basis of a degenerate
eigenspace), so the same robot gets the same vibration modes on every machine."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = [
    "DENSE_LIMIT",
    "canonical_eigenvectors",
    "cluster_at_end",
    "dense_eigh",
    "lowest_eigenpairs",
    "reference_fields",
]


def reference_fields(size: int, count: int) -> np.ndarray:
    """``count`` fixed generic displacement fields (size, count), the same on every machine:
    centred uniform doubles from PCG64 with a fixed seed (a stream NumPy keeps stable)."""
    rng = np.random.Generator(np.random.PCG64(20261202))
    return rng.random((count, size)).T - 0.5


def canonical_eigenvectors(
    lam: np.ndarray, vec: np.ndarray, mass3: np.ndarray, keep: int, rel_gap: float = 1e-6
) -> np.ndarray:
    """The first ``keep`` generalised eigenvectors (columns of ``vec``, ascending ``lam``) in a
    basis that does not depend on the eigensolver's arbitrary choices.

    An eigensolver returns each eigenvector up to sign, and any M-orthonormal basis of a
    degenerate eigenspace; which one depends on the last bits of its arithmetic, so the same
    robot built on two machines (two BLAS kernels) could get bases with flipped or rotated
    columns, and a control space B_c found on one would mean another actuation on the other.
    Here eigenvalues within ``rel_gap`` (relative) of each other form a cluster, and each
    cluster's span gets the basis obtained by M-projecting fixed generic fields w_1, ..., w_d
    (:func:`reference_fields`) on it and M-orthonormalising them in order: for a simple
    eigenvalue, the eigenvector whose sign makes w^T M u > 0. Where the cut at ``keep``
    falls inside a cluster, the kept columns are the first of its canonical basis (the part of
    the eigenspace the fields w_1, w_2, ... reach first): an arbitrary choice, but the same on
    every machine. Raises ValueError when that cluster runs to the last eigenpair given (its
    full extent is unknown: compute more eigenpairs).
    """
    lam = np.asarray(lam, dtype=float)
    out = np.empty((vec.shape[0], keep))
    start = 0
    while start < keep:
        stop = start + 1
        while stop < len(lam) and abs(lam[stop] - lam[stop - 1]) <= rel_gap * abs(lam[stop]):
            stop += 1
        if start < keep < stop and stop == len(lam):
            raise ValueError(
                f"the {keep} kept vibration modes end inside a degenerate eigenspace that "
                f"reaches the last of the {len(lam)} eigenpairs computed (lambda = "
                f"{lam[start]:.6g}): compute more eigenpairs, or choose another M"
            )
        block = vec[:, start:stop]
        fields = reference_fields(vec.shape[0], stop - start)
        # Coefficients of each field's M-projection on the cluster, then Gram-Schmidt (QR)
        # in coefficient space: the block is M-orthonormal, so this is Gram-Schmidt in M.
        coeffs = block.T @ (mass3[:, None] * fields)
        q, r = np.linalg.qr(coeffs)
        q = q * np.where(np.diag(r) < 0, -1.0, 1.0)  # positive projections
        out[:, start : min(stop, keep)] = (block @ q)[:, : min(stop, keep) - start]
        start = stop
    return out


DENSE_LIMIT = 600  # 3N up to which the generalised eigenproblem is solved densely


def lowest_eigenpairs(k0: sp.spmatrix, mass3: np.ndarray, want: int, scale: float
                       ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The ``want`` lowest eigenpairs of K u = lambda M u, ascending."""
    n3 = len(mass3)
    if n3 <= DENSE_LIMIT:
        lam, vec = dense_eigh(k0, mass3)
        return lam[:want], vec[:, :want]
    lam, vec = spla.eigsh(
        k0,
        k=want,
        M=sp.diags(mass3),
        sigma=-1e-6 * scale,
        which="LM",
        tol=1e-10,
        v0=np.ones(n3),  # a fixed start vector keeps the result reproducible
    )
    order = np.argsort(lam)
    return lam[order], vec[:, order]


def cluster_at_end(lam: np.ndarray, rel_gap: float = 1e-6) -> bool:
    """Whether the eigenvalues from the first to the last are all one cluster (a degenerate
    eigenspace that the computed pairs may not cover)."""
    return len(lam) > 1 and bool(np.all(np.abs(np.diff(lam)) <= rel_gap * np.abs(lam[1:])))


def dense_eigh(k0: sp.spmatrix, mass3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Generalised eigenpairs of a small system by a dense solver (all of them)."""
    from scipy.linalg import eigh

    minv = 1.0 / np.sqrt(mass3)
    a = minv[:, None] * k0.toarray() * minv[None, :]
    lam, w = eigh(a)
    return lam, minv[:, None] * w
