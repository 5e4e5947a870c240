"""
softrom C++ simulation core (FEM, reduced model, contact, batched rollouts).
"""
from __future__ import annotations
import numpy
import numpy.typing
import typing
__all__: list[str] = ['FEMModel', 'ReducedConfig', 'ReducedModel', 'ReducedState', 'kernel_instruction_set', 'reduced_element_forces']
class FEMModel:
    """
    Full-space finite-element model of a soft body.
    
    Linear tetrahedra with the stable Neo-Hookean material (Smith et al. 2018)
    
        Psi(F) = mu/2 (I_C - 3) - mu (J - 1) + lambda/2 (J - 1)^2,  lambda = lambda_Lame + mu,
    
    which reduces to linear elasticity (E, nu) at small strain and stays restoring under
    inversion. Lumped mass, gravity (default (0, 0, -9.81) m/s^2, z up), Rayleigh damping
    D = damping_alpha M + damping_beta K(x_n). SI units throughout; positions are (N, 3) arrays.
    
    Parameters
    ----------
    nodes : (N, 3) array of float
        Rest positions in metres.
    tets : (T, 4) array of int
        Node indices of each tetrahedron, positively oriented (positive rest volume).
    youngs_modulus : float
        E in Pa, > 0.
    poisson_ratio : float
        nu, in (-1, 0.5).
    density : float
        rho in kg/m^3, > 0.
    """
    def __init__(self, nodes: typing.Any, tets: typing.Any, youngs_modulus: typing.SupportsFloat | typing.SupportsIndex, poisson_ratio: typing.SupportsFloat | typing.SupportsIndex, density: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    def energy(self, x: typing.Any) -> float:
        """
        Elastic potential energy E(x) in J for positions x (N, 3). Raises ValueError where positions so large that the material model overflows make it non-finite.
        """
    def forces(self, x: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Internal elastic forces -dE/dx (N, 3) in N.
        """
    def step(self, x: typing.Any, v: typing.Any, dt: typing.Any, fixed: typing.Any = None) -> tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64]]:
        """
        One implicit Euler step; returns (x_new, v_new), each (N, 3).
        
        Newton's method on the incremental potential with a backtracking line search and a sparse
        Cholesky solve (see ``solver``). ``fixed`` (boolean mask (N,) or distinct node indices; empty fixes
        none) clamps nodes in place.
        Raises RuntimeError if the step diverges.
        """
    def stiffness(self, x: typing.Any, project: bool = False) -> typing.Any:
        """
        Stiffness K = d(-forces)/dx as a scipy.sparse CSR (3N, 3N) matrix; row 3i+k is node i, axis k. project=True clamps each element's Hessian to be PSD, as step() does (a 9x9 eigensolver for solver='reference', the closed-form eigensystem otherwise).
        """
    @property
    def damping_alpha(self) -> float:
        """
        Mass-proportional Rayleigh damping, 1/s (default 0: it would also damp free flight).
        """
    @damping_alpha.setter
    def damping_alpha(self, arg1: typing.Any) -> None:
        ...
    @property
    def damping_beta(self) -> float:
        """
        Stiffness-proportional Rayleigh damping, s (default 0.005).
        """
    @damping_beta.setter
    def damping_beta(self, arg1: typing.Any) -> None:
        ...
    @property
    def density(self) -> float:
        ...
    @property
    def gravity(self) -> list[float]:
        """
        Gravitational acceleration (3,), m/s^2.
        """
    @gravity.setter
    def gravity(self, arg1: typing.Any) -> None:
        ...
    @property
    def last_step_stats(self) -> dict:
        """
        Newton iterations, factorisations and line-search energy evaluations, final max |dx|/dt, convergence flag and wall seconds per phase (assemble_s, gradient_s, factorize_s, solve_s, line_search_s) of the last step.
        """
    @property
    def mass(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        Lumped mass per node (N,), kg.
        """
    @property
    def max_newton_iterations(self) -> int:
        """
        Cap on Newton iterations per step (at most 1000: a step is interrupted only between steps).
        """
    @max_newton_iterations.setter
    def max_newton_iterations(self, arg1: typing.Any) -> None:
        ...
    @property
    def newton_tolerance(self) -> float:
        """
        Newton stops when max |dx| / dt falls below this, m/s.
        """
    @newton_tolerance.setter
    def newton_tolerance(self, arg1: typing.Any) -> None:
        ...
    @property
    def num_nodes(self) -> int:
        ...
    @property
    def num_tets(self) -> int:
        ...
    @property
    def poisson_ratio(self) -> float:
        ...
    @property
    def rest_positions(self) -> numpy.typing.NDArray[numpy.float64]:
        ...
    @property
    def solver(self) -> str:
        """
        How step() solves its Newton systems. 'supernodal_llt' (default), 'simplicial_llt' and 'simplicial_ldlt' share the fast step (closed-form element projection, in-place assembly on a pre-permuted pattern, symbolic analysis once, no factorisation once a bound proves convergence) and differ in the sparse Cholesky; 'reference' is the original step, kept to measure against. All converge to the same implicit-Euler solution under newton_tolerance.
        """
    @solver.setter
    def solver(self, arg1: typing.Any) -> None:
        ...
    @property
    def volume(self) -> float:
        """
        Total rest volume, m^3.
        """
    @property
    def volumes(self) -> numpy.typing.NDArray[numpy.float64]:
        """
        Rest volume per tetrahedron (T,), m^3.
        """
    @property
    def youngs_modulus(self) -> float:
        ...
class ReducedState:
    """
    State of a reduced model: q_r and qdot_r (M + 6,) and the contact impulses (3 per surface
    node) that warm-start the next contact solve. Copies in, copies out; picklable (by its
    constructor's arguments, so an unpickled state is checked as a new one is).
    """
    def __copy__(self) -> ReducedState:
        ...
    def __deepcopy__(self, arg0: dict) -> ReducedState:
        ...
    def __init__(self, q: typing.Any, qdot: typing.Any, impulses: typing.Any) -> None:
        ...
    def __reduce__(self) -> tuple[type, tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64]]]:
        ...
    def __repr__(self) -> str:
        ...
    def copy(self) -> ReducedState:
        ...
    @property
    def impulses(self) -> numpy.typing.NDArray[numpy.float64]:
        ...
    @property
    def q(self) -> numpy.typing.NDArray[numpy.float64]:
        ...
    @property
    def qdot(self) -> numpy.typing.NDArray[numpy.float64]:
        ...
