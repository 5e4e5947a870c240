"""The floating frame (``frame="floating"``, docs/FLOATING_FRAME.md): x_i = c + R (X_i + U_i z)
with an exact rotation, stepped by momentum-form implicit Euler with the actuation following
the body, torque-free. Checked against finite differences (the Newton Jacobian, the node
velocities), the full space (a complete basis reproduces FullSpaceModel with body-following
actuation, to the step's first-order error), the linear model (they agree to second order in
the amplitude; a dropped block lands on the same path), the invariants (angular momentum, the
centre of mass's fall, rotation equivariance in air, water and walking, the rotation's
composition), and the envs. The incline, contact-condition and drop-and-bounce tests of
test_reduced.py and test_solver.py run in both frames."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import cpp_sim
from softrom_gym.full_space import FullSpaceModel
from softrom_gym.rom import build_reduced_model, build_subspace

G = 9.81


def _model(bar, M: int = 6, **settings) -> cpp_sim.ReducedModel:
    """The bar in free flight in the floating frame, actuated in its first three modes."""
    options = dict(contact="none", control_basis=np.eye(M)[:, :3], frame="floating")
    options.update(settings)
    return build_reduced_model(bar, subspace=build_subspace(bar, M), **options)


def _mass(robot) -> np.ndarray:
    return np.asarray(robot.fem_model().mass)


def _stroke(model, k: int, body_weights: float) -> np.ndarray:
    """A travelling wave through the three actuated modes at 4 Hz."""
    amp = body_weights * np.sqrt(model.total_mass) * G
    return amp * np.sin(2.0 * np.pi * 4.0 * k * model.dt - 2.0 * np.pi * np.arange(3) / 3.0)


def _state(model, q, qdot) -> cpp_sim.ReducedState:
    return cpp_sim.ReducedState(q, qdot, np.zeros(3 * len(model.surface_nodes)))


def _moving(model, seed: int) -> cpp_sim.ReducedState:
    """A turned, deformed, spinning and vibrating state."""
    rng = np.random.default_rng(seed)
    M = model.M
    q = np.concatenate([[0.1, -0.2, 0.3], [0.4, -0.9, 0.3], 0.02 * rng.standard_normal(M)])
    qdot = np.concatenate([[0.0, 0.1, 0.2], [1.5, -0.7, 2.0], 0.2 * rng.standard_normal(M)])
    return _state(model, q, qdot)


def _finite_difference_jacobian(model, state, fc, x) -> np.ndarray:
    """The floating residual's Jacobian in x by central differences (steps of 1e-6)."""
    fd = np.empty((x.size, x.size))
    for k in range(x.size):
        dx = np.zeros_like(x)
        dx[k] = 1e-6
        plus, _ = model._floating_residual(state, fc, x + dx)
        minus, _ = model._floating_residual(state, fc, x - dx)
        fd[:, k] = (plus - minus) / 2e-6
    return fd


def _angular_momentum(model, state, mass) -> tuple[np.ndarray, float]:
    """L about the centre of mass from the node positions and velocities, and its scale
    sum m |x - c| |v|."""
    x = model.positions(state.q)
    v = model.velocities(state.q, state.qdot)
    r = x - mass @ x / mass.sum()
    moment = np.sum(mass[:, None] * np.cross(r, v), axis=0)
    return moment, float(np.sum(mass * np.linalg.norm(r, axis=1) * np.linalg.norm(v, axis=1)))


@pytest.mark.parametrize(
    ("solver", "fluid_density"), [("fast", 0.0), ("reference", 0.0), ("fast", 1000.0)]
)
def test_newton_jacobian_matches_finite_differences(bar, solver, fluid_density):
    # Every term: gyroscopic, rotation line, elastic stiffness, both dampings, the torque-free
    # actuation's derivative, the linearised drag. A wrong term costs Newton its quadratic
    # convergence silently.
    model = _model(
        bar, solver=solver, damping_alpha=0.3, damping_beta=0.01, fluid_density=fluid_density
    )
    state = _moving(model, 0)
    fc = np.array([3.0, -2.0, 1.0])
    x = np.concatenate(
        [[0.1, 0.0, -0.3, 1.2, -0.4, 2.6], 0.3 * np.random.default_rng(1).standard_normal(model.M)]
    )
    r, jac = model._floating_residual(state, fc, x)
    assert r.shape == (model.dim,) and jac.shape == (model.dim, model.dim)
    fd = _finite_difference_jacobian(model, state, fc, x)
    assert np.abs(jac - fd).max() < 1e-7 * np.abs(jac).max()


