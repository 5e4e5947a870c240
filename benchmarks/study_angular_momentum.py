"""Study: angular momentum in free flight, and what a floating frame would change.

Issue #8 asks for a test that actuation conserves angular momentum in free flight; with
linearised rotations the reduced model does not (``tests/test_solver.py``, a strict xfail).
This study asks which part of that is the reduced model's fault. One robot floats free (no
gravity, ground, drag or damping; dt = 5 ms by default) for ``--seconds``, and each model's angular
momentum about its centre of mass is compared with its start against its scale,
max |L - L_0| / sum m |x - c| |v|:

* ``actuated``: the xfail's stroke (a 2 Hz travelling wave of ``--stroke`` body weights in
  the first three modes, from rest) on the linear reduced model and on its full-space
  counterpart, whose actuation is the same modal force field M B_d B_c f_c
  (:meth:`FullSpaceModel.matching`): fixed in the world, so it has no net force, and no
  torque at rest, but a torque once the body has deformed or turned;
* ``unactuated``: elastic forces only, from a state moving in the first three modes at
  ``--speed`` (RMS node speed, m/s), and optionally spinning at ``--spin`` rad/s about y. Here
  the full space keeps L but for implicit Euler's drift, and each model's nodes are also
  compared with the full space's (RMS distance over the robot's RMS radius).

The models: ``full space`` (:class:`FullSpaceModel`), ``linear`` (the package's reduced model,
x = X + B_r q), ``linear, projected`` (the same with its internal forces projected so they
exert no torque on the reduced state: the component of B_r^T f along T(q)^T is removed, with
T(q) qdot = L; a constrained Galerkin projection) and ``floating frame``, a Python prototype
of x = c + R (X + U z) (U: B_r's deformation columns; L-exact implicit Euler, below). The
projected model is a study only; the floating frame, designed here, is now in the package's
core (``frame="floating"``), and ``--core`` checks the two against each other. ``--stroke``
on the floating frame acts on z in the body frame, so it is internal and L stays exact; its
two lines are there for that and for where the prototype's Newton fails: ``f on z`` is the
generalised force f_a on z itself, ``torque-free`` the nodal field M R U f_a less the rigid
rotation that cancels its torque, whose generalised force is (I - S^T I^-1 S) f_a on z
(``--follower`` says why it matters).

    python benchmarks/study_angular_momentum.py [--robot beam] [--seconds 1] [--speed 0.2]
        [--spin 3] [--stroke 0.8] [--dt 0.005] [--step-convergence]
        [--linearised-turns [--best-bases DIR]] [--swim] [--follower [--modes 20]] [--core]

``--step-convergence`` runs only the stroke, on the prototype and the linear model, at dt,
dt/2 and dt/4, to tell whether the prototype's fast frame spin (docs/FLOATING_FRAME.md) is the
step's or the model's. ``--linearised-turns`` runs only what a linearised turn costs: the
elastic pull-back of a pure turn per benchmark robot, and how far each env turns in an episode
and under MPC with the control spaces the reproduction's runs found (``--best-bases``; the
figures behind the envs' turn warning, ``LINEARISED_TURN_LIMIT``). ``--swim`` runs only
open-loop swims of ``--robot`` for ``--seconds`` (the cross for 5 s is the swimmer's case; about
9 min): the linear model, the prototype with the package's drag (actuated on z, and by the
world-fixed modal forces) and the full space, which swims since FullSpaceModel gained drag.
``--follower`` runs only the stroke as a force that follows the body, in the full space (its
best-fit frame's M R U f_c, torque removed) and on the prototype (f on z; torque-free; the full
space's nodal field), at dt, dt/2 and dt/4: whether the frame's fast spin is the material's
(about 4 min per stroke on the beam). ``--core`` runs only the package's floating frame
(``frame="floating"``, C++) against the prototype under the torque-free law: the stroke in
free flight and, in water with the package's drag, the 2 Hz 0/120/240 swim; the largest node
distance between the two over ``--seconds`` and the seconds per step of each.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import cpp_sim
from softrom_gym.body_frame import best_fit_rotation, following_forces
from softrom_gym.full_space import FullSpaceModel, FullSpaceState
from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model, build_subspace

G = 9.81
DT = 0.005  # the default step of every model here
RUNS = Path(__file__).resolve().parent.parent / "docs" / "reproduction-45m" / "runs"


def newton(residual: Callable[[np.ndarray], np.ndarray], x: np.ndarray, tol: float
           ) -> tuple[np.ndarray, bool]:  # fmt: skip
    """Newton's method with a forward-difference Jacobian and a backtracking line search on
    |residual|; returns the root and whether |residual| fell below ``tol``."""
    n = x.size
    for _ in range(40):
        r = residual(x)
        norm = np.linalg.norm(r)
        if norm < tol:
            return x, True
        jac = np.empty((n, n))
        for k in range(n):
            dx = np.zeros(n)
            dx[k] = 1e-7
            jac[:, k] = (residual(x + dx) - r) / 1e-7
        step = np.linalg.solve(jac, r)
        t = 1.0
        while t > 1e-4 and np.linalg.norm(residual(x - t * step)) > (1.0 - 1e-4 * t) * norm:
            t *= 0.5
        x = x - t * step
    return x, bool(np.linalg.norm(residual(x)) < tol)


class ProjectedLinearModel:
    """The linear reduced model, x = X + B_r q with M_r = I, whose internal forces (elastic
    and actuation) are projected off T(q)^T, T(q) = sum_i m_i [x_i - c]_x B_i (3 x (M + 6)),
    so that they leave T(q) qdot = L unchanged: qddot = P(q) (f_el + f_a), P = I - T^T (T T^T)^-1 T.
    Implicit Euler, Newton on qdot_{n+1}."""

    def __init__(self, model: cpp_sim.ReducedModel, basis: np.ndarray, nodes: np.ndarray,
                 mass: np.ndarray) -> None:  # fmt: skip
        self.model = model
        self.dt = float(model.dt)
        n = len(mass)
        self.b = basis.reshape(n, 3, -1)
        rest = nodes - mass @ nodes / mass.sum()
        eps = np.zeros((3, 3, 3))
        eps[0, 1, 2] = eps[1, 2, 0] = eps[2, 0, 1] = 1.0
        eps[0, 2, 1] = eps[2, 1, 0] = eps[1, 0, 2] = -1.0
        # T(q) = T0 + sum_j q_j T1_j ((a x b)_c = eps_cab a_a b_b)
        self.t0 = np.einsum("cab,i,ia,ibk->ck", eps, mass, rest, self.b)
        self.t1 = np.einsum("cab,i,iaj,ibk->jck", eps, mass, self.b, self.b)

    def internal(self, q: np.ndarray, fa: np.ndarray) -> np.ndarray:
        f = np.zeros(q.size)
        f[3:] = self.model.elastic_forces(q[3:])
        f[6 : 6 + fa.size] += fa
        t = self.t0 + np.einsum("j,jck->ck", q, self.t1)
        return f - t.T @ np.linalg.solve(t @ t.T, t @ f)

    def step(self, q: np.ndarray, qdot: np.ndarray, fa: np.ndarray) -> tuple[np.ndarray, ...]:
        h = self.dt
        v, ok = newton(lambda w: w - qdot - h * self.internal(q + h * w, fa), qdot, 1e-10)
        if not ok:
            raise FloatingPointError("Newton did not converge")
        return q + h * v, v


class FloatingFramePrototype:
    """x_i = c + R r_i, r_i = X_i + U_i z (X about the centre of mass; U: B_r's M deformation
    columns, mass-orthonormal and mass-orthogonal to the rigid modes at rest, so c stays the
    centre of mass and the frame is the linear mean-axis frame). Velocities u = c', omega (body
    frame), w = z'. Kinetic energy T = 1/2 m |u|^2 + 1/2 sum_i m_i |omega x r_i + U_i w|^2,
    elastic energy E(z) by the package's cubature (rotation-invariant: it sees X + U z only).

    Momentum-form implicit Euler, with c' = c + h u', R' = R exp(h omega'), z' = z + h w':
      m (u' - u) = h F_ext,
      Pi' = exp(-h omega') Pi                      (R' Pi' = R Pi: world L exactly kept),
      p_z' - p_z = h (dT/dz' - dE/dz' + f_a),
    with Pi = dT/d omega = sum m r x (omega x r + U w) and p_z = dT/dw. Actuation f_a acts on
    z, in the body frame: internal, so it cannot change L either."""

    def __init__(self, model: cpp_sim.ReducedModel, basis: np.ndarray, nodes: np.ndarray,
                 mass: np.ndarray) -> None:  # fmt: skip
        self.model = model
        self.dt = float(model.dt)
        self.mass = mass
        self.total = float(mass.sum())
        self.com = mass @ nodes / self.total
        self.rest = nodes - self.com
        self.u = basis[:, 6:].reshape(len(mass), 3, -1)
        self.dim = self.u.shape[2]

    def _body(self, z: np.ndarray, om: np.ndarray, w: np.ndarray):
        r = self.rest + self.u @ z
        rel = np.cross(om, r) + self.u @ w  # omega x r + U w, body frame
        pi = np.sum(self.mass[:, None] * np.cross(r, rel), axis=0)
        pz = np.einsum("i,iaj,ia->j", self.mass, self.u, rel)
        return r, rel, pi, pz

    def _dt_dz(self, om: np.ndarray, rel: np.ndarray) -> np.ndarray:
        om_u = np.cross(om[None, :, None], self.u, axisa=1, axisb=1, axisc=1)
        return np.einsum("i,iaj,ia->j", self.mass, om_u, rel)

    def step(self, state: tuple, fa: np.ndarray, loads: Callable | None = None,
             torque_free: bool = False) -> tuple:  # fmt: skip
        """One step under actuation ``fa`` on z (body frame) and, optionally, ``loads(state)``
        -> (force on c, world frame; torque about c, body frame; generalised force on z),
        taken at the step's start and linearised in the velocities (u, omega, w) by forward
        differences, as the package's step takes its drag.

        ``torque_free``: ``fa`` stands for the nodal field M R U f_a less the rigid-rotation
        field that cancels its torque about c, whose generalised force is on z alone,
        (I - S(z)^T I(z)^-1 S(z)) f_a, with I(z) = sum m [r]x^T [r]x the inertia and
        S(z) = sum m [r]x U (taken at the step's end). Without it the generalised force on z is
        f_a itself: internal too, but a different field once the body has deformed."""
        c, rot, z, u, om, w = state
        h, n = self.dt, self.dim
        _, _, pi0, pz0 = self._body(z, om, w)
        f_a = np.zeros(n)
        f_a[: fa.size] = fa
        v0 = np.concatenate([u, om, w])
        load0, load_jac = np.zeros(6 + n), np.zeros((6 + n, 6 + n))
        if loads is not None:
            load0 = np.concatenate(loads(state))
            for k in range(6 + n):
                dv = v0.copy()
                dv[k] += 1e-7
                moved = (c, rot, z, dv[:3], dv[3:6], dv[6:])
                load_jac[:, k] = (np.concatenate(loads(moved)) - load0) / 1e-7

        def residual(x: np.ndarray) -> np.ndarray:
            u1, om1, w1 = x[:3], x[3:6], x[6:]
            z1 = z + h * w1
            _, rel, pi, pz = self._body(z1, om1, w1)
            elastic = self.model.elastic_forces(np.concatenate([np.zeros(3), z1]))[3:]
            load = load0 + load_jac @ (x - v0)
            push = f_a
            if torque_free:
                r1 = self.rest + self.u @ z1
                s1 = np.einsum("i,iaj->aj", self.mass, np.cross(r1[:, :, None], self.u, axis=1))
                i1 = np.einsum("i,ij,ik->jk", self.mass, r1, r1)
                i1 = np.trace(i1) * np.eye(3) - i1
                push = f_a - s1.T @ np.linalg.solve(i1, s1 @ f_a)
            return np.concatenate([
                self.total * (u1 - u) - h * load[:3],
                pi - Rotation.from_rotvec(-h * om1).as_matrix() @ (pi0 + h * load[3:6]),
                pz - pz0 - h * (self._dt_dz(om1, rel) + elastic + push + load[6:]),
            ])  # fmt: skip

        x, ok = newton(residual, v0, 1e-10 * max(1.0, self.total))
        if not ok:
            raise FloatingPointError(f"Newton did not converge (|omega| {np.linalg.norm(om):.3g})")
        u1, om1, w1 = x[:3], x[3:6], x[6:]
        turn = Rotation.from_rotvec(h * om1).as_matrix()
        return (c + h * u1, rot @ turn, z + h * w1, u1, om1, w1)

    def generalised(self, state: tuple, forces: np.ndarray) -> tuple[np.ndarray, ...]:
        """Nodal forces (N, 3, world frame) at ``state`` as the loads ``step`` takes."""
        rot, z = state[1], state[2]
        r = self.rest + self.u @ z
        body = forces @ rot  # rows R^T f_i
        return (
            forces.sum(axis=0),
            np.cross(r, body).sum(axis=0),
            np.einsum("iaj,ia->j", self.u, body),
        )

    def world(self, state: tuple) -> tuple[np.ndarray, np.ndarray]:
        c, rot, z, u, om, w = state
        r, rel, _, _ = self._body(z, om, w)
        return c + r @ rot.T, u + rel @ rot.T


def momentum_ratio(mass: np.ndarray, x: np.ndarray, v: np.ndarray, start: np.ndarray | None = None
                   ) -> float:  # fmt: skip
    """|L - L_0| over sum m |x - c| |v|, L the angular momentum about the centre of mass and
    L_0 ``start`` (default 0)."""
    r = x - mass @ x / mass.sum()
    moment = np.sum(mass[:, None] * np.cross(r, v), axis=0)
    if start is not None:
        moment = moment - start
    scale = np.sum(mass * np.linalg.norm(r, axis=1) * np.linalg.norm(v, axis=1))
    return float(np.linalg.norm(moment) / scale)


def step_convergence(robot, sub, stroke: float, seconds: float, dt: float) -> dict:
    """The actuated stroke on the floating-frame prototype and on the linear model at dt, dt/2
    and dt/4: the frame's peak rate, and how far each model's nodes at mid-run and at the end
    lie from its own dt/4 run (RMS over the RMS radius)."""
    basis, nodes, mass = sub.basis, robot.nodes, np.asarray(robot.fem_model().mass)
    rest = nodes - mass @ nodes / mass.sum()
    radius = np.sqrt(mass @ (rest**2).sum(1) / mass.sum())
    amp = stroke * np.sqrt(mass.sum()) * G
    phase = 2.0 * np.pi * np.arange(3) / 3.0
    steps_of = {h: round(seconds / h) for h in (dt, dt / 2, dt / 4)}
    at: dict = {}
    for h, steps in steps_of.items():
        linear = build_reduced_model(
            robot, subspace=sub, contact="none", gravity=[0, 0, 0],
            control_basis=np.eye(20)[:, :3], damping_beta=0.0, dt=h,
        )  # fmt: skip
        floating = FloatingFramePrototype(linear, basis, nodes, mass)
        state = (floating.com, np.eye(3), np.zeros(20), np.zeros(3), np.zeros(3), np.zeros(20))
        ls, spin, snaps = linear.rest_state(), 0.0, {}
        for k in range(steps):
            u = amp * np.sin(2.0 * np.pi * 2.0 * k * h - phase)
            state = floating.step(state, u)
            ls, _ = linear.step(ls, u)
            spin = max(spin, float(np.linalg.norm(state[4])))
            if k + 1 in (steps // 2, steps):
                snaps[k + 1 == steps] = (floating.world(state)[0], linear.positions(ls.q))
        at[h] = (spin, snaps)
        print(f"dt = {h * 1e3:g} ms: the floating frame turned at up to {spin:.3g} rad/s",
              flush=True)  # fmt: skip

    def apart(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(mass @ ((a - b) ** 2).sum(1) / mass.sum()) / radius)

    out = {h: {"peak_frame_rate": at[h][0]} for h in at}
    finest = at[dt / 4][1]
    for h in (dt, dt / 2):
        for which, name in enumerate(("floating frame", "linear")):
            d = [apart(at[h][1][end][which], finest[end][which]) for end in (False, True)]
            out[h][name] = d
            print(f"dt = {h * 1e3:g} ms against dt = {dt / 4 * 1e3:g} ms, {name}: nodes apart by "
                  f"{d[0]:.3f} (mid-run) / {d[1]:.3f} (end) of the radius")  # fmt: skip
    return out


def linearised_turns(best_bases: Path | None, angles: tuple[float, ...] = (0.1, 0.2, 0.3, 0.5)
                     ) -> dict:  # fmt: skip
    """What a linearised turn costs, per benchmark robot: the angular acceleration with which
    the elastic forces pull back a pure turn by each angle (about the worst axis; the turn's
    stretch of ~theta^2 / 2, read through the env's orientation rows), against g / L (L the RMS
    radius); and how far each walking and swimming env turns in one episode under random,
    sinusoidal and full-bound square-wave actions (2 Hz and 1 Hz, phases 2 pi k / C), and
    under MPC with the control spaces of ``best_bases`` (:func:`mpc_turns`), when given."""
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)
    from softrom_gym.envs.observations import orientation_rows

    out: dict = {}
    for name in ("cross", "beam", "quadruped", "tripod"):
        robot = ROBOTS[name]()
        sub = build_subspace(robot, 20)
        mass = np.asarray(robot.fem_model().mass)
        model = build_reduced_model(robot, subspace=sub, contact="none", gravity=[0, 0, 0])
        rows = orientation_rows(robot.nodes, mass, sub.basis)
        rest = robot.nodes - mass @ robot.nodes / mass.sum()
        radius = float(np.sqrt(mass @ (rest**2).sum(1) / mass.sum()))
        pull = []
        for angle in angles:
            worst = 0.0
            for axis in range(3):
                q_e = np.zeros(model.M + 3)  # (rotations, deformation): B_r's columns 3..
                q_e[:3] = np.linalg.solve(rows[:, 3:6], angle * np.eye(3)[axis])
                force = model.elastic_forces(q_e)  # M_r = I: the reduced acceleration
                worst = max(worst, abs(float(rows[axis, 3:6] @ force[:3])))
            pull.append(worst)
        out[name] = {"g_over_L": G / radius, "pull": dict(zip(angles, pull, strict=True))}
        said = ", ".join(f"{a:g} rad {p:,.4g}" for a, p in zip(angles, pull, strict=True))
        print(f"{name}: a turn pulled back at {said} rad/s^2 (g / L = {G / radius:.0f})",
              flush=True)  # fmt: skip
    for env_id in ("CrossSwim-v0", "CrossWalk-v0", "BeamWalk-v0", "QuadrupedWalk-v0",
                   "TripodWalk-v0"):  # fmt: skip
        env = gym.make(f"softrom_gym/{env_id}")
        bound = env.action_space.high
        phase = 2.0 * np.pi * np.arange(bound.size) / bound.size
        turned = {}
        for kind in ("random", "sine", "square"):
            env.reset(seed=0)
            rng, most, steps, t, done = np.random.default_rng(0), 0.0, 0, 0.0, False
            while not done:
                if kind == "random":
                    action = rng.uniform(-bound, bound)
                elif kind == "sine":
                    action = bound * np.sin(2.0 * np.pi * 2.0 * t - phase)
                else:
                    action = bound * np.sign(np.sin(2.0 * np.pi * t - phase))
                *_, terminated, truncated, info = env.step(action.astype(np.float32))
                most, steps = max(most, info["orientation"]), steps + 1
                t, done = steps * env.unwrapped.dt, terminated or truncated
            turned[kind] = most
        env.close()
        out[env_id] = turned
        said = ", ".join(f"{k} {v:.3f}" for k, v in turned.items())
        print(f"{env_id}: turned at most {said} rad in an episode of {t:g} s", flush=True)
    if best_bases is not None:
        out["mpc"] = mpc_turns(best_bases)
    return out


def mpc_turns(runs: Path, seconds: float = 10.0) -> dict:
    """How far MPC (mppi, the benchmark's settings, seed 0) turns each benchmark robot in a
    ``seconds`` episode with the control space a recorded run found: ``runs/<env>-boca/
    best_basis.npy`` (docs/reproduction-45m's runs), where there is one."""
    import gymnasium as gym

    import controllers
    from controllers.episode import run_episode
    from softrom_gym.registration import control_period

    out = {}
    for env_id in ("CrossSwim-v0", "CrossWalk-v0", "BeamWalk-v0", "QuadrupedWalk-v0",
                   "TripodWalk-v0"):  # fmt: skip
        path = runs / f"{env_id}-boca" / "best_basis.npy"
        if not path.is_file():
            print(f"{env_id}: no {path}, skipped", flush=True)
            continue
        full_id = f"softrom_gym/{env_id}"
        env = gym.make(full_id, control_basis=np.load(path), max_episode_steps=None)
        planner, every = controllers.planner_for(full_id, "mppi", dt=control_period(full_id))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the turn warning: the figure is printed here
            result = run_episode(env, planner, seconds, replan_every=every, seed=0,
                                 progress=False)  # fmt: skip
        env.close()
        out[env_id] = float(result.orientation.max())
        print(f"{env_id}: MPC with {path} turned at most {out[env_id]:.3f} rad in {seconds:g} s "
              f"(moved {result.distance[-1]:.2f} m)", flush=True)  # fmt: skip
    return out


def follower(robot, sub, stroke: float, seconds: float, dt: float) -> dict:
    """The stroke as actuation that follows the body, in the full space and on the prototype,
    at dt, dt/2 and dt/4: is the prototype's fast frame spin (docs/FLOATING_FRAME.md) the
    material's, or its model's?

    The full space's force (``actuation_frame="body"``) is M R U f_c (R: the best-fit rotation
    of its nodes, ``softrom_gym.body_frame``, the frame the prototype's R is) less the
    rigid-rotation field m (alpha x (x - c)) that cancels its torque about the centre of mass,
    so it is internal and L stays 0 (to implicit Euler's drift). The prototype runs three
    times: with f_c on z (its body-frame actuation), with f_c on z made torque-free
    (``FloatingFramePrototype.step``'s ``torque_free``: the same field, in closed form, at the
    step's end) and under the full space's nodal force field itself (at the step's start).
    Each run reports the frame's peak rate (the full space's from R at consecutive steps) and
    the peak about the long axis (the rest inertia's least axis); each prototype run, the RMS
    distance of its nodes from the full space's at mid-run and at the end (over the radius)."""
    basis, nodes, mass = sub.basis, robot.nodes, np.asarray(robot.fem_model().mass)
    n, m = len(mass), basis.shape[1] - 6
    rest = nodes - mass @ nodes / mass.sum()
    radius = np.sqrt(mass @ (rest**2).sum(1) / mass.sum())
    inertia = np.einsum("i,ij,ik->jk", mass, rest, rest)
    inertia = np.trace(inertia) * np.eye(3) - inertia
    moments, axes = np.linalg.eigh(inertia)
    axis = axes[:, 0]  # the long axis: the least moment
    u3 = basis[:, 6:9].reshape(n, 3, 3)
    amp = stroke * np.sqrt(mass.sum()) * G
    phase = 2.0 * np.pi * np.arange(3) / 3.0

    def following(x: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Nodal forces (N, 3): m (R U f - alpha x r), torque-free about the centre of mass."""
        return following_forces(x, rest, mass, u3 @ f)

    per_kg = np.round(moments / mass.sum(), 5)
    print(f"{robot.name}: M = {m}, {stroke:g} body-weight stroke following the body, "
          f"{seconds:g} s; rest moments {per_kg} m^2 per kg")  # fmt: skip
    names = ("full space", "floating, f on z", "floating, f on z torque-free",
             "floating, same nodal force")  # fmt: skip
    out: dict = {}
    for h in (dt, dt / 2, dt / 4):
        steps = round(seconds / h)
        full = FullSpaceModel(robot, actuation=basis[:, 6:9], dt=h, gravity=(0.0, 0.0, 0.0),
                              damping_beta=0.0, contact="none", newton_tolerance=1e-10,
                              actuation_frame="body")  # fmt: skip
        linear = build_reduced_model(
            robot, subspace=sub, contact="none", gravity=[0, 0, 0],
            control_basis=np.eye(m)[:, :3], damping_beta=0.0, dt=h,
        )  # fmt: skip
        floating = FloatingFramePrototype(linear, basis, nodes, mass)
        start = (floating.com, np.eye(3), np.zeros(m), np.zeros(3), np.zeros(3), np.zeros(m))
        states = dict.fromkeys(names[1:], start)
        fs = full.rest_state()
        failed: dict = dict.fromkeys(names[1:])
        peak = {k: [0.0, 0.0] for k in names}
        apart: dict = {k: [] for k in names[1:]}
        momentum = 0.0

        def note(name: str, rate: np.ndarray, peak: dict = peak) -> None:
            was = peak[name]
            peak[name] = [max(was[0], float(np.linalg.norm(rate))),
                          max(was[1], abs(float(rate @ axis)))]  # fmt: skip

        for k in range(steps):
            f = amp * np.sin(2.0 * np.pi * 2.0 * k * h - phase)
            rot = best_fit_rotation(fs.x, rest, mass)
            fs, _ = full.step(fs, f)
            turn = Rotation.from_matrix(rot.T @ best_fit_rotation(fs.x, rest, mass)).as_rotvec()
            note("full space", turn / h)  # body frame
            momentum = max(momentum, momentum_ratio(mass, fs.x, fs.v))

            def loads(
                state: tuple, f: np.ndarray = f, model: FloatingFramePrototype = floating
            ) -> tuple[np.ndarray, ...]:
                return model.generalised(state, following(model.world(state)[0], f))

            for name in names[1:]:
                if failed[name] is not None:
                    continue
                try:
                    if name.startswith("floating, f on z"):
                        free = name.endswith("torque-free")
                        states[name] = floating.step(states[name], f, torque_free=free)
                    else:
                        states[name] = floating.step(states[name], np.zeros(3), loads)
                except FloatingPointError as exc:
                    failed[name] = f"stopped at t = {k * h:.3f} s: {exc}"
                    continue
                note(name, states[name][4])
                if k + 1 in (steps // 2, steps):
                    d = floating.world(states[name])[0] - fs.x
                    apart[name].append(float(np.sqrt(mass @ (d * d).sum(1) / mass.sum()) / radius))
        out[h] = {"peak": peak, "momentum_full": momentum, "apart": apart, "failed": failed}
        print(f"dt = {h * 1e3:g} ms (full space max |L|/scale {momentum:.2e}):", flush=True)
        for name in names:
            said = " / ".join(f"{a:.3f}" for a in apart.get(name, [])) or "-"
            print(f"  {name:<28} frame peak {peak[name][0]:7.3g} rad/s, about the long axis "
                  f"{peak[name][1]:7.3g}; nodes from the full space's {said} (mid / end)"
                  + (f"; {failed[name]}" if failed.get(name) else ""), flush=True)  # fmt: skip
    return out


def swimming(robot, sub, seconds: float, dt: float) -> dict:
    """Open-loop swims from rest (no damping; the package's drag, ``FullSpaceModel``'s law for
    the prototype): the centre of mass's displacement and the largest turn of the linear
    model, the floating-frame prototype with actuation on z (body frame: f_a itself, and its
    torque-free law) and with the world-fixed modal forces, and the full space (world-fixed,
    as ``matching`` builds it, and following the body: ``actuation_frame="body"``, the
    counterpart of the torque-free law)."""
    from softrom_gym.envs.observations import orientation_rows

    basis, nodes, mass = sub.basis, robot.nodes, np.asarray(robot.fem_model().mass)
    n = len(mass)
    linear = build_reduced_model(
        robot, subspace=sub, contact="none", gravity=[0, 0, 0], fluid_density=1000.0,
        control_basis=np.eye(20)[:, :3], damping_beta=0.0, dt=dt,
    )  # fmt: skip
    full = FullSpaceModel.matching(linear, robot, basis)
    full_body = FullSpaceModel.matching(linear, robot, basis, actuation_frame="body")
    floating = FloatingFramePrototype(linear, basis, nodes, mass)
    rows = orientation_rows(nodes, mass, basis)
    rest = nodes - mass @ nodes / mass.sum()

    def drag(state: tuple) -> tuple[np.ndarray, ...]:
        x, v = floating.world(state)
        force, _ = full._drag(x, v, jacobian=False)
        return floating.generalised(state, force.reshape(n, 3))

    def turned(x: np.ndarray) -> float:  # the best-fit rotation's angle
        fit = best_fit_rotation(x, rest, mass)
        return float(np.linalg.norm(Rotation.from_matrix(fit).as_rotvec()))

    out: dict = {}
    steps = round(seconds / dt)
    weight = np.sqrt(mass.sum()) * G
    print(f"{robot.name}: open-loop swims of {seconds:g} s from rest, dt = {dt * 1e3:g} ms, "
          "no damping; centre of mass moved (m) and largest turn (rad)")  # fmt: skip
    for freq, order, scale in ((2.0, (0, 1, 2), 0.8), (2.0, (2, 1, 0), 0.8), (3.0, (1, 0, 2), 0.5)):
        phase = 2.0 * np.pi * np.asarray(order) / 3.0
        forces = [
            scale * weight * np.sin(2.0 * np.pi * freq * k * dt - phase) for k in range(steps)
        ]
        start = time.perf_counter()
        ls, fs, fb = linear.rest_state(), full.rest_state(), full_body.rest_state()
        rest_frame = (floating.com, np.eye(3), np.zeros(20), np.zeros(3), np.zeros(3), np.zeros(20))
        body, free, world = rest_frame, rest_frame, rest_frame
        keys = ("linear", "floating, f on z", "floating, torque-free", "floating, world-fixed f")
        most = dict.fromkeys((*keys, "full", "full, body-frame f"), 0.0)
        for k, f in enumerate(forces):
            ls, _ = linear.step(ls, f)
            fs, _ = full.step(fs, f)
            fb, _ = full_body.step(fb, f)
            body = floating.step(body, f, drag)
            free = floating.step(free, f, drag, torque_free=True)
            push = mass[:, None] * (basis[:, 6:9] @ f).reshape(n, 3)  # M U f, world-fixed

            def world_fixed(state: tuple, push: np.ndarray = push) -> tuple[np.ndarray, ...]:
                extra = floating.generalised(state, push)
                return tuple(a + b for a, b in zip(drag(state), extra, strict=True))

            world = floating.step(world, np.zeros(3), world_fixed)
            most["linear"] = max(most["linear"], float(np.linalg.norm(rows @ ls.q)))
            for key, frame in zip(keys[1:], (body, free, world), strict=True):
                angle = float(np.linalg.norm(Rotation.from_matrix(frame[1]).as_rotvec()))
                most[key] = max(most[key], angle)
            if k % 20 == 19:
                most["full"] = max(most["full"], turned(fs.x))
                most["full, body-frame f"] = max(most["full, body-frame f"], turned(fb.x))
        moved = {
            "linear": linear.com(ls.q) - floating.com,
            "floating, f on z": body[0] - floating.com,
            "floating, torque-free": free[0] - floating.com,
            "floating, world-fixed f": world[0] - floating.com,
            "full": full.com(fs.x) - floating.com,
            "full, body-frame f": full.com(fb.x) - floating.com,
        }
        label = f"{freq:g} Hz {'/'.join(str(120 * o) for o in order)} {scale:g} bw"
        out[label] = {k: {"moved": moved[k].tolist(), "turned": most[k]} for k in moved}
        for key in moved:
            size = np.linalg.norm(moved[key])
            print(f"  {label:<20} {key:<24} moved {size:6.3f} m {np.round(moved[key], 3)}, "
                  f"turned up to {most[key]:.3f} rad", flush=True)  # fmt: skip
        print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    return out


def core_against_prototype(robot, sub, stroke: float, seconds: float, dt: float) -> dict:
    """The package's floating frame (C++) against the prototype (torque-free law): the largest
    node distance between them and the seconds per step of each, in free flight under the
    stroke and swimming (the package's drag on both; the prototype's taken from the full
    space's law at the step's start, as in ``swimming``)."""
    basis, nodes, mass = sub.basis, robot.nodes, np.asarray(robot.fem_model().mass)
    n, steps = len(mass), round(seconds / dt)
    weight = np.sqrt(mass.sum()) * G
    out: dict = {}
    print(f"{robot.name}: the core's floating frame against the prototype, {seconds:g} s, "
          f"dt = {dt * 1e3:g} ms")  # fmt: skip
    for case, fluid in (("free flight", 0.0), ("swimming", 1000.0)):
        settings = dict(contact="none", gravity=[0, 0, 0], control_basis=np.eye(20)[:, :3],
                        damping_beta=0.0, dt=dt, fluid_density=fluid)  # fmt: skip
        linear = build_reduced_model(robot, subspace=sub, **settings)
        core = build_reduced_model(robot, subspace=sub, frame="floating", newton_tolerance=1e-9,
                                   **settings)  # fmt: skip
        prototype = FloatingFramePrototype(linear, basis, nodes, mass)
        loads = None
        if fluid > 0.0:
            full = FullSpaceModel.matching(linear, robot, basis)

            def loads(
                state: tuple, full: FullSpaceModel = full, model: FloatingFramePrototype = prototype
            ) -> tuple[np.ndarray, ...]:
                x, v = model.world(state)
                force, _ = full._drag(x, v, jacobian=False)
                return model.generalised(state, force.reshape(n, 3))

        amp = (stroke if fluid == 0.0 else 0.8) * weight
        phase = 2.0 * np.pi * np.arange(3) / 3.0
        state = core.rest_state()
        frame = (prototype.com, np.eye(3), np.zeros(20), np.zeros(3), np.zeros(3), np.zeros(20))
        apart, spent, iterations = 0.0, [0.0, 0.0], []
        for k in range(steps):
            f = amp * np.sin(2.0 * np.pi * 2.0 * k * dt - phase)
            start = time.perf_counter()
            state, info = core.step(state, f)
            spent[0] += time.perf_counter() - start
            iterations.append(info["newton_iterations"])
            start = time.perf_counter()
            frame = prototype.step(frame, f, loads, torque_free=True)
            spent[1] += time.perf_counter() - start
            x, _ = prototype.world(frame)
            apart = max(apart, float(np.abs(core.positions(state.q) - x).max()))
        turned = float(np.linalg.norm(state.q[3:6]))
        out[case] = {"apart_m": apart, "core_s_per_step": spent[0] / steps,
                     "prototype_s_per_step": spent[1] / steps, "turned_rad": turned,
                     "newton_iterations": float(np.mean(iterations))}  # fmt: skip
        print(f"  {case:<12} nodes apart at most {apart:.2e} m, turned {turned:.3f} rad; "
              f"core {1e3 * spent[0] / steps:.2f} ms/step ({np.mean(iterations):.2f} Newton "
              f"iterations), prototype {1e3 * spent[1] / steps:.1f} ms/step",
              flush=True)  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", choices=sorted(ROBOTS), default="beam")
    p.add_argument("--seconds", type=float, default=1.0)
    p.add_argument("--speed", type=float, default=0.2, help="RMS node speed at the start, m/s")
    p.add_argument("--spin", type=float, default=3.0, help="a second unactuated run's spin, rad/s")
    p.add_argument("--stroke", type=float, default=0.8, help="body weights (the xfail's 0.8)")
    p.add_argument("--dt", type=float, default=DT, help="time step, s")
    p.add_argument("--linearised-turns", action="store_true",
                   help="only what a linearised turn costs (every robot) and how far the "
                   "envs turn in an episode")  # fmt: skip
    p.add_argument("--best-bases", default=str(RUNS),
                   help="--linearised-turns: runs folder of recorded best bases for its MPC "
                   "episodes ('none': skip them)")  # fmt: skip
    p.add_argument("--swim", action="store_true",
                   help="only open-loop swims (--seconds each, 5 s is a fair choice): the "
                   "linear model, the prototype with drag, and the full space")  # fmt: skip
    p.add_argument("--follower", action="store_true",
                   help="only the stroke following the body, full space against the prototype "
                   "at dt, dt/2 and dt/4 (is the frame spin the material's?)")  # fmt: skip
    p.add_argument(
        "--modes",
        type=int,
        default=20,
        help="--follower: the deformation modes M of B_r (the other modes use 20)",
    )
    p.add_argument("--core", action="store_true",
                   help="only the package's floating frame against the prototype, in free "
                   "flight and swimming")  # fmt: skip
    p.add_argument("--step-convergence", action="store_true",
                   help="only the actuated stroke at dt, dt/2 and dt/4 (the prototype's frame "
                   "spin against the step)")  # fmt: skip
    args = p.parse_args(argv)
    if min(args.seconds, args.speed, args.stroke, args.dt) <= 0:
        p.error("--seconds, --speed, --stroke and --dt must be positive")
    if args.modes < 3:
        p.error(f"--modes must be at least 3 (the stroke drives three), got {args.modes}")
    dt = args.dt
    if args.linearised_turns:
        return linearised_turns(None if args.best_bases == "none" else Path(args.best_bases))
    robot = ROBOTS[args.robot]()
    if args.follower:
        return follower(robot, build_subspace(robot, args.modes), args.stroke, args.seconds, dt)
    sub = build_subspace(robot, 20)
    if args.core:
        return core_against_prototype(robot, sub, args.stroke, args.seconds, dt)
    if args.step_convergence:
        return step_convergence(robot, sub, args.stroke, args.seconds, dt)
    if args.swim:
        return swimming(robot, sub, args.seconds, dt)
    basis, nodes, mass = sub.basis, robot.nodes, np.asarray(robot.fem_model().mass)
    n, steps = len(mass), round(args.seconds / dt)
    m3 = np.repeat(mass, 3)
    linear = build_reduced_model(
        robot, subspace=sub, contact="none", gravity=[0, 0, 0],
        control_basis=np.eye(20)[:, :3], damping_beta=0.0, dt=dt,
    )  # fmt: skip
    full = FullSpaceModel(robot, actuation=basis[:, 6:9], dt=dt, gravity=(0.0, 0.0, 0.0),
                          damping_beta=0.0, ground_height=-1e3, newton_tolerance=1e-10)  # fmt: skip
    projected = ProjectedLinearModel(linear, basis, nodes, mass)
    floating = FloatingFramePrototype(linear, basis, nodes, mass)
    rest = nodes - mass @ nodes / mass.sum()
    radius = np.sqrt(mass @ (rest**2).sum(1) / mass.sum())
    print(f"{robot.name}: N = {n}, M = 20, dt = {dt * 1e3:g} ms, {args.seconds:g} s of free flight")
    head = f"{'case':<34} {'model':<30} {'max |L-L0|/scale':>16}"
    print(f"{head} {'distance from full, mid / end':>30}")
    out: dict = {}

    def report(case: str, name: str, ratios: list[float], dist: list[float] | None,
               failed: str | None = None) -> None:  # fmt: skip
        # failed: a note after the row (why a model stopped, how fast the frame turned)
        mid = len(dist) // 2 - 1 if dist else 0
        d = f"{dist[mid]:.3f} / {dist[-1]:.3f}" if dist and len(dist) == steps else "-"
        note = f"  ({failed})" if failed else ""
        print(f"{case:<34} {name:<30} {max(ratios):>16.2e} {d:>30}{note}", flush=True)
        row = {"max_momentum_ratio": max(ratios), "distance": dist, "note": failed}
        out[f"{case}: {name}"] = row

    # -- actuated: the xfail's stroke -----------------------------------------------------------
    amp = args.stroke * np.sqrt(mass.sum()) * G
    phase = 2.0 * np.pi * np.arange(3) / 3.0
    strokes = [amp * np.sin(2.0 * np.pi * 2.0 * k * dt - phase) for k in range(steps)]
    case = f"actuated, {args.stroke:g} body weights"
    fs, ratios = full.rest_state(), []
    for u in strokes:
        fs, _ = full.step(fs, u)
        ratios.append(momentum_ratio(mass, fs.x, fs.v))
    report(case, "full space (world-fixed forces)", ratios, None)
    ls, ratios = linear.rest_state(), []
    for u in strokes:
        ls, _ = linear.step(ls, u)
        ratios.append(momentum_ratio(mass, linear.positions(ls.q), (basis @ ls.qdot).reshape(n, 3)))
    report(case, "linear", ratios, None)
    for free, name in ((False, "floating frame (f on z)"), (True, "floating frame (torque-free)")):
        state = (floating.com, np.eye(3), np.zeros(20), np.zeros(3), np.zeros(3), np.zeros(20))
        ratios, failed, spin_max = [], None, 0.0
        for k, u in enumerate(strokes):
            try:
                state = floating.step(state, u, torque_free=free)
            except FloatingPointError as exc:
                failed = f"stopped at t = {k * dt:.3f} s: {exc}"
                break
            ratios.append(momentum_ratio(mass, *floating.world(state)))
            spin_max = max(spin_max, float(np.linalg.norm(state[4])))
        # how fast the frame turned: the slender-axis hazard of docs/FLOATING_FRAME.md
        spun = f"frame up to {spin_max:.3g} rad/s"
        report(case, name, ratios, None, f"{spun}; {failed}" if failed else spun)

    # -- unactuated: elastic forces alone ---------------------------------------------------------
    for spin in (0.0, args.spin):
        w0 = np.zeros(20)
        w0[:3] = [3.0, -2.0, 1.0]
        w0 *= args.speed * np.sqrt(mass.sum()) / np.linalg.norm(w0)  # RMS node speed = speed
        om0 = np.array([0.0, spin, 0.0])
        v0 = (basis[:, 6:] @ w0).reshape(n, 3) + np.cross(om0, rest)
        case = f"unactuated, {args.speed:g} m/s" + (f", spin {spin:g} rad/s" if spin else "")
        zeros = np.zeros(3)
        fs = FullSpaceState(nodes.copy(), v0.copy(), full.rest_state().impulses)
        l0 = np.sum(mass[:, None] * np.cross(rest, v0), axis=0)
        q0, qd0 = np.zeros(basis.shape[1]), basis.T @ (m3 * v0.ravel())  # B_r^T M v: exact here
        ls = cpp_sim.ReducedState(q0, qd0, linear.rest_state().impulses)
        pq = (q0.copy(), qd0.copy())
        fl = (floating.com, np.eye(3), np.zeros(20), np.zeros(3), om0.copy(), w0.copy())
        names = ("full space", "linear", "linear, projected", "floating frame")
        ratios_of: dict[str, list[float]] = {k: [] for k in names}
        dist_of: dict[str, list[float]] = {k: [] for k in names[1:]}
        failed_of: dict[str, str | None] = dict.fromkeys(names)
        start = time.perf_counter()
        for k in range(steps):
            fs, _ = full.step(fs)
            ratios_of["full space"].append(momentum_ratio(mass, fs.x, fs.v, l0))
            ls, _ = linear.step(ls, zeros)
            at = {"linear": (linear.positions(ls.q), (basis @ ls.qdot).reshape(n, 3))}
            if failed_of["linear, projected"] is None:
                try:
                    pq = projected.step(*pq, zeros)
                    at["linear, projected"] = (nodes + (basis @ pq[0]).reshape(n, 3),
                                               (basis @ pq[1]).reshape(n, 3))  # fmt: skip
                except FloatingPointError as exc:
                    failed_of["linear, projected"] = f"stopped at t = {k * dt:.3f} s: {exc}"
            if failed_of["floating frame"] is None:
                try:
                    fl = floating.step(fl, zeros)
                    at["floating frame"] = floating.world(fl)
                except FloatingPointError as exc:
                    failed_of["floating frame"] = f"stopped at t = {k * dt:.3f} s: {exc}"
            for name, (x, v) in at.items():
                ratios_of[name].append(momentum_ratio(mass, x, v, l0))
                d = x - fs.x
                dist_of[name].append(float(np.sqrt(mass @ (d * d).sum(1) / mass.sum()) / radius))
        for name in names:
            report(case, name, ratios_of[name], dist_of.get(name), failed_of[name])
        print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    return out


if __name__ == "__main__":
    main()
