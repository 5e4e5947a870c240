"""Bad input to the compiled core raises clear Python errors, never crashes."""

import pickle

import numpy as np
import pytest

import cpp_sim


@pytest.fixture
def tet():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3]])
    return nodes, tets


def make(nodes, tets, e=1e5, nu=0.3, rho=1000.0):
    return cpp_sim.FEMModel(nodes, tets, e, nu, rho)


def test_wrong_node_shape(tet):
    nodes, tets = tet
    with pytest.raises(ValueError, match=r"nodes has shape \(4, 2\), expected \(N, 3\)"):
        make(nodes[:, :2], tets)
    with pytest.raises(ValueError, match=r"nodes has shape \(12,\)"):
        make(nodes.ravel(), tets)


def test_wrong_dtypes(tet):
    nodes, tets = tet
    with pytest.raises(TypeError, match="tets must be an integer array, got dtype float64"):
        make(nodes, tets.astype(float))
    with pytest.raises(TypeError, match="nodes must hold real numbers, got dtype complex128"):
        make(nodes.astype(complex), tets)
    with pytest.raises(TypeError, match="nodes must hold real numbers"):
        make(np.array([["a", "b", "c"]] * 4), tets)


def test_tet_index_out_of_range(tet):
    nodes, _ = tet
    with pytest.raises(ValueError, match=r"tets\[0\] has node index 7 out of range \[0, 4\)"):
        make(nodes, np.array([[0, 1, 2, 7]]))
    with pytest.raises(ValueError, match=r"tets\[0\] has node index -1 out of range"):
        make(nodes, np.array([[0, 1, 2, -1]]))


def test_inverted_or_degenerate_tet(tet):
    nodes, _ = tet
    with pytest.raises(
        ValueError, match=r"tets\[0\] = \[0, 2, 1, 3\] has non-positive rest volume"
    ):
        make(nodes, np.array([[0, 2, 1, 3]]))
    flat = nodes.copy()
    flat[3] = [0.5, 0.5, 0.0]
    with pytest.raises(ValueError, match="non-positive rest volume"):
        make(flat, np.array([[0, 1, 2, 3]]))
    # positive but a sliver: refused, and not called non-positive (it was)
    flat[3] = [0.5, 0.5, 1e-14]
    with pytest.raises(ValueError, match=r"has a near-zero rest volume 1\.66667e-15 \(under"):
        make(flat, np.array([[0, 1, 2, 3]]))


def test_unreferenced_node(tet):
    nodes, tets = tet
    with pytest.raises(ValueError, match="node 4 is not used by any tetrahedron"):
        make(np.vstack([nodes, [[2.0, 2.0, 2.0]]]), tets)


def test_non_finite_nodes(tet):
    nodes, tets = tet
    nodes[2, 1] = np.nan
    with pytest.raises(ValueError, match="nodes contains a non-finite value"):
        make(nodes, tets)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"e": 0.0}, "youngs_modulus must be a finite number > 0, got 0"),
        ({"e": -5.0}, "youngs_modulus must be a finite number > 0, got -5"),
        ({"e": np.inf}, "youngs_modulus must be a finite number > 0, got inf"),
        ({"nu": 0.5}, r"poisson_ratio must lie in \(-1, 0.5\), got 0.5"),
        ({"nu": -1.0}, r"poisson_ratio must lie in \(-1, 0.5\), got -1"),
        ({"nu": np.nan}, r"poisson_ratio must lie in \(-1, 0.5\), got nan"),
        ({"rho": 0.0}, "density must be a finite number > 0, got 0"),
    ],
)
def test_bad_material(tet, kwargs, message):
    with pytest.raises(ValueError, match=message):
        make(*tet, **kwargs)


