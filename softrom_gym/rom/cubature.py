"""Optimized cubature for reduced elastic forces (An, Kim & James 2008).

The reduced force is a sum over all T tetrahedra, f_r(q) = sum_e g_e(q). Cubature replaces it
with a few elements and non-negative weights, f_r(q) ~ sum_{e in S} w_e g_e(q), trained by
greedy non-negative least squares on sampled poses, so a step costs O(|S|), not O(T).
"""

from __future__ import annotations

import hashlib
import os
import sys
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

import cpp_sim

from .._validate import integer, real
from ..robots import Robot
from .cache import cache_path, load_entry, mesh_key, save_entry
from .subspace import Subspace

__all__ = ["Cubature", "sample_poses", "train_cubature"]


@dataclass(frozen=True)
class Cubature:
    """A cubature rule: element indices, non-negative weights, and its training error."""

    elements: np.ndarray
    weights: np.ndarray
    training_error: float

    def __len__(self) -> int:
        return len(self.elements)


def sample_poses(
    robot: Robot, subspace: Subspace, count: int, rng: np.random.Generator
) -> np.ndarray:
    """Random elastic coordinates q_e = q[3:] (count, M + 3): rotations, then deformation.

    Deformation column j gets a Gaussian coefficient scaled by 1 / omega_j (stiffer columns
    move less, as they do in motion), scaled so the pose's largest node displacement is
    between 2% and 30% of the robot's size in its largest coordinate (up to ~43 % as a node's
    whole displacement). The linearised rotation gets a random axis and an angle whose
    largest coordinate displacement is up to 5% of the size (about 0.1 rad, the turns
    the benchmark robots make): larger training turns spend the rule's accuracy on the
    stretch a linearised turn carries, at the expense of deformation.
    """
    size = float(np.ptp(robot.nodes, axis=0).max())
    omega = np.asarray(subspace.frequencies, dtype=float)
    if not np.all(omega > 0):  # build_subspace never gives one (it refuses extra zero modes)
        raise ValueError("the subspace has a column of zero frequency: poses cannot be scaled")
    defo = subspace.deformation
    rot = subspace.rotations
    poses = np.empty((count, subspace.M + 3))
    poses[:, :3] = rng.standard_normal((count, 3))
    poses[:, 3:] = rng.standard_normal((count, subspace.M)) / omega
    turn = size * rng.uniform(0.0, 0.05, size=count)
    target = size * rng.uniform(0.02, 0.30, size=count)
    for p in range(count):
        poses[p, :3] *= turn[p] / np.abs(rot @ poses[p, :3]).max()
        poses[p, 3:] *= target[p] / np.abs(defo @ poses[p, 3:]).max()
    return poses


def _ranked(score: np.ndarray, rel_tol: float = 1e-7) -> np.ndarray:
    """Indices by descending score, each score rounded to a multiple of ``rel_tol`` times the
    largest, equal rounded scores ordered by index.

    A symmetric mesh has mirror-image elements with equal scores; ranking them by their last
    bits made the rule (and so the physics) depend on the machine's BLAS kernels.
    """
    top = np.max(score[np.isfinite(score)], initial=0.0)
    if not top > 0:
        return np.argsort(-score, kind="stable")
    level = np.where(np.isfinite(score), np.round(score / (rel_tol * top)), -np.inf)
    return np.argsort(-level, kind="stable")


def _greedy_nnls(
    a: np.ndarray, b: np.ndarray, tolerance: float, max_elements: int, verbose: bool
) -> tuple[np.ndarray, np.ndarray, float]:
    norms = np.linalg.norm(a, axis=0)
    norms[norms == 0] = np.inf
    bnorm = np.linalg.norm(b)
    selected: list[int] = []
    weights = np.zeros(0)
    residual = b.copy()
    err = 1.0
    batch = 4  # candidates added per round; NNLS then prunes the useless ones
    # A round whose picks NNLS all prunes leaves the set as it was, and the next round picks
    # them again: at a tolerance near round-off (1e-16), with duplicated elements, training
    # never ended (a review, session 54). Such a round stops it, and so does a round cap.
    for _ in range(20 * max_elements):
        if not (err > tolerance and len(selected) < max_elements):
            break
        before = list(selected)  # (selected grows in place below)
        score = (a.T @ residual) / norms
        score[selected] = -np.inf
        room = max_elements - len(selected)  # NNLS only prunes: never pick past the cap
        picks = [int(i) for i in _ranked(score)[: min(batch, room)] if score[i] > 0]
        if not picks:
            break
        selected += picks
        weights, _ = nnls(a[:, selected], b, maxiter=50 * len(selected))
        keep = weights > 0
        selected = [s for s, k in zip(selected, keep, strict=True) if k]
        weights = weights[keep]
        residual = b - a[:, selected] @ weights
        err = float(np.linalg.norm(residual) / bnorm)
        if selected == before:
            break  # (no candidate can improve the fit: the training error is final)
        if verbose and len(selected) % 20 < batch:
            print(f"softrom_gym:   {len(selected)} elements, training error {err:.4f} "
                  f"(target {tolerance:g})", file=sys.stderr, flush=True)  # fmt: skip
    return np.array(selected, dtype=np.int64), weights, err


