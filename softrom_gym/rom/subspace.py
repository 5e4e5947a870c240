"""The simulation space B_r: exact rigid translations, linearised rotations, modes and modal
derivatives.

``build_subspace(robot, M)`` returns a :class:`Subspace` whose basis B_r has ``M + 6`` columns:

* columns 0..2: the three rigid translations, each ``e_k / sqrt(total mass)``, so the robot
  can travel arbitrarily far with no error;
* columns 3..5: the three infinitesimal rotations ``w x (X - c)`` about the rest centre of
  mass c, mass-orthonormalised (the robot can turn, rock and tip);
* columns 6..M+5: ``M`` deformation columns: the lowest free-vibration modes of
  ``K u = lambda M u`` at rest (rigid modes split off) followed by modal derivatives
  (Barbič & James 2005), mass-orthonormalised.

``M`` counts deformation coordinates only, so a control space B_c (M x C) acts on
deformation and can never push the centre of mass (the paper's f_r = B_c f_c).

Rotation is *linearised*: a turn by angle theta is represented as ``X + theta w x (X - c)``,
a true rotation to first order that also stretches the body by about theta^2 / 2 (0.5% at
0.1 rad, 4.5% at 0.3 rad). The elastic energy sees the rotation columns too, so the reduced
model is exactly the full-space model restricted to B_r (with all modes it reproduces full
space), and that stretch is resisted like any other: turning is free at small angles and
meets a restoring energy growing as E theta^4 beyond, sooner for stiffer and smaller bodies
(a 0.2 m block of E = 1 MPa spun at 0.5 rad/s stops near 0.07 rad; random actuation turns
the 50 kPa benchmark walkers and swimmer by 0.09-0.12 rad in 10 s). So robots rock, tip
and veer by small angles, which the task regulariser penalises anyway, but cannot turn
around or flip over: that needs the floating frame (``frame="floating"``,
docs/FLOATING_FRAME.md), which simulates the same B_r's deformation columns with an exact
rotation.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._validate import integer
from ..robots import Robot
from .cache import cache_path, load_entry, mesh_key, save_entry
from .eigen import (
    DENSE_LIMIT,
    canonical_eigenvectors,
    cluster_at_end,
    lowest_eigenpairs,
    reference_fields,
)

__all__ = ["Subspace", "build_subspace", "canonical_eigenvectors"]


@dataclass(frozen=True, eq=False)
class Subspace:
    """A mass-orthonormal reduced basis B_r (3N x (M + 6)), ``B_r^T M B_r = I``.

    Attributes
    ----------
    basis : (3N, M + 6) float64
        B_r; row ``3 i + k`` is node i, axis k. Columns 0..2 are rigid translations, 3..5
        linearised rotations about the centre of mass, 6.. deformation.
    frequencies : (M,) float64
        sqrt(u^T K u) of each deformation column (rad/s), a Rayleigh-quotient frequency.
    num_modes : int
        Number of linear vibration modes among the deformation columns.
    """

    basis: np.ndarray
    frequencies: np.ndarray
    num_modes: int

    @property
    def M(self) -> int:
        """Number of deformation coordinates."""
        return self.basis.shape[1] - 6

    @property
    def rotations(self) -> np.ndarray:
        """The linearised rotation columns of B_r, (3N, 3)."""
        return self.basis[:, 3:6]

    @property
    def deformation(self) -> np.ndarray:
        """The deformation columns of B_r, (3N, M)."""
        return self.basis[:, 6:]

    @property
    def elastic(self) -> np.ndarray:
        """The columns the elastic energy sees, rotations and deformation: (3N, M + 3)."""
        return self.basis[:, 3:]

    def signature(self) -> np.ndarray:
        """B_r^T w (M + 6,) for a fixed generic field w: a fingerprint of what each reduced
        coordinate means. Two bases whose columns differ (a flipped or rotated mode, another
        mesh or material) differ here well above round-off; RBBO runs record it, so that a
        B_c is never replayed in a simulation space other than the one it was found in."""
        return self.basis.T @ reference_fields(self.basis.shape[0], 1)[:, 0]


def _mass_gram_schmidt(
    columns: list[np.ndarray], mass3: np.ndarray, start: np.ndarray, tol: float = 1e-6
) -> list[np.ndarray]:
    """Mass-orthonormalise ``columns`` against ``start`` and each other, dropping dependents."""
    basis = [c for c in start.T]
    out = []
    for c in columns:
        v = c.copy()
        norm0 = np.sqrt(v @ (mass3 * v))
        if norm0 == 0:
            continue
        for _ in range(2):  # twice is enough (Kahan)
            for b in basis:
                v -= (b @ (mass3 * v)) * b
        norm = np.sqrt(v @ (mass3 * v))
        if norm < tol * norm0:
            continue
        v /= norm
        basis.append(v)
        out.append(v)
    return out


def _rigid_modes(nodes: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Mass-orthonormal rigid translations (3) and linearised rotations (3), (3N, 6)."""
    n = len(nodes)
    com = mass @ nodes / mass.sum()
    r = nodes - com
    cols = []
    for k in range(3):
        t = np.zeros((n, 3))
        t[:, k] = 1.0
        cols.append(t.ravel())
    for k in range(3):
        axis = np.zeros(3)
        axis[k] = 1.0
        cols.append(np.cross(axis, r).ravel())
    mass3 = np.repeat(mass, 3)
    return np.column_stack(_mass_gram_schmidt(cols, mass3, np.zeros((3 * n, 0))))


