"""The reduced model's step in the full space: the M -> 3N limit of a reduced gait.

:class:`FullSpaceModel` steps the same time discretisation, the same contact model and the
same fluid drag as :class:`cpp_sim.ReducedModel`'s staggered-projection walk and its swim, in
nodal coordinates instead of B_r's. With x_{n+1} = x_n + h v, the contact-free velocity v*
solves the implicit Euler step

    M (v - v_n) = h (M g + M B_d B_c f_c + f_e(x_n + h v) - alpha M v - beta K_0 v
                     + f_d + J_d (v - v_n)),

by Newton's method (M lumped, f_e every tetrahedron's stable Neo-Hookean force, K_0 the rest
stiffness of the Rayleigh term, B_d B_c the actuation's full-space mode shapes, so the same
f_c is the same force as in the reduced model, or, with ``actuation_frame="body"``, that
field turned with the body and made torque-free (:mod:`softrom_gym.body_frame`); f_d the
quadratic drag on the surface triangles advancing into still fluid, f = -1/2 rho C_d A
max(n.v, 0)^2 n shared by a triangle's three nodes, and J_d its velocity Jacobian, both at
the step's start: the reduced step's law and linearisation), and the step's velocity is the
staggered projection of v* in the metric A of the last Newton matrix: the normal problem
min 1/2 |v - v'|_A^2 s.t. v_z,i >= b_i on every candidate node (b_i = -z_i / h above the
ground, -beta_s z_i / h for a penetrating node), alternated with one reweighted least-squares
step of the Coulomb friction problem min 1/2 |v - v''|_A^2 + sum_i mu lambda_n,i |v_t,i|_eps,
until the contact nodes' velocities stop changing: the reduced model's ``solve_contacts`` with
B_r = I. A reduced B_r spanning all 3N directions computes the same trajectory (checked in
``tests/test_full_space.py``), so a gait's distance here is what the reduced model's distances
converge to as M grows.

In nodal coordinates each contact row is one node's coordinate, so the Delassus matrix
W = J A^-1 J^T is well conditioned, and both problems are solved over the impulses: one sparse
factorisation of A and 3k solves (k candidate nodes) per step, then k-sized dense algebra per
stagger. The Newton matrix uses each element's Hessian projected on the PSD cone (the reduced
reference uses the exact one while the matrix stays positive definite; they differ only where an
element's Hessian is indefinite). Penalty contact is not implemented.

This is a check, not a simulator to control: a sparse factorisation per Newton iteration
costs tens of milliseconds per step on the benchmark robots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_factor, solve_triangular
from scipy.optimize import nnls
from scipy.sparse.linalg import splu

import cpp_sim

from ._validate import real_array
from .body_frame import following_forces
from .robots import Robot

__all__ = ["FullSpaceModel", "FullSpaceState"]

# Rounds of adding the candidates a contact solve drove below their bounds (the reduced core's
# kMaxCandidateRounds).
_MAX_CANDIDATE_ROUNDS = 3


@dataclass
class FullSpaceState:
    """Nodal positions and velocities (N, 3), and each surface node's last contact impulse
    (n_s, 3: two tangential, then normal; N s), which warm-starts the next contact solve."""

    x: np.ndarray
    v: np.ndarray
    impulses: np.ndarray


class FullSpaceRollout(TypedDict):
    """What :meth:`FullSpaceModel.rollout` returns (a plain dict)."""

    com: np.ndarray
    converged: np.ndarray
    contact_converged: np.ndarray
    state: FullSpaceState


@dataclass
class FullSpaceModel:
    """Implicit Euler with staggered-projection ground contact (or none) and quadratic fluid
    drag (where ``fluid_density`` > 0) in the full space.

    Parameters
    ----------
    robot : Robot
    actuation : (3N, C) array, optional
        Full-space mode shapes of the controls: the force of f_c is M @ actuation @ f_c (N).
        For a reduced model's B_c, ``actuation = B_d @ B_c`` with B_d the deformation columns
        of B_r (:meth:`matching` builds it). The field is fixed in the world: it has no net
        force (B_d is mass-orthogonal to the translations) and no torque at rest, but a torque
        once the body has deformed or turned, which the reduced model's linearised rotation
        columns do not see (``benchmarks/study_angular_momentum.py``). ``actuation_frame``
        "body" turns it with the body instead.
    actuation_frame : {"world", "body"}
        "world" (default, the reduced model's actuation): the field above, fixed in the
        world. "body": the field turned by the body's best-fit rotation and made torque-free
        (:func:`softrom_gym.body_frame.following_forces`, taken at the step's start), so it
        is internal at every configuration, as an actuator built into the robot is; the
        reference for a floating frame's actuation (``docs/FLOATING_FRAME.md``).
    dt, gravity, friction, ground_height, contact_margin, contact_tolerance,
    friction_smoothing, stabilization, damping_alpha, damping_beta, newton_tolerance,
    max_newton_iterations, max_stagger_iterations, fluid_density, drag_coefficient
        As the :class:`cpp_sim.ReducedModel` settings of the same names (``damping_beta``
        times the rest stiffness K_0 on world velocities, the linear model's damping: once
        the body has turned it brakes rigid spin too, which ``FEMModel.step``'s K(x_n) and
        the floating frame's do not; README, the M limits); ``newton_tolerance``
        bounds the mass-weighted RMS of a Newton update, |dv|_M / sqrt(m) (m/s), and
        ``fluid_density`` > 0 switches the quadratic drag on (the swimmers'; kg/m^3).
    contact : {"staggered", "none"}
        The ground plane with staggered projection (the walkers'), or none (the swimmers').
    project_hessian : bool
        Project each element's Hessian on the PSD cone in the Newton matrix (default), which
        keeps it positive definite under any deformation; False uses the exact Hessian, as
        the reduced reference solver does while its matrix stays positive definite.
    """

    robot: Robot
    actuation: np.ndarray | None = None
    dt: float = 1.0 / 200.0
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    friction: float = 0.8
    ground_height: float = 0.0
    contact_margin: float = 1e-3
    contact_tolerance: float = 1e-4
    friction_smoothing: float | None = None
    stabilization: float = 0.2
    damping_alpha: float = 0.0
    damping_beta: float = 0.005
    newton_tolerance: float = 1e-6
    max_newton_iterations: int = 30
    max_stagger_iterations: int = 60
    project_hessian: bool = True
    contact: str = "staggered"
    fluid_density: float = 0.0
    drag_coefficient: float = 1.0
    actuation_frame: str = "world"
    # The frame of the reduced model ``matching`` made this one from ("linear" otherwise).
    _reduced_frame: str = field(default="linear", init=False, repr=False)

    def __post_init__(self) -> None:
        n = self.robot.num_nodes
        self._check_settings()
        if self.actuation is not None:
            a = real_array("actuation", self.actuation)
            if a.ndim != 2 or a.shape[0] != 3 * n or not np.all(np.isfinite(a)):
                raise ValueError(
                    f"actuation must be a finite (3N, C) = ({3 * n}, C) array, got shape {a.shape}"
                )
            self.actuation = a
        self._fem = self.robot.fem_model()
        self._mass = np.asarray(self._fem.mass)
        self._m3 = np.repeat(self._mass, 3)
        self._total_mass = float(np.sum(self._mass))
        self._rest = self.robot.nodes - self._mass @ self.robot.nodes / self._total_mass
        self._k0 = sp.csr_matrix(self._fem.stiffness(self.robot.nodes, project=False))
        self._surface = np.asarray(self.robot.surface_nodes, dtype=np.int64)
        self._faces = np.asarray(self.robot.surface_faces, dtype=np.int64)

    def _check_settings(self) -> np.ndarray:
        """Refuse a setting that is no finite number of the right sign. The model is a
        mutable dataclass, so :meth:`step` checks again: ``model.dt = -0.01`` after
        construction stepped backwards in time without a word, and a new ``gravity`` was
        ignored). Returns the gravity (3,) in m/s^2."""

        def real(name: str) -> float:
            value = getattr(self, name)
            ok = not isinstance(value, bool) and isinstance(value, (int, float, np.number))
            if not (ok and np.isfinite(value)):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
            return float(value)

        for name in ("dt", "contact_tolerance", "newton_tolerance"):
            if not real(name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if self.friction_smoothing is not None and not real("friction_smoothing") > 0:
            raise ValueError(
                f"friction_smoothing must be > 0 or None, got {self.friction_smoothing!r}"
            )
        if self.contact not in ("staggered", "none"):
            raise ValueError(f"contact must be 'staggered' or 'none', got {self.contact!r}")
        if self.actuation_frame not in ("world", "body"):
            raise ValueError(
                f"actuation_frame must be 'world' or 'body', got {self.actuation_frame!r}"
            )
        for name in ("friction", "contact_margin", "damping_alpha", "damping_beta",
                     "fluid_density", "drag_coefficient"):  # fmt: skip
            if not real(name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        real("ground_height")
        if not 0.0 <= real("stabilization") <= 1.0:
            raise ValueError(f"stabilization must be in [0, 1], got {self.stabilization!r}")
        for name in ("max_newton_iterations", "max_stagger_iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        try:
            g = real_array("gravity", self.gravity)
        except ValueError:
            g = None
        if g is None or g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"gravity must be 3 finite numbers (m/s^2), got {self.gravity!r}")
        return g

    @classmethod
    def matching(cls, model: cpp_sim.ReducedModel, robot: Robot, basis: np.ndarray,
                 actuation_frame: str | None = None) -> FullSpaceModel:  # fmt: skip
        """The full-space counterpart of a reduced ``model`` of ``robot`` with staggered or no
        contact, with B_r = ``basis`` (3N x (M + 6)): its settings (its drag too), and its B_c
        as full-space shapes, applied in ``actuation_frame``: by default as the reduced model
        applies them, "world" for a linear-frame model and "body" (turned with the body,
        torque-free) for a floating-frame one; either may be asked for. (The floating model
        compared with a world-fixed field stayed 3.7-5.6 mm apart at every dt, with "body"
        the gap closed as dt.)"""
        if actuation_frame is None:
            actuation_frame = "body" if str(model.frame) == "floating" else "world"
        said = str(model.contact)
        contact = said.lower()
        if contact not in ("staggered", "none"):
            raise ValueError(f"only staggered-projection contact or none has a full-space "
                             f"counterpart, the model's contact is {said!r}")  # fmt: skip
        if model.num_nodes != robot.num_nodes:
            raise ValueError(f"the model has {model.num_nodes} nodes and the robot "
                             f"{robot.num_nodes}: it was built for another robot")  # fmt: skip
        basis = np.asarray(basis, dtype=np.float64)
        bc = np.asarray(model.control_basis, dtype=np.float64)
        if basis.shape != (3 * robot.num_nodes, bc.shape[0] + 6):
            expected = (3 * robot.num_nodes, bc.shape[0] + 6)
            raise ValueError(f"basis has shape {basis.shape}, expected {expected} for this model")
        names = ("dt", "friction", "ground_height", "contact_margin", "contact_tolerance",
                 "friction_smoothing", "stabilization", "damping_alpha", "damping_beta",
                 "newton_tolerance", "max_newton_iterations", "max_stagger_iterations",
                 "fluid_density", "drag_coefficient")  # fmt: skip
        settings = {name: getattr(model, name) for name in names}
        full = cls(robot, basis[:, 6:] @ bc, gravity=tuple(model.gravity), contact=contact,
                   actuation_frame=actuation_frame, **settings)  # fmt: skip
        full._reduced_frame = str(model.frame)  # (state_from_reduced needs the model then)
        return full

    # -- states ----------------------------------------------------------------------------
    def rest_state(self) -> FullSpaceState:
        """The robot at rest: x the rest nodes (N, 3), v and the contact impulses zero."""
        n, ns = self.robot.num_nodes, len(self._surface)
        return FullSpaceState(self.robot.nodes.copy(), np.zeros((n, 3)), np.zeros((ns, 3)))

    def state_from_reduced(
        self,
        basis: np.ndarray,
        state: cpp_sim.ReducedState,
        model: cpp_sim.ReducedModel | None = None,
    ) -> FullSpaceState:
        """x = X + B_r q, v = B_r q_dot; the contact impulses carry over per surface node.

        ``basis`` is B_r (3N, M + 6), the reduced model's; a wrong shape, a complex or a
        non-finite entry raises ValueError (they were a matmul error or a state of NaNs).
        Given the reduced ``model``, the nodes are its ``positions(q)`` and
        ``velocities(q, q_dot)`` instead, which a floating-frame model needs: its q is the
        centre of mass, the rotation and the deformation, not coordinates in B_r (read as
        those, a beam 60 steps into a stroke was placed 0.16 m off). A model ``matching`` made
        from a floating-frame one refuses to go without it."""
        n = self.robot.num_nodes
        q = np.asarray(state.q)
        if model is not None:
            if model.num_nodes != n or model.dim != q.size:
                raise ValueError(f"model has {model.num_nodes} nodes and dimension {model.dim}, "
                                 f"expected {n} and the state's {q.size}")  # fmt: skip
            x = np.asarray(model.positions(q), dtype=np.float64)
            v = np.asarray(model.velocities(q, np.asarray(state.qdot)), dtype=np.float64)
            impulses = np.asarray(state.impulses, dtype=np.float64).reshape(-1, 3).copy()
            return FullSpaceState(x, v, impulses)
        if self._reduced_frame != "linear":
            raise ValueError("this model matches a floating-frame reduced model, whose q is not "
                             "coordinates in B_r: pass model= (the reduced model)")  # fmt: skip
        basis = real_array("basis", basis)
        if basis.shape != (3 * n, q.size):
            raise ValueError(f"basis has shape {basis.shape}, expected (3N, M + 6) = "
                             f"({3 * n}, {q.size}) for this robot and state")  # fmt: skip
        if not np.all(np.isfinite(basis)):
            raise ValueError("basis has a non-finite entry")
        x = self.robot.nodes + (basis @ q).reshape(n, 3)
        v = (basis @ np.asarray(state.qdot)).reshape(n, 3)
        impulses = np.asarray(state.impulses, dtype=np.float64).reshape(-1, 3).copy()
        return FullSpaceState(x, v, impulses)

    def com(self, x: np.ndarray) -> np.ndarray:
        """Centre of mass (3,) of positions x (N, 3), in m."""
        return self._mass @ self._nodal("x", x) / self._total_mass

    def _nodal(self, name: str, value: object, rows: int | None = None) -> np.ndarray:
        """``value`` as a finite real (rows, 3) array (rows defaults to N); a wrong shape, a
        complex, boolean or non-finite entry is named here rather than surfacing as a
        broadcasting error, a dropped imaginary part or a 'Newton step diverged'."""
        rows = self.robot.num_nodes if rows is None else rows
        a = real_array(name, value)
        if a.shape != (rows, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({rows}, 3)")
        bad = np.argwhere(~np.isfinite(a))
        if bad.size:
            raise ValueError(f"{name} has a non-finite value ({a[tuple(bad[0])]}) at row "
                             f"{bad[0][0]}")  # fmt: skip
        return a

    # -- one step --------------------------------------------------------------------------
    def step(self, state: FullSpaceState, controls: np.ndarray | None = None
             ) -> tuple[FullSpaceState, dict]:  # fmt: skip
        """One step under controls f_c (C,); returns the new state and an info dict
        (``newton_iterations``, ``converged``, ``stagger_iterations``, ``contact_converged``,
        ``active_rows``, ``contacts``)."""
        gravity = self._check_settings()
        h = self.dt
        m3 = self._m3
        n = self.robot.num_nodes
        x_n = self._nodal("state.x", state.x).ravel()
        v_n = self._nodal("state.v", state.v).ravel()
        warm = self._nodal("state.impulses", state.impulses, rows=len(self._surface))
        f_ext = m3 * np.tile(gravity, n)
        if controls is not None:
            actuation = self.actuation
            if actuation is None:
                raise ValueError(
                    "this model has no actuation, so it takes no controls (give "
                    "actuation, or FullSpaceModel.matching a reduced model)"
                )
            fc = real_array("controls", controls)
            if fc.shape != (actuation.shape[1],) or not np.all(np.isfinite(fc)):
                raise ValueError(f"controls must be finite with shape "
                                 f"({actuation.shape[1]},), got {fc.shape}")  # fmt: skip
            field = actuation @ fc
            if self.actuation_frame == "body":
                push = following_forces(
                    x_n.reshape(n, 3), self._rest, self._mass, field.reshape(n, 3)
                )
                f_ext = f_ext + push.ravel()
            else:
                f_ext = f_ext + m3 * field
        diag = sp.diags(m3 * (1.0 + h * self.damping_alpha))
        damping = h * self.damping_beta * self._k0
        drag_f = drag_j = None
        if self.fluid_density > 0.0:  # at the step's start, linearised in v (the reduced step's)
            drag_f, drag_j = self._drag(x_n.reshape(n, 3), v_n.reshape(n, 3))
        v = v_n.copy()
        info = {"newton_iterations": 0, "converged": False}
        scale = np.sqrt(self._total_mass)
        for it in range(int(self.max_newton_iterations)):
            x = (x_n + h * v).reshape(n, 3)
            try:
                f = np.asarray(self._fem.forces(x)).ravel()
            except ValueError as e:  # x came from the iteration, so the iteration is at fault
                # (The reduced reference's Newton, which this mirrors, takes full steps too:
                # far outside the envs' settings, e.g. 4 m/s random node velocities at
                # dt = 20 ms, it diverges where FEMModel's line-searched step does not.)
                raise FloatingPointError(
                    f"the Newton step diverged at iteration {it + 1} ({e})"
                ) from e
            r = m3 * (v - v_n) - h * (f_ext + f) + h * self.damping_alpha * m3 * v
            r += damping @ v
            a = (
                diag
                + h * h * sp.csr_matrix(self._fem.stiffness(x, project=self.project_hessian))
                + damping
            )
            if drag_f is not None and drag_j is not None:
                r -= h * (drag_f + drag_j @ (v - v_n))
                a = a - h * drag_j
            factor = splu(sp.csc_matrix(a))
            dv = -factor.solve(r)
            info["newton_iterations"] = it + 1
            if not np.all(np.isfinite(dv)):
                raise FloatingPointError(f"the Newton step diverged at iteration {it + 1}")
            v += dv
            if np.sqrt(np.sum(m3 * dv * dv)) / scale < self.newton_tolerance:
                info["converged"] = True
                break
        if self.contact == "staggered":
            v, impulses, contact = self._contacts(x_n, v, factor, warm)
        else:
            impulses = np.zeros_like(warm)
            contact = {"stagger_iterations": 0, "contact_converged": True, "active_rows": 0,
                       "contacts": 0}  # fmt: skip
        info.update(contact)
        new = FullSpaceState((x_n + h * v).reshape(n, 3), v.reshape(n, 3), impulses)
        return new, info

    def _drag(self, x: np.ndarray, v: np.ndarray, jacobian: bool = True
              ) -> tuple[np.ndarray, sp.csr_matrix | None]:  # fmt: skip
        """Quadratic drag at positions x and velocities v (N, 3): the force (3N,) and its
        velocity Jacobian J_d (3N x 3N, symmetric negative semi-definite). Each surface
        triangle advancing into the fluid (n.v > 0, v the mean of its nodes') takes
        f = -1/2 rho C_d A (n.v)^2 n, a third on each node, so J_d's 3 x 3 blocks between two
        of its nodes are -2 (1/2 rho C_d A) (n.v) n n^T / 9 (the reduced model's law)."""
        f3 = self._faces
        a, b, d = x[f3[:, 0]], x[f3[:, 1]], x[f3[:, 2]]
        normal = np.cross(b - a, d - a)
        twice_area = np.linalg.norm(normal, axis=1)
        keep = twice_area > 0.0
        normal[keep] /= twice_area[keep, None]
        speed = np.einsum("fa,fa->f", normal, (v[f3[:, 0]] + v[f3[:, 1]] + v[f3[:, 2]]) / 3.0)
        adv = keep & (speed > 0.0)
        coef = 0.5 * self.fluid_density * self.drag_coefficient * 0.5 * twice_area[adv]
        n_adv, s_adv, faces = normal[adv], speed[adv], f3[adv]
        force = np.zeros_like(x)
        share = -(coef * s_adv**2)[:, None] * n_adv / 3.0
        for corner in range(3):
            np.add.at(force, faces[:, corner], share)
        if not jacobian:
            return force.ravel(), None
        blocks = (-2.0 / 9.0 * coef * s_adv)[:, None, None] * np.einsum("fa,fb->fab", n_adv, n_adv)
        # the 9 coordinates of each face's nodes, and every pair of them: the same 3 x 3 block
        # between any two of its nodes
        dofs = (3 * faces[:, :, None] + np.arange(3)).reshape(-1, 9)
        rows = np.broadcast_to(dofs[:, :, None], (len(faces), 9, 9))
        cols = np.broadcast_to(dofs[:, None, :], (len(faces), 9, 9))
        vals = np.tile(blocks, (1, 3, 3))
        size = x.size
        jac = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(size, size))
        return force.ravel(), jac

    def _normal_velocity_bound(self, z: np.ndarray) -> np.ndarray:
        """The least normal velocity a node at height z above the ground may end a step with
        (the core's ``normal_velocity_bound``): it may reach the plane, and a penetrating
        node rises by a fraction ``stabilization`` of its depth."""
        return np.where(z >= 0.0, -z / self.dt, -self.stabilization * z / self.dt)

    def _candidates(self, z: np.ndarray, vn: np.ndarray) -> np.ndarray:
        """The contact candidates among the surface nodes at heights z above the ground with
        contact-free normal velocities vn: every node on or near the ground, or reaching it
        within two steps (the reduced core's rule)."""
        return np.flatnonzero(z + 2.0 * self.dt * np.minimum(vn, 0.0) < self.contact_margin)

    def _contacts(self, x_n: np.ndarray, v: np.ndarray, factor, warm: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, dict]:  # fmt: skip
        """Project the contact-free velocity v (v*) onto the ground's conditions; returns the
        step's velocity, the surface nodes' impulses (n_s, 3) and the contact info. The
        candidates are picked from v*, and the impulses on them can drive another node below
        its bound (a lever: the reduced cross walker's arm, session 51). Such nodes join the
        candidates and the solve is repeated from v*, warm-started from the impulses it found,
        at most ``_MAX_CANDIDATE_ROUNDS`` times, as the reduced core does (49d2956); a step
        still missing some is reported with ``contact_converged`` False. Along 300-step
        full-space gaits of the cross and beam walkers it never fired (candidates are picked
        two steps ahead, and no mode couples a far node to a near one), so it is the core's
        safeguard kept, and those answers are unchanged."""
        surface = self._surface
        z = x_n[3 * surface + 2] - self.ground_height
        active = self._candidates(z, v[3 * surface + 2])
        impulses = np.zeros((len(surface), 3))
        info = {"stagger_iterations": 0, "contact_converged": True, "active_rows": len(active),
                "contacts": 0}  # fmt: skip
        if len(active) == 0:
            return v, impulses, info
        tol = self.contact_tolerance
        # (less the tolerance staggering stops within)
        bound = self._normal_velocity_bound(z) - tol
        staggers = 0
        for round_ in range(_MAX_CANDIDATE_ROUNDS + 1):
            v_end, impulses, info = self._solve_candidates(x_n, v, factor, warm, active)
            staggers += info["stagger_iterations"]
            member = np.zeros(len(surface), dtype=bool)
            member[active] = True
            missed = np.flatnonzero(~member & (v_end[3 * surface + 2] < bound))
            if missed.size == 0:
                break
            if round_ == _MAX_CANDIDATE_ROUNDS:  # still missing some: say so
                info["contact_converged"] = False
                break
            active = np.concatenate([active, missed])
            warm = impulses  # the impulses it found; the new candidates' are zero
        info["stagger_iterations"] = staggers
        info["active_rows"] = len(active)
        return v_end, impulses, info

    def _solve_candidates(self, x_n: np.ndarray, v: np.ndarray, factor, warm: np.ndarray,
                          active: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:  # fmt: skip
        """The staggered projection of v on the surface nodes ``active`` (indices into the
        surface nodes), warm-started from ``warm`` (n_s, 3)."""
        mu, tol = self.friction, self.contact_tolerance
        surface = self._surface
        z = x_n[3 * surface + 2] - self.ground_height
        impulses = np.zeros((len(surface), 3))
        k = len(active)
        info = {"stagger_iterations": 0, "contact_converged": True, "active_rows": k,
                "contacts": 0}  # fmt: skip
        nodes = surface[active]
        # Contact rows: k normals, then (x, y) of each candidate; impulses in the same order.
        rows = np.concatenate([3 * nodes + 2, np.column_stack([3 * nodes, 3 * nodes + 1]).ravel()])
        unit = np.zeros((v.size, 3 * k))
        unit[rows, np.arange(3 * k)] = 1.0
        g = factor.solve(unit)  # A^-1 J^T
        w = g[rows]  # the Delassus matrix J A^-1 J^T
        w = 0.5 * (w + w.T)
        c = v[rows]  # contact velocities of v*
        b = self._normal_velocity_bound(z[active])
        lam = np.concatenate([np.maximum(warm[active, 2], 0.0), warm[active, :2].ravel()])
        wnn = cho_factor(w[:k, :k], lower=True)
        low = np.tril(wnn[0])

        def normal_solve() -> bool:
            # min over lambda_n >= 0 of 1/2 l^T W_nn l - l^T (b - J_n v'), v' the velocity
            # with the friction impulses held: with W_nn = L L^T, an NNLS in L^T l.
            d = b - (c[:k] + w[:k, k:] @ lam[k:])
            lam_n, _ = nnls(low.T, solve_triangular(low, d, lower=True), maxiter=50 * k)
            lam[:k] = lam_n
            vel = c[:k] + w[:k] @ lam
            return bool(np.max(b - vel) <= tol)

        eps = tol if self.friction_smoothing is None else self.friction_smoothing
        # The first stagger is judged against the warm start's velocity, the iterate it
        # continues, as the reduced core does since session 51: judged against v*, a warm start
        # whose friction alone lifted every candidate ended the step at once, "converged" at
        # zero impulses with the normal conditions unmet.
        previous = c + w @ lam
        converged = False
        ok = True
        stagger = 0
        while stagger < int(self.max_stagger_iterations):
            stagger += 1
            ok = normal_solve() and ok
            # One reweighted least-squares step of the friction problem, normals held.
            vel = c + w @ lam
            loaded = np.flatnonzero((lam[:k] > 0.0) & (mu > 0.0))
            second = c + w[:, :k] @ lam[:k]  # J v'', no friction impulse
            lam[k:] = 0.0
            if loaded.size:
                cols = k + np.column_stack([2 * loaded, 2 * loaded + 1]).ravel()
                ut = vel[cols].reshape(-1, 2)
                weight = mu * lam[loaded] / np.sqrt(np.sum(ut * ut, axis=1) + eps * eps)
                dw = np.repeat(weight, 2)
                # (A + J_L^T D J_L) v = A v''  =>  (I + W_LL D) J_L v = J_L v''
                u = np.linalg.solve(np.eye(cols.size) + w[np.ix_(cols, cols)] * dw, second[cols])
                lam[cols] = -dw * u
            vel = c + w @ lam
            change = np.max(np.abs(vel[:k] - previous[:k]))
            held = k + np.column_stack([2 * np.flatnonzero(lam[:k] > 0.0),
                                        2 * np.flatnonzero(lam[:k] > 0.0) + 1]).ravel()  # fmt: skip
            if held.size:
                change = max(change, float(np.max(np.abs(vel[held] - previous[held]))))
            previous = vel
            if change < tol:
                converged = True
                break
        # Capped after a friction half, or converged with a candidate that half left below
        # its bound by more than the tolerance (the stopping test bounds the last stagger's
        # change, not that violation): restore the normal constraints, friction held, as the
        # core does (session 53).
        if not converged or np.max(b - (c[:k] + w[:k] @ lam)) > tol:
            ok = normal_solve() and ok
        v = v + g @ lam
        lam_t = lam[k:].reshape(k, 2)
        bound = mu * lam[:k]
        norm = np.linalg.norm(lam_t, axis=1)
        over = norm > bound
        lam_t[over] *= (bound[over] / norm[over])[:, None]
        impulses[active, :2] = lam_t
        impulses[active, 2] = lam[:k]
        info.update(stagger_iterations=stagger, contact_converged=converged and ok,
                    contacts=int(np.sum(lam[:k] > 0.0)))  # fmt: skip
        return v, impulses, info

    # -- many steps ------------------------------------------------------------------------
    def rollout(self, state: FullSpaceState, controls: np.ndarray, *, progress: bool = False
                ) -> FullSpaceRollout:  # fmt: skip
        """Step through ``controls`` (H, C), one row per step; returns ``com`` (H, 3) after
        each step, ``converged`` and ``contact_converged`` (H,) flags, and the final
        ``state``."""
        u = np.asarray(controls, dtype=np.float64)
        if u.ndim != 2:
            raise ValueError(f"controls must be (H, C), got shape {u.shape}")
        com = np.empty((len(u), 3))
        flags = np.zeros((len(u), 2), dtype=bool)
        steps = range(len(u))
        if progress:
            from tqdm import tqdm

            steps = tqdm(steps, desc="full space", unit="step", leave=False)
        unactuated = self.actuation is None and u.shape[1] == 0  # (H, 0): no controls
        for t in steps:
            state, info = self.step(state, None if unactuated else u[t])
            com[t] = self.com(state.x)
            flags[t] = info["converged"], info["contact_converged"]
        return {"com": com, "converged": flags[:, 0], "contact_converged": flags[:, 1],
                "state": state}  # fmt: skip