@pytest.mark.parametrize(
    ("solver", "fluid_density", "sink"),
    [("fast", 0.0, 2e-3), ("reference", 0.0, 2e-3), ("fast", 1000.0, 2e-3),
     ("fast", 0.0, 5e-5), ("reference", 0.0, 5e-5)],
)  # fmt: skip
def test_penalty_ground_jacobian_matches_finite_differences(bar, solver, fluid_density, sink):
    # The penalty ground's force enters the residual on the surface rows at the step's start,
    # and its Jacobian is exact: the springs and dampers, the friction's (I - t t^T) block and
    # its coupling to the normal force (as the linear frame's, test_solver.py's check).
    # At 50 um the lowest node's end-of-step sink lies in the first 0.1 mm, where the damper
    # ramps in with the sink (its derivative then has a term in the sink's own velocity).
    model = _model(bar, solver=solver, contact="penalty", fluid_density=fluid_density,
                   damping_alpha=0.3, damping_beta=0.01)  # fmt: skip
    rng = np.random.default_rng(0)
    q = np.concatenate([[0.0, 0.0, 0.0], [0.2, -0.1, 0.3], 0.02 * rng.standard_normal(model.M)])
    qdot = np.concatenate([[0.3, -0.2, -0.3], [1.5, -0.7, 2.0], 0.2 * rng.standard_normal(model.M)])
    x = qdot + 0.05 * rng.standard_normal(qdot.size)
    # Sink the body until its lowest node ends the step `sink` below the ground, as the start's
    # rows predict it (a translation moves every node alike and leaves the rows as they are).
    ends = model.positions(q) + model.dt * model.velocities(q, x)
    low = ends[model.surface_nodes, 2].min()
    q[2] = (model.ground_height - sink - low) * np.sqrt(model.total_mass)
    state = _state(model, q, qdot)
    fc = np.array([3.0, -2.0, 1.0])
    ends = model.positions(q) + model.dt * model.velocities(q, x)
    below = ends[model.surface_nodes, 2] < model.ground_height
    assert 0 < below.sum() < below.size
    r, jac = model._floating_residual(state, fc, x)
    fd = _finite_difference_jacobian(model, state, fc, x)
    assert np.abs(jac - fd).max() < 1e-8 * np.abs(jac).max()  # measured 1e-10 to 2e-10
    free, _ = _model(bar, solver=solver, fluid_density=fluid_density, damping_alpha=0.3,
                     damping_beta=0.01)._floating_residual(state, fc, x)  # fmt: skip
    assert np.abs(r - free).max() > 1e-3 * np.abs(r).max()  # the ground pushes