def test_bad_step_arguments(tet):
    nodes, tets = tet
    fem = make(nodes, tets)
    v = np.zeros_like(nodes)
    with pytest.raises(ValueError, match="dt must be a finite number > 0, got 0"):
        fem.step(nodes, v, 0.0)
    with pytest.raises(ValueError, match="dt must be a finite number > 0, got -0.1"):
        fem.step(nodes, v, -0.1)
    # A bool is no time step (True ran a 1-s step), as it is no setting; a dt whose 1 / dt^2
    # overflows is named, not reported as a diverged step.
    for flag in (True, np.True_):
        with pytest.raises(TypeError, match="dt must be a real number, got (True|np.True_)"):
            fem.step(nodes, v, flag)
    with pytest.raises(ValueError, match="dt is too small: 1 / dt\\^2 overflows, got 1e-160"):
        fem.step(nodes, v, 1e-160)
    x_new, _ = fem.step(nodes, v, 1)  # an int is a real number
    assert np.all(np.isfinite(x_new))
    with pytest.raises(ValueError, match=r"x has shape \(3, 3\), expected \(4, 3\)"):
        fem.step(nodes[:3], v, 0.01)
    with pytest.raises(ValueError, match=r"v has shape \(4, 2\), expected \(4, 3\)"):
        fem.step(nodes, v[:, :2], 0.01)
    bad = v.copy()
    bad[1, 0] = np.inf
    with pytest.raises(ValueError, match="v contains a non-finite value"):
        fem.step(nodes, bad, 0.01)
    with pytest.raises(ValueError, match="fixed is a boolean mask of length 3, expected 4"):
        fem.step(nodes, v, 0.01, fixed=np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match=r"fixed contains node index 9 out of range \[0, 4\)"):
        fem.step(nodes, v, 0.01, fixed=[9])
    with pytest.raises(ValueError, match=r"fixed contains node index 4 out of range \[0, 4\)"):
        fem.step(nodes, v, 0.01, fixed=[4])  # one past the last node
    # A 0/1 integer mask read as indices would fix nodes 0 and 1, not the nodes it marks.
    with pytest.raises(ValueError, match=r"fixed lists node index 1 more than once.*astype"):
        fem.step(nodes, v, 0.01, fixed=np.array([0, 1, 1, 0]))
    with pytest.raises(TypeError, match="x must be an array, got None"):
        fem.energy(None)


def test_bad_settings(tet):
    fem = make(*tet)
    with pytest.raises(ValueError, match="damping_beta must be a finite number >= 0, got -1"):
        fem.damping_beta = -1.0
    with pytest.raises(ValueError, match=r"gravity has shape \(2,\), expected \(3,\)"):
        fem.gravity = [0.0, 1.0]
    with pytest.raises(ValueError, match=r"gravity has shape \(3, 1\), expected \(3,\)"):
        fem.gravity = np.ones((3, 1))
    with pytest.raises((TypeError, ValueError), match="gravity"):
        fem.gravity = [[1.0], [1.0, 2.0]]  # ragged: numpy cannot make an array of it
    fem.gravity = [0.0, 0.0, -1.62]
    assert fem.gravity == [0.0, 0.0, -1.62]
    # each setter names itself, as the reduced model's settings do
    for name, value, error, match in (
        ("max_newton_iterations", 2.5, TypeError, "max_newton_iterations must be an integer"),
        ("max_newton_iterations", 1001, ValueError, "max_newton_iterations must be at most 1000"),
        ("damping_alpha", "1", TypeError, "damping_alpha must be a real number, got '1'"),
        ("newton_tolerance", True, TypeError, "newton_tolerance must be a real number, got True"),
        ("solver", None, TypeError, "solver must be a string, got None"),
    ):
        with pytest.raises(error, match=match):
            setattr(fem, name, value)
    fem.max_newton_iterations = np.int64(7)
    assert fem.max_newton_iterations == 7


def test_threads_stepping_one_model_take_turns():
    """step() runs without the GIL: two threads on one model must not share its scratch (a
    block of ~100 nodes, as the review that found the race segfaulted)."""
    import threading

    import trimesh

    from softrom_gym.robots import from_mesh

    robot = from_mesh(trimesh.creation.box((0.2, 0.1, 0.1)), 6)
    nodes, tets = robot.nodes, robot.tets
    fem = make(nodes, tets)
    v0 = np.zeros_like(nodes)
    v0[:, 2] = -0.5
    v0[0] = [0.3, -0.2, 0.1]  # an uneven start, so that each step does Newton work
    expected = make(nodes, tets).step(nodes, v0, 0.005)
    results, errors = [], []

    def work():
        try:
            for _ in range(20):
                results.append(fem.step(nodes, v0, 0.005))
        except Exception as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(results) == 80
    for x, v in results:
        np.testing.assert_array_equal(x, expected[0])
        np.testing.assert_array_equal(v, expected[1])


def test_integer_settings_accept_numpy_integers_and_name_overflow():
    config = cpp_sim.ReducedConfig(max_newton_iterations=np.int64(7))
    assert config.max_newton_iterations == 7
    with pytest.raises(ValueError, match="max_newton_iterations must be at most 1000, got 1099"):
        cpp_sim.ReducedConfig(max_newton_iterations=2**40)
    # a step is interrupted only between steps: its caps bound how long one may run
    assert cpp_sim.ReducedConfig(max_newton_iterations=1000).max_newton_iterations == 1000
    with pytest.raises(ValueError, match="max_newton_iterations must be at most 1000, got 1001"):
        cpp_sim.ReducedConfig(max_newton_iterations=1001)
    assert cpp_sim.ReducedConfig(max_stagger_iterations=10**4).max_stagger_iterations == 10**4
    with pytest.raises(ValueError, match="max_stagger_iterations must be at most 10000, got 10001"):
        cpp_sim.ReducedConfig(max_stagger_iterations=10001)
    with pytest.raises(TypeError, match="max_newton_iterations must be an integer, got True"):
        cpp_sim.ReducedConfig(max_newton_iterations=True)
    with pytest.raises(TypeError, match="max_newton_iterations must be an integer, got 2.5"):
        cpp_sim.ReducedConfig(max_newton_iterations=2.5)