class ReducedModel:
    """
    Reduced-order soft body in the simulation space B_r (softrom_gym.rom.build_reduced_model is
    the Python front end that builds the basis and cubature).
    
    q_r = (3 rigid translations, 3 linearised rotations, M deformation coordinates),
    x = X + B_r q_r, B_r^T M B_r = I. Implicit Euler with Newton on the (M + 6)-dimensional system; elastic forces by cubature;
    ground contact by staggered projection (default) or penalty; quadratic drag when
    fluid_density > 0; actuation f_r = B_c f_c on deformation coordinates only.
    """
    SOLVERS: typing.ClassVar[tuple] = ('reference', 'fast')
    def __init__(self, nodes: typing.Any, tets: typing.Any, youngs_modulus: typing.SupportsFloat | typing.SupportsIndex, poisson_ratio: typing.SupportsFloat | typing.SupportsIndex, density: typing.SupportsFloat | typing.SupportsIndex, basis: typing.Any, cubature_elements: typing.Any, cubature_weights: typing.Any, surface_nodes: typing.Any, surface_faces: typing.Any) -> None:
        ...
    def _elastic_energy_fast(self, q_e: typing.Any) -> float:
        """
        The cubature energy as the fast solver's line search computes it (for its tests).
        """
    def _floating_residual(self, state: ReducedState, f_c: typing.Any, x: typing.Any) -> tuple[numpy.typing.NDArray[numpy.float64], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]]:
        """
        The floating frame's implicit-Euler residual at x = (u', omega', w') from `state`, and its Jacobian (for the tests' finite-difference check).
        """
    def _penalty_load(self, q: typing.Any, v: typing.Any, x: typing.Any = None) -> tuple[numpy.typing.NDArray[numpy.float64], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"], typing.Any]:
        """
        The linear frame's penalty ground force at q + dt v, its Jacobian in v as the solver forms it (the symmetric part, and the friction's coupling C), and C x as the Newton step applies it (None without x): for the tests.
        """
    def com(self, q: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Centre of mass (3,) of reduced coordinates q.
        """
    def elastic_energy(self, q_e: typing.Any) -> float:
        """
        Elastic energy E(X + B_e q_e) in J by cubature (sum_k w_k E_k over the cubature elements k), q_e = q[3:] (M + 3,): the rotations and deformation coordinates; translations store no energy.
        """
    def elastic_forces(self, q_e: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Reduced elastic force B_e^T f(X + B_e q_e) (M + 3,) by cubature, q_e = q[3:].
        """
    def elastic_stiffness(self, q_e: typing.Any, project: bool = False) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        """
        Reduced stiffness -d(elastic_forces)/dq_e = sum_k w_k U_k^T H_k U_k (M + 3, M + 3) by cubature, H_k element k's energy Hessian. project=True clamps each H_k to be PSD first (the implicit step does not: where its Newton matrix is not positive definite it clamps the summed stiffness instead).
        """
    def min_volume_ratio(self, q: typing.Any) -> float:
        """
        min det F over every tetrahedron at reduced coordinates q: the smallest deformed-to-rest volume ratio J. J <= 0: an element is inverted (a material too soft for the loads).
        """
    def positions(self, q: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Node positions (N, 3) of reduced coordinates q (in the model's `frame`).
        """
    def rest_state(self) -> ReducedState:
        """
        The undeformed state at rest: q = qdot = 0 (M + 6,), no contact impulses.
        """
    def rollout(self, state: typing.Any, controls: typing.Any, threads: typing.Any = None, observe: typing.Any = None) -> dict:
        """
        B rollouts of H steps from one state (or a sequence of B states), controls (B, H, C).
        
        Returns a dict: rewards (B, H) = d . v_com dt per step, q / qdot (B, M + 6) and impulses
        (B, 3 n_surface) of the final states, diverged (B,), converged (B,: every step's Newton and
        contact solve reached its tolerance; False for a diverged rollout), good_steps (B,: the
        steps solved before the one that diverged; H for a rollout that did not) and com (B, H, 3);
        with `observe` (P x (M + 6)), also observed (B, H, P) = observe @ q_r after each step. Rollouts run on
        `threads` C++ threads with the GIL released; results do not depend on the thread count. A
        diverged rollout keeps its last good state and earns zero reward from then on. Called from
        the main thread, Ctrl-C stops it within about 0.1 s (after the step in progress) and raises
        KeyboardInterrupt.
        """
    def step(self, state: ReducedState, f_c: typing.Any = None) -> tuple[ReducedState, dict]:
        """
        One implicit step; returns (new_state, info). A diverged step returns the input state and info['diverged'] = True and does not raise (a state or f_c of the wrong size raises ValueError).
        """
    def velocities(self, q: typing.Any, qdot: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Node velocities (N, 3) of reduced coordinates q and velocities qdot (in the model's `frame`: B_r qdot, or u + R (omega x r_i + U_i w)).
        """
    @property
    def C(self) -> int:
        """
        control dimension
        """
    @property
    def M(self) -> int:
        """
        deformation coordinates
        """
    @property
    def config(self) -> ReducedConfig:
        """
        A copy of all settings (ReducedConfig); assign one to change several at once.
        """
    @config.setter
    def config(self, arg1: ReducedConfig) -> None:
        ...
    @property
    def contact(self) -> typing.Any:
        """
        'staggered' (default: staggered projection, the accurate model), 'penalty' (an approximate spring ground, slower than 'staggered' with the fast solver) or 'none'
        """
    @contact.setter
    def contact(self, arg1: typing.Any) -> None:
        ...
    @property
    def contact_margin(self) -> typing.Any:
        """
        m: surface nodes predicted closer than this to the ground are contact candidates
        """
    @contact_margin.setter
    def contact_margin(self, arg1: typing.Any) -> None:
        ...
    @property
    def contact_tolerance(self) -> typing.Any:
        """
        staggered projection stops when contact-node velocities change less than this, m/s
        """
    @contact_tolerance.setter
    def contact_tolerance(self, arg1: typing.Any) -> None:
        ...
    @property
    def control_basis(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        """
        B_c, (M, C), orthonormal: f_r = B_c f_c acts on the deformation coordinates.
        """
    @control_basis.setter
    def control_basis(self, arg1: typing.Any) -> None:
        ...
    @property
    def damping_alpha(self) -> typing.Any:
        """
        Rayleigh damping on all reduced coordinates, 1/s
        """
    @damping_alpha.setter
    def damping_alpha(self, arg1: typing.Any) -> None:
        ...
    @property
    def damping_beta(self) -> typing.Any:
        """
        Rayleigh damping times the rest stiffness K_0, s
        """
    @damping_beta.setter
    def damping_beta(self, arg1: typing.Any) -> None:
        ...
    @property
    def dim(self) -> int:
        """
        M + 6
        """
    @property
    def direction(self) -> typing.Any:
        """
        unit task direction d; per-step reward d . v_com dt
        """
    @direction.setter
    def direction(self, arg1: typing.Any) -> None:
        ...
    @property
    def drag_coefficient(self) -> typing.Any:
        """
        C_d of the quadratic drag
        """
    @drag_coefficient.setter
    def drag_coefficient(self, arg1: typing.Any) -> None:
        ...
    @property
    def dt(self) -> typing.Any:
        """
        time step h, s
        """
    @dt.setter
    def dt(self, arg1: typing.Any) -> None:
        ...
    @property
    def fluid_density(self) -> typing.Any:
        """
        kg/m^3; > 0 turns quadratic surface drag on
        """
    @fluid_density.setter
    def fluid_density(self, arg1: typing.Any) -> None:
        ...
    @property
    def frame(self) -> typing.Any:
        """
        'linear' (default: x = X + B_r q, rotations linearised) or 'floating' (x = c + R (X + U z) with an exact rotation: q = (sqrt(m) (c - c_0), rotation vector of R, z), qdot = (sqrt(m) c', body-frame angular velocity, z'); actuation follows the body, so free flight keeps the angular momentum; any contact; solver='fast' freezes the Newton matrix's stiffness at K_0, 'reference' is exact Newton)
        """
    @frame.setter
    def frame(self, arg1: typing.Any) -> None:
        ...
    @property
    def friction(self) -> typing.Any:
        """
        Coulomb coefficient mu
        """
    @friction.setter
    def friction(self, arg1: typing.Any) -> None:
        ...
    @property
    def friction_smoothing(self) -> typing.Any:
        """
        eps (m/s) of staggered projection's smoothed friction, sqrt(|v_t|^2 + eps^2): sticking nodes creep at about eps. None (default): contact_tolerance, so that tightening contact_tolerance alone also sharpens the friction law; set it to keep the law while the stop tightens
        """
    @friction_smoothing.setter
    def friction_smoothing(self, arg1: typing.Any) -> None:
        ...
    @property
    def gravity(self) -> typing.Any:
        """
        gravitational acceleration (3,), m/s^2
        """
    @gravity.setter
    def gravity(self, arg1: typing.Any) -> None:
        ...
    @property
    def ground_height(self) -> typing.Any:
        """
        height of the ground plane z = ground_height, m
        """
    @ground_height.setter
    def ground_height(self, arg1: typing.Any) -> None:
        ...
    @property
    def max_newton_iterations(self) -> typing.Any:
        """
        cap on implicit-solve iterations per step (at most 1000: a step is interrupted only between steps)
        """
    @max_newton_iterations.setter
    def max_newton_iterations(self, arg1: typing.Any) -> None:
        ...
    @property
    def max_speed(self) -> typing.Any:
        """
        RMS node speed (m/s) above which a step counts as diverged
        """
    @max_speed.setter
    def max_speed(self, arg1: typing.Any) -> None:
        ...
    @property
    def max_stagger_iterations(self) -> typing.Any:
        """
        cap on staggered-projection iterations per step (at most 10000: a step is interrupted only between steps)
        """
    @max_stagger_iterations.setter
    def max_stagger_iterations(self, arg1: typing.Any) -> None:
        ...
    @property
    def newton_tolerance(self) -> typing.Any:
        """
        the implicit solve stops when max |dv| / sqrt(m) < this, m/s
        """
    @newton_tolerance.setter
    def newton_tolerance(self, arg1: typing.Any) -> None:
        ...
    @property
    def num_cubature_elements(self) -> int:
        ...
    @property
    def num_nodes(self) -> int:
        ...
    @property
    def penalty_stiffness(self) -> typing.Any:
        """
        N/m per node for contact='penalty', at most 1e12 (0: the body's weight over its resting nodes per 1 mm of sink, plus 0.25 m_i / dt^2: they sink a little under 1 mm)
        """
    @penalty_stiffness.setter
    def penalty_stiffness(self, arg1: typing.Any) -> None:
        ...
    @property
    def profile(self) -> typing.Any:
        """
        time the parts of each step: step() then reports time_dynamics, time_drag, time_normal, time_friction (s), and stagger_trace, the staggered projection's course (benchmarks/trace_staggers.py)
        """
    @profile.setter
    def profile(self, arg1: typing.Any) -> None:
        ...
    @property
    def solver(self) -> typing.Any:
        """
        'fast' (default: quasi-Newton from the rest stiffness with a line search) or 'reference' (exact Newton every iteration), kept to check the fast path against
        """
    @solver.setter
    def solver(self, arg1: typing.Any) -> None:
        ...
    @property
    def stabilization(self) -> typing.Any:
        """
        fraction of a ground penetration removed per step (Baumgarte)
        """
    @stabilization.setter
    def stabilization(self, arg1: typing.Any) -> None:
        ...
    @property
    def surface_nodes(self) -> list[int]:
        ...
    @property
    def total_mass(self) -> float:
        ...
class ReducedConfig:
    """
    Every setting of a reduced model, in one object. `ReducedModel.config` returns a copy and
    accepts one; each setting is also a property of the model itself. Values are validated when
    set; `ReducedConfig.SETTINGS` lists the names.
    """
    SETTINGS: typing.ClassVar[tuple] = ('dt', 'gravity', 'contact', 'solver', 'friction', 'ground_height', 'contact_margin', 'penalty_stiffness', 'fluid_density', 'drag_coefficient', 'damping_alpha', 'damping_beta', 'newton_tolerance', 'max_newton_iterations', 'contact_tolerance', 'friction_smoothing', 'max_stagger_iterations', 'stabilization', 'direction', 'max_speed', 'profile', 'frame')
    __hash__: typing.ClassVar[None] = None
    def __eq__(self, arg0: ReducedConfig) -> bool:
        ...
    @typing.overload
    def __init__(self) -> None:
        ...
    @typing.overload
    def __init__(self, **kwargs) -> None:
        """
        ReducedConfig(**settings): defaults, then the given settings (validated).
        """
    def __reduce__(self) -> tuple[typing.Any, tuple]:
        ...
    def __repr__(self) -> str:
        ...
    def validate(self) -> None:
        """
        Raise ValueError if the settings, each valid alone, cannot be stepped together. Every combination steps today (frame='floating' with the penalty ground since 2026-12-07), so it returns; it stays so that code calling it keeps working.
        """
    @property
    def contact(self) -> typing.Any:
        """
        'staggered' (default: staggered projection, the accurate model), 'penalty' (an approximate spring ground, slower than 'staggered' with the fast solver) or 'none'
        """
    @contact.setter
    def contact(self, arg1: typing.Any) -> None:
        ...
    @property
    def contact_margin(self) -> typing.Any:
        """
        m: surface nodes predicted closer than this to the ground are contact candidates
        """
    @contact_margin.setter
    def contact_margin(self, arg1: typing.Any) -> None:
        ...
    @property
    def contact_tolerance(self) -> typing.Any:
        """
        staggered projection stops when contact-node velocities change less than this, m/s
        """
    @contact_tolerance.setter
    def contact_tolerance(self, arg1: typing.Any) -> None:
        ...
    @property
    def damping_alpha(self) -> typing.Any:
        """
        Rayleigh damping on all reduced coordinates, 1/s
        """
    @damping_alpha.setter
    def damping_alpha(self, arg1: typing.Any) -> None:
        ...
    @property
    def damping_beta(self) -> typing.Any:
        """
        Rayleigh damping times the rest stiffness K_0, s
        """
    @damping_beta.setter
    def damping_beta(self, arg1: typing.Any) -> None:
        ...
    @property
    def direction(self) -> typing.Any:
        """
        unit task direction d; per-step reward d . v_com dt
        """
    @direction.setter
    def direction(self, arg1: typing.Any) -> None:
        ...
    @property
    def drag_coefficient(self) -> typing.Any:
        """
        C_d of the quadratic drag
        """
    @drag_coefficient.setter
    def drag_coefficient(self, arg1: typing.Any) -> None:
        ...
    @property
    def dt(self) -> typing.Any:
        """
        time step h, s
        """
    @dt.setter
    def dt(self, arg1: typing.Any) -> None:
        ...
    @property
    def fluid_density(self) -> typing.Any:
        """
        kg/m^3; > 0 turns quadratic surface drag on
        """
    @fluid_density.setter
    def fluid_density(self, arg1: typing.Any) -> None:
        ...
    @property
    def frame(self) -> typing.Any:
        """
        'linear' (default: x = X + B_r q, rotations linearised) or 'floating' (x = c + R (X + U z) with an exact rotation: q = (sqrt(m) (c - c_0), rotation vector of R, z), qdot = (sqrt(m) c', body-frame angular velocity, z'); actuation follows the body, so free flight keeps the angular momentum; any contact; solver='fast' freezes the Newton matrix's stiffness at K_0, 'reference' is exact Newton)
        """
    @frame.setter
    def frame(self, arg1: typing.Any) -> None:
        ...
    @property
    def friction(self) -> typing.Any:
        """
        Coulomb coefficient mu
        """
    @friction.setter
    def friction(self, arg1: typing.Any) -> None:
        ...
    @property
    def friction_smoothing(self) -> typing.Any:
        """
        eps (m/s) of staggered projection's smoothed friction, sqrt(|v_t|^2 + eps^2): sticking nodes creep at about eps. None (default): contact_tolerance, so that tightening contact_tolerance alone also sharpens the friction law; set it to keep the law while the stop tightens
        """
    @friction_smoothing.setter
    def friction_smoothing(self, arg1: typing.Any) -> None:
        ...
    @property
    def gravity(self) -> typing.Any:
        """
        gravitational acceleration (3,), m/s^2
        """
    @gravity.setter
    def gravity(self, arg1: typing.Any) -> None:
        ...
    @property
    def ground_height(self) -> typing.Any:
        """
        height of the ground plane z = ground_height, m
        """
    @ground_height.setter
    def ground_height(self, arg1: typing.Any) -> None:
        ...
    @property
    def max_newton_iterations(self) -> typing.Any:
        """
        cap on implicit-solve iterations per step (at most 1000: a step is interrupted only between steps)
        """
    @max_newton_iterations.setter
    def max_newton_iterations(self, arg1: typing.Any) -> None:
        ...
    @property
    def max_speed(self) -> typing.Any:
        """
        RMS node speed (m/s) above which a step counts as diverged
        """
    @max_speed.setter
    def max_speed(self, arg1: typing.Any) -> None:
        ...
    @property
    def max_stagger_iterations(self) -> typing.Any:
        """
        cap on staggered-projection iterations per step (at most 10000: a step is interrupted only between steps)
        """
    @max_stagger_iterations.setter
    def max_stagger_iterations(self, arg1: typing.Any) -> None:
        ...
    @property
    def newton_tolerance(self) -> typing.Any:
        """
        the implicit solve stops when max |dv| / sqrt(m) < this, m/s
        """
    @newton_tolerance.setter
    def newton_tolerance(self, arg1: typing.Any) -> None:
        ...
    @property
    def penalty_stiffness(self) -> typing.Any:
        """
        N/m per node for contact='penalty', at most 1e12 (0: the body's weight over its resting nodes per 1 mm of sink, plus 0.25 m_i / dt^2: they sink a little under 1 mm)
        """
    @penalty_stiffness.setter
    def penalty_stiffness(self, arg1: typing.Any) -> None:
        ...
    @property
    def profile(self) -> typing.Any:
        """
        time the parts of each step: step() then reports time_dynamics, time_drag, time_normal, time_friction (s), and stagger_trace, the staggered projection's course (benchmarks/trace_staggers.py)
        """
    @profile.setter
    def profile(self, arg1: typing.Any) -> None:
        ...
    @property
    def solver(self) -> typing.Any:
        """
        'fast' (default: quasi-Newton from the rest stiffness with a line search) or 'reference' (exact Newton every iteration), kept to check the fast path against
        """
    @solver.setter
    def solver(self, arg1: typing.Any) -> None:
        ...
    @property
    def stabilization(self) -> typing.Any:
        """
        fraction of a ground penetration removed per step (Baumgarte)
        """
    @stabilization.setter
    def stabilization(self, arg1: typing.Any) -> None:
        ...
def _kernel_cholesky(a: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], b: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]) -> tuple[bool, typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"], bool, typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]]:
    """
    (ok, L padded with 3 rows, x, ok, U, x): A = L L^T by the lower Cholesky kernel and A = U^T U by the scalar loops, each with its solve of A x = b (for their tests).
    """
def _kernel_cols_dot(a: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], x: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]:
    """
    A^T x through the fast solver's column-dot kernel (for its tests).
    """
def _kernel_cols_dot_times(a: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], x: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]) -> tuple[typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]]:
    """
    (A^T x, A A^T x) through the fast solver's fused kernel (for its tests).
    """