def _entry_problem(entry: dict[str, np.ndarray], num_tets: int) -> str | None:
    """What makes a cached rule unusable for a mesh of ``num_tets`` elements, or None."""
    if not {"elements", "weights", "training_error"} <= entry.keys():
        return "missing arrays"
    elements, weights = entry["elements"], entry["weights"]
    if elements.ndim != 1 or elements.dtype.kind not in "iu" or weights.shape != elements.shape:
        return "elements and weights are not matching index and weight vectors"
    if elements.size and not (elements.min() >= 0 and elements.max() < num_tets):
        return f"an element index outside [0, {num_tets})"
    if not (np.isfinite(weights).all() and np.all(weights >= 0)):
        return "a negative or non-finite weight"
    return None


def train_cubature(
    robot: Robot,
    subspace: Subspace,
    *,
    num_poses: int = 100,
    tolerance: float = 0.005,
    max_elements: int | None = None,
    seed: int = 0,
    cache: bool | str | os.PathLike = True,
    verbose: bool = False,
) -> Cubature:
    """Train a cubature rule for the reduced elastic force of ``subspace``.

    Parameters
    ----------
    robot : Robot
        The robot whose elastic forces the rule approximates.
    subspace : Subspace
        Its B_r (:func:`~softrom_gym.rom.build_subspace`): the rule fits B_r^T f(X + B_r q).
    num_poses : int
        Training poses (see :func:`sample_poses`).
    tolerance : float
        Stop when the relative force error over all training poses is below this.
    max_elements : int, optional
        Cap on the rule's size (default ``min(T, 25 M)``).
    seed : int
        Seed of the pose sampler; the rule is deterministic for a given seed.
    cache : bool or path
        As in :func:`~softrom_gym.rom.build_subspace`.
    verbose : bool
        Say on stderr what is being computed and how long it took (nothing when the rule
        comes from the cache).
    """
    # A bool is an int to Python: seed=True silently seeded 1, num_poses=True sampled 1 pose.
    for name, value, low in (("num_poses", num_poses, 1), ("seed", seed, 0)):
        if integer(name, value) < low:
            raise ValueError(f"{name} must be >= {low}, got {value}")
    tolerance = real("tolerance", tolerance)
    if not 0 < tolerance < 1:
        raise ValueError(f"tolerance must be in (0, 1), got {tolerance}")
    if max_elements is None:
        max_elements = min(robot.num_tets, 25 * subspace.M)
    elif integer("max_elements", max_elements) < 1:
        raise ValueError(f"max_elements must be >= 1, got {max_elements}")
    # The poses are scaled by the subspace's frequencies, so the rule depends on them as
    # well as on the basis (they differ for a hand-built Subspace).
    digest = hashlib.sha256(np.ascontiguousarray(subspace.basis).tobytes())
    digest.update(np.ascontiguousarray(subspace.frequencies, dtype=float).tobytes())
    basis_hash = digest.hexdigest()
    key = mesh_key(robot, basis_hash, num_poses, tolerance, max_elements, seed)
    path = cache_path(cache, f"cubature-{key}.npz")
    entry = load_entry(path, lambda e: _entry_problem(e, robot.num_tets))
    if entry is not None:
        return Cubature(entry["elements"], entry["weights"], float(entry["training_error"]))
    if verbose:
        print(f"softrom_gym: training the cubature rule for {robot.name} ({num_poses} poses, "
              f"at most {max_elements} of {robot.num_tets} elements); it is cached after this "
              "first time", file=sys.stderr, flush=True)  # fmt: skip
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    poses = sample_poses(robot, subspace, num_poses, rng)
    fem = robot.fem_model()
    g = cpp_sim.reduced_element_forces(fem, subspace.elastic, poses)  # (P, T, M + 3)
    b = g.sum(axis=1)  # (P, M + 3)
    # Each pose counts equally, whatever its force magnitude.
    scale = 1.0 / np.maximum(np.linalg.norm(b, axis=1), 1e-300)
    a = (g * scale[:, None, None]).transpose(0, 2, 1).reshape(-1, g.shape[1])
    elements, weights, err = _greedy_nnls(a, (b * scale[:, None]).ravel(), tolerance,
                                          max_elements, verbose)  # fmt: skip
    rule = Cubature(elements, weights, err)
    if verbose:
        print(
            f"softrom_gym: trained the cubature rule for {robot.name}: {len(rule)} of "
            f"{robot.num_tets} elements, training error {err:.4f}, "
            f"{time.perf_counter() - t0:.2f} s",
            file=sys.stderr,
            flush=True,
        )
    save_entry(path, elements=elements, weights=weights, training_error=err)
    return rule