def test_evaluations_that_overflow_raise_instead_of_returning_nan(tet):
    # Finite but huge positions overflow inside the material model (|F|^2 is inf, inf - inf
    # NaN); the energy, forces and stiffness say so rather than return NaN as physics.
    nodes, tets = tet
    fem = make(nodes, tets)
    huge = nodes * 1e200
    for name, call in (
        ("elastic energy", lambda: fem.energy(huge)),
        ("elastic force", lambda: fem.forces(huge)),
        ("stiffness", lambda: fem.stiffness(huge)),
    ):
        message = rf"the {name} is not finite at x \(largest \|x\| = 1e\+200\)"
        with pytest.raises(ValueError, match=message):
            call()
    # large but representable positions still evaluate
    assert np.isfinite(fem.energy(nodes * 1e3))


def test_reduced_config_pickles_copies_and_compares():
    import copy
    import pickle

    config = cpp_sim.ReducedConfig(friction=0.3, gravity=[0.0, 0.0, -1.62], contact="penalty")
    for twin in (pickle.loads(pickle.dumps(config)), copy.copy(config), copy.deepcopy(config)):
        assert twin == config and twin is not config
        assert repr(twin) == repr(config)
    twin.friction = 0.4
    assert twin != config
    assert config != "friction=0.3" and config != None  # noqa: E711 (== None is the point)


def test_reduced_config_refuses_an_unknown_setting():
    # a misspelt keyword would otherwise build the default setting (friction 0.8, not 0.5)
    with pytest.raises(TypeError, match="unknown setting 'frction'"):
        cpp_sim.ReducedConfig(frction=0.5)
    with pytest.raises(TypeError, match="unknown setting 'frction'"):
        cpp_sim.ReducedConfig(friction=0.5, frction=0.5)
    assert cpp_sim.ReducedConfig(friction=0.5).friction == 0.5


def test_reduced_settings_refuse_values_outside_their_range():
    # Each bound of the reduced model's settings table, just past its edge, raises an error
    # naming the setting and the value; the edges themselves are accepted.
    for name, value, match in (
        ("stabilization", 1.5, r"stabilization must lie in \(0, 1\], got 1.5"),
        ("friction", np.inf, "friction must be a finite number >= 0, got inf"),
        ("dt", np.inf, "dt must be a finite number > 0, got inf"),
        ("contact_margin", np.nan, "contact_margin must be a finite number >= 0, got nan"),
        ("max_stagger_iterations", 0, "max_stagger_iterations must be >= 1, got 0"),
        ("max_newton_iterations", -3, "max_newton_iterations must be >= 1, got -3"),
        ("ground_height", np.nan, "ground_height must be finite"),
        # (at 1e160 m the contact solve's bounds overflowed and the step fell freely,
        # reported as not diverged; a review, session 53)
        ("ground_height", -1.0001e9, r"ground_height must lie within \+-1e\+09 m, got -1.0001e"),
        ("direction", [0.0, 0.0, 0.0], "direction must be a non-zero vector"),
        # (from about 1e22 N/m the penalty normal force was round-off noise: friction
        # vanished on steps reported converged; a review, session 54)
        (
            "penalty_stiffness",
            1.0001e12,
            r"penalty_stiffness must be at most 1e\+12 N/m per node, got 1.0001e\+12",
        ),
        ("penalty_stiffness", -1.0, "penalty_stiffness must be a finite number >= 0, got -1"),
        ("friction_smoothing", 0.0, "friction_smoothing must be a finite number > 0, got 0"),
    ):
        with pytest.raises(ValueError, match=match):
            cpp_sim.ReducedConfig(**{name: value})
    edge = cpp_sim.ReducedConfig(stabilization=1.0, max_stagger_iterations=1, friction=0.0,
                                 ground_height=1e9, penalty_stiffness=1e12)  # fmt: skip
    assert (edge.stabilization, edge.max_stagger_iterations, edge.friction) == (1.0, 1, 0.0)
    assert edge.ground_height == 1e9 and edge.penalty_stiffness == 1e12


