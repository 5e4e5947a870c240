"""The model-predictive control API of :class:`~softrom_gym.envs.soft_robot_env.SoftRobotEnv`:
copying its state, and batched rollouts of control sequences from a state through the C++
core, with the per-step terms a planner scores."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

import cpp_sim

from .._validate import real_array
from ..robots import Robot

__all__ = ["PlanningAPI"]


class PlanningAPI:
    """The methods a planner uses, mixed into :class:`SoftRobotEnv` (which sets the
    attributes below): its state, a state's centre of mass, and :meth:`rollout`."""

    model: cpp_sim.ReducedModel
    robot: Robot
    direction: np.ndarray
    frame_skip: int
    action_bound: float
    action_space: spaces.Box
    _orientation: np.ndarray  # (3, M + 6): q_r -> orientation (rotation vector; observations.py)
    _state: cpp_sim.ReducedState

    def get_state(self) -> cpp_sim.ReducedState:
        """A copy of the full simulation state (q_r, qdot_r and contact warm-start)."""
        return self._state.copy()

    def set_state(self, state: cpp_sim.ReducedState) -> None:
        """Restore a state returned by :meth:`get_state`."""
        self._state = self._checked_state(state)

    def _checked_state(self, state: cpp_sim.ReducedState) -> cpp_sim.ReducedState:
        """A copy of ``state``, or an error naming why it is not a state of this env."""
        if not isinstance(state, cpp_sim.ReducedState):
            raise TypeError(f"state must be a ReducedState from get_state(), got {type(state)}")
        if state.q.shape != (self.model.dim,):
            raise ValueError(f"state has dimension {state.q.shape[0]}, expected {self.model.dim}")
        impulses = 3 * len(self.model.surface_nodes)  # (the next step's would refuse others)
        if state.impulses.shape != (impulses,):
            raise ValueError(f"state has {state.impulses.size} contact impulses, expected "
                             f"{impulses} (3 per surface node of this env's robot)")  # fmt: skip
        theta = np.asarray(state.q[3:6])
        angle = float(np.linalg.norm(theta))
        if str(self.model.frame) == "floating" and angle > np.pi:
            # The same rotation by its vector of angle <= pi, as every step keeps it: the
            # orientation observed and reported after reset(options={"state": ...}) read
            # 6.78 rad for 2 pi + 0.5 (0.5 from the first step on).
            q = np.array(state.q)
            q[3:6] = theta * (1.0 - 2.0 * np.pi * round(angle / (2.0 * np.pi)) / angle)
            return cpp_sim.ReducedState(q, np.array(state.qdot), np.array(state.impulses))
        return state.copy()

    def center_of_mass(self, state: cpp_sim.ReducedState | None = None) -> np.ndarray:
        """The centre of mass (3,) of ``state`` (default: the current state), m."""
        return self.model.com((self._state if state is None else state).q)

    @property
    def dt(self) -> float:
        """The control period: seconds of simulated time per env step (frame_skip * dt)."""
        return self.frame_skip * float(self.model.dt)

    @property
    def body_length(self) -> float:
        """The robot's largest horizontal extent at rest (m): the unit of locomotion distance."""
        return float(np.ptp(self.robot.nodes[:, :2], axis=0).max())

    def rollout(
        self,
        state: cpp_sim.ReducedState | list[cpp_sim.ReducedState],
        controls: np.ndarray,
        threads: int | None = None,
        observe: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """Run B control sequences of H env steps from ``state`` (batched, in C++).

        ``H`` calls of :meth:`step` with the same actions from the same state give the same
        rewards, terms and states to the last bit, whatever the actions' dtype: both paths
        clip f_c to the action bound and round it to the action space's float32.

        Parameters
        ----------
        state : ReducedState or list of B ReducedState
            One start state shared by all rollouts, or one per rollout.
        controls : (B, H, C) array
            f_c per env step (each held for ``frame_skip`` simulation steps), clipped to the
            action bound, then rounded to float32.
        threads : int, optional
            C++ worker threads (default: the CPUs this process may run on, its affinity).
            Results do not depend on it.
        observe : (P, M + 6) array, optional
            Linear observables of q_r to return after every env step (``observed``).

        Returns
        -------
        dict of arrays, per env step t = 1..H (the value at the end of step t):

        * ``rewards`` (B, H): the paper's R per step, d · (com_t - com_{t-1}) (m).
        * ``com`` (B, H, 3): centre of mass (m).
        * ``theta`` (B, H, 3): orientation, the rotation vector vs. rest (rad): linearised in
          the linear frame, the exact rotation with ``frame="floating"``; ``orientation``
          (B, H) is its norm.
        * ``lateral`` (B, H): |motion orthogonal to d in the ground plane| this step (m).
        * ``effort`` (B, H): |f_c / a|^2 (dimensionless).
        * ``lost`` (B, H): 1.0 on the step a rollout diverges and on every step after it,
          else 0.0. A diverged rollout keeps its last good state and earns zero reward from
          then on, so a planner must price these steps (a controller's Λ charges a weight in
          metres per lost step) or a blow-up would beat a trajectory that goes backwards.
        * ``diverged`` (B,): whether the rollout diverged.
        * ``converged`` (B,): whether every physics step of the rollout ended with its Newton
          iteration and contact solve at their tolerances (a step that does not is kept and
          goes on; see the README's penalty ground).
        * ``observed`` (B, H, P): ``observe @ q_r``, only when ``observe`` is given.
        * ``q``, ``qdot`` (B, M + 6), ``impulses``: the final states.
        """
        if not isinstance(state, (cpp_sim.ReducedState, list, tuple)):
            raise TypeError(f"state must be a ReducedState (env.get_state()) or a list of B "
                            f"of them, got {type(state).__name__}")  # fmt: skip
        u = real_array("controls", controls)
        if u.ndim != 3 or u.shape[2] != self.action_space.shape[0] or 0 in u.shape[:2]:
            raise ValueError(f"controls has shape {u.shape}, expected (B, H, "
                             f"{self.action_space.shape[0]}) with B, H >= 1")  # fmt: skip
        if not np.all(np.isfinite(u)):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(u))[0])
            raise ValueError(f"controls contains non-finite values, e.g. {u[bad]} at "
                             f"(rollout, step, dimension) = {bad}")  # fmt: skip
        # The same rounding as a float32 action through step(): a plan replays bit for bit.
        u = np.clip(u, -self.action_bound, self.action_bound).astype(np.float32).astype(float)
        b, h, _ = u.shape
        k = self.frame_skip
        n_orient = self._orientation.shape[0]
        rows = self._orientation
        if observe is not None:
            extra = np.asarray(observe, dtype=np.float64)
            if extra.ndim != 2 or extra.shape[1] != self.model.dim:
                raise ValueError(f"observe has shape {extra.shape}, expected (P, {self.model.dim})")
            if not np.all(np.isfinite(extra)):
                # named here: the core sees observe under the orientation rows, n_orient lower
                bad = tuple(int(i) for i in np.argwhere(~np.isfinite(extra))[0])
                raise ValueError(f"observe contains a non-finite value ({extra[bad]}) at {bad}")
            rows = np.vstack([rows, extra])
        out = self.model.rollout(state, np.repeat(u, k, axis=1), threads=threads, observe=rows)
        com = out["com"].reshape(b, h, k, 3)[:, :, -1]
        states = [state] if isinstance(state, cpp_sim.ReducedState) else list(state)
        start = np.array([self.model.com(s.q) for s in states]).reshape(-1, 1, 3)
        prev = np.concatenate([np.broadcast_to(start, (b, 1, 3)), com[:, :-1]], axis=1)
        delta = (com - prev)[..., :2]
        d2 = self.direction[:2]
        lateral = np.linalg.norm(delta - (delta @ d2)[..., None] * d2, axis=-1)
        observed = out["observed"].reshape(b, h, k, -1)[:, :, -1]
        theta = observed[..., :n_orient]
        rewards = out["rewards"].reshape(b, h, k)
        # A step is lost when any of its sub-steps is: the diverging one and every one after
        # it, as the core counts them (guessed from where the COM froze, a robot that was
        # at rest before it diverged had every step lost).
        lost = (np.arange(h)[None, :] >= (out["good_steps"] // k)[:, None]).astype(float)
        result = {
            "rewards": rewards.sum(axis=2),
            "com": com,
            "theta": theta,
            "orientation": np.linalg.norm(theta, axis=-1),
            "lateral": lateral,
            "effort": np.sum((u / self.action_bound) ** 2, axis=-1),
            "lost": lost,
            "diverged": out["diverged"],
            "converged": out["converged"],
            "q": out["q"],
            "qdot": out["qdot"],
            "impulses": out["impulses"],
        }
        if observe is not None:
            result["observed"] = observed[..., n_orient:]
        return result

    def _step_once(self, f_c: np.ndarray) -> tuple[cpp_sim.ReducedState, dict[str, Any]]:
        """One env step from the current state with ``f_c`` (C,), already checked and clipped:
        :meth:`rollout` for B = H = 1 without its checks and batch bookkeeping, the per-step
        path ``step`` takes millions of times under RL. Returns the new state and the terms
        ``step`` reports, each computed as ``rollout`` computes it (the same numpy operations
        on arrays of the same layout, so a plan replays through ``step`` to the last bit)."""
        # rollout()'s rounding of a control (its clip is done: f_c is within the bound)
        u = f_c.astype(np.float32).astype(float)
        k = self.frame_skip
        state = self._state
        out = self.model.rollout(state, np.repeat(u[None, None, :], k, axis=1), threads=1,
                                 observe=self._orientation)  # fmt: skip
        # (1, 1, n) views, as rollout()'s (B, H, n) arrays: matmul and norm see one layout
        delta = (out["com"][:, -1:] - self.model.com(state.q))[..., :2]
        d2 = self.direction[:2]
        # sqrt(add.reduce(x * x)) and add.reduce: what np.linalg.norm(x, axis=-1) and np.sum
        # compute, without their Python layers
        off = delta - (delta @ d2)[..., None] * d2
        lateral = np.sqrt(np.add.reduce(off * off, axis=-1))
        theta = out["observed"][:, -1:]
        terms = {
            "reward": float(out["rewards"][0].sum()),
            "orientation": float(np.sqrt(np.add.reduce(theta * theta, axis=-1))[0, 0]),
            "lateral": float(lateral[0, 0]),
            "effort": float(np.add.reduce((u / self.action_bound) ** 2, axis=-1)),
            "diverged": bool(out["diverged"][0]),
            "converged": bool(out["converged"][0]),
        }
        new = cpp_sim.ReducedState(out["q"][0], out["qdot"][0], out["impulses"][0])
        return new, terms

    def final_states(self, result: Mapping[str, np.ndarray]) -> list[cpp_sim.ReducedState]:
        """The B final states of a :meth:`rollout` result, as states to start from again.

        ``rollout`` returns them as arrays (``q``, ``qdot``, ``impulses``); a planner that
        continues rollouts from where others ended (multiple shooting, a tree of plans, a
        forward pass in segments) passes these to ``rollout`` or ``set_state``. Each is what
        :meth:`get_state` would return after the same steps, the contact impulses that
        warm-start the next step included, so continuing from it matches one longer rollout to
        the last bit.
        """
        try:
            q, qdot, impulses = (np.asarray(result[key]) for key in ("q", "qdot", "impulses"))
        except (KeyError, TypeError):
            raise TypeError("result must be the dict rollout() returned, with its final states "
                            "'q', 'qdot' and 'impulses'") from None  # fmt: skip
        dim = self.model.dim
        if q.ndim != 2 or q.shape[1] != dim or qdot.shape != q.shape or len(impulses) != len(q):
            raise ValueError(
                f"result's final states have shapes q {q.shape}, qdot {qdot.shape}, impulses "
                f"{impulses.shape}: expected (B, {dim}) each and B rows of impulses, as this "
                "env's rollout() returns"
            )
        return [cpp_sim.ReducedState(q[i], qdot[i], impulses[i]) for i in range(len(q))]