def _modal_derivatives(
    fem, nodes: np.ndarray, modes: np.ndarray, pairs: list[tuple[int, int]], k0, rigid, mass3
) -> list[np.ndarray]:
    """Barbič & James modal derivatives: K Phi_ij = -(dK/dq_i) psi_j, by central differences
    of the stiffness along psi_i; the rigid null space of K is regularised out."""
    # K + M R R^T M is non-singular and agrees with K on the deformation complement.
    mr = mass3[:, None] * rigid
    a = (k0 + sp.csr_matrix(mr @ mr.T)).tocsc() if len(nodes) < 400 else None
    solve = (
        spla.splu(a).solve
        if a is not None
        else _woodbury_solver(k0, mr)  # avoids a dense (3N)^2 matrix on big meshes
    )
    scale = float(np.ptp(nodes, axis=0).max())  # the body's size, wherever it sits
    derivs = []
    dk_cache: dict[int, sp.spmatrix] = {}
    for i, j in pairs:
        if i not in dk_cache:
            u = modes[:, i].reshape(-1, 3)
            eps = 1e-4 * scale / np.abs(u).max()
            kp = fem.stiffness(nodes + eps * u)
            km = fem.stiffness(nodes - eps * u)
            dk_cache[i] = (kp - km) / (2 * eps)
        rhs = -(dk_cache[i] @ modes[:, j])
        # The force has no net force, and a net torque only at second order (dK/du_i u_j of
        # the rest state is not exactly torque-free): projected out, so phi is solvable with
        # K singular on the rigid motions.
        rhs -= mr @ (rigid.T @ rhs)
        phi = solve(rhs)
        phi -= rigid @ (mr.T @ phi)
        derivs.append(phi)
    return derivs


def _woodbury_solver(k0: sp.spmatrix, mr: np.ndarray):
    """Solve (K + U U^T) x = b with U = M R via a shifted sparse factorisation of K."""
    shift = 1e-8 * np.abs(k0.diagonal()).max()
    lu = spla.splu((k0 + shift * sp.identity(k0.shape[0])).tocsc(), permc_spec="MMD_AT_PLUS_A")
    ku = lu.solve(mr)
    cap = np.eye(mr.shape[1]) + mr.T @ ku

    def solve(b: np.ndarray) -> np.ndarray:
        kb = lu.solve(b)
        return kb - ku @ np.linalg.solve(cap, mr.T @ kb)

    return solve