def test_friction_smoothing_is_none_until_set_and_none_restores_the_tolerances():
    # None (the default) means contact_tolerance, as before the setting existed; a value is
    # kept through a copy (pickle) and equality, and None sets it back.
    config = cpp_sim.ReducedConfig()
    assert config.friction_smoothing is None
    config.friction_smoothing = 3e-5
    copy = pickle.loads(pickle.dumps(config))
    assert copy.friction_smoothing == 3e-5 and copy == config
    copy.friction_smoothing = None
    assert copy.friction_smoothing is None and copy != config
    with pytest.raises(TypeError, match="friction_smoothing must be a real number"):
        cpp_sim.ReducedConfig(friction_smoothing="1e-4")


def test_real_settings_refuse_numpy_bools(tet):
    # A real-valued setting is never a bool: numpy's bool_ (no subclass of bool, but it
    # converts to 1.0 or 0.0) is refused as Python's bool is, as the Python front end refuses
    # both; numpy's floats are still accepted.
    bools = r"(np\.)?True_?"
    for name in ("friction", "dt", "ground_height", "stabilization"):
        with pytest.raises(TypeError, match=rf"{name} must be a real number, got {bools}$"):
            cpp_sim.ReducedConfig(**{name: np.True_})
    fem = make(*tet)
    with pytest.raises(TypeError, match=rf"newton_tolerance must be a real number, got {bools}$"):
        fem.newton_tolerance = np.True_
    assert cpp_sim.ReducedConfig(friction=np.float64(0.3)).friction == 0.3
    fem.newton_tolerance = np.float32(1e-5)
    assert fem.newton_tolerance == pytest.approx(1e-5)


def test_constructors_refuse_bools_and_a_tetrahedron_listed_twice(tet):
    # pybind11 converts True to 1.0: FEMModel(nodes, tets, True, 0.3, True) built a 1 Pa,
    # 1 kg/m^3 model; and a tetrahedron listed twice (any vertex order) counted twice.
    nodes, tets = tet
    with pytest.raises(TypeError, match="youngs_modulus must be a real number, got True"):
        make(nodes, tets, e=True)
    with pytest.raises(TypeError, match="density must be a real number, got True"):
        make(nodes, tets, rho=np.True_)
    with pytest.raises(TypeError, match="poisson_ratio must be a real number, got False"):
        make(nodes, tets, nu=False)
    assert make(nodes, tets, e=50000).youngs_modulus == 50000.0  # an int is a real number
    nodes2 = np.vstack([nodes, [[1.0, 1.0, 1.0]]])
    twice = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [1, 2, 0, 3]])  # [1, 2, 0, 3]: an even turn
    with pytest.raises(ValueError, match=r"tets\[0\] and tets\[2\] are the same tetrahedron"):
        make(nodes2, twice)


def test_coordinates_that_overflow_are_named_not_returned_as_nan():
    # Finite q can give NaN nodes: a floating frame's rotation vector near 1e300 has no norm,
    # coordinates near 1e200 overflow det F (min_volume_ratio passed the NaN over and read
    # +inf, "nothing inverted"); the element forces of huge poses overflow the material.
    from softrom_gym.robots.robot import Robot
    from softrom_gym.robots.voxel import voxels_to_tets
    from softrom_gym.rom import build_reduced_model, build_subspace

    nodes, tets = voxels_to_tets(np.ones((2, 1, 1), dtype=bool), 0.1)
    robot = Robot("pair", nodes, tets, youngs_modulus=2e4)
    sub = build_subspace(robot, 4)
    model = build_reduced_model(robot, subspace=sub, frame="floating", contact="none")
    q = np.zeros(model.dim)
    q[3:6] = 1e300
    with pytest.raises(ValueError, match=r"the positions at q are not finite \(largest"):
        model.positions(q)
    with pytest.raises(ValueError, match="the velocities at q are not finite"):
        model.velocities(q, np.zeros_like(q))
    q = np.zeros(model.dim)
    q[6:] = 1e200
    with pytest.raises(ValueError, match="the volume ratios at q are not finite"):
        model.min_volume_ratio(q)
    fem = robot.fem_model()
    basis = sub.basis[:, 3:]
    with pytest.raises(ValueError, match=r"the element forces is not finite at poses\[1\]"):
        cpp_sim.reduced_element_forces(
            fem, basis, np.vstack([np.zeros(basis.shape[1]), np.full(basis.shape[1], 1e160)])
        )


def test_reduced_settings_refuse_a_tiny_dt_and_choices_that_are_not_strings():
    with pytest.raises(ValueError, match="dt is too small: 1 / dt\\^2 overflows, got 1e-160"):
        cpp_sim.ReducedConfig(dt=1e-160)

    class Named:
        def __str__(self) -> str:
            return "none"

    for name in ("contact", "solver", "frame"):
        with pytest.raises(TypeError, match=f"{name} must be a str, got"):
            cpp_sim.ReducedConfig(**{name: Named()})
    assert cpp_sim.ReducedConfig(contact=np.str_("none")).contact == "none"