def test_actuation_is_the_generalised_force_of_the_body_following_field(bar):
    # Q_a(z) = (I - S^T I^-1 S) B_c f_c is the generalised force on z of the nodal field
    # M R U B_c f_c less the rigid rotation that cancels its torque (softrom_gym.body_frame,
    # FullSpaceModel's actuation_frame="body"), not B_c f_c itself: on a slender body the bare
    # law spun the frame at 205 rad/s (docs/FLOATING_FRAME.md). It is the residual's only
    # term in f_c: r_w(f_c) - r_w(0) = -h Q_a(z'), z' = z + h w'.
    from softrom_gym.body_frame import following_forces

    mass = _mass(bar)
    model = _model(bar)
    state = _moving(model, 8)
    fc = np.array([3.0, -2.0, 1.0])
    x = np.concatenate(
        [[0.0, 0.1, 0.0, 0.5, 0.2, -1.0], 0.4 * np.random.default_rng(2).standard_normal(6)]
    )
    with_f, _ = model._floating_residual(state, fc, x)
    without, _ = model._floating_residual(state, np.zeros(3), x)
    q_a = -(with_f - without)[6:] / model.dt
    # the field's generalised force at z' (the frame's rotation R and c do not matter)
    q = state.q.copy()
    q[6:] += model.dt * x[6:]
    nodes = model.positions(q)
    turn = Rotation.from_rotvec(q[3:6]).as_matrix()
    shapes = build_subspace(bar, 6).deformation.reshape(-1, 3, 6)
    rest = bar.nodes - mass @ bar.nodes / mass.sum()
    forces = following_forces(nodes, rest, mass, shapes[:, :, :3] @ fc)
    expected = np.einsum("iaj,ia->j", shapes, forces @ turn)  # sum U_i^T R^T F_i
    np.testing.assert_allclose(q_a, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    # and it is not the bare law
    assert np.abs(expected - np.eye(6)[:, :3] @ fc).max() > 1e-3 * np.abs(fc).max()


def test_velocities_are_the_time_derivative_of_positions(bar):
    model = _model(bar)
    state = _moving(model, 2)
    q, qdot, M = state.q, state.qdot, model.M

    def at(t: float) -> np.ndarray:  # c + t u, R exp(t omega), z + t w
        turn = Rotation.from_rotvec(q[3:6]) * Rotation.from_rotvec(t * qdot[3:6])
        moved = np.concatenate([q[:3] + t * qdot[:3], turn.as_rotvec(), q[6:] + t * qdot[6:]])
        return model.positions(moved)

    fd = (at(1e-6) - at(-1e-6)) / 2e-6
    v = model.velocities(q, qdot)
    assert v.shape == (bar.num_nodes, 3)
    np.testing.assert_allclose(v, fd, rtol=0, atol=1e-8 * np.abs(v).max())
    assert M == 6
    # the linear frame's node velocities are B_r qdot
    model.frame = "linear"
    basis = build_subspace(bar, 6).basis
    np.testing.assert_allclose(model.velocities(q, qdot).ravel(), basis @ qdot, atol=1e-14)


def test_actuated_free_flight_keeps_angular_momentum(bar):
    # The rotation line keeps R Pi, so L is kept to the Newton tolerance whatever the internal
    # forces: elastic, beta damping, the body-following actuation. (The linear model's |L|
    # reaches 62% of the scale on the beam: test_solver.py.)
    mass = _mass(bar)
    model = _model(bar, damping_beta=0.01, gravity=[0.0, 0.0, -G])
    state = _moving(model, 3)
    start, _ = _angular_momentum(model, state, mass)
    worst = 0.0
    for k in range(100):
        state, info = model.step(state, _stroke(model, k, 0.5))
        assert info["converged"] and not info["diverged"]
        moment, scale = _angular_momentum(model, state, mass)
        worst = max(worst, float(np.linalg.norm(moment - start) / scale))
    assert worst < 1e-10
    # mass-proportional damping -alpha m_i v_i takes L down by 1 / (1 + h alpha) a step
    model.damping_alpha = 2.0
    state = _moving(model, 3)
    for k in range(50):
        state, _ = model.step(state, _stroke(model, k, 0.5))
    moment, scale = _angular_momentum(model, state, mass)
    expected = start / (1.0 + model.dt * 2.0) ** 50
    assert np.linalg.norm(moment - expected) < 1e-10 * scale


def test_centre_of_mass_falls_as_implicit_euler_says_whatever_the_actuation(bar):
    mass = _mass(bar)
    model = _model(bar, gravity=[0.0, 0.0, -G])
    state = _moving(model, 4)
    h, c0 = model.dt, model.com(state.q)
    u0 = state.qdot[:3] / np.sqrt(model.total_mass)
    for k in range(1, 41):
        state, _ = model.step(state, _stroke(model, k, 0.5))
        x = model.positions(state.q)
        # c is the centre of mass of the nodes (sum m U = 0) ...
        np.testing.assert_allclose(mass @ x / mass.sum(), model.com(state.q), rtol=0, atol=1e-12)
        # ... and moves as u_j = u_0 + j h g, c_k = c_0 + h sum_j u_j
        expected = c0 + h * (k * u0 + h * k * (k + 1) / 2 * np.array([0.0, 0.0, -G]))
        np.testing.assert_allclose(model.com(state.q), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("swim", [False, True])
def test_a_turned_start_follows_the_turned_trajectory(bar, swim):
    # Every term of the step is rotation-equivariant. Under gravity (on c alone) the body's
    # turn about the centre of mass does not change c's path; in still water (isotropic) the
    # whole motion, c's velocity too, turns about the starting centre of mass.
    settings = (
        {"gravity": [0.0, 0.0, 0.0], "fluid_density": 1000.0}
        if swim
        else {"gravity": [0.0, 0.0, -G]}
    )
    model = _model(bar, **settings)
    plain = _moving(model, 5)
    q, qdot = plain.q.copy(), plain.qdot.copy()
    turn = Rotation.from_rotvec([0.5, 1.2, -0.4])
    q[3:6] = (turn * Rotation.from_rotvec(q[3:6])).as_rotvec()
    if swim:
        qdot[:3] = turn.apply(qdot[:3])
    turned = _state(model, q, qdot)
    c0 = model.com(q)
    for k in range(60):
        u = _stroke(model, k, 0.5)
        plain, _ = model.step(plain, u)
        turned, info = model.step(turned, u)
        assert info["converged"]
        c = c0 if swim else model.com(plain.q)
        expected = c + (model.positions(plain.q) - c) @ turn.as_matrix().T
        np.testing.assert_allclose(model.positions(turned.q), expected, rtol=0, atol=1e-9)
    if swim:  # the water acted: it took speed off the coast
        assert np.linalg.norm(turned.qdot[:3]) < 0.9 * np.linalg.norm(qdot[:3])


def test_rotation_composes_exactly_and_stays_within_pi(bar):
    # R_{n+1} = R_n exp(h omega_{n+1}), the rotation vector kept at |theta| <= pi as the body
    # tumbles through several turns.
    model = _model(bar, gravity=[0.0, 0.0, 0.0])
    state = _moving(model, 6)
    qdot = state.qdot.copy()
    qdot[3:6] = [9.0, -4.0, 6.0]
    state = _state(model, state.q, qdot)
    angles = []
    for _ in range(200):
        before = Rotation.from_rotvec(state.q[3:6])
        state, info = model.step(state, np.zeros(3))
        assert info["converged"]
        after = before * Rotation.from_rotvec(model.dt * state.qdot[3:6])
        np.testing.assert_allclose(
            Rotation.from_rotvec(state.q[3:6]).as_matrix(), after.as_matrix(), atol=1e-12
        )
        angles.append(np.linalg.norm(state.q[3:6]))
    assert max(angles) <= np.pi + 1e-12
    assert max(angles) > 3.0  # it did turn past pi and wrap


def test_an_unconverged_step_returns_no_worse_an_answer_than_its_start(bar):
    # Spun at h |omega| = 2.5-3.5 rad a step about random axes, some steps' Newton iteration
    # fails (its line search too, 8 halvings without a decrease). It used to go on by t = 1/256
    # regardless and return its last iterate: |r| three times the start's (57.6 -> 186), the
    # kinetic energy 4x, reported only as unconverged. Now it returns the iterate of least
    # residual, and a step that came no nearer a solution than its start is diverged.
    from softrom_gym.robots.robot import Robot

    stiff = Robot("bar", bar.nodes, bar.tets, youngs_modulus=1e7)
    model = build_reduced_model(stiff, subspace=build_subspace(stiff, 6), contact="none",
                                frame="floating", gravity=[0.0, 0.0, 0.0], damping_alpha=0.0,
                                damping_beta=0.0, dt=0.01, max_speed=1e9)  # fmt: skip
    rng = np.random.default_rng(1)
    axes = rng.standard_normal((40, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    q = model.rest_state().q
    failed = 0
    for spin in (250.0, 350.0):
        for axis in axes:
            qdot = np.zeros_like(q)
            qdot[3:6] = spin * axis
            start = _state(model, q, qdot)
            after, info = model.step(start)
            if info["converged"]:
                continue
            failed += 1
            if info["diverged"]:
                continue
            r0, _ = model._floating_residual(start, np.zeros(0), start.qdot)
            r1, _ = model._floating_residual(start, np.zeros(0), after.qdot)
            assert np.linalg.norm(r1) < np.linalg.norm(r0)
    assert failed >= 5  # (2 of 40 at 250 rad/s, 9 at 350: the case is exercised)


@pytest.mark.parametrize("fluid_density", [0.0, 1000.0])
def test_a_complete_basis_reproduces_the_full_space_with_body_following_actuation(
    bar, fluid_density
):
    # With all 3N - 6 deformation columns and exact elastic forces the floating frame is the
    # full space in other coordinates, and its actuation the full space's actuation_frame=
    # "body" (the frame is Buckens' best fit, which FullSpaceModel turns the field by). The two
    # implicit Euler steps differ at first order in dt: measured 2.0 / 0.68 mm apart after
    # 0.3 s at dt = 5 / 1.25 ms (in water, with both sides' drag linearised at the step's
    # start: 1.75 / 0.55 mm). Against the world-fixed field the gap does not close (3.6 /
    # 5.6 mm; in water 3.0 / 4.3 mm).
    mass = _mass(bar)
    M = 3 * bar.num_nodes - 6
    sub = build_subspace(bar, M)

    def apart(dt: float, actuation_frame: str) -> float:
        model = build_reduced_model(
            bar, subspace=sub, forces="exact", contact="none", gravity=[0.0, 0.0, -G],
            control_basis=np.eye(M)[:, :3], damping_beta=0.0, dt=dt, frame="floating",
            newton_tolerance=1e-10, fluid_density=fluid_density,
        )  # fmt: skip
        full = FullSpaceModel(
            bar, sub.basis[:, 6:9], dt=dt, gravity=(0.0, 0.0, -G), contact="none",
            damping_beta=0.0, newton_tolerance=1e-12, actuation_frame=actuation_frame,
            fluid_density=fluid_density,
        )  # fmt: skip
        state, full_state = model.rest_state(), full.rest_state()
        for k in range(round(0.3 / dt)):
            u = (
                0.3
                * np.sqrt(mass.sum())
                * G
                * np.sin(8.0 * np.pi * k * dt - 2.0 * np.pi * np.arange(3) / 3)
            )
            state, info = model.step(state, u)
            assert info["converged"]
            full_state, _ = full.step(full_state, u)
        return float(np.abs(model.positions(state.q) - full_state.x).max())

    body = [apart(dt, "body") for dt in (0.005, 0.00125)]
    assert body[1] < 0.45 * body[0] and body[1] < 1e-3
    world = [apart(dt, "world") for dt in (0.005, 0.00125)]
    assert world[1] > world[0] > body[0]


def test_small_strokes_agree_with_the_linear_model_to_second_order(bar):
    # The linear model is the floating frame linearised in the rotation (and its actuation at
    # rest), so they part at second order: halving the stroke quarters the gap (measured 4.09,
    # 4.04) while the deflection halves.
    mass = _mass(bar)
    rest = bar.nodes - mass @ bar.nodes / mass.sum()

    def gap(body_weights: float) -> tuple[float, float]:
        x = {}
        for frame in ("linear", "floating"):
            model = _model(bar, frame=frame, gravity=[0.0, 0.0, -G])
            state = model.rest_state()
            for k in range(60):
                state, _ = model.step(state, _stroke(model, k, body_weights))
            x[frame] = model.positions(state.q)
            c = model.com(state.q)
        deflection = np.abs(x["linear"] - c - rest).max()
        return float(np.abs(x["linear"] - x["floating"]).max()), float(deflection)

    (large, bend), (small, _) = gap(0.1), gap(0.05)
    assert large / small > 3.5
    assert large < 0.15 * bend


def test_rollouts_step_as_single_steps_do(bar):
    model = _model(bar, gravity=[0.0, 0.0, -G])
    start = _moving(model, 7)
    controls = np.stack([[_stroke(model, k, s) for k in range(30)] for s in (0.2, 0.5)])
    outs = [model.rollout(start, controls, threads=t) for t in (1, 2)]
    np.testing.assert_array_equal(outs[0]["q"], outs[1]["q"])
    for b in range(2):
        state = start
        for k in range(30):
            state, _ = model.step(state, controls[b, k])
        np.testing.assert_array_equal(outs[0]["q"][b], state.q)
        np.testing.assert_array_equal(outs[0]["com"][b, -1], model.com(state.q))
    assert outs[0]["converged"].all() and not outs[0]["diverged"].any()


@pytest.mark.parametrize("fluid_density", [0.0, 1000.0])
def test_the_fast_solver_lands_where_exact_newton_does(bar, fluid_density):
    # solver="fast" keeps every term of the Newton matrix but the stiffness, which it freezes at
    # K_0 (K(z') replaces it only on a stall), and forms the drag by the fast kernels;
    # solver="reference" is exact Newton on the reference kernels. Both stop at the same
    # tolerance, so their trajectories agree to it: measured 5e-8 (air) and 7e-8 (water) in q
    # and 2e-7 in qdot after 200 steps of a spinning, vibrating start, with 1 stiffness
    # evaluation on the fast side against one per Newton iteration (601) on the other.
    states, evaluations = {}, {}
    for solver in ("fast", "reference"):
        model = _model(bar, M=12, solver=solver, fluid_density=fluid_density)
        state, count = _moving(model, 3), 0
        for k in range(200):
            state, info = model.step(state, _stroke(model, k, 0.5))
            assert info["converged"] and not info["diverged"]
            count += info["stiffness_evaluations"]
        states[solver], evaluations[solver] = state, count
    np.testing.assert_allclose(states["fast"].q, states["reference"].q, rtol=0, atol=1e-6)
    np.testing.assert_allclose(states["fast"].qdot, states["reference"].qdot, rtol=0, atol=2e-6)
    assert evaluations["reference"] >= 600 and evaluations["fast"] < 20


def test_a_bad_frame_is_refused_by_name_and_every_ground_steps(bar):
    with pytest.raises(ValueError, match="frame must be 'linear' or 'floating'; got 'spinning'"):
        cpp_sim.ReducedConfig(frame="spinning")
    model = _model(bar)
    with pytest.raises(ValueError, match="frame must be 'linear' or 'floating'; got 'exact'"):
        model.frame = "exact"
    state = model.rest_state()
    u = np.zeros((1, 2, 3))
    for contact in ("none", "staggered", "penalty"):
        model.contact = contact
        model.config.validate()  # (kept for callers: every combination steps)
        _, info = model.step(state, u[0, 0])
        out = model.rollout(state, u)
        assert info["converged"] and not out["diverged"].any()


def test_a_block_dropped_on_the_penalty_ground_rests_as_in_the_linear_frame(box):
    # Without a turn the two frames are one model, on the penalty ground too: a block dropped
    # from 2 cm lands on the same path (measured 1.0e-7 m apart, the Newton tolerance's
    # doing) and rests sunk by the penalty's sizing, a little under 1 mm (0.92 mm).
    sub = build_subspace(box, 12)
    paths = {}
    for frame in ("linear", "floating"):
        model = build_reduced_model(box, subspace=sub, frame=frame, contact="penalty")
        q = model.rest_state().q
        q[2] = 0.02 * np.sqrt(model.total_mass)
        state = _state(model, q, np.zeros_like(q))
        path = []
        for _ in range(120):
            state, info = model.step(state)
            assert info["converged"]
            path.append(model.com(state.q))
        paths[frame] = np.array(path)
        assert np.abs(state.qdot[:3]).max() < 1e-6 * np.sqrt(model.total_mass)
        low = model.positions(state.q)[model.surface_nodes, 2].min()
        assert -1e-3 < low - model.ground_height < -5e-4
    np.testing.assert_allclose(paths["floating"], paths["linear"], rtol=0, atol=1e-6)


def test_a_dropped_block_lands_and_rests_as_in_the_linear_frame(box):
    # Without a turn the two frames are the same model: a block dropped from 2 cm on its face
    # lands, bounces a little and comes to rest on the same path, and the floating frame's
    # contact rows, which follow its exact rotation, hold it on the plane.
    # (At the impact one step stops at the stagger cap in both frames, and says so.)
    sub = build_subspace(box, 12)
    paths, capped = {}, {}
    for frame in ("linear", "floating"):
        model = build_reduced_model(box, subspace=sub, frame=frame)
        q = model.rest_state().q
        q[2] = 0.02 * np.sqrt(model.total_mass)
        state = _state(model, q, np.zeros_like(q))
        path, capped[frame] = [], []
        for k in range(120):
            state, info = model.step(state)
            assert info["converged"]
            if not info["contact_converged"]:
                capped[frame].append(k)
            path.append(model.com(state.q))
        paths[frame] = np.array(path)
        assert info["contacts"] > 0
        assert np.abs(state.qdot[:3]).max() < 1e-5 * np.sqrt(model.total_mass)
        low = model.positions(state.q)[model.surface_nodes, 2].min()
        assert -1e-4 < low - model.ground_height < 1e-6
    np.testing.assert_allclose(paths["floating"], paths["linear"], rtol=0, atol=1e-7)
    assert capped["floating"] == capped["linear"] and len(capped["linear"]) <= 2


@pytest.mark.parametrize("turn", [2.0 * np.pi + 0.5, np.pi + 0.5, -3.0 * np.pi - 0.25])
def test_a_reset_to_a_state_turned_past_pi_reports_its_rotation_within_pi(turn):
    # The orientation observed and reported after reset(options={"state": ...}) is that of the
    # rotation vector of angle <= pi, as after any step (it read 6.78 rad for 2 pi + 0.5).
    import gymnasium as gym

    env = gym.make("softrom_gym/CrossSwim-v0", frame="floating")
    base = env.unwrapped
    rest = base.model.rest_state()
    q = rest.q.copy()
    q[3:6] = [0.0, 0.0, turn]
    _, info = env.reset(options={"state": cpp_sim.ReducedState(q, rest.qdot, rest.impulses)})
    wrapped = (turn + np.pi) % (2.0 * np.pi) - np.pi
    assert abs(info["orientation"] - abs(wrapped)) < 1e-12  # (the angle |theta|)
    theta = base.get_state().q[3:6]
    assert np.linalg.norm(theta) <= np.pi
    turned = Rotation.from_rotvec([0.0, 0.0, turn]).as_matrix()
    np.testing.assert_allclose(Rotation.from_rotvec(theta).as_matrix(), turned, atol=1e-12)


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")
@pytest.mark.filterwarnings("ignore:.*space (minimum|maximum) value is -?infinity")
def test_the_swimmer_env_runs_in_the_floating_frame():
    # frame="floating" through gym.make: the orientation slots read the exact rotation vector
    # and the body-frame angular velocity, a plan replays bit for bit, a copy keeps the frame.
    import copy

    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make("softrom_gym/CrossSwim-v0", frame="floating")
    base = env.unwrapped
    assert base.model.frame == "floating" and base.model.fluid_density > 0
    check_env(base, skip_render_check=True)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(10):
        obs, _, terminated, _, info = env.step(env.action_space.sample())
    state = base.get_state()
    np.testing.assert_allclose(obs[4:7], state.q[3:6], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(obs[7:10], state.qdot[3:6], rtol=1e-6, atol=1e-9)
    assert info["orientation"] == pytest.approx(np.linalg.norm(state.q[3:6]))
    assert not terminated and info["distance"] != 0.0
    controls = np.random.default_rng(1).uniform(-1, 1, (2, 5, 3)) * base.action_bound
    out = base.rollout(state, controls)
    for t in range(5):
        _, r, *_ = env.step(controls[0, t])
        assert r == out["rewards"][0, t]
    np.testing.assert_array_equal(base.get_state().q, out["q"][0])
    twin = copy.deepcopy(base)
    assert twin.model.frame == "floating"
    env.close()
    vec = gym.make_vec("softrom_gym/CrossSwim-v0", num_envs=2, frame="floating")
    assert vec.unwrapped.env.model.frame == "floating"
    vec.reset(seed=0)
    obs, *_ = vec.step(vec.action_space.sample())
    assert obs.shape == (2, base.observation_space.shape[0]) and np.isfinite(obs).all()
    vec.close()


@pytest.mark.parametrize("contact", ["staggered", "penalty"])
def test_a_walker_turned_about_the_vertical_walks_the_turned_path(contact):
    # Ground and gravity are invariant under a turn about the vertical, so is the isotropic
    # Coulomb cone (and the penalty ground's regularised one), and the floating frame's
    # contact rows turn with the body: a beam started 0.7 rad round walks its stroke's path
    # turned by 0.7 rad, to the contact solve's tolerance (staggered: measured 2.8e-6 m after
    # 0.5 s; 1e-5 after 1 s of a 2 Hz stroke; penalty: 7e-16, its heights' rows being the
    # same numbers). The linear frame cannot even start there: its 0.7 rad "turn" stretches
    # the body by 22%.
    from softrom_gym.robots import beam

    robot = beam()
    model = build_reduced_model(robot, subspace=build_subspace(robot, 20), frame="floating",
                                control_basis=np.eye(20)[:, :3], contact=contact)  # fmt: skip
    plain = model.rest_state()
    turn = Rotation.from_rotvec([0.0, 0.0, 0.7])
    q = plain.q.copy()
    q[3:6] = turn.as_rotvec()
    turned = cpp_sim.ReducedState(q, plain.qdot, plain.impulses)
    c0 = model.com(plain.q)
    for k in range(100):
        u = _stroke(model, k, 0.8)
        plain, info = model.step(plain, u)
        turned, _ = model.step(turned, u)
        expected = c0 + (model.positions(plain.q) - c0) @ turn.as_matrix().T
        np.testing.assert_allclose(model.positions(turned.q), expected, rtol=0, atol=3e-5)
    if contact == "staggered":
        assert info["contacts"] > 0
    else:  # on the springs: its lowest node sunk a little
        low = model.positions(plain.q)[model.surface_nodes, 2].min() - model.ground_height
        assert -5e-3 < low < 0.0
    assert np.linalg.norm(model.com(plain.q)[:2] - c0[:2]) > 5e-3  # it went somewhere


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")
@pytest.mark.filterwarnings("ignore:.*space (minimum|maximum) value is -?infinity")
def test_a_walker_env_runs_in_the_floating_frame():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make("softrom_gym/QuadrupedWalk-v0", frame="floating")
    base = env.unwrapped
    assert base.model.frame == "floating" and base.model.contact == "staggered"
    check_env(base, skip_render_check=True)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(20):
        obs, _, terminated, _, info = env.step(env.action_space.sample())
    assert not terminated and not info["diverged"]
    state = base.get_state()
    np.testing.assert_allclose(obs[4:7], state.q[3:6], rtol=1e-6, atol=1e-9)
    assert (state.impulses.reshape(-1, 3)[:, 2] > 0).any()  # it stands on the ground
    controls = np.random.default_rng(1).uniform(-1, 1, (2, 5, 3)) * base.action_bound
    out = base.rollout(state, controls, threads=2)
    for t in range(5):
        _, r, *_ = env.step(controls[1, t])
        assert r == out["rewards"][1, t]
    np.testing.assert_array_equal(base.get_state().q, out["q"][1])
    sprung = gym.make("softrom_gym/QuadrupedWalk-v0", frame="floating", contact="penalty")
    assert sprung.unwrapped.model.contact == "penalty"
    sprung.reset(seed=0)
    for _ in range(5):
        *_, info = sprung.step(sprung.action_space.sample())
    assert info["contact"] == "penalty" and not info["diverged"]
    sprung.close()
    with pytest.raises(ValueError, match="frame must be 'linear' or 'floating'; got 'exact'"):
        gym.make("softrom_gym/CrossSwim-v0", frame="exact")
    env.close()