def build_subspace(
    robot: Robot,
    M: int = 20,
    *,
    num_derivatives: int | None = None,
    cache: bool | str | os.PathLike = True,
    verbose: bool = False,
) -> Subspace:
    """Build the simulation space B_r of a robot (3N x (M + 6), mass-orthonormal).

    Parameters
    ----------
    robot : Robot
    M : int
        Deformation coordinates (>= 1). The basis has ``M + 6`` columns.
    num_derivatives : int, optional
        How many of the M columns are modal derivatives (default ``M // 3`` for M >= 6,
        else 0); the rest are the lowest linear vibration modes.
    cache : bool or path
        ``True`` caches under :func:`cache_dir`, a path caches there, ``False`` never caches.
    verbose : bool
        Say on stderr what is being computed and how long it took (nothing when B_r comes
        from the cache).
    """
    n = robot.num_nodes
    M = integer("M", M)  # (a numpy integer becomes an int: the cache key, and Subspace.M)
    max_m = 3 * n - 6
    if M < 1:
        raise ValueError(f"M must be >= 1 deformation mode, got {M}")
    if M > max_m:
        raise ValueError(
            f"M = {M} deformation modes requested, but the robot has only {max_m} "
            f"(3N - 6 with N = {n}); choose 1 <= M <= {max_m}"
        )
    if num_derivatives is None:
        num_derivatives = M // 3 if M >= 6 else 0
    else:  # 1.5 was a slice-index TypeError deep in the build, True silently one derivative
        num_derivatives = integer("num_derivatives", num_derivatives)
    if not 0 <= num_derivatives < M:
        raise ValueError(f"num_derivatives must be in [0, M), got {num_derivatives} for M = {M}")
    num_modes = M - num_derivatives

    path = cache_path(cache, f"subspace-{mesh_key(robot, M, num_derivatives)}.npz")
    entry = load_entry(path, lambda e: _entry_problem(e, 3 * n, M))
    if entry is not None:
        return Subspace(entry["basis"], entry["frequencies"], int(entry["num_modes"]))

    if verbose:
        print(f"softrom_gym: building B_r for {robot.name} (N = {n} nodes, M = {M}); it is "
              "cached after this first time", file=sys.stderr, flush=True)  # fmt: skip
    t0 = time.perf_counter()
    fem = robot.fem_model()
    mass3 = np.repeat(fem.mass, 3)
    k0 = fem.stiffness(robot.nodes)
    rigid = _rigid_modes(robot.nodes, fem.mass)

    # Shift-invert Lanczos around a small negative shift finds the smallest eigenpairs;
    # the six rigid modes sit at lambda ~ 0 and are split off below.
    # One eigenpair beyond those kept shows whether the cut splits a degenerate eigenspace;
    # only then are more computed, to see it whole (canonical_eigenvectors).
    scale = float(np.mean(k0.diagonal() / mass3))
    # The dense solver returns every pair; ARPACK (larger meshes) at most 3N - 1 of them.
    most = 3 * n if 3 * n <= DENSE_LIMIT else 3 * n - 1
    if num_modes + 6 > most:
        raise ValueError(
            f"M = {M} with num_derivatives = {num_derivatives} needs {num_modes} vibration "
            f"modes, more than the {most - 6} this {n}-node mesh's eigensolver can return"
        )
    want = min(num_modes + 7, most)
    lam, vec = lowest_eigenpairs(k0, mass3, want, scale)
    while want < most and cluster_at_end(lam[6 + num_modes - 1 :]):
        want = min(want + 8, most)
        lam, vec = lowest_eigenpairs(k0, mass3, want, scale)
    rigid_like = lam < 1e-8 * scale
    if rigid_like.sum() > 6:
        raise ValueError(
            f"the robot's stiffness has {int(rigid_like.sum())} zero modes (6 expected): the "
            "mesh is probably disconnected"
        )
    lam_modes, modes = lam[6:], vec[:, 6:]
    # Remove any rigid component that leaked in (degenerate lambda ~ 0 subspace).
    modes = modes - rigid @ ((mass3[:, None] * rigid).T @ modes)
    modes = canonical_eigenvectors(lam_modes, modes, mass3, keep=num_modes)

    columns = list(modes.T)
    if num_derivatives:
        # Pairs of low modes in order of their contribution, as Barbič & James weight them:
        # lambda_1 / (lambda_i lambda_j) -- lowest products first.
        base = min(num_modes, max(2, int(np.ceil(np.sqrt(2 * num_derivatives))) + 1))
        lam_def = lam[6 : 6 + base]
        # Products equal up to round-off (degenerate eigenvalues of a symmetric body) are
        # tied and ordered by (i, j), so the order does not depend on the machine's last bits.
        unit = lam_def[0] * lam_def[0]
        pairs = sorted(
            ((i, j) for i in range(base) for j in range(i, base)),
            key=lambda p: (float(np.round(lam_def[p[0]] * lam_def[p[1]] / unit, 6)), p),
        )[: 2 * num_derivatives]
        columns += _modal_derivatives(fem, robot.nodes, modes, pairs, k0, rigid, mass3)

    deformation = _mass_gram_schmidt(columns, mass3, rigid)[:M]
    if len(deformation) < M:
        raise ValueError(
            f"could only build {len(deformation)} independent deformation columns, M = {M}"
        )
    # No sign rule here: the modes are canonical (canonical_eigenvectors), and the modal
    # derivatives and the Gram-Schmidt are fixed functions of them.
    basis = np.column_stack([rigid, *deformation])
    defo = basis[:, 6:]
    freq = np.sqrt(np.maximum(np.einsum("ij,ij->j", defo, k0 @ defo), 0.0))
    sub = Subspace(basis, freq, num_modes)
    if verbose:
        print(
            f"softrom_gym: built B_r for {robot.name}: N = {n}, M = {M} ({num_modes} modes + "
            f"{num_derivatives} derivatives) in {time.perf_counter() - t0:.2f} s",
            file=sys.stderr,
            flush=True,
        )
    save_entry(path, basis=basis, frequencies=freq, num_modes=num_modes)
    return sub


def _entry_problem(entry: dict[str, np.ndarray], rows: int, M: int) -> str | None:
    """What makes a cached subspace unusable for a 3N = ``rows``, M-column request, or None."""
    shapes = {"basis": (rows, M + 6), "frequencies": (M,), "num_modes": ()}
    for key, shape in shapes.items():
        if key not in entry:
            return f"no {key!r} array"
        if entry[key].shape != shape or not np.isfinite(entry[key]).all():
            return f"{key!r} is not a finite {shape} array"
    return None
