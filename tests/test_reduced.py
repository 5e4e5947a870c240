"""Reduced dynamics (cpp_sim.ReducedModel): accuracy, contact, friction, drag, actuation,
batched rollouts and bad input."""

import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import cpp_sim
from softrom_gym.robots import beam, cross, quadruped
from softrom_gym.robots.robot import Robot
from softrom_gym.robots.voxel import voxels_to_tets
from softrom_gym.rom import build_reduced_model, build_subspace
from softrom_gym.rom.subspace import Subspace, _mass_gram_schmidt, _rigid_modes

G = 9.81


def com_velocity(model, state):
    return state.qdot[:3] / np.sqrt(model.total_mass)


def full_basis(robot) -> Subspace:
    """A B_r spanning all 3N directions: rigid modes, then the rest mass-orthonormalised."""
    mass = robot.fem_model().mass
    rigid = _rigid_modes(robot.nodes, mass)
    rest = _mass_gram_schmidt(list(np.eye(3 * robot.num_nodes)), np.repeat(mass, 3), rigid)
    basis = np.column_stack([rigid, *rest])
    return Subspace(basis, np.ones(basis.shape[1] - 6), basis.shape[1] - 6)


def test_full_basis_reproduces_full_space_trajectory():
    # Small block; B_r spans all 3N directions (rigid motions + everything else).
    nodes, tets = voxels_to_tets(np.ones((2, 1, 1), dtype=bool), 0.1)
    robot = Robot("block", nodes, tets, youngs_modulus=1e4)
    fem = robot.fem_model()
    m3 = np.repeat(fem.mass, 3)
    sub = full_basis(robot)
    basis = sub.basis
    assert basis.shape == (36, 36)
    model = build_reduced_model(
        robot, forces="exact", subspace=sub, contact="none", damping_beta=0.0, dt=0.01,
        newton_tolerance=1e-10, max_newton_iterations=30,
    )  # fmt: skip
    fem.damping_beta = 0.0
    fem.newton_tolerance = 1e-10
    rng = np.random.default_rng(3)
    x = nodes + 0.01 * rng.standard_normal(nodes.shape)
    v = 0.2 * rng.standard_normal(nodes.shape)
    q = basis.T @ (m3 * (x - nodes).ravel())
    qdot = basis.T @ (m3 * v.ravel())
    state = cpp_sim.ReducedState(q, qdot, np.zeros(3 * len(robot.surface_nodes)))
    for _ in range(30):
        x, v = fem.step(x, v, 0.01)
        state, info = model.step(state)
        assert not info["diverged"]
    np.testing.assert_allclose(model.positions(state.q), x, atol=1e-7)


def test_free_fall_follows_half_g_t_squared():
    robot = beam()
    model = build_reduced_model(robot, dt=1 / 500)
    state = model.rest_state()
    q = state.q
    q[2] = 1.0 * np.sqrt(model.total_mass)  # lift 1 m
    state = cpp_sim.ReducedState(q, state.qdot, state.impulses)
    z0 = model.com(state.q)[2]
    steps = 200  # 0.4 s, before impact
    for _ in range(steps):
        state, _ = model.step(state)
    t = steps * model.dt
    drop = z0 - model.com(state.q)[2]
    assert drop == pytest.approx(0.5 * G * t * t, rel=0.01)
    assert model.positions(state.q)[:, 2].min() > 0.0
    # Gravity loads only the translation columns, which nothing else couples to in free fall
    # (no damping on rigid motion), so the step is implicit Euler's exactly: v_n = -g n dt and
    # a drop of g dt^2 n (n + 1) / 2 (0.5 % above g t^2 / 2 here; measured to 3e-15).
    assert drop == pytest.approx(G * model.dt**2 * steps * (steps + 1) / 2, rel=1e-9)
    assert com_velocity(model, state)[2] == pytest.approx(-G * t, rel=1e-9)


def test_resting_contact_neither_sinks_nor_drifts():
    robot = quadruped()
    model = build_reduced_model(robot)
    height = np.ptp(robot.nodes[:, 2])
    state = model.rest_state()
    com = []
    for _ in range(400):  # 2 s
        state, info = model.step(state)
        assert not info["diverged"]
        com.append(model.com(state.q))
    penetration = -model.positions(state.q)[:, 2].min()
    assert penetration < 0.01 * height
    com = np.array(com)
    drift = np.linalg.norm(com[-1, :2] - com[199, :2]) / 1.0  # over the last second
    assert drift < 1e-3, f"tangential drift {drift * 1e3:.3f} mm/s"


def _incline(box, theta, mu, seconds=0.6, frame="linear"):
    model = build_reduced_model(box, M=12, friction=mu, damping_beta=0.01, frame=frame)
    model.gravity = [G * np.sin(theta), 0.0, -G * np.cos(theta)]
    state = model.rest_state()
    ts, vs = [], []
    for n in range(round(seconds / model.dt)):
        state, info = model.step(state)
        assert not info["diverged"]
        ts.append((n + 1) * model.dt)
        vs.append(com_velocity(model, state)[0])
    return np.array(ts), np.array(vs)


