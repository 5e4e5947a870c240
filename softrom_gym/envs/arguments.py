"""The arguments of :class:`~softrom_gym.envs.soft_robot_env.SoftRobotEnv`, checked and turned
into what the env is built from: the robot, the task direction d, the control space B_c, the
dimensions (M, C) and the model's settings. Each function raises naming the value it refuses,
before anything slow (B_r and the cubature rule, minutes for a new robot) is built. Also the
spec of an env whose B_c was swapped (:func:`spec_with_control_basis`)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

import cpp_sim

from .._validate import real
from ..robots import ROBOTS, Robot, from_mesh

if TYPE_CHECKING:
    from gymnasium.envs.registration import EnvSpec

__all__ = [
    "check_on_ground",
    "check_sizes_and_scales",
    "checked_control_basis",
    "dimensions",
    "is_trimesh",
    "make_robot",
    "model_settings",
    "read_basis",
    "spec_with_control_basis",
    "task_direction",
]


def is_trimesh(value: object) -> bool:
    """Whether ``value`` is a ``trimesh.Trimesh`` or ``trimesh.Scene`` (a mesh to build a
    robot from; ``trimesh.load`` gives a scene for a .glb)."""
    # trimesh is imported on use (a second at start-up): a Trimesh exists only if it was.
    import sys

    module = sys.modules.get("trimesh")
    return module is not None and isinstance(value, (module.Trimesh, module.Scene))


def task_direction(direction: float | np.ndarray) -> np.ndarray:
    """The task direction d as a unit 3-vector in the ground plane, from an angle in radians
    (about z, from +x) or a non-zero 2-vector."""
    # (True was read as 1 rad, as every other numeric argument refuses a bool; as objects,
    # a bool array's entries are numpy bools)
    if any(isinstance(x, (bool, np.bool_)) for x in np.asarray(direction, dtype=object).ravel()):
        raise ValueError(
            f"direction must be an angle in radians or a non-zero 2-vector, got {direction!r}"
        )
    try:
        d = np.asarray(direction, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"direction must be an angle in radians or a non-zero 2-vector, got {direction!r}"
        ) from None
    if d.ndim == 0:
        if not np.isfinite(d):
            raise ValueError(f"direction angle must be finite, got {direction!r}")
        return np.array([np.cos(d), np.sin(d), 0.0])
    if d.shape != (2,) or not np.all(np.isfinite(d)) or not np.any(d):
        raise ValueError(
            f"direction must be an angle in radians or a non-zero 2-vector, got {direction!r}"
        )
    # scaled first: the norm of [1e-200, 1e-200] underflows to 0, that of [1e200, 1e200] to inf
    d = d / np.abs(d).max()
    return np.array([d[0], d[1], 0.0]) / np.linalg.norm(d)


def read_basis(b_c: npt.ArrayLike | os.PathLike | None) -> npt.ArrayLike | None:
    """B_c from a ``.npy`` file when given a path (as a str it keeps ``env.spec``
    JSON-serialisable, which an array does not; ``~`` is the home folder, as in a robot's
    mesh path), else ``b_c`` as given."""
    if not isinstance(b_c, (str, os.PathLike)):
        return b_c
    try:
        b = np.load(os.path.expanduser(os.fspath(b_c)), allow_pickle=False)
    except FileNotFoundError:
        raise FileNotFoundError(f"control_basis file {os.fspath(b_c)!r} does not exist") from None
    except (OSError, ValueError) as exc:
        raise ValueError(
            f"control_basis file {os.fspath(b_c)!r} is not a .npy array: {exc}"
        ) from None
    if not isinstance(b, np.ndarray):  # an .npz archive
        raise ValueError(f"control_basis file {os.fspath(b_c)!r} holds several arrays (.npz); "
                         "save B_c alone with np.save")  # fmt: skip
    return b


def dimensions(
    b_c: npt.ArrayLike | None, sim_dim: int | None, control_dim: int | None
) -> tuple[int, int]:
    """(M, C): as given, else the shape of B_c when one is given, else (20, 3)."""
    shape = np.shape(b_c) if b_c is not None else ()
    if len(shape) != 2:  # no basis, or one checked_control_basis will refuse with its shape
        shape = (20, 3)
    elif shape[0] < shape[1] and (sim_dim is None or control_dim is None):
        raise ValueError(f"control_basis has shape {shape}: B_c is M x C with M >= C, one "
                         "column per control direction (is it transposed?)")  # fmt: skip
    return (shape[0] if sim_dim is None else sim_dim,
            shape[1] if control_dim is None else control_dim)  # fmt: skip


def check_sizes_and_scales(
    sim_dim: int,
    control_dim: int,
    frame_skip: int,
    action_scale: float,
    reset_noise_scale: float,
    orthonormalize: bool,
    material: Mapping[str, float] | None,
) -> tuple[float, float]:
    """``action_scale`` and ``reset_noise_scale`` as floats, once M, C and ``frame_skip`` are
    positive integers with C <= M, the scales finite (the first > 0, the second >= 0),
    ``orthonormalize`` a bool and ``material`` a mapping or None."""
    for name, value in (("control_dim", control_dim), ("sim_dim", sim_dim),
                        ("frame_skip", frame_skip)):  # fmt: skip
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if control_dim > sim_dim:
        raise ValueError(f"control_dim = {control_dim} exceeds sim_dim = {sim_dim}")
    action_scale = real("action_scale", action_scale)
    reset_noise_scale = real("reset_noise_scale", reset_noise_scale)
    if not (np.isfinite(action_scale) and action_scale > 0):
        raise ValueError(f"action_scale must be > 0, got {action_scale}")
    if not (np.isfinite(reset_noise_scale) and reset_noise_scale >= 0):
        raise ValueError(f"reset_noise_scale must be finite and >= 0, got {reset_noise_scale}")
    if not isinstance(orthonormalize, (bool, np.bool_)):
        raise TypeError(f"orthonormalize must be True or False, got {orthonormalize!r}")
    if material is not None and not isinstance(material, Mapping):
        raise TypeError(
            "material must be a dict of youngs_modulus, poisson_ratio and density, got "
            f"{material!r}"
        )
    return action_scale, reset_noise_scale


def model_settings(
    task: str,
    dt: float,
    direction: np.ndarray,
    contact: str,
    friction: float,
    fluid_density: float,
    frame: str = "linear",
) -> dict[str, Any]:
    """The reduced model's settings for ``task`` (a swimmer has no contact and no gravity),
    each checked by the C++ core's config."""
    settings: dict[str, Any] = {"dt": dt, "direction": direction, "frame": frame}
    swim = {"fluid_density": fluid_density}
    walk = {"contact": contact, "friction": friction}
    if task == "swim":
        settings.update(contact="none", gravity=[0.0, 0.0, 0.0], **swim)
    else:
        settings.update(walk)
    # Checked before B_r and the cubature are built (minutes for a new robot), the other
    # task's settings too: they do nothing here (a swimmer has no ground, a walker no
    # fluid), but a bad value is named rather than silently accepted.
    check = cpp_sim.ReducedConfig()
    for name, value in {**settings, **walk, **swim}.items():
        setattr(check, name, value)
    return settings


