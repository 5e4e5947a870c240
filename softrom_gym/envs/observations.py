"""What :class:`~softrom_gym.envs.soft_robot_env.SoftRobotEnv` reports of a state: the
observation vector, the step info (Λ's terms, a warning for an inverted element or a turn past
what linearised rotations model), the rendered frame; and the action checked on its way in."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import cpp_sim

from .._validate import real_array
from ..robots import Robot

if TYPE_CHECKING:
    from ..rendering import SoftwareRenderer

__all__ = ["LINEARISED_TURN_LIMIT", "Observations", "orientation_rows"]

# B_r's rotations are linearised: a turn by theta is a rotation plus a stretch of
# sqrt(1 + theta^2) - 1 (~theta^2 / 2), which the elastic forces resist as they would a real
# one, pulling the turn back with an angular acceleration that grows as theta^3. At 0.3 rad
# it is above g / L (L: the RMS radius) about the worst axis of every benchmark robot: cross
# 53, tripod 109, quadruped 164, beam 2,130 rad/s^2 (its roll), against g / L = 31-47. Past it
# the env says once that the motion is not the robot's. Full-bound open-loop actions turn the
# cross and beam walkers 0.32-0.42 rad in a 10 s episode, random ones 0.05-0.14 rad, MPC with
# the reproduction's best control spaces 0.12-0.31 rad (the swimmer's past it)
# (benchmarks/study_angular_momentum.py --linearised-turns).
LINEARISED_TURN_LIMIT = 0.3  # rad


def orientation_rows(nodes: np.ndarray, mass: np.ndarray, b_r: np.ndarray) -> np.ndarray:
    """The (3, M + 6) matrix taking q_r to the linearised orientation of a robot whose rest
    ``nodes`` (N, 3) have lumped ``mass`` (N,), simulated in B_r ``b_r`` (3N, M + 6)."""
    # Linearised orientation: the rotation vector theta whose infinitesimal rotation
    # A theta (A = [e_k x (X - c)]) best fits x - X in the mass norm,
    # theta = (A^T M A)^-1 A^T M B_r q_r; exact on B_r's rotation columns.
    r = nodes - mass @ nodes / mass.sum()
    a = np.column_stack([np.cross(e, r).ravel() for e in np.eye(3)])
    ma = a * np.repeat(mass, 3)[:, None]
    return np.linalg.solve(a.T @ ma, ma.T @ b_r)


class Observations:
    """The observation, info and frame of :class:`SoftRobotEnv`, mixed into it (which sets
    the attributes below)."""

    model: cpp_sim.ReducedModel
    robot: Robot
    task: str
    direction: np.ndarray
    action_bound: float
    action_space: spaces.Box
    render_mode: str | None
    # (3, M + 6): q_r -> orientation (rotation vector): linearised, or q[3:6] in the floating frame
    _orientation: np.ndarray
    _sqrt_m: float
    _com0: np.ndarray
    _state: cpp_sim.ReducedState
    _renderer: SoftwareRenderer | None
    # Set by the first inverted element this env reports (the warning is said once); a class
    # default, so an env pickled before it existed unpickles with it.
    _inversion_warned: bool = False
    _turn_warned: bool = False  # the same, for the first turn past LINEARISED_TURN_LIMIT

    def _obs(self, state: cpp_sim.ReducedState, com: np.ndarray | None = None) -> np.ndarray:
        """The observation of ``state``; ``com`` is its centre of mass when the caller has it."""
        q, qdot = state.q, state.qdot
        if com is None:
            com = self.model.com(q)
        return np.concatenate(
            [
                [com[2] - self.model.ground_height],
                qdot[:3] / self._sqrt_m,
                self._orientation @ q,
                self._orientation @ qdot,
                q[6:],
                qdot[6:],
            ]
        ).astype(np.float32)

    def _check_action(self, action: np.ndarray) -> np.ndarray:
        a = real_array("action", action)
        if a.shape != self.action_space.shape:
            raise ValueError(
                f"action has shape {a.shape}, expected {self.action_space.shape} "
                f"(control_dim = {self.action_space.shape[0]})"
            )
        if not np.isfinite(a).all():
            raise ValueError(f"action contains non-finite values: {a}")
        return a.clip(-self.action_bound, self.action_bound)

    def _info(
        self,
        state: cpp_sim.ReducedState,
        lateral: float,
        effort: float,
        diverged: bool,
        orientation: float | None = None,
        com: np.ndarray | None = None,
        converged: bool = True,
    ) -> dict[str, Any]:
        """The step info of ``state``; ``com`` is its centre of mass when the caller has it."""
        q = state.q
        if com is None:
            com = self.model.com(q)
        if orientation is None:
            orientation = float(np.linalg.norm(self._orientation @ q))
        volume_ratio = float(self.model.min_volume_ratio(q))
        if volume_ratio <= 0.0 and not self._inversion_warned:
            # Stable Neo-Hookean is defined for inverted elements and restores them, so the step
            # goes on, but while det F <= 0 the motion is not a physical one: say so once.
            self._inversion_warned = True
            warnings.warn(
                f"{self.robot.name}: a tetrahedron is inverted (det F = "
                f"{volume_ratio:.3g}): the material (youngs_modulus = "
                f"{self.robot.youngs_modulus:g} Pa) is too soft for actions up to "
                f"{self.action_bound:.3g}, and the motion is not physical while "
                'info["min_volume_ratio"] <= 0; raise youngs_modulus or lower action_scale',
                stacklevel=3,
            )
        if (orientation > LINEARISED_TURN_LIMIT and not self._turn_warned
                and self.model.frame == "linear"):  # fmt: skip
            self._turn_warned = True
            warnings.warn(
                f"{self.robot.name}: the robot has turned {orientation:.2f} rad from rest. "
                "Rotations are linearised, so a turn this large also stretches the body by "
                f"up to {100.0 * (np.sqrt(1.0 + orientation**2) - 1.0):.0f} %, which its "
                "elastic forces resist: past "
                f'{LINEARISED_TURN_LIMIT} rad (info["orientation"]) the motion is not the '
                "robot's (the README's 'Rotation is linearised')",
                stacklevel=3,
            )
        return {
            "distance": float(self.direction @ (com - self._com0)),
            "orientation": orientation,
            "lateral": lateral,
            "effort": effort,
            "com": com,
            "diverged": diverged,
            "converged": converged,
            "min_volume_ratio": volume_ratio,
            "contact": self.model.contact,
        }

    def render(self) -> np.ndarray | None:
        """An RGB frame (height, width, 3) when ``render_mode="rgb_array"``: the shaded robot
        surface on a ground grid, the task direction as a red arrow, the camera following the
        centre of mass. Software-rendered with numpy: no display or OpenGL needed."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self._renderer is None:
            from ..rendering import SoftwareRenderer, ground_cell

            size = float(np.ptp(self.robot.nodes, axis=0).max())
            # the ground scales with the robot as the camera does (a fixed 10 cm checker
            # was one grey line under a 6 mm robot, a moire under a 4 m one)
            self._renderer = SoftwareRenderer(distance=2.2 * size, cell=ground_cell(size))
        positions = self.model.positions(self._state.q)
        com = self.model.com(self._state.q)
        return self._renderer.render(
            positions, self.robot.surface_faces, target=com, arrow=self.direction,
            ground=self.task == "walk",
        )  # fmt: skip