@pytest.mark.parametrize("frame", ["linear", "floating"])
@pytest.mark.parametrize("theta_deg", [10.0, 25.0])
def test_friction_sticks_below_the_cone(box, theta_deg, frame):
    mu = 0.6  # tan(25 deg) = 0.47 < 0.6
    t, v = _incline(box, np.deg2rad(theta_deg), mu, frame=frame)
    assert np.abs(v[t > 0.2]).max() < 1e-3


@pytest.mark.parametrize("frame", ["linear", "floating"])
@pytest.mark.parametrize(("theta_deg", "mu"), [(35.0, 0.5), (30.0, 0.2)])
def test_friction_slides_with_coulomb_acceleration(box, theta_deg, mu, frame):
    # In both frames (the floating frame's contact rows follow the body's exact rotation).
    theta = np.deg2rad(theta_deg)
    t, v = _incline(box, theta, mu, frame=frame)
    late = t > 0.2
    accel = np.polyfit(t[late], v[late], 1)[0]
    expected = G * (np.sin(theta) - mu * np.cos(theta))
    # The stiff block slides as a rigid one: measured within 4e-8 of the Coulomb answer,
    # where rel = 0.1 let up to a fifth of the friction force go missing (at 30 degrees).
    assert accel == pytest.approx(expected, rel=1e-4)


@pytest.mark.parametrize("frame", ["linear", "floating"])
@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_a_block_that_should_stick_creeps_at_the_smoothed_laws_speed(box, solver, frame):
    # Staggered projection's friction is Coulomb's smoothed: mu lambda_n v_t / |v_t|_eps with
    # |v_t|_eps = sqrt(|v_t|^2 + eps^2). So a block on an incline inside the cone (r = tan(theta)
    # / mu < 1) slides at the speed where that balances gravity, eps r / sqrt(1 - r^2). eps is
    # friction_smoothing (None: contact_tolerance), so a tighter stop keeps the law when the
    # setting is given. Measured: within 3e-4 of the answer at eps = 1e-4 (either stop) and
    # 0.4 % at 3e-5 (the block's own elastic settling is a few 1e-7 m/s).
    theta, mu = np.deg2rad(25.0), 0.6
    r = np.tan(theta) / mu
    tight = {"contact_tolerance": 1e-7, "max_stagger_iterations": 3000}
    for settings, eps, rel in (
        ({}, 1e-4, 1e-3),
        ({**tight, "friction_smoothing": 1e-4}, 1e-4, 1e-3),
        ({**tight, "friction_smoothing": 3e-5}, 3e-5, 1e-2),
        (tight, 1e-7, None),  # eps follows the tolerance: a creep too slow to see
    ):
        model = build_reduced_model(box, M=12, friction=mu, damping_beta=0.01, frame=frame,
                                    solver=solver, **settings)  # fmt: skip
        model.gravity = [G * np.sin(theta), 0.0, -G * np.cos(theta)]
        state, v = model.rest_state(), []
        for _ in range(160):
            state, info = model.step(state)
            assert info["converged"] and info["contact_converged"]
            v.append(com_velocity(model, state)[0])
        creep = np.mean(v[100:])
        if rel is None:
            assert abs(creep) < 2e-6
        else:
            assert creep == pytest.approx(eps * r / np.sqrt(1.0 - r * r), rel=rel)


@pytest.fixture(scope="module")
def swimmer():
    return cross()


def swim_model(robot, **kw):
    return build_reduced_model(robot, contact="none", gravity=[0, 0, 0], fluid_density=1000.0, **kw)


def test_drag_decelerates_a_coasting_body_monotonically(swimmer):
    model = swim_model(swimmer)
    state = model.rest_state()
    qdot = state.qdot
    qdot[:3] = np.array([0.5, 0.2, 0.3]) * np.sqrt(model.total_mass)
    state = cpp_sim.ReducedState(state.q, qdot, state.impulses)
    speeds = []
    # The cross's faces are axis-aligned, so in a rigid translation each axis k meets only
    # the faces facing +-e_k (area A_k) and slows by itself, m dv_k/dt = -1/2 rho C_d A_k
    # v_k |v_k|; a step takes the drag linearised at its start (implicit in the Jacobian):
    # v <- v - h k v |v| / (1 + 2 h k |v|). The coasting body follows that per axis to within
    # 0.4 % of its fastest component (measured: elastic and rotational wobble), so 2 % is
    # allowed; a drag along |v| rather than the normal speed is off by tens of percent.
    x, faces = swimmer.nodes, swimmer.surface_faces
    normal = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    twice_area = np.linalg.norm(normal, axis=1)
    facing = normal / twice_area[:, None] > 0.5  # (faces, axes): outward normal along +e_k
    area = 0.5 * twice_area @ facing
    np.testing.assert_allclose(area[2], swimmer.volume / np.ptp(x[:, 2]), rtol=1e-12)
    k = 0.5 * model.fluid_density * model.drag_coefficient * area / model.total_mass
    v = np.array([0.5, 0.2, 0.3])
    h = model.dt
    for _ in range(200):
        state, _ = model.step(state)
        speeds.append(np.linalg.norm(com_velocity(model, state)))
        v = v - h * k * v * np.abs(v) / (1 + 2 * h * k * np.abs(v))
        np.testing.assert_allclose(com_velocity(model, state), v, rtol=0, atol=0.02 * v.max())
    assert np.all(np.diff(speeds) < 0)


