"""Points of the Grassmannian Gr(M, C) and the extrinsic (projection) distance between them.

A control space B_c is an M x C matrix with orthonormal columns; only its column span matters
to RBBO, i.e. the point B_c B_c^T of Gr(M, C) (the paper's Sec. "Bilevel Control-Space
Optimization"). Following the paper (and Lin et al. 2019), two subspaces are compared by the
Frobenius distance of their orthogonal projectors,

    d(B_i, B_j) = ||B_i B_i^T - B_j B_j^T||_F,   d^2 = 2 C - 2 ||B_i^T B_j||_F^2,

which is invariant under B -> B Q for any orthogonal C x C matrix Q. All pairs' distances are
one matrix product of the flattened projectors vec(B B^T) (:func:`projection_sq_distances`);
:func:`projection_distance` forms the two projectors themselves. Bases travel through
scikit-learn as flat rows of M * C numbers (row-major, :func:`flatten`), because scikit-learn
needs a 2-D ``X``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "canonical",
    "dimension",
    "flatten",
    "identity_basis",
    "orthonormalize",
    "projection_distance",
    "projection_sq_distances",
    "projectors",
    "random_points",
    "unflatten",
    "validate_basis",
]

ORTHONORMAL_TOL = 1e-8


def _check_dims(sim_dim: int, control_dim: int) -> tuple[int, int]:
    for name, value in (("sim_dim", sim_dim), ("control_dim", control_dim)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if control_dim > sim_dim:
        raise ValueError(f"control_dim = {control_dim} exceeds sim_dim = {sim_dim}")
    return int(sim_dim), int(control_dim)


def dimension(sim_dim: int, control_dim: int) -> int:
    """Dimension C (M - C) of Gr(M, C) as a manifold."""
    m, c = _check_dims(sim_dim, control_dim)
    return c * (m - c)


def validate_basis(
    b_c: np.ndarray,
    sim_dim: int | None = None,
    control_dim: int | None = None,
    *,
    name: str = "B_c",
    tol: float = ORTHONORMAL_TOL,
) -> np.ndarray:
    """Return B_c as a float (M, C) array, or raise naming what is wrong with it.

    Parameters
    ----------
    b_c
        Candidate control basis B_c.
    sim_dim, control_dim
        Expected M and C (either may be None to accept any).
    name
        How error messages call the argument.
    tol
        Largest accepted entry of |B_c^T B_c - I|.
    """
    try:
        raw = np.asarray(b_c)
        b = None if np.iscomplexobj(raw) else np.asarray(b_c, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a real (M, C) array, got {type(b_c).__name__}") from exc
    if b is None:  # (float() would drop the imaginary part with a warning only)
        raise TypeError(f"{name} must be real, got a {raw.dtype} array")
    if b.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (M, C) array, got shape {b.shape}")
    m, c = b.shape
    if (sim_dim is not None and m != sim_dim) or (control_dim is not None and c != control_dim):
        raise ValueError(
            f"{name} has shape {b.shape}, expected (sim_dim, control_dim) = "
            f"({sim_dim if sim_dim is not None else 'M'}, "
            f"{control_dim if control_dim is not None else 'C'})"
        )
    _check_dims(m, c)
    if not np.all(np.isfinite(b)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(b))[0])
        raise ValueError(f"{name} contains non-finite values, e.g. {b[bad]} at {bad}")
    err = float(np.abs(b.T @ b - np.eye(c)).max())
    if err > tol:
        raise ValueError(
            f"{name} is not orthonormal: max |B_c^T B_c - I| = {err:.3g} (tolerance {tol:g})"
        )
    return b


def orthonormalize(a: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the column span of a full-rank M x C matrix (QR, R_ii > 0).

    Used to map an unconstrained M x C matrix (e.g. a CMA-ES sample) onto Gr(M, C).
    """
    a = np.asarray(a, dtype=float)
    # (C = 0 reached numpy's "zero-size array to reduction operation minimum")
    if a.ndim != 2 or not 1 <= a.shape[1] <= a.shape[0]:
        raise ValueError(f"orthonormalize needs an M x C matrix with 1 <= C <= M, got shape "
                         f"{a.shape}")  # fmt: skip
    if not np.all(np.isfinite(a)):
        raise ValueError("orthonormalize got non-finite values")
    q, r = np.linalg.qr(a)
    d = np.diag(r)
    if np.abs(d).min() <= 1e-12 * max(np.abs(d).max(), 1e-300):
        raise ValueError(f"orthonormalize needs a full-rank matrix; |diag R| = {np.abs(d)}")
    return q * np.sign(d)


# A row of B_c whose part outside the span of the earlier pivot rows is shorter than this is
# not a pivot. An absolute length: rows of an orthonormal B_c are at most 1 long. It keeps
# rounding (~1e-16) from making a pivot of a row that lies in that span; the price is that a
# pivot whose residual is just above it is normalised with a relative error up to ~1e-8.
_PIVOT_TOLERANCE = 1e-8


