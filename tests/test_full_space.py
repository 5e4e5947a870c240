"""The full-space walking step (softrom_gym.full_space): the reduced model's step with a B_r
spanning all 3N directions, Coulomb sliding against the analytic answer, and bad input."""

import numpy as np
import pytest
from test_reduced import full_basis

import cpp_sim
from softrom_gym.full_space import FullSpaceModel, FullSpaceState
from softrom_gym.robots.robot import Robot
from softrom_gym.robots.voxel import voxels_to_tets
from softrom_gym.rom import build_reduced_model

G = 9.81


def test_the_centre_of_mass_is_mass_weighted(bar):
    # Guards: com() as the plain mean of the nodes. The deformation columns are mass-orthogonal
    # to the translations, so no deformation moves the (mass-weighted) centre of mass.
    sub = full_basis(bar)
    model = FullSpaceModel(bar)
    rest = model.com(bar.nodes)
    for j in range(sub.M):
        moved = model.com(bar.nodes + 0.01 * sub.deformation[:, j].reshape(-1, 3))
        np.testing.assert_allclose(moved, rest, rtol=0, atol=1e-12)


@pytest.mark.parametrize("smoothing", [None, 1e-4])
def test_is_the_reduced_step_with_a_full_basis(bar, smoothing):
    """Dropped 1 cm onto a frictional ground and actuated in two shapes, the full-space model
    follows the reduced reference solver whose B_r spans all 3N directions: the same implicit
    step, the same staggered projection, in other coordinates; with the friction law's
    smoothing following the tolerance (None) or set apart from it."""
    sub = full_basis(bar)
    rng = np.random.default_rng(0)
    bc = np.linalg.qr(rng.standard_normal((sub.M, 2)))[0]
    settings = dict(friction=0.5, dt=0.005, newton_tolerance=1e-10, contact_tolerance=1e-6,
                    max_stagger_iterations=500, max_newton_iterations=50,
                    friction_smoothing=smoothing)  # fmt: skip
    reduced = build_reduced_model(bar, forces="exact", subspace=sub, control_basis=bc,
                                  solver="reference", **settings)  # fmt: skip
    full = FullSpaceModel.matching(reduced, bar, sub.basis)
    assert full.friction_smoothing == smoothing
    full.project_hessian = False  # the reference's exact Hessian
    bound = 0.6 * np.sqrt(reduced.total_mass) * G
    state = reduced.rest_state()
    q = np.array(state.q)
    q[:3] = np.array([0.0, 0.0, 0.01]) * np.sqrt(reduced.total_mass)  # 1 cm up
    qdot = np.zeros_like(q)
    qdot[:3] = np.array([0.3, 0.1, 0.0]) * np.sqrt(reduced.total_mass)  # sliding on landing
    state = cpp_sim.ReducedState(q, qdot, state.impulses)
    fstate = full.state_from_reduced(sub.basis, state)
    gap, contacts = 0.0, 0
    for n in range(160):
        fc = bound * np.array(
            [np.sin(2 * np.pi * 3 * n * 0.005), np.cos(2 * np.pi * 5 * n * 0.005)]
        )
        state, info = reduced.step(state, fc)
        fstate, finfo = full.step(fstate, fc)
        assert info["converged"] and finfo["converged"]
        # the same iteration in other coordinates: the same number of staggers to converge
        assert finfo["stagger_iterations"] == info["stagger_iterations"]
        assert finfo["contact_converged"] == info["contact_converged"]
        contacts = max(contacts, finfo["contacts"])
        x = bar.nodes + (sub.basis @ state.q).reshape(-1, 3)
        gap = max(gap, np.abs(x - fstate.x).max())
    assert contacts >= 4  # it landed and stands on its bottom face
    assert gap < 1e-6
    np.testing.assert_allclose(fstate.v.ravel(), sub.basis @ state.qdot, atol=1e-4)