@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_without_contact_a_step_keeps_the_impulses_and_counts_no_contacts(swimmer, solver):
    # Only the staggered projection solves impulses; without it a step passes the state's
    # impulses through untouched (the fast step skips them entirely) and reports no contacts,
    # even when the state carries positive normal impulses from an earlier contact model.
    model = swim_model(swimmer, solver=solver, control_basis=np.eye(20)[:, :3])
    rest = model.rest_state()
    impulses = np.zeros_like(rest.impulses)
    impulses[2::3] = np.linspace(0.0, 1e-3, impulses.size // 3)
    state = cpp_sim.ReducedState(rest.q, rest.qdot, impulses)
    state, info = model.step(state, np.array([5.0, -3.0, 1.0]))
    np.testing.assert_array_equal(state.impulses, impulses)
    assert info["contacts"] == 0 and info["stagger_iterations"] == 0
    assert np.abs(state.qdot).max() > 0.0


def test_drag_on_a_broadside_plate_matches_quadratic_law(swimmer):
    # Moving along +z, only the top face (area A) advances into the fluid:
    # m dv/dt = -1/2 rho C_d A v^2  =>  v(t) = v0 / (1 + k v0 t), k = rho C_d A / (2 m).
    model = swim_model(swimmer, drag_coefficient=1.2)
    v0 = 0.3
    state = model.rest_state()
    qdot = state.qdot
    qdot[2] = v0 * np.sqrt(model.total_mass)
    state = cpp_sim.ReducedState(state.q, qdot, state.impulses)
    steps = 200
    for _ in range(steps):
        state, _ = model.step(state)
    area = swimmer.volume / np.ptp(swimmer.nodes[:, 2])
    k = 1000.0 * 1.2 * area / (2 * model.total_mass)
    t = steps * model.dt
    assert com_velocity(model, state)[2] == pytest.approx(v0 / (1 + k * v0 * t), rel=0.05)


def _stroke(model, lag, seconds=4.0):
    """Two modes driven at 1 Hz, ``lag`` apart; returns the centre of mass displacement."""
    state = model.rest_state()
    amp = 0.5 * np.sqrt(model.total_mass) * G  # half a body weight, in modal units
    omega = 2 * np.pi * 1.0
    start = model.com(state.q)
    for n in range(round(seconds / model.dt)):
        t = n * model.dt
        f_c = amp * np.array([np.sin(omega * t), np.sin(omega * t - lag)])
        state, info = model.step(state, f_c)
        assert not info["diverged"]
    return model.com(state.q) - start


def test_travelling_wave_stroke_swims(swimmer):
    model = swim_model(swimmer, control_basis=np.eye(20)[:, :2])
    travel = np.linalg.norm(_stroke(model, np.pi / 2))
    assert travel > 0.03, f"net displacement {travel:.4f} m"
    # The thrust is the fluid's: the same stroke without drag goes nowhere.
    model.fluid_density = 0.0
    assert np.linalg.norm(_stroke(model, np.pi / 2)) < 1e-9


@pytest.fixture(scope="module")
def walker():
    model = build_reduced_model(beam(), control_basis=np.eye(20)[:, :3])
    return model


def test_rollout_matches_stepping_and_is_thread_count_independent(walker):
    rng = np.random.default_rng(1)
    controls = 20.0 * rng.standard_normal((4, 30, 3))
    start = walker.rest_state()
    one = walker.rollout(start, controls, threads=1)
    two = walker.rollout(start, controls, threads=2)
    for key in ("rewards", "q", "qdot", "impulses", "com", "diverged"):
        np.testing.assert_array_equal(one[key], two[key])
    state = start
    rewards = []
    for t in range(30):
        state, _ = walker.step(state, controls[2, t])
        rewards.append(walker.direction @ com_velocity(walker, state) * walker.dt)
    np.testing.assert_array_equal(one["q"][2], state.q)
    np.testing.assert_allclose(one["rewards"][2], rewards, rtol=1e-12, atol=1e-15)
    assert one["rewards"].shape == (4, 30) and one["com"].shape == (4, 30, 3)


def test_diverging_rollout_is_flagged_and_isolated(walker):
    rng = np.random.default_rng(2)
    controls = 20.0 * rng.standard_normal((3, 10, 3))
    bad = controls.copy()
    bad[1] *= 1e12
    clean = walker.rollout(walker.rest_state(), controls, threads=2)
    mixed = walker.rollout(walker.rest_state(), bad, threads=2)
    assert list(mixed["diverged"]) == [False, True, False]
    assert np.all(np.isfinite(mixed["q"])) and np.all(np.isfinite(mixed["rewards"]))
    for b in (0, 2):
        np.testing.assert_array_equal(mixed["q"][b], clean["q"][b])
    # A diverging step leaves the whole state, contact warm-start included, as it was.
    state = walker.rest_state()
    for _ in range(5):
        state, _ = walker.step(state, np.zeros(3))  # settle into contact: non-zero impulses
    after, info = walker.step(state, np.array([1e15, -1e15, 1e15]))
    assert info["diverged"] and np.abs(state.impulses).max() > 0
    for name in ("q", "qdot", "impulses"):
        np.testing.assert_array_equal(getattr(after, name), getattr(state, name))
    # A normal problem the contact solve cannot solve (a ground 1 000 km above the body) is
    # a diverged step too, not free fall with the constraints dropped.
    walker.ground_height = 1e6
    try:
        after, info = walker.step(state, np.zeros(3))
    finally:
        walker.ground_height = 0.0
    assert info["diverged"] and not info["contact_converged"]
    np.testing.assert_array_equal(after.q, state.q)


def test_a_diverged_rollout_earns_no_reward_from_then_on(walker):
    # (rollout's documented contract.) A rollout moving along the task direction earns
    # reward until a step diverges; from then on it keeps its last good state and earns
    # zero, not that state's d . v_com dt again.
    rest = walker.rest_state()
    qdot = rest.qdot
    qdot[0] = 0.4 * np.sqrt(walker.total_mass)
    start = cpp_sim.ReducedState(rest.q, qdot, rest.impulses)
    controls = np.zeros((2, 6, 3))
    controls[0, 2:] = 1e15  # diverges at the third step
    out = walker.rollout(start, controls, threads=1)
    assert list(out["diverged"]) == [True, False]
    assert np.all(out["rewards"][0, :2] > 0) and np.all(out["rewards"][0, 2:] == 0.0)
    assert list(out["good_steps"]) == [2, 6]  # the steps solved before the divergence


def test_a_rollout_stopped_by_max_speed_is_not_converged(walker):
    # A step whose RMS node speed passes max_speed is rejected as diverged, though its
    # Newton converged; the rollout's later steps are never solved, so the rollout is not
    # converged (it said converged True with diverged True; a review, session 53).
    rng = np.random.default_rng(1)
    controls = 3.0 * np.sqrt(walker.total_mass) * G * rng.standard_normal((2, 30, 3))
    saved = walker.max_speed
    walker.max_speed = 0.5
    try:
        out = walker.rollout(walker.rest_state(), controls, threads=2)
    finally:
        walker.max_speed = saved
    assert list(out["diverged"]) == [True, True]
    assert list(out["converged"]) == [False, False]


def test_a_rollout_steps_with_the_control_basis_its_controls_were_checked_against(walker):
    # The caller's code that a rollout runs before it starts (iterating `state`, here) may
    # assign control_basis; the rollout keeps the B_c its controls were checked against. It
    # read the controls with the new C's stride: another rollout, and past the buffer's end
    # for a wider B_c (a review, session 53).
    rng = np.random.default_rng(0)
    controls = np.sqrt(walker.total_mass) * G * rng.standard_normal((2, 20, 3))
    start = walker.rest_state()
    expected = walker.rollout([start, start], controls, threads=1)

    def starts(width):
        walker.control_basis = np.eye(20)[:, :width]
        yield start
        yield start

    try:
        for width in (1, 20):
            walker.control_basis = np.eye(20)[:, :3]
            out = walker.rollout(starts(width), controls, threads=1)
            assert walker.C == width  # the assignment took effect, for later calls
            np.testing.assert_array_equal(out["q"], expected["q"])
    finally:
        walker.control_basis = np.eye(20)[:, :3]


def test_a_state_pickles_by_value_and_cannot_be_changed_in_place(walker):
    import copy
    import pickle

    state, _ = walker.step(walker.rest_state(), np.array([0.5, -0.2, 0.1]))
    for twin in (pickle.loads(pickle.dumps(state)), copy.copy(state), copy.deepcopy(state)):
        for field in ("q", "qdot", "impulses"):
            np.testing.assert_array_equal(getattr(twin, field), getattr(state, field))
        # a twin steps exactly as the original does
        np.testing.assert_array_equal(walker.step(twin, np.zeros(3))[0].q,
                                      walker.step(state, np.zeros(3))[0].q)  # fmt: skip
    # pybind11's pickle support made __setstate__ a constructor, ignored on a built state:
    # state.__setstate__((q, qdot, impulses)) returned None and changed nothing.
    assert not hasattr(state, "__setstate__")


def test_rollouts_from_a_sequence_of_states_each_start_from_their_own(walker):
    # One start state per rollout: rollout b continues from starts[b], as stepping does.
    rest = walker.rest_state()
    starts = []
    for speed in (0.0, 0.4):
        qdot = rest.qdot
        qdot[0] = speed * np.sqrt(walker.total_mass)
        starts.append(cpp_sim.ReducedState(rest.q, qdot, rest.impulses))
    controls = np.zeros((2, 4, 3))
    out = walker.rollout(starts, controls, threads=1)
    for b, start in enumerate(starts):
        state = start
        for u in controls[b]:
            state, _ = walker.step(state, u)
        np.testing.assert_array_equal(out["q"][b], state.q)


@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_a_step_faster_than_max_speed_is_diverged(solver):
    # max_speed (an RMS node speed) is the divergence test's last line: a finite step that
    # ends faster is reported diverged and leaves the state as it was; a slower one is not.
    model = build_reduced_model(beam(), contact="none", gravity=[0, 0, 0], solver=solver)
    model.max_speed = 1.0  # m/s
    rest = model.rest_state()
    for speed, diverged in ((0.5, False), (2.0, True)):
        qdot = rest.qdot
        qdot[0] = speed * np.sqrt(model.total_mass)  # a rigid translation at `speed`
        state = cpp_sim.ReducedState(rest.q, qdot, rest.impulses)
        after, info = model.step(state)
        assert info["diverged"] == diverged
        if diverged:
            np.testing.assert_array_equal(after.q, state.q)
            np.testing.assert_array_equal(after.qdot, state.qdot)


def test_leaving_the_ground_clears_the_impulses(walker):
    # A step with no contact candidate has no contact impulses: a body lifted off the ground
    # must not carry its resting impulses (the next contact's warm start, the contacts count).
    state = walker.rest_state()
    for _ in range(5):
        state, _ = walker.step(state, np.zeros(3))
    assert state.impulses[2::3].max() > 0
    q = state.q
    q[2] += 1.0 * np.sqrt(walker.total_mass)  # 1 m up: no node is a contact candidate
    after, info = walker.step(cpp_sim.ReducedState(q, state.qdot, state.impulses), np.zeros(3))
    assert info["active_rows"] == 0 and info["contacts"] == 0
    np.testing.assert_array_equal(after.impulses, 0.0)


def test_rollout_with_no_observables_returns_an_empty_observed(walker):
    out = walker.rollout(
        walker.rest_state(), np.zeros((2, 3, 3)), observe=np.zeros((0, walker.dim))
    )
    assert out["observed"].shape == (2, 3, 0)
    assert "observed" not in walker.rollout(walker.rest_state(), np.zeros((2, 3, 3)))


def test_a_model_without_actuation_steps_and_rolls_out_as_a_passive_body():
    # C = 0 (no control space) is accepted: its controls are (..., 0) arrays, and the body
    # moves as the same model with B_c actuated by zero forces
    model = build_reduced_model(beam(), control_basis=np.zeros((20, 0)))
    assert model.C == 0
    actuated = build_reduced_model(beam(), control_basis=np.eye(20)[:, :3])
    state, _ = model.step(model.rest_state(), np.zeros(0))
    other, _ = actuated.step(actuated.rest_state(), np.zeros(3))
    np.testing.assert_array_equal(state.q, other.q)
    out = model.rollout(model.rest_state(), np.zeros((2, 5, 0)))
    np.testing.assert_array_equal(
        out["q"], actuated.rollout(actuated.rest_state(), np.zeros((2, 5, 3)))["q"]
    )
    model.control_basis = np.zeros((20, 0))  # the setter too (Eigen checks build: no assert)


_LONG_ROLLOUT = """
import sys
import numpy as np
from softrom_gym.robots import beam
from softrom_gym.rom import build_reduced_model
model = build_reduced_model(beam(), control_basis=np.eye(20)[:, :3])
threads = int(sys.argv[1])
controls = np.zeros((threads, 2_000_000, 3))
print("ready", flush=True)
model.rollout(model.rest_state(), controls, threads=threads)  # line 10
print("finished", flush=True)
"""


@pytest.mark.parametrize("threads", [1, 2])
def test_ctrl_c_stops_a_long_rollout(threads):
    # Two million steps a rollout (minutes); SIGINT must end it with KeyboardInterrupt,
    # though the step loop runs in C++ without the GIL (on the pool's threads with 2).
    proc = subprocess.Popen(
        [sys.executable, "-c", _LONG_ROLLOUT, str(threads)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout.readline() == "ready\n"
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert "finished" not in out
    assert proc.returncode != 0 and "KeyboardInterrupt" in err
    assert 'File "<string>", line 10' in err  # raised in the rollout, not before it


_NESTED_ROLLOUT = """
import os, signal, threading
import numpy as np
from softrom_gym.robots import beam
from softrom_gym.rom import build_reduced_model
model = build_reduced_model(beam(), control_basis=np.eye(20)[:, :3])
def handler(sig, frame):
    model.rollout(model.rest_state(), np.zeros((2, 5, 3)), threads=2)
    print("nested done", flush=True)
    raise KeyboardInterrupt  # then stop the outer rollout, as Ctrl-C would
signal.signal(signal.SIGINT, handler)
threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
try:
    model.rollout(model.rest_state(), np.zeros((2, 2_000_000, 3)), threads=2)  # minutes
except KeyboardInterrupt:
    print("outer interrupted", flush=True)
"""


def test_a_rollout_started_by_a_signal_handler_during_a_rollout_runs(walker):
    # Ctrl-C's check runs Python signal handlers on the rollout's calling thread, inside the
    # thread pool's batch; a handler that starts another rollout on 2 threads locked the
    # pool's call mutex a second time and hung for good (a review, session 53). It now runs
    # its batch on that thread; the handler then stops the outer rollout.
    proc = subprocess.run([sys.executable, "-c", _NESTED_ROLLOUT], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["nested", "done", "outer", "interrupted"]


def test_bad_input_raises_clear_errors(walker):
    state = walker.rest_state()
    with pytest.raises(ValueError, match=r"control_basis has shape \(19, 3\), expected \(20,"):
        walker.control_basis = np.zeros((19, 3))
    with pytest.raises(
        ValueError, match=r"control_basis is not orthonormal: max \|B_c\^T B_c - I\| = 3 "
    ):
        walker.control_basis = 2.0 * np.eye(20)[:, :3]
    with pytest.raises(ValueError, match="dt must be a finite number > 0, got 0"):
        walker.dt = 0.0
    with pytest.raises(ValueError, match="friction must be a finite number >= 0, got -0.1"):
        walker.friction = -0.1
    with pytest.raises(ValueError, match=r"controls has shape \(2, 5, 4\), expected \(B, H, 3\)"):
        walker.rollout(state, np.zeros((2, 5, 4)))
    nan = np.zeros((2, 5, 3))
    nan[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="controls contains a non-finite value"):
        walker.rollout(state, nan)
    with pytest.raises(ValueError, match=r"f_c has shape \(2,\), expected \(3,\)"):
        walker.step(state, np.zeros(2))
    with pytest.raises(ValueError, match="f_c contains a non-finite value"):
        walker.step(state, np.array([0.0, np.inf, 0.0]))
    with pytest.raises(ValueError, match="contact must be one of"):
        walker.contact = "soft"
    for threads in (2.5, "2", True):
        with pytest.raises(TypeError, match="threads must be an int or None, got"):
            walker.rollout(state, np.zeros((2, 1, 3)), threads=threads)
    with pytest.raises(ValueError, match="threads must be >= 1, got 0"):
        walker.rollout(state, np.zeros((2, 1, 3)), threads=0)
    assert walker.rollout(state, np.zeros((2, 1, 3)), threads=np.int64(2**40))["q"].shape[0] == 2
    with pytest.raises(TypeError, match="profile must be True or False, got 'no'"):
        walker.profile = "no"
    with pytest.raises(ValueError, match=r"q has shape \(1, 26\), expected a 1-D array"):
        cpp_sim.ReducedState(state.q[None], state.qdot, state.impulses)
    with pytest.raises(ValueError, match="impulses has 7 entries, not a multiple of 3"):
        cpp_sim.ReducedState(state.q, state.qdot, np.zeros(7))
    with pytest.raises(ValueError, match=r"q has 5 entries, expected M \+ 6 >= 7"):
        cpp_sim.ReducedState(np.zeros(5), np.zeros(5), np.zeros(0))
    # |d| of a finite d can overflow or underflow; the unit direction must not
    for d, unit in (([1e200, 0, 0], [1, 0, 0]), ([1e154, 1e154, 0], [0.5**0.5, 0.5**0.5, 0]),
                    ([1e-170, 0, 0], [1, 0, 0])):  # fmt: skip
        walker.direction = d
        np.testing.assert_allclose(walker.direction, unit, rtol=1e-15)
    walker.direction = [1, 0, 0]
    with pytest.raises(TypeError, match="unknown setting"):
        build_reduced_model(beam(), frction=0.5)
    with pytest.raises(ValueError, match="M = 5000 deformation modes requested"):
        build_subspace(beam(), 5000)
    robot = beam()
    sub = build_subspace(robot, 20)
    swapped = sub.basis.copy()
    swapped[:, [3, 6]] = swapped[:, [6, 3]]  # a deformation column where a rotation belongs
    with pytest.raises(ValueError, match="basis columns 3..5 must be linearised rotations"):
        build_reduced_model(robot, subspace=Subspace(swapped, sub.frequencies, sub.num_modes))
    material = [robot.youngs_modulus, robot.poisson_ratio, robot.density]
    surface = [robot.surface_nodes, robot.surface_faces]
    args = [robot.nodes, robot.tets, *material, sub.basis, np.arange(3), np.zeros(3), *surface]
    with pytest.raises(ValueError, match="cubature_weights must have a positive sum"):
        cpp_sim.ReducedModel(*args)
    args[7] = np.ones(3)
    args[8] = np.concatenate([robot.surface_nodes, robot.surface_nodes[:1]])
    node = int(robot.surface_nodes[0])
    with pytest.raises(ValueError, match=f"surface_nodes lists node {node} more than once"):
        cpp_sim.ReducedModel(*args)
    args[8] = robot.surface_nodes[None]
    with pytest.raises(ValueError, match=r"surface_nodes has shape \(1, \d+\), expected a 1-D"):
        cpp_sim.ReducedModel(*args)
    args[8], args[6] = robot.surface_nodes, np.arange(4).reshape(2, 2)
    with pytest.raises(ValueError, match=r"cubature_elements has shape \(2, 2\), expected a 1-D"):
        cpp_sim.ReducedModel(*args)


def test_a_spinning_body_turns_then_meets_its_linearisation_limit(box):
    # Linearised rotation columns: a stiff block spun at w about z (no gravity, no ground)
    # first turns by w t with its centre of mass fixed; past small angles the stretch that a
    # linearised turn carries (theta^2 / 2) is resisted elastically, so the turn stays bounded
    # (the documented limit of the model), instead of being impossible as with no rotation
    # columns at all.
    model = build_reduced_model(box, contact="none", gravity=[0, 0, 0], damping_beta=0.0)
    mass = box.fem_model().mass
    r = box.nodes - mass @ box.nodes / mass.sum()
    a = np.column_stack([np.cross(e, r).ravel() for e in np.eye(3)])
    m3 = np.repeat(mass, 3)
    basis = build_subspace(box, 20).basis
    omega = np.array([0.0, 0.0, 0.5])
    state = model.rest_state()
    state = cpp_sim.ReducedState(state.q, basis.T @ (m3 * (a @ omega)), state.impulses)
    com0 = model.com(state.q)

    def angle(state):
        x = (model.positions(state.q) - box.nodes).ravel()
        return np.linalg.solve(a.T @ (m3[:, None] * a), a.T @ (m3 * x))

    for _ in range(8):  # 0.04 s
        state, _ = model.step(state)
    np.testing.assert_allclose(angle(state), omega * 8 * model.dt, rtol=0.02, atol=2e-4)
    peak = 0.0
    for _ in range(200):  # 1 s more
        state, _ = model.step(state)
        peak = max(peak, angle(state)[2])
    assert 0.02 < peak < 0.1  # turned on, then held back well short of w t = 0.52 rad
    np.testing.assert_allclose(model.com(state.q), com0, atol=1e-12)


@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_full_basis_with_ground_contact_matches_clamped_full_space_at_rest(solver):
    # A soft block settling under gravity on a sticky ground (B_r spanning all 3N directions,
    # staggered projection) reaches the full-space equilibrium with its bottom nodes clamped
    # where they stand: the ground carries the weight and friction holds the bottom's
    # Poisson expansion. The sag is 2.7 mm; the two agree to 3e-5 m.
    nodes, tets = voxels_to_tets(np.ones((3, 1, 1), dtype=bool), 0.1)
    robot = Robot("block", nodes, tets, youngs_modulus=1e4)
    fem = robot.fem_model()
    sub = full_basis(robot)
    model = build_reduced_model(
        robot, forces="exact", subspace=sub, friction=5.0, damping_alpha=5.0, dt=0.01,
        solver=solver,
    )  # fmt: skip
    fem.damping_alpha = 5.0
    bottom = nodes[:, 2] <= nodes[:, 2].min() + 1e-9
    x, v = nodes.copy(), np.zeros_like(nodes)
    state = model.rest_state()
    for _ in range(300):
        x, v = fem.step(x, v, 0.01, bottom)
        state, info = model.step(state)
        assert not info["diverged"]
    sag = nodes[:, 2].max() - x[:, 2].max()
    assert 2e-3 < sag < 2e-2
    np.testing.assert_allclose(model.positions(state.q), x, atol=0.02 * sag)


@pytest.mark.parametrize("frame", ["linear", "floating"])
def test_min_volume_ratio_is_the_smallest_det_f_over_the_mesh(bar, frame):
    # The smallest det F = det(D_s) / det(D_m) over every tetrahedron at the nodes that
    # model.positions gives, whichever way the core forms them (the floating frame's in the
    # body frame, where det F is the same).
    model = build_reduced_model(bar, contact="none", frame=frame)
    rng = np.random.default_rng(4)
    q = 0.3 * rng.standard_normal(model.dim)
    x = model.positions(q).reshape(-1, 3)
    rest = np.asarray(bar.nodes)
    tets = np.asarray(bar.tets)

    def dets(p):
        return np.linalg.det(np.stack([p[tets[:, k]] - p[tets[:, 0]] for k in (1, 2, 3)], -1))

    expected = (dets(x) / dets(rest)).min()
    assert expected < 0.95  # deformed enough that the minimum means something
    assert model.min_volume_ratio(q) == pytest.approx(expected, rel=1e-12)
    assert model.min_volume_ratio(model.rest_state().q) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("frame", ["linear", "floating"])
@pytest.mark.parametrize("solver", ["fast", "reference"])
@pytest.mark.parametrize("density", [50.0, 20000.0])  # m = 0.15 kg and 60 kg
def test_max_speed_is_an_rms_node_speed_whatever_the_mass(solver, density, frame):
    # max_speed bounds the RMS node speed |qdot| / sqrt(m), not |qdot|: a rigid translation at
    # 0.9 max_speed is kept and one at 1.1 max_speed is rejected, on bodies far from 1 kg
    # (test_a_step_faster_than_max_speed_is_diverged brackets 1 m/s by 0.5 and 2.0 on a beam
    # of ~3.6 kg, where sqrt(m) ~ 1.9 hid a test on |qdot|). In free flight without gravity or
    # contact a rigid translation is undamped: the step keeps its speed.
    nodes, tets = voxels_to_tets(np.ones((3, 1, 1), dtype=bool), 0.1)
    robot = Robot("bar", nodes, tets, youngs_modulus=2e4, density=density)
    model = build_reduced_model(robot, forces="exact", subspace=full_basis(robot),
                                contact="none", gravity=[0, 0, 0], solver=solver,
                                frame=frame)  # fmt: skip
    m = model.total_mass
    assert m == pytest.approx(density * 0.003, rel=1e-9)
    model.max_speed = 1.0
    rest = model.rest_state()
    direction = np.array([0.6, 0.0, 0.8])
    for speed, diverged in ((0.9, False), (1.1, True)):
        qdot = rest.qdot
        qdot[:3] = speed * np.sqrt(m) * direction
        state = cpp_sim.ReducedState(rest.q, qdot, rest.impulses)
        after, info = model.step(state)
        assert info["diverged"] == diverged, (m, speed)
        if diverged:
            np.testing.assert_array_equal(after.qdot, state.qdot)
        else:
            np.testing.assert_allclose(after.qdot[:3] / np.sqrt(m), speed * direction, rtol=1e-9)


def _translated(model, dz, vz):
    s = model.rest_state()
    q, qdot = s.q, s.qdot
    q[2] = dz * np.sqrt(model.total_mass)
    qdot[2] = vz * np.sqrt(model.total_mass)
    return cpp_sim.ReducedState(q, qdot, s.impulses)


@pytest.mark.parametrize("solver", ["fast", "reference"])
@pytest.mark.parametrize("beta", [0.2, 0.5])
def test_a_penetrating_body_rises_by_the_baumgarte_fraction_of_its_depth(box, solver, beta):
    # A stiff block at rest with its bottom face 1 mm into the ground, no gravity: the normal
    # bound of every bottom node is beta d / dt, and nothing pushes it further, so each loaded
    # node ends the step at exactly beta d / dt (to the contact tolerance) and none below it;
    # the block rises as a body at that speed (its bottom face stays flat: the stiff box's
    # deformation costs ~40x its motion in A's metric). A bound that removed the whole
    # penetration (-z / dt), or none of it, is off by 1 / beta or more.
    depth = 1e-3
    model = build_reduced_model(box, solver=solver, gravity=[0, 0, 0], stabilization=beta,
                                contact_tolerance=1e-7, max_stagger_iterations=2000)  # fmt: skip
    state = _translated(model, -depth, 0.0)
    nxt, info = model.step(state)
    assert info["converged"] and info["contact_converged"] and not info["diverged"]
    nodes = np.asarray(model.surface_nodes)
    z0 = model.positions(state.q)[nodes, 2] - model.ground_height
    z1 = model.positions(nxt.q)[nodes, 2] - model.ground_height
    bottom = z0 < -0.5 * depth
    assert bottom.sum() >= 4
    rise = (z1 - z0)[bottom] / model.dt  # the bottom nodes' normal velocities
    bound = beta * depth / model.dt
    loaded = nxt.impulses.reshape(-1, 3)[:, 2] > 0.0
    assert loaded.any() and np.all(loaded <= bottom)
    np.testing.assert_allclose((z1 - z0)[loaded] / model.dt, bound, rtol=0, atol=1e-5)
    assert rise.min() >= bound - 1e-5
    com_vz = nxt.qdot[2] / np.sqrt(model.total_mass)
    assert com_vz == pytest.approx(bound, rel=0.05)


@pytest.mark.parametrize("solver", ["fast", "reference"])
def test_a_body_arriving_faster_than_its_gap_allows_lands_on_the_plane(box, solver):
    # 1 mm above the ground and falling at 1 m/s (5 mm in a step): the bound -z / dt lets each
    # bottom node reach the plane and no further, so the step ends with the bottom face on the
    # plane (to the contact tolerance times dt): its nodes moved down at z / dt, not at the 1 m/s
    # they came with. (The rest of the block keeps coming and squeezes it a little: the centre of
    # mass is not bounded by the bottom face's speed.)
    gap = 1e-3
    model = build_reduced_model(box, solver=solver, gravity=[0, 0, 0],
                                contact_tolerance=1e-7, max_stagger_iterations=2000)  # fmt: skip
    state = _translated(model, gap, -1.0)
    nxt, info = model.step(state)
    assert info["converged"] and info["contact_converged"] and not info["diverged"]
    nodes = np.asarray(model.surface_nodes)
    z0 = model.positions(state.q)[nodes, 2] - model.ground_height
    z1 = model.positions(nxt.q)[nodes, 2] - model.ground_height
    bottom = z0 < 1.5 * gap
    loaded = nxt.impulses.reshape(-1, 3)[:, 2] > 0.0
    assert loaded.any() and np.all(loaded <= bottom)
    np.testing.assert_allclose(z1[loaded], 0.0, rtol=0, atol=1e-7 * model.dt * 10)
    assert z1.min() >= -1e-7 * model.dt * 10
