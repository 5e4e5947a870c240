"""``SoftRobotEnv``: a soft robot walking or swimming through its control space B_c."""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import cpp_sim

from .._validate import real, real_array
from ..robots import Robot
from ..rom import build_reduced_model, build_subspace
from .arguments import (
    check_on_ground,
    checked_control_basis,
    dimensions,
    make_robot,
    read_basis,
    spec_with_control_basis,
    task_direction,
)

if TYPE_CHECKING:
    from ..rendering import SoftwareRenderer

__all__ = ["TASKS", "SoftRobotEnv"]

TASKS = ("walk", "swim")
G = 9.81


def _first_frozen_substep(rewards: np.ndarray, com: np.ndarray) -> int:
    """The sub-step at which a diverged rollout froze: from the diverging step on, the C++
    core keeps the last good state (the COM stops, bit for bit) and pays zero reward."""
    frozen = (rewards == 0.0) & np.all(com == com[-1], axis=1)
    moving = np.flatnonzero(~frozen)
    return int(moving[-1]) + 1 if moving.size else 0


class SoftRobotEnv(gym.Env):
    r"""A finite-element soft robot that walks or swims, actuated in a control space B_c.

    The robot is simulated in the reduced simulation space B_r (``sim_dim`` = M deformation
    modes plus 3 exact rigid translations and 3 linearised rotations; see
    :mod:`softrom_gym.rom`) and actuated by the
    reduced force f_r = B_c f_c, where the action is f_c and B_c (M x C) is the control space
    (the paper's Eq. OPT). Actuation is internal: it deforms the body and never pushes its
    centre of mass; motion comes from ground friction (walk) or fluid drag (swim).

    ## Action Space
    ``Box(-a, a, (C,), float32)``: f_c, the generalised force along each column of B_c, held
    for ``frame_skip`` simulation steps. Units are N·kg^(-1/2), a mass-normalised modal
    force (B_r is mass-orthonormal). The bound ``a = action_scale * sqrt(m) * g`` is the
    modal force equivalent of the robot's weight: a prototype found no net motion below about
    0.75 body weight and hopping artefacts of linear modes above about 2. Actions beyond the
    bound are clipped. RL libraries that prefer [-1, 1] can wrap the env in
    ``gymnasium.wrappers.RescaleAction(env, -one, one)`` with
    ``one = np.ones(C, dtype=np.float32)`` (float32 bounds, as the box's: Python floats make
    the wrapper warn that it casts them).

    ## Observation Space
    ``Box(-inf, inf, (10 + 2 M,), float32)``:

    | index          | observation                                             | unit   |
    |----------------|---------------------------------------------------------|--------|
    | 0              | centre-of-mass height above the ground                  | m      |
    | 1..3           | centre-of-mass velocity (x, y, z)                       | m/s    |
    | 4..6           | linearised orientation (rotation vector vs. rest)       | rad    |
    | 7..9           | angular velocity (x, y, z)                              | rad/s  |
    | 10..9+M        | deformation coordinates q_d of B_r                      | m·kg½  |
    | 10+M..9+2M     | their velocities                                        | m·kg½/s|

    Orientation is the rotation vector of B_r's linearised rotation coordinates (small-angle:
    faithful to a few tenths of a radian, see :mod:`softrom_gym.rom.subspace`).

    ## Rewards
    Per step, the displacement of the centre of mass along the task direction d,
    ``R = sum over sub-steps of d · v_com · dt`` (metres; the paper's R). A step in which the
    simulation diverges pays its sub-steps before the divergence only: from the diverging
    sub-step on, the C++ core keeps the last good state (the robot stops where it was) and
    pays zero, with no penalty (see Episode End). ``info`` holds the
    terms of the regulariser Λ separately: ``orientation`` (|rotation vector|, rad),
    ``lateral`` (motion orthogonal to d in the ground plane this step, m) and ``effort``
    (|f_c / a|^2), plus ``distance`` (along d since reset, m), ``com``, ``diverged``,
    ``min_volume_ratio`` (the smallest det F over the mesh's tetrahedra; at or below 0 one is
    inverted, which a material too soft for the action bound allows, and the env warns once)
    and ``contact`` (the model's contact setting: "staggered", "penalty" or "none").

    ## Starting State
    The robot at rest (on the ground for walking), with deformation velocities drawn
    uniformly in ±``reset_noise_scale`` · sqrt(m) · 0.01 m/s from ``np_random`` (for a robot
    shorter than 10 cm, 0.01 m/s becomes 10 % of its body length per second).
    ``reset(options={"state": state})`` starts from a ``ReducedState`` of ``get_state()``
    instead (distance is then counted from there); any other option is a ValueError.

    ## Episode End
    Terminated when the simulation diverges (``info["diverged"] = True``, False on every
    other step and at reset; the observation is the last good state's, finite; reset() makes
    the env usable again). Terminated, not truncated: the stopped robot is an absorbing state
    that pays zero reward, which is what ``terminated`` tells an RL algorithm (its value is 0,
    as when a MuJoCo Hopper falls), where ``truncated`` would have it bootstrap from the frozen
    state as if the episode could go on. No penalty is charged, so the reward stays the
    distance: divergence is rare (under random full-bound actions no benchmark diverged at
    the default bound, nor BeamWalk at 100 times it or 10 times softer; the tests provoke it
    with ``action_scale=1e9``). An agent that goes backwards could still end its losses by
    diverging; to price that (as the planners' Λ prices lost steps), subtract a penalty in a
    ``gymnasium.Wrapper`` whose ``step`` reads ``info["diverged"]``. Truncated by the
    TimeLimit wrapper (``max_episode_steps``; 400 steps = 10 s for the registered ids).

    ## Arguments
    ``robot`` (name in :data:`softrom_gym.robots.ROBOTS`, a mesh path in metres, a
    trimesh.Trimesh or trimesh.Scene, or a Robot; a walking Robot's lowest node must lie on
    the ground, z = 0, as named and meshed robots' do), ``task``
    ("walk" or "swim"), ``direction`` (angle in radians or 2-vector), ``control_dim`` C
    (default 3, or the columns of ``control_basis``), ``sim_dim`` M (default 20, or the rows
    of ``control_basis``), ``control_basis`` B_c (M x C, orthonormal to 1e-8, or the path of
    a ``.npy`` file holding it, such as a run's ``best_basis.npy``: given as a str, it keeps
    ``env.spec`` JSON-serialisable, which an array does not; default: the
    first C deformation modes), ``orthonormalize`` (accept any full-rank B_c),
    ``frame_skip`` (simulation steps per action, default 5: 40 Hz control at dt = 1/200 s),
    ``dt``, ``action_scale``, ``friction`` (mu), ``contact`` ("staggered", "penalty" or
    "none"),
    ``fluid_density`` (swim), ``material`` (dict of youngs_modulus / poisson_ratio /
    density), ``resolution`` (mesh resolution), ``scale`` (multiplies a mesh's coordinates:
    0.001 for one in millimetres), ``reset_noise_scale``, ``render_mode``.

    ## For model-predictive control
    ``get_state()`` / ``set_state(state)`` copy the full simulation state, and
    ``rollout(state, controls)`` runs B control sequences (B, H, C) of H env steps from a
    state (or one state per sequence) through the batched C++ path (see :meth:`rollout`),
    returning the per-step terms a planner needs (COM, orientation vector, R, Λ's terms, lost
    steps after a divergence); ``final_states(result)`` makes its B final states states to
    roll out from again.
    ``center_of_mass(state)`` is a state's COM (m) and ``direction`` the task direction d (a
    unit 3-vector in the ground plane): R of a rollout is d · (com_H - center_of_mass(state)),
    as the planners score it. Through ``gym.make``'s wrappers reach them, and
    ``action_bound`` (a, the box's bound), ``dt`` (control period, s) and ``body_length`` (m),
    with ``env.get_wrapper_attr(name)``. A plan replays exactly: ``rollout`` of H actions and H
    calls of ``step`` agree to the last bit. A planner leaves the env's state as it found it:
    ``rollout`` does; ``step`` moves it (and counts against the time limit).

    ## Version History
    * v0: initial release.
    """

    # Not a ClassVar: gym.Env declares it per instance (__init__ sets this env's render_fps).
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 40}  # noqa: RUF012
    action_space: spaces.Box
    observation_space: spaces.Box
    # Set by the first inverted element this env reports (the warning is said once); a class
    # default, so an env pickled before it existed unpickles with it.
    _inversion_warned: bool = False

    def __init__(
        self,
        robot: str | os.PathLike | Robot = "quadruped",
        task: str = "walk",
        direction: float | np.ndarray = 0.0,
        control_dim: int | None = None,
        sim_dim: int | None = None,
        control_basis: np.ndarray | str | os.PathLike | None = None,
        orthonormalize: bool = False,
        frame_skip: int = 5,
        dt: float = 1.0 / 200.0,
        action_scale: float = 1.0,
        friction: float = 0.8,
        contact: str = "staggered",
        fluid_density: float = 1000.0,
        material: dict[str, float] | None = None,
        resolution: int | None = None,
        scale: float | None = None,
        reset_noise_scale: float = 1.0,
        render_mode: str | None = None,
    ) -> None:
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; valid tasks: {list(TASKS)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode {render_mode!r} is not supported; valid: "
                f"{self.metadata['render_modes']}"
            )
        b_c = read_basis(control_basis)
        sim_dim, control_dim = dimensions(b_c, sim_dim, control_dim)
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
        self.render_mode = render_mode
        self.task = task
        self.frame_skip = int(frame_skip)
        self.robot = make_robot(robot, material or {}, resolution, scale)
        if task == "walk":  # (a swimmer has no ground)
            check_on_ground(self.robot)
        self.direction = task_direction(direction)
        self.control_basis = checked_control_basis(b_c, sim_dim, control_dim, orthonormalize)

        settings: dict[str, Any] = {"dt": dt, "direction": self.direction}
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

        # verbose: a new robot or M takes seconds to minutes to build, once; say so on stderr
        self.subspace = build_subspace(self.robot, sim_dim, verbose=True)
        self.model = build_reduced_model(
            self.robot, sim_dim, subspace=self.subspace, control_basis=self.control_basis,
            verbose=True, **settings,
        )  # fmt: skip
        mass = self.robot.fem_model().mass
        self._sqrt_m = float(np.sqrt(mass.sum()))
        # Linearised orientation: the rotation vector theta whose infinitesimal rotation
        # A theta (A = [e_k x (X - c)]) best fits x - X in the mass norm,
        # theta = (A^T M A)^-1 A^T M B_r q_r; exact on B_r's rotation columns.
        r = self.robot.nodes - mass @ self.robot.nodes / mass.sum()
        a = np.column_stack([np.cross(e, r).ravel() for e in np.eye(3)])
        ma = a * np.repeat(mass, 3)[:, None]
        self._orientation = np.linalg.solve(a.T @ ma, ma.T @ self.subspace.basis)
        self.action_bound = float(action_scale * self._sqrt_m * G)
        c = control_dim
        m = sim_dim
        self.action_space = spaces.Box(-self.action_bound, self.action_bound, (c,), np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (10 + 2 * m,), np.float32)
        self.reset_noise_scale = float(reset_noise_scale)
        self._state = self.model.rest_state()
        self._com0 = self.model.com(self._state.q)
        # At least 1: a video writer cannot take 0 frames per second (env steps of 1 s or more).
        fps = max(1, round(1.0 / (self.model.dt * self.frame_skip)))
        self.metadata = {**self.metadata, "render_fps": fps}
        self._renderer: SoftwareRenderer | None = None

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

    # ---------------------------------------------------------------- observations
    def _obs(self, state: cpp_sim.ReducedState) -> np.ndarray:
        q, qdot = state.q, state.qdot
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
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains non-finite values: {a}")
        return np.clip(a, -self.action_bound, self.action_bound)

    # ---------------------------------------------------------------- gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        start = self._reset_start(options)  # (checked before anything changes)
        super().reset(seed=seed)
        rest = self.model.rest_state()
        qdot = rest.qdot
        # 0.01 m/s, or 10 % of a body length per second for robots under 10 cm (every
        # benchmark is longer): on a 1 mm robot 0.01 m/s alone drifts 1.4 body lengths a second.
        speed = 0.01 * min(1.0, self.body_length / 0.1)
        noise = self.reset_noise_scale * speed * self._sqrt_m
        qdot[6:] = self.np_random.uniform(-noise, noise, size=qdot.size - 6)
        # (the velocities are drawn even for a given start: the stream goes on as without it)
        self._state = cpp_sim.ReducedState(rest.q, qdot, rest.impulses) if start is None else start
        self._com0 = self.model.com(self._state.q)
        return self._obs(self._state), self._info(self._state, 0.0, 0.0, False)

    def _reset_start(self, options: dict | None) -> cpp_sim.ReducedState | None:
        """The state ``reset``'s options start from (None: the robot at rest), or an error."""
        if not options:
            return None
        if not isinstance(options, dict):
            raise TypeError(f"options must be a dict or None, got {type(options).__name__}")
        unknown = sorted(set(options) - {"state"})
        if unknown:
            raise ValueError(f"reset takes the option 'state' only (a ReducedState from "
                             f"get_state()), got {unknown}")  # fmt: skip
        return self._checked_state(options["state"])

    def _info(
        self, state, lateral: float, effort: float, diverged: bool, orientation: float | None = None
    ) -> dict[str, Any]:
        com = self.model.com(state.q)
        if orientation is None:
            orientation = float(np.linalg.norm(self._orientation @ state.q))
        volume_ratio = float(self.model.min_volume_ratio(state.q))
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
        return {
            "distance": float(self.direction @ (com - self._com0)),
            "orientation": orientation,
            "lateral": lateral,
            "effort": effort,
            "com": com,
            "diverged": diverged,
            "min_volume_ratio": volume_ratio,
            "contact": self.model.contact,
        }

    def step(self, action):
        f_c = self._check_action(action)
        out = self.rollout(self._state, f_c[None, None, :], threads=1)
        diverged = bool(out["diverged"][0])
        self._state = cpp_sim.ReducedState(out["q"][0], out["qdot"][0], out["impulses"][0])
        reward = float(out["rewards"][0, 0])
        # The terms as rollout() computed them: a planner's prediction is what step reports.
        info = self._info(self._state, float(out["lateral"][0, 0]), float(out["effort"][0, 0]),
                          diverged, float(out["orientation"][0, 0]))  # fmt: skip
        return self._obs(self._state), reward, diverged, False, info

    # ---------------------------------------------------------------- copying
    def __getstate__(self) -> dict[str, Any]:
        """Everything but the compiled model, for ``pickle`` and ``copy.deepcopy`` (a
        ``ProcessPoolExecutor`` or a vector env sending an env to a worker, a planner copying
        one). The model is rebuilt on unpickling from the robot, B_r, the current B_c and the
        model's current settings, so a copy steps exactly as the original would."""
        state = self.__dict__.copy()
        config = state.pop("model").config
        state["_model_settings"] = {name: getattr(config, name) for name in config.SETTINGS}
        state["_renderer"] = None  # a copy renders with its own renderer
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        settings = dict(state)
        model_settings = settings.pop("_model_settings")
        self.__dict__.update(settings)
        # (an array unpickles writeable: read-only again, as checked_control_basis made it)
        self.control_basis = self.control_basis.copy()
        self.control_basis.flags.writeable = False
        self.model = build_reduced_model(
            self.robot, self.control_basis.shape[0], subspace=self.subspace,
            control_basis=self.control_basis, **model_settings,
        )  # fmt: skip

    # ---------------------------------------------------------------- control space
    def set_control_basis(
        self, control_basis: np.ndarray | str | os.PathLike, orthonormalize: bool = False
    ) -> None:
        """Swap the control space B_c (M x C, the same C) on this env, keeping its simulation
        space, cubature and state: the public way to evaluate many bases with one env.
        ``control_basis`` may be the path of a ``.npy`` file holding it, as for the constructor.

        Raises ValueError naming the problem for a wrong shape, non-finite entries, or a
        non-orthonormal B_c (pass ``orthonormalize=True`` to accept any full-rank matrix).

        ``env.unwrapped.spec`` follows: its ``control_basis`` becomes this one, so
        ``gym.make(spec)`` makes an env with this B_c, as Gymnasium's spec is meant to make the
        env it describes. A path stays a path (the spec stays JSON-serialisable), with
        ``orthonormalize`` as given; an array is held as the B_c now used (a copy), with
        ``orthonormalize=False``. The spec is a new ``EnvSpec``: one read earlier is left as
        it was. This method cannot reach the wrappers around the env, and Gymnasium's keep
        the copy of the spec they made at their first read of ``env.spec``: when ``env`` from
        ``gym.make`` was asked for its spec before the swap, ``env.spec`` still names the old
        B_c after it (``env.unwrapped.spec`` does not). To swap B_c with the wrappers'
        specs following, call :func:`softrom_gym.envs.set_control_basis` with the wrapped
        env: ``set_control_basis(env, control_basis)``.
        """
        m, c = self.control_basis.shape
        b = checked_control_basis(read_basis(control_basis), m, c, orthonormalize)
        self.model.control_basis = b
        self.control_basis = b
        self.spec = spec_with_control_basis(self.spec, control_basis, b, orthonormalize)

    # ---------------------------------------------------------------- MPC API
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
        * ``theta`` (B, H, 3): linearised orientation, the rotation vector vs. rest (rad);
          ``orientation`` (B, H) is its norm.
        * ``lateral`` (B, H): |motion orthogonal to d in the ground plane| this step (m).
        * ``effort`` (B, H): |f_c / a|^2 (dimensionless).
        * ``lost`` (B, H): 1.0 on the step a rollout diverges and on every step after it,
          else 0.0. A diverged rollout keeps its last good state and earns zero reward from
          then on, so a planner must price these steps (a controller's Λ charges a weight in
          metres per lost step) or a blow-up would beat a trajectory that goes backwards.
        * ``diverged`` (B,): whether the rollout diverged.
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
        # The C++ core zeroes the reward of every sub-step from the diverging one on; a step
        # is lost when any of its sub-steps is.
        lost = np.zeros((b, h))
        for i in np.flatnonzero(out["diverged"]):
            lost[i, _first_frozen_substep(rewards[i].ravel(), out["com"][i]) // k :] = 1.0
        result = {
            "rewards": rewards.sum(axis=2),
            "com": com,
            "theta": theta,
            "orientation": np.linalg.norm(theta, axis=-1),
            "lateral": lateral,
            "effort": np.sum((u / self.action_bound) ** 2, axis=-1),
            "lost": lost,
            "diverged": out["diverged"],
            "q": out["q"],
            "qdot": out["qdot"],
            "impulses": out["impulses"],
        }
        if observe is not None:
            result["observed"] = observed[..., n_orient:]
        return result

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