def _kernel_cols_times(a: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], x: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]:
    """
    A x through the fast solver's matrix-vector kernel (for its tests).
    """
def _kernel_cols_times_pair(a: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], x: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"], y: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]) -> tuple[typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]]:
    """
    (A x, A y) through the fast solver's one-pass kernel (for its tests).
    """
def _least_distance_sequence(e: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], fs: typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]", "flags.f_contiguous"], solver: str = 'fast') -> list:
    """
    The least-distance programmes min |x| s.t. E x >= f for each row f of fs, solved in sequence as the staggered projection's normal half solves them (warm-started, and with the fast solver the NNLS factor carried over): a list of (x, lambda, feasible, converged), x NaN where infeasible (for its tests).
    """
def kernel_instruction_set() -> str:
    """
    The instruction set of the fast solver's dense kernels (cubature force and stiffness, contact products) in this process: 'x86-64-v3' (AVX2 + FMA, on an x86-64 CPU that has it, in builds by GCC 12 or later) or 'baseline'. The set is chosen once per process, at the kernels' first use (building a model, or a call of this function); set the environment variable SOFTROM_KERNELS=baseline before that to use the baseline: the two round differently (fused multiply-adds), so chaotic trajectories computed with the two part at round-off level.
    """
def reduced_element_forces(fem: FEMModel, basis: typing.Any, poses: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
    """
    Per-element reduced elastic forces -V_e G_e^T vec P(F_e) (P, T, K) at poses (P, K) of a basis (3N, K), the cubature's B_e (rotations and deformation, K = M + 3): the training data for cubature.
    """