def test_swims_as_the_reduced_step_with_a_full_basis(bar):
    """In still water (no gravity, no ground) and actuated in two shapes, the full-space model
    follows the reduced reference solver whose B_r spans all 3N directions: the same implicit
    step and the same drag, linearised at the step's start, in other coordinates."""
    sub = full_basis(bar)
    bc = np.linalg.qr(np.random.default_rng(1).standard_normal((sub.M, 2)))[0]
    reduced = build_reduced_model(bar, forces="exact", subspace=sub, control_basis=bc,
                                  solver="reference", contact="none", gravity=[0, 0, 0],
                                  fluid_density=1000.0, newton_tolerance=1e-10,
                                  max_newton_iterations=50)  # fmt: skip
    full = FullSpaceModel.matching(reduced, bar, sub.basis)
    assert full.contact == "none" and full.fluid_density == 1000.0
    full.project_hessian = False  # the reference's exact Hessian
    bound = 2.0 * np.sqrt(reduced.total_mass) * G
    state = reduced.rest_state()
    qdot = np.zeros_like(state.qdot)
    qdot[:3] = np.array([0.2, 0.0, -0.1]) * np.sqrt(reduced.total_mass)  # coasting
    state = cpp_sim.ReducedState(state.q, qdot, state.impulses)
    fstate = full.state_from_reduced(sub.basis, state)
    gap = 0.0
    for n in range(120):
        fc = bound * np.array(
            [np.sin(2 * np.pi * 3 * n * 0.005), np.cos(2 * np.pi * 2 * n * 0.005)]
        )
        state, info = reduced.step(state, fc)
        fstate, finfo = full.step(fstate, fc)
        assert info["converged"] and finfo["converged"] and finfo["active_rows"] == 0
        x = bar.nodes + (sub.basis @ state.q).reshape(-1, 3)
        gap = max(gap, np.abs(x - fstate.x).max())
    assert gap < 1e-7
    np.testing.assert_allclose(fstate.v.ravel(), sub.basis @ state.qdot, atol=1e-6)
    # the fluid slowed the coasting: the drag acted
    assert np.linalg.norm(full.com(fstate.v)) < 0.9 * np.linalg.norm([0.2, 0.0, -0.1])


def test_a_swimming_step_from_rest_at_full_width(bar):
    """From rest no face advances into the fluid, so the drag's factor W has no columns.
    Eigen's blocked rank update divided by that zero width once M + 6 was past its
    small-matrix path (48 here, not the benchmarks' 26): the reference solver's first swimming
    step stopped the process with SIGFPE (until 2026-12-07), and the floating frame's, which
    always forms J_d, too."""
    sub = full_basis(bar)
    for frame in ("linear", "floating"):
        model = build_reduced_model(
            bar, forces="exact", subspace=sub, solver="reference", frame=frame,
            control_basis=np.eye(sub.M)[:, :2], contact="none", gravity=[0, 0, 0],
            fluid_density=1000.0,
        )  # fmt: skip
        state, info = model.step(model.rest_state(), np.array([1.0, -1.0]))
        assert info["converged"] and not info["diverged"]
        assert np.abs(state.qdot).max() > 0.0


def test_drag_on_a_translating_bar_is_its_end_face_s_pressure_drag(bar):
    # A rigid translation along the bar's axis: only the leading end face (0.1 m x 0.1 m, normal
    # +x) advances into the fluid, so the drag is -1/2 rho C_d A v^2 along x, and its Jacobian
    # takes a uniform velocity change d to -rho C_d A v d (the derivative of v^2 / 2).
    model = FullSpaceModel(bar, contact="none", fluid_density=1000.0, drag_coefficient=0.8)
    speed = 0.3
    v = np.tile([speed, 0.0, 0.0], (bar.num_nodes, 1))
    force, jac = model._drag(bar.nodes, v)
    total = force.reshape(-1, 3).sum(axis=0)
    area = 0.1 * 0.1
    np.testing.assert_allclose(total, [-0.5 * 1000.0 * 0.8 * area * speed**2, 0.0, 0.0],
                               rtol=1e-12, atol=1e-15)  # fmt: skip
    uniform = np.tile([1.0, 0.0, 0.0], bar.num_nodes)
    np.testing.assert_allclose((jac @ uniform).reshape(-1, 3).sum(axis=0),
                               [-1000.0 * 0.8 * area * speed, 0.0, 0.0], rtol=1e-12)  # fmt: skip
    # moving backwards, the other end face takes it; at rest, no face does
    back, _ = model._drag(bar.nodes, -v)
    np.testing.assert_allclose(back.reshape(-1, 3).sum(axis=0), -total, rtol=1e-12)
    rest, rest_jac = model._drag(bar.nodes, np.zeros_like(v))
    assert not rest.any() and not rest_jac.toarray().any()


