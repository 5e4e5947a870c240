"""``SoftRobotEnv``: a soft robot walking or swimming through its control space B_c."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import cpp_sim

from ..robots import Robot
from ..rom import build_reduced_model, build_subspace, train_cubature
from .advice import warn_if_unsuited
from .arguments import (
    check_on_ground,
    check_sizes_and_scales,
    checked_control_basis,
    dimensions,
    make_robot,
    model_settings,
    read_basis,
    spec_with_control_basis,
    task_direction,
)
from .observations import Observations, orientation_rows
from .planning import PlanningAPI

if TYPE_CHECKING:
    from ..rendering import SoftwareRenderer

__all__ = ["TASKS", "SoftRobotEnv"]

TASKS = ("walk", "swim")
G = 9.81


class SoftRobotEnv(PlanningAPI, Observations, gym.Env):
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
    | 0              | centre-of-mass height above ``ground_height`` (¹)       | m      |
    | 1..3           | centre-of-mass velocity (x, y, z)                       | m/s    |
    | 4..6           | orientation (rotation vector vs. rest)                  | rad    |
    | 7..9           | angular velocity (x, y, z)                              | rad/s  |
    | 10..9+M        | deformation coordinates q_d of B_r                      | m·kg½  |
    | 10+M..9+2M     | their velocities                                        | m·kg½/s|

    (¹) The ground plane z = ``ground_height`` (0 by default), a swimmer's too: there it is
    the height above the plane the robot starts resting on, not above a floor.

    In the default ``frame="linear"`` orientation is the rotation vector of B_r's linearised
    rotation coordinates (small-angle: faithful to a few tenths of a radian, see
    :mod:`softrom_gym.rom.subspace`) and the angular velocity its rate. With
    ``frame="floating"`` the rotation is exact: orientation is the rotation vector of the
    body frame R (|θ| <= π) and the angular velocity the body-frame ω.

    ## Rewards
    Per step, the displacement of the centre of mass along the task direction d,
    ``R = sum over sub-steps of d · v_com · dt`` (metres; the paper's R). A step in which the
    simulation diverges pays its sub-steps before the divergence only: from the diverging
    sub-step on, the C++ core keeps the last good state (the robot stops where it was) and
    pays zero, with no penalty (see Episode End). ``info`` holds the
    terms of the regulariser Λ separately: ``orientation`` (|rotation vector|, rad),
    ``lateral`` (motion orthogonal to d in the ground plane this step, m) and ``effort``
    (|f_c / a|^2), plus ``distance`` (along d since reset, m), ``com``, ``diverged``,
    ``converged`` (whether every physics sub-step's Newton iteration and contact solve reached
    its tolerance: a step that does not is still taken, and this says so; True after reset),
    ``min_volume_ratio`` (the smallest det F over the mesh's tetrahedra; at or below 0 one is
    inverted, which a material too soft for the action bound allows, and the env warns once)
    and ``contact`` (the model's contact setting: "staggered", "penalty" or "none"). In the
    linear frame rotations are linearised, so the env also warns once when ``orientation``
    passes ``LINEARISED_TURN_LIMIT`` (0.3 rad), past which the turn's stretch makes the motion
    unphysical; the floating frame turns freely.

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
    0.001 for one in millimetres), ``reset_noise_scale``, ``render_mode``, ``frame`` (how the
    rigid motion is represented, not ``frame_skip``: "linear", the default and every recorded
    figure's, or "floating", an exact rotation with the actuation following the body, with
    any ground; ``docs/FLOATING_FRAME.md``).

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
        frame: str = "linear",
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
        action_scale, reset_noise_scale = check_sizes_and_scales(
            sim_dim, control_dim, frame_skip, action_scale, reset_noise_scale, orthonormalize,
            material,
        )  # fmt: skip
        self.render_mode = render_mode
        self.task = task
        self.frame_skip = int(frame_skip)
        self.robot = make_robot(robot, material or {}, resolution, scale)
        if task == "walk":  # (a swimmer has no ground)
            check_on_ground(self.robot)
        self.direction = task_direction(direction)
        self.control_basis = checked_control_basis(b_c, sim_dim, control_dim, orthonormalize)
        settings = model_settings(task, dt, self.direction, contact, friction, fluid_density,
                                  frame)  # fmt: skip
        # verbose: a new robot or M takes seconds to minutes to build, once; say so on stderr
        self.subspace = build_subspace(self.robot, sim_dim, verbose=True)
        # kept, and pickled with the env: a copy unpickled in another process must not get
        # its rule again from that process's cache (retrained there: seconds, and weights
        # that differ in the last bits under another BLAS, so the copy stepped differently)
        self.cubature = train_cubature(self.robot, self.subspace, verbose=True)
        self.model = build_reduced_model(
            self.robot, sim_dim, subspace=self.subspace, cubature=self.cubature,
            control_basis=self.control_basis, **settings,
        )  # fmt: skip
        mass = self.robot.fem_model().mass
        self._sqrt_m = float(np.sqrt(mass.sum()))
        if self.model.frame == "floating":  # q[3:6] is the rotation vector itself
            self._orientation = np.eye(3, self.model.dim, 3)
        else:
            self._orientation = orientation_rows(self.robot.nodes, mass, self.subspace.basis)
        self.action_bound = float(action_scale * self._sqrt_m * G)
        warn_if_unsuited(self.robot.nodes, self.subspace.deformation, self.subspace.frequencies,
                         self.action_bound, str(self.model.frame))  # fmt: skip
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

    def step(self, action):
        f_c = self._check_action(action)
        self._state, terms = self._step_once(f_c)
        com = self.model.com(self._state.q)
        # The terms as rollout() computes them: a planner's prediction is what step reports.
        info = self._info(self._state, terms["lateral"], terms["effort"], terms["diverged"],
                          terms["orientation"], com, terms["converged"])  # fmt: skip
        return self._obs(self._state, com), terms["reward"], terms["diverged"], False, info

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
        # (an env pickled before it kept its rule gets one as its constructor did)
        self.model = build_reduced_model(
            self.robot, self.control_basis.shape[0], subspace=self.subspace,
            cubature=getattr(self, "cubature", None), control_basis=self.control_basis,
            **model_settings,
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