def canonical(b_c: np.ndarray) -> np.ndarray:
    """The canonical orthonormal representative of span(B_c): its reduced column-echelon form.

    The pivot rows p_1 < ... < p_C are found greedily: p_k is the first row of B_c that does
    not lie in the span of rows p_1 .. p_{k-1} (its residual after projecting them out is
    longer than ``1e-8``). With Q = [q_1 .. q_C] the Gram-Schmidt orthonormalisation of those
    rows, the representative is B_c Q: row p_k is zero after column k and has q_k's positive
    length at column k. Replacing B_c by B_c U (U orthogonal) rotates every row by U^T, which
    keeps the residual lengths (so the pivots) and turns Q into U^T Q, so B_c U U^T Q = B_c Q:
    the result depends on span(B_c) only, for every subspace, the singular cases included.

    In floating point, for an orthonormal B_c, B_c and B_c U give results within about
    1e-16 / rho of each other, rho the shortest residual of a pivot other than the last
    (~1e-15 where the pivots' residuals are of order 1; up to ~1e-8 where one is near the
    threshold, and a residual within rounding of it can pick another pivot). A B_c that
    :func:`validate_basis` accepts with an orthonormality error e gives results within about
    e of those of its exact span, and as orthonormal as B_c is. When the first C rows are the
    pivots (almost every subspace) this is the lower-trapezoidal representative with a
    positive diagonal. The identity basis (the first C modes) is its own representative, and
    so is any selection of C modes in ascending order, e.g. the columns e_4, e_5, e_6 of I_M.
    """
    b = validate_basis(b_c)
    m, c = b.shape
    q = np.zeros((c, c))
    found = 0
    for row in b:
        if found == c:
            break
        residual = row.copy()
        for _ in range(2):  # Gram-Schmidt twice: orthogonal to working precision
            residual -= q[:, :found] @ (q[:, :found].T @ residual)
        length = np.linalg.norm(residual)
        if length > _PIVOT_TOLERANCE:
            q[:, found] = residual / length
            found += 1
    if found < c:  # unreachable for an orthonormal B_c (rank C); kept as a guard
        raise ValueError(f"B_c of shape {(m, c)} has rank below {c}")
    return b @ q


def identity_basis(sim_dim: int, control_dim: int) -> np.ndarray:
    """The identity baseline B_c = first C columns of I_M (the C most salient modes of B_r)."""
    m, c = _check_dims(sim_dim, control_dim)
    return np.eye(m)[:, :c]


def random_points(
    sim_dim: int, control_dim: int, n: int | None = None, rng: np.random.Generator | None = None
) -> np.ndarray:
    """Points of Gr(M, C) drawn from the uniform (Haar) distribution.

    Returns an (M, C) basis when ``n`` is None, else an (n, M, C) stack. QR of a Gaussian
    matrix with the signs of diag(R) fixed is Haar-distributed on the Stiefel manifold, whose
    span is uniform on the Grassmannian.
    """
    m, c = _check_dims(sim_dim, control_dim)
    rng = np.random.default_rng(rng)
    if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0):
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    k = 1 if n is None else int(n)
    g = rng.standard_normal((k, m, c))
    q, r = np.linalg.qr(g)
    signs = np.sign(np.diagonal(r, axis1=1, axis2=2))
    signs[signs == 0] = 1.0
    q = q * signs[:, None, :]
    return q[0] if n is None else q


def flatten(bases: np.ndarray) -> np.ndarray:
    """(n, M, C) or (M, C) bases -> (n, M * C) rows (row-major), scikit-learn's ``X``."""
    b = np.asarray(bases, dtype=float)
    if b.ndim == 2:
        b = b[None]
    if b.ndim != 3:
        raise ValueError(f"bases must have shape (n, M, C) or (M, C), got {b.shape}")
    return b.reshape(b.shape[0], b.shape[1] * b.shape[2])  # (-1 is ambiguous when n = 0)


def unflatten(x: np.ndarray, sim_dim: int, control_dim: int) -> np.ndarray:
    """(n, >= M * C) rows -> (n, M, C) bases; columns past M * C (e.g. fidelity) are ignored."""
    m, c = _check_dims(sim_dim, control_dim)
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] < m * c:
        raise ValueError(
            f"X must have shape (n, >= M * C) = (n, >= {m * c}) for M = {m}, C = {c}, got {x.shape}"
        )
    return x[:, : m * c].reshape(-1, m, c)


def projectors(bases: np.ndarray) -> np.ndarray:
    """Flattened projectors vec(B B^T), shape (n, M * M), for a stack of (n, M, C) bases.

    With them ||B_i^T B_j||_F^2 = <vec(P_i), vec(P_j)>, so all pairwise distances are one
    matrix product (cheaper than pairwise C x C products once n is in the hundreds).
    """
    b = np.asarray(bases, dtype=float)
    if b.ndim == 2:
        b = b[None]
    p = np.einsum("nmc,nkc->nmk", b, b)
    return p.reshape(b.shape[0], -1)


def projection_sq_distances(
    bases_a: np.ndarray, bases_b: np.ndarray | None = None, *, control_dim: int | None = None
) -> np.ndarray:
    """Pairwise squared distances 2 C - 2 ||B_i^T B_j||_F^2 between two stacks of bases.

    Inputs are (n, M, C) stacks of orthonormal bases (not validated: this is the hot path);
    the result is (n_a, n_b), clipped at 0 against round-off.
    """
    a = np.asarray(bases_a, dtype=float)
    b = a if bases_b is None else np.asarray(bases_b, dtype=float)
    c = a.shape[-1] if control_dim is None else control_dim
    overlap = projectors(a) @ projectors(b).T
    return np.maximum(2.0 * c - 2.0 * overlap, 0.0)


def projection_distance(b_i: np.ndarray, b_j: np.ndarray) -> float:
    """The extrinsic distance ||B_i B_i^T - B_j B_j^T||_F between two subspaces.

    Both bases are validated (orthonormal, same shape). Computed from the projectors
    themselves: 2 C - 2 ||B_i^T B_j||_F^2 (:func:`projection_sq_distances`) cancels, and
    near-identical subspaces would come out ~1e-8 apart whatever their distance.
    """
    bi = validate_basis(b_i, name="B_i")
    bj = validate_basis(b_j, *bi.shape, name="B_j")
    return float(np.linalg.norm(bi @ bi.T - bj @ bj.T))