def checked_control_basis(
    b_c: npt.ArrayLike | None, sim_dim: int, control_dim: int, orthonormalize: bool
) -> np.ndarray:
    """B_c as a float (M, C) matrix with orthonormal columns (the first C modes when None):
    a read-only array of its own.

    A matrix that is not orthonormal to 1e-8 is refused, or with ``orthonormalize`` replaced
    by the Q of its QR (each column keeping its orientation) when it has full rank.
    """
    # Checked here as well as in __init__: set_control_basis comes here alone, and a string
    # such as "no" would be truthy and orthonormalise silently.
    if not isinstance(orthonormalize, (bool, np.bool_)):
        raise TypeError(f"orthonormalize must be True or False, got {orthonormalize!r}")
    b = _checked_basis(b_c, sim_dim, control_dim, orthonormalize)
    # Never the caller's array (np.asarray does not copy a float64 one), and read-only: the
    # C++ model holds a copy, so a write into either would leave the env's B_c and the
    # model's apart, and a pickled or deep-copied env (rebuilt from the env's) unlike it.
    b = np.array(b, dtype=float, copy=True)
    b.flags.writeable = False
    return b


def spec_with_control_basis(
    spec: EnvSpec | None,
    given: npt.ArrayLike | os.PathLike,
    used: np.ndarray,
    orthonormalize: bool,
) -> EnvSpec | None:
    """A new ``spec`` whose kwargs make an env with the control space B_c ``used`` (None
    stays None), after a swap to ``given``: a path stays a path (the spec stays
    JSON-serialisable), with ``orthonormalize`` as given; an array is held as ``used`` (a
    copy), with ``orthonormalize=False``. ``spec`` itself is left as it was."""
    if spec is None:
        return None
    if isinstance(given, (str, os.PathLike)):
        kwargs: dict[str, Any] = {"control_basis": given, "orthonormalize": bool(orthonormalize)}
    else:
        kwargs = {"control_basis": used.copy(), "orthonormalize": False}
    return dataclasses.replace(spec, kwargs={**spec.kwargs, **kwargs})