@pytest.mark.parametrize(("theta_deg", "mu"), [(35.0, 0.5), (20.0, 0.6)])
def test_a_block_slides_with_the_coulomb_acceleration_or_sticks(theta_deg, mu):
    nodes, tets = voxels_to_tets(np.ones((2, 2, 1), dtype=bool), 0.1)
    box = Robot("block", nodes, tets, youngs_modulus=1e6)
    theta = np.deg2rad(theta_deg)
    model = FullSpaceModel(box, friction=mu, damping_beta=0.01,
                           gravity=(G * np.sin(theta), 0.0, -G * np.cos(theta)))  # fmt: skip
    state = model.rest_state()
    ts, vs = [], []
    for n in range(100):
        state, info = model.step(state)
        assert info["converged"]
        ts.append((n + 1) * model.dt)
        vs.append(model.com(state.v)[0])
    t, v = np.array(ts), np.array(vs)
    late = t > 0.2
    expected = max(G * (np.sin(theta) - mu * np.cos(theta)), 0.0)
    accel = np.polyfit(t[late], v[late], 1)[0]
    assert accel == pytest.approx(expected, rel=0.02, abs=0.02)


def test_bad_input_is_named(bar):
    with pytest.raises(ValueError, match=r"actuation must be a finite \(3N, C\) = \(48, C\)"):
        FullSpaceModel(bar, np.ones((47, 2)))
    with pytest.raises(ValueError, match="friction must be >= 0"):
        FullSpaceModel(bar, friction=-1.0)
    model = FullSpaceModel(bar, np.ones((48, 2)))
    with pytest.raises(ValueError, match=r"controls must be finite with shape \(2,\)"):
        model.step(model.rest_state(), np.ones(3))
    sub = full_basis(bar)
    pressed = build_reduced_model(bar, forces="exact", subspace=sub, contact="penalty")
    with pytest.raises(ValueError, match="only staggered-projection contact or none has a "
                       "full-space counterpart, the model's contact is 'penalty'"):  # fmt: skip
        FullSpaceModel.matching(pressed, bar, sub.basis)
    for bad, match in (({"ground_height": float("nan")}, "ground_height must be a finite"),
                       ({"dt": float("inf")}, "dt must be a finite number"),
                       ({"gravity": (0.0, -9.81)}, "gravity must be 3 finite numbers"),
                       ({"max_newton_iterations": 2.5}, "max_newton_iterations must be an "
                                                        "integer >= 1"),
                       ({"actuation_frame": "rotating"}, "actuation_frame must be 'world' or "
                                                         "'body', got 'rotating'")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            FullSpaceModel(bar, **bad)
    with pytest.raises(ValueError, match="this model has no actuation, so it takes no controls"):
        FullSpaceModel(bar).step(FullSpaceModel(bar).rest_state(), np.ones(2))
    walk = build_reduced_model(
        bar, forces="exact", subspace=sub, control_basis=np.eye(sub.M)[:, :2]
    )
    other = Robot(
        "longer", *voxels_to_tets(np.ones((4, 1, 1), dtype=bool), 0.1), youngs_modulus=2e4
    )
    with pytest.raises(ValueError, match="the model has 16 nodes and the robot 20"):
        FullSpaceModel.matching(walk, other, np.zeros((60, sub.M + 6)))


def test_rollout_is_its_steps_and_names_controls_of_another_shape(bar, monkeypatch):
    """rollout (H, C) is the public many-step call; no test ran it."""
    sub = full_basis(bar)
    walk = build_reduced_model(bar, forces="exact", subspace=sub, friction=0.5,
                               control_basis=np.eye(sub.M)[:, :2])  # fmt: skip
    model = FullSpaceModel.matching(walk, bar, sub.basis)
    controls = 0.3 * np.sqrt(walk.total_mass) * G * np.array([[1.0, 0.0], [0.5, -1.0],
                                                              [0.0, 1.0]])  # fmt: skip
    out = model.rollout(model.rest_state(), controls)
    state = model.rest_state()
    for t, fc in enumerate(controls):
        state, info = model.step(state, fc)
        np.testing.assert_array_equal(out["com"][t], model.com(state.x))
        assert out["converged"][t] == info["converged"]
        assert out["contact_converged"][t] == info["contact_converged"]
    np.testing.assert_array_equal(out["state"].x, state.x)
    np.testing.assert_array_equal(out["state"].v, state.v)
    assert out["converged"].all()
    with pytest.raises(ValueError, match=r"controls must be \(H, C\), got shape \(2,\)"):
        model.rollout(model.rest_state(), controls[0])
    with pytest.raises(ValueError, match=r"controls must be finite with shape \(2,\), got \(3,\)"):
        model.rollout(model.rest_state(), np.zeros((1, 3)))
    # (H, 0) means "no controls" only to a model without actuation
    with pytest.raises(ValueError, match=r"controls must be finite with shape \(2,\), got \(0,\)"):
        model.rollout(model.rest_state(), np.zeros((1, 0)))
    # each step's two flags land in their own arrays (every step above converged both ways)
    step, flags = model.step, iter([(True, False), (False, True)])

    def flagged(state, fc=None):
        state, info = step(state, fc)
        info["converged"], info["contact_converged"] = next(flags)
        return state, info

    monkeypatch.setattr(model, "step", flagged)
    out = model.rollout(model.rest_state(), controls[:2])
    assert out["converged"].tolist() == [True, False]
    assert out["contact_converged"].tolist() == [False, True]
    # a model without actuation takes H steps of no controls as (H, 0)
    unactuated = FullSpaceModel(bar)
    free = unactuated.rollout(unactuated.rest_state(), np.zeros((2, 0)))
    state = unactuated.step(unactuated.step(unactuated.rest_state())[0])[0]
    np.testing.assert_array_equal(free["state"].x, state.x)


def test_settings_and_models_without_a_full_space_counterpart_are_named(bar):
    for bad, match in (({"dt": 0.0}, "dt must be > 0, got 0.0"),
                       ({"newton_tolerance": -1e-6}, "newton_tolerance must be > 0, got -1e-06"),
                       ({"stabilization": 1.5}, r"stabilization must be in \[0, 1\], got 1.5"),
                       ({"friction_smoothing": 0.0},
                        "friction_smoothing must be > 0 or None, got 0.0"),
                       ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            FullSpaceModel(bar, **bad)
    for edge in (0.0, 1.0):  # [0, 1] is closed: guards `<= 1` becoming `< 1`
        assert FullSpaceModel(bar, stabilization=edge).stabilization == edge
    for bad, match in (({"contact": "penalty"}, "contact must be 'staggered' or 'none', got "
                                                "'penalty'"),
                       ({"fluid_density": -1.0}, "fluid_density must be >= 0, got -1.0"),
                       ({"drag_coefficient": float("nan")}, "drag_coefficient must be a finite"),
                       ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            FullSpaceModel(bar, **bad)
    sub = full_basis(bar)
    walk = build_reduced_model(bar, forces="exact", subspace=sub,
                               control_basis=np.eye(sub.M)[:, :2])  # fmt: skip
    with pytest.raises(ValueError, match=rf"basis has shape \(48, {sub.M + 5}\), expected "
                       rf"\(48, {sub.M + 6}\) for this model"):  # fmt: skip
        FullSpaceModel.matching(walk, bar, sub.basis[:, :-1])


def test_a_bad_state_or_a_setting_changed_after_construction_is_named(bar):
    """Found by calling step with hand-made states: a (N, 2) x was a numpy broadcasting error,
    an inf velocity was reported as 'x contains a non-finite value', impulses of the wrong
    length were used silently as the warm start, a complex x lost its imaginary part with a
    warning only, and ``model.dt = -0.01`` after construction stepped backwards in time."""
    model = FullSpaceModel(bar)
    rest = model.rest_state()
    x, v, imp = rest.x, rest.v, rest.impulses
    n, ns = bar.num_nodes, len(bar.surface_nodes)
    cases = (
        ((x[:, :2], v, imp), rf"state.x has shape \({n}, 2\), expected \({n}, 3\)"),
        ((x, v[:-1], imp), rf"state.v has shape \({n - 1}, 3\), expected \({n}, 3\)"),
        ((x, v + np.inf, imp), r"state.v has a non-finite value \(inf\) at row 0"),
        ((x, v, imp[:-1]), rf"state.impulses has shape \({ns - 1}, 3\), expected \({ns}, 3\)"),
        ((x + 0j, v, imp), "state.x must be real numbers, got a complex128 array"),
        ((x, v, "abc"), "state.impulses must be real numbers"),
    )
    from softrom_gym.full_space import FullSpaceState

    for fields, match in cases:
        with pytest.raises(ValueError, match=match):
            model.step(FullSpaceState(*fields))
    with pytest.raises(ValueError, match=rf"x has shape \(5, 3\), expected \({n}, 3\)"):
        model.com(x[:5])
    with pytest.raises(ValueError, match="actuation must be real numbers, got a bool array"):
        FullSpaceModel(bar, np.ones((3 * n, 2), dtype=bool))
    with pytest.raises(ValueError, match="gravity must be 3 finite numbers"):
        FullSpaceModel(bar, gravity="abc")
    model.dt = -0.01
    with pytest.raises(ValueError, match="dt must be > 0, got -0.01"):
        model.step(rest)
    # A gravity set after construction is the one the step uses: one step of free fall from
    # rest moves every node by g dt^2 (implicit Euler), here along +x, far above the ground.
    model.dt, model.gravity = 0.01, (3.0, 0.0, 0.0)
    lifted = FullSpaceState(x + np.array([0.0, 0.0, 1.0]), v, imp)
    new, _ = model.step(lifted)
    np.testing.assert_allclose(new.x - lifted.x, np.tile([3.0e-4, 0.0, 0.0], (n, 1)), atol=1e-9)


def test_state_from_reduced_names_a_bad_basis(bar):
    """Found by passing B_r with a column or rows missing, a NaN and a complex entry: a matmul
    or reshape error, or silently a state of NaNs / the real part."""
    sub = full_basis(bar)
    walk = build_reduced_model(bar, forces="exact", subspace=sub)
    model = FullSpaceModel.matching(walk, bar, sub.basis)
    state = walk.rest_state()
    shape = r"expected \(3N, M \+ 6\) = \(48, 48\)"
    for bad, match in ((sub.basis[:, :-1], shape), (sub.basis[:-3], shape),
                       (sub.basis * np.nan, "basis has a non-finite entry"),
                       (sub.basis + 0j, "basis must be real numbers")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            model.state_from_reduced(bad, state)
    # The good basis: X + B_r q at rest, and the impulses carried over per surface node.
    full = model.state_from_reduced(sub.basis, state)
    np.testing.assert_allclose(full.x, bar.nodes, atol=1e-12)
    assert full.impulses.shape == (len(bar.surface_nodes), 3)


def test_a_floating_frame_state_maps_through_its_model(bar):
    """A floating frame's q is (centre of mass, rotation, deformation), not coordinates in
    B_r: read as those, a beam 60 steps into a stroke was placed 0.16 m off (a review,
    session 54). Given the model, the state is its positions and velocities; without it, a
    matching model of a floating-frame one refuses."""
    sub = full_basis(bar)
    floating = build_reduced_model(bar, forces="exact", subspace=sub, frame="floating",
                                   control_basis=np.eye(sub.M)[:, :3])  # fmt: skip
    model = FullSpaceModel.matching(floating, bar, sub.basis)
    # the floating frame's actuation turns with the body, torque-free: so, by default, does
    # its counterpart's (a world-fixed field kept them 3.7-5.6 mm apart at every dt)
    assert model.actuation_frame == "body"
    linear = build_reduced_model(bar, forces="exact", subspace=sub,
                                 control_basis=np.eye(sub.M)[:, :3])  # fmt: skip
    assert FullSpaceModel.matching(linear, bar, sub.basis).actuation_frame == "world"
    state = floating.rest_state()
    for _ in range(20):  # turning and moving: q is no longer B_r coordinates
        state, _ = floating.step(state, np.array([0.0, 3.0, -2.0]) * np.sqrt(floating.total_mass))
    with pytest.raises(ValueError, match="pass model="):
        model.state_from_reduced(sub.basis, state)
    full = model.state_from_reduced(sub.basis, state, model=floating)
    np.testing.assert_array_equal(full.x, floating.positions(state.q))
    np.testing.assert_array_equal(full.v, floating.velocities(state.q, state.qdot))
    wrong = sub.basis @ state.q  # (the linear frame's reading)
    assert np.abs(full.x.ravel() - (bar.nodes.ravel() + wrong)).max() > 1e-6


def test_a_resting_body_warm_started_settles_in_one_stagger_as_the_reduced_step(bar):
    # The first stagger is judged against the warm start's velocity (the reduced core since
    # session 51, the full space since 52): a body at rest on the ground, warm-started with
    # the impulses that hold it, converges in one stagger. Judged against v*, which gravity
    # pulls down by g dt, the full space took two, and a warm start whose friction alone
    # lifted every candidate could end a step at once with its normal conditions unmet.
    sub = full_basis(bar)
    reduced = build_reduced_model(bar, forces="exact", subspace=sub, solver="reference",
                                  friction=0.5)  # fmt: skip
    full = FullSpaceModel.matching(reduced, bar, sub.basis)
    state, fstate = reduced.rest_state(), full.rest_state()
    staggers = []
    for _ in range(120):
        state, info = reduced.step(state)
        fstate, finfo = full.step(fstate)
        staggers.append((info["stagger_iterations"], finfo["stagger_iterations"]))
    assert finfo["contacts"] >= 4 and np.abs(fstate.v).max() < 1e-3  # resting on its face
    assert staggers[-20:] == [(1, 1)] * 20


class _MissingACorner(FullSpaceModel):
    """A full space whose candidate rule misses one loaded node of the bottom face, as the
    reduced cross's rule missed a levered arm (session 51)."""

    def _candidates(self, z, vn):
        picked = super()._candidates(z, vn)
        return picked[picked != self.dropped]


def test_a_node_the_candidates_missed_joins_them_and_the_step_is_solved_again(bar, monkeypatch):
    # The candidates are picked from v*, and the impulses on them can drive another node below
    # its bound; such a node joins them and the step is re-solved (the reduced core's
    # completion, 49d2956). Here the rule misses a corner of the resting bar's bottom face, so
    # without the completion that corner falls through the ground (g dt^2 on the first step,
    # and on), and the bar tilts.
    full = FullSpaceModel(bar, friction=0.5)
    surface = np.asarray(bar.surface_nodes)
    corner = int(np.flatnonzero(bar.nodes[surface, 2] == 0.0)[0])
    missing = _MissingACorner(bar, friction=0.5)
    missing.dropped = corner
    state, fstate = full.rest_state(), missing.rest_state()
    for _ in range(40):
        state, info = full.step(state)
        fstate, finfo = missing.step(fstate)
        assert finfo["contact_converged"]
        assert finfo["active_rows"] == info["active_rows"]  # the corner joined them
        # on or above the ground, to the stagger tolerance over a step
        assert fstate.x[:, 2].min() > -2 * missing.contact_tolerance * missing.dt
    # The same rest as the rule that saw the corner (the bar sags 2.6 mm and spreads 0.8 mm),
    # each step's answer within about two stagger tolerances of the other's (measured: 2.3e-5
    # m apart after the 40 steps)
    tol = 2 * 40 * full.contact_tolerance * full.dt
    np.testing.assert_allclose(fstate.x, state.x, rtol=0, atol=tol)
    assert fstate.impulses[corner, 2] > 0.0  # the corner carries its share of the weight
    # Allowed no round, the step says that it left a node out, and counts the candidates it
    # solved over (as the core does when its rounds run out).
    monkeypatch.setattr("softrom_gym.full_space._MAX_CANDIDATE_ROUNDS", 0)
    _, finfo = missing.step(missing.rest_state())
    assert not finfo["contact_converged"]
    assert finfo["active_rows"] == info["active_rows"] - 1


def test_a_diverging_newton_step_says_so():
    # Full Newton steps, as the reduced reference takes them, far outside the envs' settings
    # (4 m/s random node velocities at dt = 20 ms): the iterate overflowed the material and
    # the error blamed the state x, which the caller never gave.
    nodes, tets = voxels_to_tets(np.ones((6, 3, 3), dtype=bool), 0.05)
    robot = Robot("block", nodes, tets, youngs_modulus=3e4)
    v0 = 4.0 * np.random.default_rng(0).standard_normal(nodes.shape)
    model = FullSpaceModel(robot, contact="none", gravity=(0, 0, 0), dt=0.02, damping_beta=0.0)
    state = model.rest_state()
    with pytest.raises(FloatingPointError, match="the Newton step diverged at iteration"):
        model.step(type(state)(state.x, v0, state.impulses))


def test_free_fall_with_mass_damping_is_the_exact_implicit_step(bar):
    """A body falling from rest without contact stays undeformed, so the implicit step is
    linear: M (v - 0) = h (M g - alpha M v) gives v = g h / (1 + h alpha) at every node, and
    Newton with the exact Jacobian lands on it in one update (the second only confirms).
    newton_tolerance bounds the mass-weighted RMS of an update, |dv|_M / sqrt(m): a tolerance
    above |v| accepts the first update. Every existing test runs with damping_alpha = 0, so
    the alpha term's sign in the residual, alpha left out of the Newton matrix, and an
    unweighted |dv| (sqrt(3N) times larger) all passed."""
    h, alpha = 0.005, 4.0
    model = FullSpaceModel(bar, contact="none", dt=h, damping_alpha=alpha,
                           newton_tolerance=1e-12)  # fmt: skip
    new, info = model.step(model.rest_state())
    expected = np.array([0.0, 0.0, -G * h / (1.0 + h * alpha)])
    np.testing.assert_allclose(new.v, np.broadcast_to(expected, new.v.shape), rtol=0, atol=1e-12)
    assert info["converged"] and info["newton_iterations"] == 2
    speed = G * h / (1.0 + h * alpha)
    for tolerance, iterations in ((1.25 * speed, 1), (0.8 * speed, 2)):
        model.newton_tolerance = tolerance
        _, info = model.step(model.rest_state())
        assert info["converged"] and info["newton_iterations"] == iterations, tolerance


@pytest.mark.parametrize("stabilization", [0.2, 0.5])
def test_a_penetrating_node_rises_by_the_stabilization_share_of_its_depth(box, stabilization):
    """A node below the ground ends the step with a normal velocity of at least
    beta_s * depth / h: placed 1 mm into the ground at rest (no gravity, so nothing else
    moves it), the stiff block's bottom rises by beta_s of its depth in one step. In every
    existing test no node starts below the ground, so a bound of depth / h (the node lifted
    out at once) passed."""
    depth, h = 1e-3, 0.005
    model = FullSpaceModel(box, gravity=(0.0, 0.0, 0.0), dt=h, friction=0.5,
                           stabilization=stabilization)  # fmt: skip
    rest = model.rest_state()
    x = box.nodes.copy()
    x[:, 2] += -x[:, 2].min() - depth
    bottom = np.flatnonzero(np.isclose(x[:, 2], -depth))
    assert len(bottom) >= 4
    new, info = model.step(FullSpaceState(x, np.zeros_like(x), rest.impulses))
    assert info["converged"] and info["contact_converged"]
    np.testing.assert_allclose(new.x[bottom, 2], -(1.0 - stabilization) * depth,
                               rtol=0, atol=0.02 * depth)  # fmt: skip