def _checked_basis(
    b_c: npt.ArrayLike | None, sim_dim: int, control_dim: int, orthonormalize: bool
) -> np.ndarray:
    if b_c is None:
        return np.eye(sim_dim, control_dim)  # (not eye(M)[:, :C]: M may be too large, named later)
    raw = np.asarray(b_c)
    if np.iscomplexobj(raw):  # (float() would drop the imaginary part with a warning only)
        raise ValueError(f"control_basis must be real, got a {raw.dtype} matrix")
    b = np.asarray(raw, dtype=float)
    if b.shape != (sim_dim, control_dim):
        raise ValueError(
            f"control_basis has shape {b.shape}, expected (sim_dim, control_dim) = "
            f"({sim_dim}, {control_dim}): an M x C matrix, one column per control direction"
        )
    if not np.all(np.isfinite(b)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(b))[0])
        raise ValueError(f"control_basis contains non-finite values, e.g. {b[bad]} at {bad}")
    if orthonormalize:
        q, r = np.linalg.qr(b)
        sv = np.linalg.svd(b, compute_uv=False)
        if sv[-1] <= 1e-10 * sv[0]:
            raise ValueError(
                "control_basis is rank-deficient (singular values "
                f"{np.array2string(sv, precision=3)}); orthonormalize needs full rank"
            )
        return q * np.sign(np.diag(r))  # keep each column's orientation
    err = float(np.abs(b.T @ b - np.eye(control_dim)).max())
    if err > 1e-8:
        raise ValueError(
            f"control_basis is not orthonormal: max |B_c^T B_c - I| = {err:.3g} (tolerance "
            "1e-8); pass orthonormalize=True to orthonormalise a full-rank matrix"
        )
    return b


def make_robot(
    robot: str | os.PathLike | Robot | Any,  # (Any: a trimesh.Trimesh or Scene, imported on use)
    material: dict[str, float],
    resolution: int | None,
    scale: float | None,
) -> Robot:
    """The robot the env simulates: a name in :data:`~softrom_gym.robots.ROBOTS`, a mesh path,
    ``trimesh.Trimesh`` or ``Scene`` (meshed with ``from_mesh``), or a :class:`Robot` as
    given, with ``material`` (youngs_modulus, poisson_ratio, density), ``resolution`` and
    ``scale`` applied where they mean something and refused by name where they do not."""
    unknown = set(material) - {"youngs_modulus", "poisson_ratio", "density"}
    if unknown:
        raise ValueError(f"unknown material parameter(s) {sorted(unknown)}")
    kwargs: dict[str, Any] = dict(material)
    if resolution is not None:
        kwargs["resolution"] = resolution
    is_mesh = is_trimesh(robot) or (
        isinstance(robot, (str, os.PathLike)) and not (isinstance(robot, str) and robot in ROBOTS)
    )
    if scale is not None:
        if not is_mesh:
            raise ValueError(f"scale = {scale!r} applies to a mesh (a file path or a "
                             "trimesh.Trimesh), not to a named or meshed robot")  # fmt: skip
        kwargs["scale"] = scale
    if isinstance(robot, Robot):
        if resolution is not None:
            raise ValueError(
                f"resolution = {resolution} applies to a robot name or a mesh path, not to "
                "a Robot that is already meshed"
            )
        if kwargs:
            from dataclasses import replace

            return replace(robot, **kwargs)  # (here kwargs is the material alone)
        return robot
    if isinstance(robot, str) and robot in ROBOTS:
        return ROBOTS[robot](**kwargs)
    if is_trimesh(robot):
        return from_mesh(robot, **kwargs)
    if isinstance(robot, (str, os.PathLike)):
        path = os.path.expanduser(os.fspath(robot))
        if os.path.splitext(path)[1] or os.path.isdir(path):
            return from_mesh(path, **kwargs)  # (which names a missing file or a folder)
        if os.path.exists(path):
            raise ValueError(f"robot {os.fspath(robot)!r} is a file without an "
                             "extension: name it .stl, .obj, .ply, ... so its format "
                             "is known")  # fmt: skip
    raise ValueError(
        f"unknown robot {robot!r}; valid robots: {sorted(ROBOTS)}, a mesh file path "
        "(STL/OBJ/PLY), a trimesh.Trimesh or Scene, or a softrom_gym.robots.Robot"
    )


def check_on_ground(robot: Robot) -> None:
    """Refuse a walking robot whose lowest node is off the ground plane z = 0.

    A robot above it would fall for the first steps of every episode (the reward counting the
    landing), one below it start interpenetrating and be kicked out by the contact. Named
    robots and meshes (``from_mesh``) are placed on it; a :class:`Robot` built from nodes is
    taken as given, so it is checked here rather than moved: its coordinates are the user's.
    Round-off (a millionth of the robot's size) is on the ground.
    """
    z = float(robot.nodes[:, 2].min())
    size = float(np.ptp(robot.nodes, axis=0).max())
    if abs(z) > 1e-6 * size:
        where = "above" if z > 0 else "below"
        raise ValueError(
            f"robot {robot.name!r} does not rest on the ground: its lowest node is {abs(z):g} m "
            f"{where} z = 0, where a walking robot starts (it would "
            f"{'fall' if z > 0 else 'start inside the ground'}); move it there, e.g. "
            "dataclasses.replace(robot, nodes=robot.nodes - [0, 0, robot.nodes[:, 2].min()])"
        )
