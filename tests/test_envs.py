"""Gymnasium environments (softrom_gym.envs): API conformance, determinism, MPC API, errors."""

import copy
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
import trimesh
from gymnasium.utils.env_checker import check_env

import cpp_sim
import softrom_gym
from softrom_gym.envs.observations import orientation_rows
from softrom_gym.robots import from_mesh

IDS = [f"softrom_gym/{name}" for name in softrom_gym.BENCHMARKS] + ["softrom_gym/SoftRobot-v0"]


@pytest.fixture(scope="module", params=IDS)
def env(request):
    env = gym.make(request.param)
    yield env
    env.close()


# The action bound is physical (a body weight of modal force), not [-1, 1], and positions and
# velocities are unbounded, as in Gymnasium's own MuJoCo envs: the checker's advice on both
# is a recommendation, not a violation.
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")
@pytest.mark.filterwarnings("ignore:.*space (minimum|maximum) value is -?infinity")
def test_check_env(env):
    check_env(env.unwrapped, skip_render_check=True)


def test_spaces_and_info(env):
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert env.action_space.shape == (3,) and env.action_space.dtype == np.float32
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    keys = ("distance", "orientation", "lateral", "effort", "com", "diverged", "contact")
    for key in (*keys, "converged", "min_volume_ratio"):
        assert key in info
    # the default material carries a random action with every element far from inverting
    assert 0.5 < info["min_volume_ratio"] < 1.5
    assert info["distance"] == pytest.approx(reward)
    assert not terminated and not truncated
    assert env.spec.max_episode_steps == 400


def test_orientation_slots_read_the_rotation_and_turning_shows_up():
    env = gym.make("softrom_gym/QuadrupedWalk-v0")
    base = env.unwrapped
    base.reset(seed=0)
    robot, basis = base.robot, base.subspace.basis
    mass = robot.fem_model().mass
    r = robot.nodes - mass @ robot.nodes / mass.sum()
    a = np.column_stack([np.cross(e, r).ravel() for e in np.eye(3)])
    m3 = np.repeat(mass, 3)
    theta, omega = np.array([0.02, -0.01, 0.05]), np.array([0.3, 0.1, -0.2])
    state = base.get_state()
    q, qdot = basis.T @ (m3 * (a @ theta)), basis.T @ (m3 * (a @ omega))
    base.set_state(cpp_sim.ReducedState(q, qdot, state.impulses))
    obs = base._obs(base.get_state())
    np.testing.assert_allclose(obs[4:7], theta, rtol=1e-5)
    np.testing.assert_allclose(obs[7:10], omega, rtol=1e-5)
    # reset's info reads the orientation of the state, not of its angular velocity (the bug
    # guarded against: |theta| computed from q_dot where step's comes from rollout)
    _, info = base.reset(options={"state": base.get_state()})
    assert info["orientation"] == pytest.approx(np.linalg.norm(theta), rel=1e-5)
    # Walking with random actuation turns the body a little (friction torques).
    env.reset(seed=1)
    env.action_space.seed(1)
    for _ in range(40):
        *_, info = env.step(env.action_space.sample())
    assert info["orientation"] > 1e-4
    env.close()


def _beam_observed_at_random_state(seed: int, first: int):
    """A BeamWalk env set to small random coordinates q[first:] and velocities qdot, with
    the observation of that state: (env, q, qdot, obs)."""
    base = gym.make("softrom_gym/BeamWalk-v0").unwrapped
    base.reset(seed=0)
    r = base.subspace.basis.shape[1]
    rng = np.random.default_rng(seed)
    q = np.zeros(r)
    q[first:] = 1e-3 * rng.normal(size=r - first)
    qdot = 1e-2 * rng.normal(size=r)
    base.set_state(cpp_sim.ReducedState(q, qdot, base.get_state().impulses))
    return base, q, qdot, base._obs(base.get_state())


def test_height_velocity_and_orientation_slots_against_their_definitions():
    # Guards: obs[0] forgetting the ground height, obs[1:4] the 1 / sqrt(m) of B_r's
    # translation columns, and the orientation fit losing its mass weighting (with it, pure
    # deformation, mass-orthogonal to the rotation columns, reads as no turn at all).
    base, q, qdot, obs = _beam_observed_at_random_state(seed=0, first=6)
    basis, mass = base.subspace.basis, base.robot.fem_model().mass
    velocity = mass @ (basis @ qdot).reshape(-1, 3) / mass.sum()
    np.testing.assert_allclose(obs[1:4], velocity, rtol=1e-5)
    np.testing.assert_allclose(obs[4:7], 0.0, atol=1e-9)
    base.model.ground_height = 0.05
    height = base.model.com(q)[2] - 0.05
    assert base._obs(base.get_state())[0] == pytest.approx(height, rel=1e-6)


def test_a_diverging_step_terminates_and_does_not_truncate():
    # Guards: step() swapping terminated and truncated (only rollout's divergence was tested).
    env = gym.make("softrom_gym/SoftRobot-v0", robot="beam", action_scale=1e9)
    env.reset(seed=0)
    action = np.full(3, env.get_wrapper_attr("action_bound"), dtype=np.float32)
    before = env.unwrapped._obs(env.unwrapped.get_state())
    obs, reward, terminated, truncated, info = env.step(action)
    assert terminated and not truncated and info["diverged"]
    # as the docstring says: the robot stops at the last good state (here the start: it
    # diverged in the first sub-step), pays nothing for the lost sub-steps, no penalty
    np.testing.assert_array_equal(obs, before)
    assert reward == 0.0 and info["distance"] == 0.0


def test_a_step_whose_solver_stops_short_says_so_in_info():
    # A physics step whose Newton iteration (or contact solve) stops at its cap is still taken
    # (the step is not lost), and info["converged"] says so: in step, in rollout and in the
    # vector env. One Newton iteration cannot converge a penalty-ground step under load.
    env = gym.make("softrom_gym/BeamWalk-v0", contact="penalty")
    env.reset(seed=0)
    action = np.full(3, 0.5 * env.get_wrapper_attr("action_bound"), dtype=np.float32)
    state = env.unwrapped.get_state()
    *_, info = env.step(action)
    assert info["converged"] and not info["diverged"]
    env.unwrapped.model.max_newton_iterations = 1
    env.unwrapped.set_state(state)
    *_, terminated, _, info = env.step(action)
    assert not info["converged"] and not info["diverged"] and not terminated
    out = env.unwrapped.rollout(state, action[None, None, :])
    assert out["converged"].tolist() == [False] and out["diverged"].tolist() == [False]
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, contact="penalty",
                        vectorization_mode="vector_entry_point")  # fmt: skip
    venv.reset(seed=0)
    *_, info = venv.step(np.stack([action, action]))
    assert info["converged"].tolist() == [True, True]
    venv.unwrapped.env.model.max_newton_iterations = 1
    *_, info = venv.step(np.stack([action, action]))
    assert info["converged"].tolist() == [False, False]
    venv.close()


def test_seeded_determinism(env):
    def trajectory(seed):
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        out = [obs]
        for _ in range(5):
            obs, reward, *_ = env.step(env.action_space.sample())
            out += [obs, [reward]]
        return np.concatenate(out)

    a, b = trajectory(7), trajectory(7)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, trajectory(8))


def test_module_prefix_make_without_import():
    env = gym.make("softrom_gym:softrom_gym/BeamWalk-v0")
    assert env.unwrapped.robot.name == "beam"


def test_rollout_equals_stepping():
    env = gym.make("softrom_gym/BeamWalk-v0").unwrapped
    env.reset(seed=3)
    start = env.get_state()
    rng = np.random.default_rng(0)
    controls = rng.uniform(-1, 1, (3, 6, 3)) * env.action_bound
    out = env.rollout(start, controls, threads=2)
    rewards, efforts = [], []
    for t in range(6):
        _, r, _, _, info = env.step(controls[1, t])
        rewards.append(r)
        efforts.append(info["effort"])
    np.testing.assert_array_equal(out["rewards"][1], rewards)
    np.testing.assert_array_equal(env.get_state().q, out["q"][1])
    np.testing.assert_allclose(out["effort"][1], efforts)
    env.set_state(start)
    np.testing.assert_array_equal(env.get_state().q, start.q)


def test_copies_step_exactly_as_the_original():
    # pickle and copy.deepcopy carry everything but the compiled model, which is rebuilt from
    # the robot, B_r, the current B_c and the model's current settings: a copy made mid-episode,
    # after a setting was changed and B_c swapped, steps bitwise as the original, and draws the
    # same reset noise.
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=3)
    base = env.unwrapped
    base.model.friction = 0.6
    rng = np.random.default_rng(1)
    base.set_control_basis(np.linalg.qr(rng.normal(size=(20, 3)))[0])
    actions = rng.uniform(-1, 1, (15, 3)) * base.action_bound
    for a in actions[:5]:
        env.step(a)
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    for c in copies:
        assert c.unwrapped.model.friction == 0.6
        np.testing.assert_array_equal(c.unwrapped.control_basis, base.control_basis)
    for a in actions[5:]:
        obs, reward, *_ = env.step(a)
        for c in copies:
            c_obs, c_reward, *_ = c.step(a)
            np.testing.assert_array_equal(c_obs, obs)
            assert c_reward == reward
    obs, _ = env.reset()
    for c in copies:
        np.testing.assert_array_equal(c.reset()[0], obs)


def test_a_copy_carries_its_cubature_rule_and_does_not_train_one(monkeypatch):
    """An unpickled env got its rule again from the receiving process's cache: retrained
    there (4.75 s on the quadruped), and under another BLAS kernel with weights 1e-13 apart,
    so the copy no longer stepped bitwise as the original (a review, session 54)."""
    import softrom_gym.rom.model as rom_model

    env = gym.make("softrom_gym/SoftRobot-v0", robot="beam", sim_dim=6, resolution=6)
    base = env.unwrapped
    data = pickle.dumps(env)

    def no_training(*args, **kwargs):
        pytest.fail("the copy trained (or loaded) a cubature rule")

    monkeypatch.setattr(rom_model, "train_cubature", no_training)
    copy_ = pickle.loads(data).unwrapped
    np.testing.assert_array_equal(copy_.cubature.elements, base.cubature.elements)
    np.testing.assert_array_equal(copy_.cubature.weights, base.cubature.weights)
    state = base.get_state()
    controls = np.full((1, 5, 3), 0.5 * base.action_bound)
    np.testing.assert_array_equal(copy_.rollout(state, controls)["q"],
                                  base.rollout(state, controls)["q"])  # fmt: skip


def test_direction_sets_the_reward_axis():
    a = gym.make("softrom_gym/SoftRobot-v0", robot="beam", direction=0.0).unwrapped
    b = gym.make("softrom_gym/SoftRobot-v0", robot="beam", direction=np.pi).unwrapped
    for env in (a, b):
        env.reset(seed=0)
    ctrl = np.full((1, 10, 3), 0.5 * a.action_bound)
    ra = a.rollout(a.get_state(), ctrl)["rewards"].sum()
    rb = b.rollout(b.get_state(), ctrl)["rewards"].sum()
    assert ra == pytest.approx(-rb, rel=1e-9, abs=1e-15)
    # a 2-vector is a direction at any scale (its norm neither underflows nor overflows)
    for scale in (1e-200, 1.0, 1e200):
        env = gym.make("softrom_gym/BeamWalk-v0", direction=[3 * scale, 4 * scale]).unwrapped
        np.testing.assert_allclose(env.direction, [0.6, 0.8, 0.0], rtol=1e-15)


def test_custom_mesh_robot_runs(tmp_path):
    capsule = trimesh.creation.capsule(height=0.3, radius=0.08)
    robot = from_mesh(capsule, 10)
    # standing on a round end, 3.3x as tall as wide (voxelised): it may tip over, which the
    # linear frame would not show
    with pytest.warns(UserWarning, match=r"3.3x as tall as its narrower side.*frame=.floating."):
        env = gym.make("softrom_gym/SoftRobot-v0", robot=robot, task="walk", sim_dim=8)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (10 + 16,)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs))
    # The same robot from a mesh file on disk, swimming.
    path = tmp_path / "capsule.stl"
    capsule.export(path)
    env = gym.make("softrom_gym/SoftRobot-v0", robot=str(path), task="swim", sim_dim=8,
                   resolution=10, frame="floating")  # fmt: skip
    assert env.unwrapped.robot.name == "capsule"
    env.reset(seed=0)
    env.step(env.action_space.sample())


def test_a_small_robot_that_will_hardly_move_is_named(tmp_path):
    # The action bound (one body weight) deforms a robot by ~rho g L / E of its size: a 9 cm
    # robot at the default 50 kPa moved 0.003 m under every full-bound gait, with nothing said.
    box = tmp_path / "box.stl"
    trimesh.creation.box((0.06, 0.03, 0.015)).export(box)
    with pytest.warns(UserWarning, match=r"deforms at most about .* of its 0.06 m size.*"
                                         "raise action_scale"):  # fmt: skip
        gym.make("softrom_gym/SoftRobot-v0", robot=str(box), resolution=6, sim_dim=6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a larger bound: no warning
        gym.make("softrom_gym/SoftRobot-v0", robot=str(box), resolution=6, sim_dim=6,
                 action_scale=100.0)  # fmt: skip


def test_bad_input_errors():
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action has shape \(2,\), expected \(3,\)"):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match="action contains non-finite values"):
        env.step(np.array([0.0, np.nan, 0.0]))
    # None was cast to nan and reported as a non-finite number, a lone None as shape ()
    for action in (None, np.array([1.0, None, 2.0], dtype=object), [0.0, None, 0.0]):
        with pytest.raises(ValueError, match=r"action must be real numbers, got .*None"):
            env.step(action)
    with pytest.raises(TypeError, match="state must be a ReducedState .* got NoneType"):
        env.unwrapped.rollout(None, np.zeros((2, 3, 3)))
    with pytest.raises(ValueError, match=r"controls has shape \(2, 3\), expected \(B, H, 3\)"):
        env.unwrapped.rollout(env.unwrapped.get_state(), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"unknown robot 'octopus'; valid robots: \['beam'"):
        gym.make("softrom_gym/SoftRobot-v0", robot="octopus")
    with pytest.raises(ValueError, match=r"unknown task 'fly'; valid tasks: \['walk', 'swim'\]"):
        gym.make("softrom_gym/SoftRobot-v0", robot="beam", task="fly")
    bad = np.eye(20)[:, :3] * 1.01
    with pytest.raises(ValueError, match=r"control_basis is not orthonormal: max \|B_c\^T B_c"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=bad)
    with pytest.raises(ValueError, match="control_basis must be real, got a complex128 matrix"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=np.eye(20)[:, :3] + 0j)
    with pytest.raises(ValueError, match=r"control_basis has shape \(20, 2\), expected"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=np.eye(20)[:, :2], control_dim=3)
    # without control_dim (sim_dim), C (M) is the basis's: its columns (rows)
    two = gym.make("softrom_gym/BeamWalk-v0", control_basis=np.eye(16)[:, :2]).unwrapped
    assert (two.action_space.shape, two.control_basis.shape) == ((2,), (16, 2))
    with pytest.raises(ValueError, match=r"shape \(3, 20\): B_c is M x C with M >= C"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=np.eye(20)[:3])
    ok = gym.make("softrom_gym/BeamWalk-v0", control_basis=bad, orthonormalize=True)
    b_c = ok.unwrapped.control_basis
    np.testing.assert_allclose(b_c.T @ b_c, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="rank-deficient"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=np.ones((20, 3)), orthonormalize=True)
    with pytest.raises(ValueError, match="reset_noise_scale must be finite and >= 0, got -1.0"):
        gym.make("softrom_gym/BeamWalk-v0", reset_noise_scale=-1.0)
    with pytest.raises(ValueError, match="M = 100000 deformation modes requested, but the robot"):
        gym.make("softrom_gym/BeamWalk-v0", sim_dim=100_000)  # named, not a 75 GB identity
    robot = env.unwrapped.robot
    with pytest.raises(ValueError, match="resolution = 5 applies to a robot name or a mesh path"):
        gym.make("softrom_gym/SoftRobot-v0", robot=robot, resolution=5)
    # a wrong type is named, not read as a number or truth value
    for kwargs, message in (
        ({"action_scale": "1"}, "action_scale must be a real number, got '1'"),
        ({"action_scale": None}, "action_scale must be a real number, got None"),
        ({"reset_noise_scale": True}, "reset_noise_scale must be a real number, got True"),
        ({"orthonormalize": "yes"}, "orthonormalize must be True or False, got 'yes'"),
        ({"material": 5}, "material must be a dict of youngs_modulus, poisson_ratio and density"),
    ):
        with pytest.raises(TypeError, match=message):
            gym.make("softrom_gym/BeamWalk-v0", **kwargs)
    with pytest.raises(ValueError, match="direction must be an angle in radians or a non-zero"):
        gym.make("softrom_gym/BeamWalk-v0", direction="north")
    # the other task's settings do nothing, but a bad value is named all the same
    with pytest.raises(ValueError, match="friction must be a finite number >= 0, got -1"):
        gym.make("softrom_gym/CrossSwim-v0", friction=-1.0)
    with pytest.raises(ValueError, match="contact must be one of 'staggered', 'penalty', 'none'"):
        gym.make("softrom_gym/CrossSwim-v0", contact="bogus")
    with pytest.raises(ValueError, match="fluid_density must be a finite number >= 0, got -1"):
        gym.make("softrom_gym/BeamWalk-v0", fluid_density=-1.0)
    # env steps of a second or more still give a video writer a frame rate it can take
    assert gym.make("softrom_gym/BeamWalk-v0", dt=0.5).unwrapped.metadata["render_fps"] == 1


def test_vector_env_equals_single_envs():
    n = 3
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=n,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    singles = [gym.make("softrom_gym/BeamWalk-v0") for _ in range(n)]
    obs, _ = venv.reset(seed=10)
    for i, env in enumerate(singles):
        o, _ = env.reset(seed=10 + i)
        np.testing.assert_array_equal(obs[i], o)
    rng = np.random.default_rng(0)
    bound = singles[0].unwrapped.action_bound
    for _ in range(4):
        actions = rng.uniform(-bound, bound, (n, 3)).astype(np.float32)
        obs, rewards, _term, _trunc, info = venv.step(actions)
        for i, env in enumerate(singles):
            o, r, *_ = env.step(actions[i])
            np.testing.assert_array_equal(obs[i], o)
            assert rewards[i] == r
        assert info["distance"].shape == (n,)
    venv.close()


def test_vector_env_unseeded_reset_continues_each_stream():
    def two_resets(seed):
        venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                            vectorization_mode="vector_entry_point")  # fmt: skip
        first, _ = venv.reset(seed=seed)
        second, _ = venv.reset()
        venv.close()
        return first, second

    a, b = two_resets(3), two_resets(np.int64(3))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])  # reproducible, as a single env's would be
    assert not np.array_equal(a[0], a[1])
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    with pytest.raises(ValueError, match="seed must be None, an int or a list of 2 ints, got 'x'"):
        venv.reset(seed="x")
    # each entry of a list as a single seed: not truncated (1.5) or parsed ("3")
    for bad, text in ((1.5, "1.5"), ("3", "'3'"), (True, "True")):
        with pytest.raises(
            ValueError, match=f"seed list entry 1 must be an int or None, got {text}"
        ):
            venv.reset(seed=[0, bad])
    venv.reset(seed=[np.int64(0), None])
    venv.close()
    with pytest.raises(ValueError, match="the vector env does not render"):
        gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, render_mode="rgb_array",
                     vectorization_mode="vector_entry_point")  # fmt: skip
    with pytest.raises(ValueError, match="max_episode_steps must be a positive integer or None"):
        gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, max_episode_steps=0,
                     vectorization_mode="vector_entry_point")  # fmt: skip
    numpy_count = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=np.int64(2),
                               vectorization_mode="vector_entry_point")  # fmt: skip
    assert numpy_count.num_envs == 2 and type(numpy_count.num_envs) is int
    numpy_count.close()


def test_vector_env_autoresets_on_the_next_step():
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, max_episode_steps=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    first, _ = venv.reset(seed=0)
    zero = np.zeros((2, 3), dtype=np.float32)
    venv.step(zero)
    _, _, _, trunc, _ = venv.step(zero)
    assert trunc.all()
    obs, rewards, term, trunc, _ = venv.step(zero)  # the autoreset step
    assert not trunc.any() and not term.any() and np.all(rewards == 0)
    assert obs.shape == first.shape
    # Guards: reset() leaving the pending autoreset armed (the step after it would reset again
    # and pay 0 instead of stepping): after a truncation and a reset, the next step is a step.
    venv.step(zero)
    _, _, _, trunc, _ = venv.step(zero)
    assert trunc.all()
    venv.reset(seed=1)
    _, rewards, _, trunc, _ = venv.step(zero)
    assert not trunc.any() and np.all(rewards != 0)


def test_vector_env_distance_counts_from_each_robot_s_own_start():
    # Guards: a step not measuring robot i's info["distance"] from robot i's own start (the
    # shared env keeps the start of the robot reset last, here one autoreset at rest after a
    # divergence, while the other goes on from a state given to reset).
    kwargs = {"robot": "beam", "action_scale": 1e9}
    single = gym.make("softrom_gym/SoftRobot-v0", **kwargs)
    single.reset(seed=0)
    bound = single.get_wrapper_attr("action_bound")
    gait = np.array([0.5, -0.5, 0.5]) * bound * 1e-9  # half a body weight of modal force
    for _ in range(10):
        single.step(gait)
    mid = single.get_wrapper_attr("get_state")()
    start = single.get_wrapper_attr("center_of_mass")(mid)
    venv = gym.make_vec("softrom_gym/SoftRobot-v0", num_envs=2,
                        vectorization_mode="vector_entry_point", **kwargs)  # fmt: skip
    venv.reset(seed=0, options={"state": mid})
    _, _, term, _, _ = venv.step(np.stack([np.full(3, bound), gait]))
    assert term.tolist() == [True, False]
    _, _, _, _, info = venv.step(np.stack([gait, gait]))  # robot 0 autoresets at rest
    assert info["distance"][0] == 0.0
    assert info["distance"][1] == pytest.approx(info["com"][1][0] - start[0], rel=1e-12)
    model = single.unwrapped.model
    assert abs(start[0] - model.com(model.rest_state().q)[0]) > 1e-6  # two starts, told apart
    venv.close()


def test_export_trajectory_writes_one_mesh_per_frame(tmp_path):
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    states = [env.unwrapped.get_state()]
    for _ in range(3):
        env.step(env.action_space.sample())
        states.append(env.unwrapped.get_state())
    files = softrom_gym.export_trajectory(states, tmp_path / "out" / "beam.ply", env=env)
    assert [f.name for f in files] == [f"beam_{i:04d}.ply" for i in range(4)]
    last = trimesh.load(files[-1])
    assert last.is_watertight
    expected = env.unwrapped.model.positions(states[-1].q)
    assert np.allclose(np.sort(last.vertices[:, 0]), np.sort(expected[np.unique(
        env.unwrapped.robot.surface_faces)][:, 0]))  # fmt: skip
    with pytest.raises(ValueError, match="unsupported mesh format"):
        softrom_gym.export_trajectory(states, tmp_path / "x.txt", env=env)
    with pytest.raises(ValueError, match="needs env= or robot="):
        softrom_gym.export_trajectory(states, tmp_path / "x.ply")
    # a generator of frames; a diverged frame is named before any file is written
    files = softrom_gym.export_trajectory((s for s in states[:2]), tmp_path / "g.obj", env=env)
    assert [f.name for f in files] == ["g_0000.obj", "g_0001.obj"]
    bad = [env.unwrapped.model.positions(s.q) for s in states]
    bad[2][5, 1] = np.nan
    with pytest.raises(ValueError, match="frame 2 has non-finite node positions"):
        softrom_gym.export_trajectory(bad, tmp_path / "nan" / "b.ply", env=env)
    assert not (tmp_path / "nan").exists()
    with pytest.raises(ValueError, match="states is empty"):
        softrom_gym.export_trajectory(iter([]), tmp_path / "e.ply", env=env)


@pytest.mark.parametrize("env_id", ["softrom_gym/QuadrupedWalk-v0", "softrom_gym/CrossSwim-v0"])
def test_rgb_array_rendering_is_headless_and_follows_the_robot(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8
    # The robot's blue dominates the centre of the picture; the sky or ground the corners.
    centre = frame[150:210, 200:280].astype(int)
    assert (centre[..., 2] - centre[..., 0]).mean() > 60
    assert np.ptp(frame.reshape(-1, 3), axis=0).min() > 50  # not a blank image
    for _ in range(3):
        env.step(env.action_space.high)
    assert not np.array_equal(env.render(), frame)
    assert env.metadata["render_fps"] == 40


@pytest.mark.filterwarnings("ignore:under the full action bound")  # (tiny robots, not moved)
def test_a_robot_renders_alike_at_any_size():
    # The ground's checker was 10 cm and the arrow 2 mm above it at any size: a 6 mm robot
    # stood on one grey grid line with the arrow poking out of its top (a 4 m one on a moire
    # of 40 cells a body length). Scene and camera now scale together.
    frames = []
    for length in (0.006, 0.06, 0.6):
        env = gym.make("softrom_gym/SoftRobot-v0", robot=trimesh.creation.box(
            (length, length / 2, length / 2)), resolution=2, sim_dim=3, control_dim=1,
            reset_noise_scale=0.0, render_mode="rgb_array")  # fmt: skip
        env.reset(seed=0)
        frames.append(env.render().astype(int))
    for frame in frames[:2]:
        differs = np.abs(frame - frames[2]).max(axis=-1) > 24
        assert differs.mean() < 0.01


def test_unknown_render_mode_is_rejected():
    from softrom_gym.envs import SoftRobotEnv

    with pytest.raises(ValueError, match=r"render_mode 'human' is not supported; valid: \['rgb"):
        SoftRobotEnv(robot="beam", render_mode="human")


def test_record_video_wrapper_writes_a_video(tmp_path):
    env = gym.make("softrom_gym/BeamWalk-v0", render_mode="rgb_array")
    env = gym.wrappers.RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda _: True,
                                   video_length=10)  # fmt: skip
    env.reset(seed=0)
    for _ in range(10):
        env.step(env.action_space.sample())
    env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000


def test_a_mesh_of_your_own_by_path_trimesh_or_scale(tmp_path):
    import trimesh

    box = trimesh.creation.box((200.0, 100.0, 50.0))  # millimetres
    path = tmp_path / "box_mm.stl"
    box.export(path)
    env = gym.make("softrom_gym/SoftRobot-v0", robot=str(path), scale=0.001, resolution=4)
    assert env.unwrapped.body_length == pytest.approx(0.2)
    same = gym.make("softrom_gym/SoftRobot-v0", robot=box, scale=0.001, resolution=4)
    np.testing.assert_array_equal(same.unwrapped.robot.nodes, env.unwrapped.robot.nodes)
    with pytest.raises(ValueError, match="scale = 0.001 applies to a mesh"):
        gym.make("softrom_gym/SoftRobot-v0", robot="beam", scale=0.001)
    (tmp_path / "noext").write_bytes(path.read_bytes())
    with pytest.raises(ValueError, match="is a file without an extension"):
        gym.make("softrom_gym/SoftRobot-v0", robot=str(tmp_path / "noext"))
    with pytest.raises(ValueError, match="is a directory, not a mesh file"):
        gym.make("softrom_gym/SoftRobot-v0", robot=str(tmp_path))


def test_boundary_arguments_a_square_control_basis_and_no_reset_noise_are_accepted():
    # Guards: `control_dim > sim_dim` becoming `>=`, and a square B_c (C = M) taken for a
    # transposed one; reset_noise_scale = 0 (a documented ">= 0") refused or still noisy.
    env = gym.make("softrom_gym/BeamWalk-v0", control_basis=np.eye(20), reset_noise_scale=0.0)
    assert env.action_space.shape == (20,)
    env.reset(seed=0)
    np.testing.assert_array_equal(env.get_wrapper_attr("get_state")().qdot, 0.0)
    # Guards: orthonormalize losing the sign fix of the QR (whose R has negative diagonal
    # entries here): each column keeps its sense. Within 1e-8 of orthonormal is accepted.
    gym.make("softrom_gym/BeamWalk-v0", control_basis=np.eye(20)[:, :3] * (1 + 1e-10))
    raw = np.random.default_rng(0).normal(size=(20, 3))
    fixed = gym.make("softrom_gym/BeamWalk-v0", control_basis=raw, orthonormalize=True)
    b_c = fixed.unwrapped.control_basis
    np.testing.assert_allclose(b_c.T @ b_c, np.eye(3), atol=1e-12)
    assert np.all(np.diag(b_c.T @ raw) > 0)


@pytest.mark.filterwarnings("ignore:under the full action bound")  # (small by design)
def test_reset_noise_is_a_fraction_of_a_small_robot_s_length():
    import trimesh

    def noise(size):
        env = gym.make("softrom_gym/SoftRobot-v0", robot=trimesh.creation.box((size,) * 3),
                       task="swim", resolution=3, sim_dim=6).unwrapped  # fmt: skip
        env.reset(seed=0)
        return env.get_state().qdot[6:] / np.sqrt(env.robot.mass), env.body_length

    # The same draws, scaled: 0.01 m/s from 10 cm up, 10 % of a body length per second below
    # (0.01 m/s on a 1 mm robot had drifted it 1.44 body lengths a second).
    big, small = noise(0.2), noise(0.02)
    np.testing.assert_allclose(noise(0.5)[0], big[0], rtol=1e-12)
    np.testing.assert_allclose(small[0], big[0] * small[1] / 0.1, rtol=1e-12)
    assert 0.005 < np.abs(big[0]).max() <= 0.01
    assert big[0].min() < 0 < big[0].max()  # in +-: guards a one-sided uniform(0, noise)


def test_a_first_build_says_what_it_computes_and_a_cached_one_is_silent(
    tmp_path, monkeypatch, capsys
):
    # a new robot or M takes seconds to minutes to build: the env says so on stderr, once
    monkeypatch.setenv("SOFTROM_CACHE_DIR", str(tmp_path))
    gym.make("softrom_gym/BeamWalk-v0", sim_dim=7).close()
    first = capsys.readouterr()
    assert "softrom_gym: building B_r for beam (N = 460 nodes, M = 7)" in first.err
    assert "softrom_gym: trained the cubature rule for beam" in first.err
    assert first.out == ""
    gym.make("softrom_gym/BeamWalk-v0", sim_dim=7).close()
    assert capsys.readouterr().err == ""


def test_a_material_too_soft_for_the_actions_warns_once_that_elements_invert(recwarn):
    # E = 1 kPa, 50x softer than the default: full-bound bang-bang actuation inverts elements
    env = gym.make("softrom_gym/SoftRobot-v0", robot="cross", material={"youngs_modulus": 1e3})
    env.reset(seed=0)
    base = env.unwrapped
    ratios = []
    for k in range(60):
        action = np.sign(np.sin(np.pi * k / 10 + np.arange(3))) * base.action_bound
        *_, info = env.step(action.astype(np.float32))
        ratios.append(info["min_volume_ratio"])
        # the reported J is the least of every tetrahedron's det F
        x = base.model.positions(base.get_state().q)
        p, p0 = x[base.robot.tets], base.robot.nodes[base.robot.tets]
        j = np.linalg.det(p[:, 1:] - p[:, :1]) / np.linalg.det(p0[:, 1:] - p0[:, :1])
        assert ratios[-1] == pytest.approx(j.min(), abs=1e-9)
    assert min(ratios) < 0.0
    said = [w for w in recwarn if "tetrahedron is inverted" in str(w.message)]
    assert len(said) == 1  # once, not at every step
    message = str(said[0].message)
    assert "youngs_modulus = 1000 Pa" in message and "lower action_scale" in message
    env.close()


def test_a_turn_past_what_linearised_rotations_model_warns_once(recwarn):
    from softrom_gym.envs import LINEARISED_TURN_LIMIT

    env = gym.make("softrom_gym/CrossSwim-v0")
    base = env.unwrapped
    env.reset(seed=0)

    def turned(angle: float) -> cpp_sim.ReducedState:
        # a state turned by `angle` about z: B_r's rotation columns, read back exactly by the
        # env's orientation rows
        rest = base.get_state()
        q = np.zeros_like(rest.q)
        q[3:6] = np.linalg.solve(base._orientation[:, 3:6], [0.0, 0.0, angle])
        return cpp_sim.ReducedState(q, np.zeros_like(q), rest.impulses)

    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    env.reset(options={"state": turned(LINEARISED_TURN_LIMIT - 0.1)})
    *_, info = env.step(zero)
    assert info["orientation"] == pytest.approx(LINEARISED_TURN_LIMIT - 0.1, abs=0.01)
    assert not [w for w in recwarn if "turned" in str(w.message)]
    env.reset(options={"state": turned(LINEARISED_TURN_LIMIT + 0.1)})
    for _ in range(3):
        *_, info = env.step(zero)
        assert info["orientation"] > LINEARISED_TURN_LIMIT
    said = [w for w in recwarn if "turned" in str(w.message)]
    assert len(said) == 1  # once, not at every step
    message = str(said[0].message)
    assert "Rotations are linearised" in message and "stretches the body by up to 8 %" in message
    env.close()


def test_a_control_basis_from_a_npy_path_steps_as_the_array_and_keeps_the_spec_json(tmp_path):
    import json

    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((20, 3)))[0]
    np.save(tmp_path / "best_basis.npy", basis)
    by_path = gym.make("softrom_gym/BeamWalk-v0", control_basis=tmp_path / "best_basis.npy")
    by_array = gym.make("softrom_gym/BeamWalk-v0", control_basis=basis)
    np.testing.assert_array_equal(by_path.unwrapped.control_basis, basis)
    action = np.full(3, 0.5 * by_path.unwrapped.action_bound, dtype=np.float32)
    for env in (by_path, by_array):
        env.reset(seed=0)
    np.testing.assert_array_equal(by_path.step(action)[0], by_array.step(action)[0])
    by_path = gym.make("softrom_gym/BeamWalk-v0", control_basis=str(tmp_path / "best_basis.npy"))
    assert json.loads(by_path.spec.to_json())["kwargs"]["control_basis"].endswith(".npy")
    missing = tmp_path / "nowhere.npy"
    with pytest.raises(FileNotFoundError, match=f"control_basis file '{missing}' does not exist"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=missing)
    (tmp_path / "text.npy").write_text("not an array")
    with pytest.raises(ValueError, match="control_basis file .*text.npy' is not a .npy array"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=tmp_path / "text.npy")
    np.savez(tmp_path / "two.npz", a=basis, b=basis)
    with pytest.raises(ValueError, match="holds several arrays"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=tmp_path / "two.npz")
    np.save(tmp_path / "flat.npy", basis.ravel())
    with pytest.raises(ValueError, match=r"control_basis has shape \(60,\)"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis=tmp_path / "flat.npy")


def test_more_bad_env_arguments_are_named_before_anything_is_built(monkeypatch):
    from softrom_gym.envs import soft_robot_env

    def never(*args, **kwargs):
        raise AssertionError("built B_r or the model before naming a bad argument")

    basis = np.eye(20)[:, :3].copy()
    basis[4, 1] = np.inf
    monkeypatch.setattr(soft_robot_env, "build_subspace", never)
    monkeypatch.setattr(soft_robot_env, "build_reduced_model", never)
    for kwargs, message in (
        ({"control_dim": 7, "sim_dim": 6}, "control_dim = 7 exceeds sim_dim = 6"),
        ({"action_scale": 0.0}, "action_scale must be > 0, got 0.0"),
        ({"action_scale": float("nan")}, "action_scale must be > 0, got nan"),
        ({"action_scale": float("inf")}, "action_scale must be > 0, got inf"),
        ({"direction": float("inf")}, "direction angle must be finite, got inf"),
        ({"direction": [0.0, 0.0]}, r"a non-zero 2-vector, got \[0.0, 0.0\]"),
        ({"direction": [1.0, 0.0, 0.0]}, r"a non-zero 2-vector, got \[1.0, 0.0, 0.0\]"),
        # (True was read as 1 rad)
        ({"direction": True}, r"a non-zero 2-vector, got True"),
        ({"direction": [True, False]}, r"a non-zero 2-vector, got \[True, False\]"),
        ({"control_basis": basis}, r"control_basis contains non-finite values, e.g. inf at "
                                   r"\(4, 1\)"),
        ({"material": {"youngs": 1e5}}, r"unknown material parameter\(s\) \['youngs'\]"),
        # 2e-6 off orthonormal, over the 1e-8 tolerance (guards a looser Python check, which
        # the core's own check would catch only after B_r and the cubature are built)
        ({"control_basis": np.eye(20)[:, :3] * (1 + 1e-6)}, "control_basis is not orthonormal"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=message):
            gym.make("softrom_gym/BeamWalk-v0", **kwargs)
    monkeypatch.undo()
    # a 0-d array is its number, as an array read from a file or a config is
    half = gym.make("softrom_gym/BeamWalk-v0", action_scale=np.array(0.5)).unwrapped
    assert half.action_bound == 0.5 * gym.make("softrom_gym/BeamWalk-v0").unwrapped.action_bound


def test_bad_reset_options_and_rollout_controls_are_named():
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    for options in ("state", [("state", None)]):
        with pytest.raises(TypeError, match=f"options must be a dict or None, got "
                           f"{type(options).__name__}"):  # fmt: skip
            env.reset(options=options)
    state, controls = env.unwrapped.get_state(), np.zeros((2, 4, 3))
    controls[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"controls contains non-finite values, e.g. nan at "
                       r"\(rollout, step, dimension\) = \(1, 2, 0\)"):  # fmt: skip
        env.unwrapped.rollout(state, controls)
    with pytest.raises(ValueError, match=r"controls has shape \(0, 4, 3\), expected \(B, H, 3\) "
                       "with B, H >= 1"):  # fmt: skip
        env.unwrapped.rollout(state, controls[:0])


def test_render_without_a_render_mode_warns_and_draws_nothing():
    """Gymnasium's convention: a warning and None, not an exception mid-episode."""
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render\\(\\) called without a render_mode; pass "
                      "render_mode='rgb_array'"):  # fmt: skip
        assert env.unwrapped.render() is None
    from softrom_gym.rendering import SoftwareRenderer

    with pytest.raises(ValueError, match="image must be at least 8 x 8 pixels, got 4 x 100"):
        SoftwareRenderer(width=4, height=100)
    with pytest.raises(ValueError, match="image must be at least 8 x 8 pixels, got 100 x 7"):
        SoftwareRenderer(width=100, height=7)


@pytest.mark.parametrize(("camera", "message"), [
    ({"distance": 0.0}, "distance must be a length > 0 m, got 0.0"),
    ({"distance": -1.0}, "distance must be a length > 0 m, got -1.0"),
    ({"distance": float("nan")}, "distance must be a length > 0 m, got nan"),
    ({"fov": 0.0}, r"fov must be an angle in \(0, 180\) degrees, got 0.0"),
    ({"fov": 180.0}, r"fov must be an angle in \(0, 180\) degrees, got 180.0"),
    ({"elevation": 90.0}, r"elevation must be an angle in \(-90, 90\) degrees, got 90.0"),
    ({"azimuth": float("inf")}, "azimuth must be a finite angle in degrees, got inf"),
])  # fmt: skip
def test_a_software_renderer_refuses_a_camera_that_cannot_see(camera, message):
    # a distance of 0 or less drew a blank frame, and a field of view of 0 raised
    # OverflowError at the first frame
    from softrom_gym.rendering import SoftwareRenderer

    with pytest.raises(ValueError, match=message):
        SoftwareRenderer(**camera)


def test_a_material_given_with_a_meshed_robot_is_the_envs_and_leaves_the_robot_alone():
    """make(robot=Robot, material=...) replaces the material of the env's copy (the path was
    never run: only robot names and meshes were given a material)."""
    from softrom_gym.robots import beam

    robot = beam(resolution=6)
    env = gym.make("softrom_gym/SoftRobot-v0", robot=robot, sim_dim=6,
                   material={"youngs_modulus": 2e5, "density": 800.0})  # fmt: skip
    mine = env.unwrapped.robot
    assert (mine.youngs_modulus, mine.density, mine.poisson_ratio) == (
        2e5, 800.0, robot.poisson_ratio)  # fmt: skip
    assert (robot.youngs_modulus, robot.density) == (beam().youngs_modulus, beam().density)
    np.testing.assert_array_equal(mine.nodes, robot.nodes)
    # the model is built from it: the mass is the new density's
    assert env.unwrapped.model.total_mass == pytest.approx(800.0 * robot.volume)


def test_vector_env_names_bad_counts_seeds_and_actions_and_stays_usable():
    for num_envs in (0, True, 1.5, "2"):
        with pytest.raises(ValueError, match=f"num_envs must be a positive integer, got "
                           f"{num_envs!r}"):  # fmt: skip
            gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=num_envs,
                         vectorization_mode="vector_entry_point")  # fmt: skip
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    with pytest.raises(ValueError, match="seed list has 3 entries, expected 2"):
        venv.reset(seed=[1, 2, 3])
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions has shape \(3, 3\), expected \(2, 3\)"):
        venv.step(np.zeros((3, 3)))
    bad = np.zeros((2, 3))
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"actions contains non-finite values \(env indices "
                       r"\[1\]\)"):  # fmt: skip
        venv.step(bad)
    # a refused step changed nothing, for the env with the bad action or the other: the next
    # one is each env's first step
    obs, *_ = venv.step(np.zeros((2, 3), dtype=np.float32))
    single = gym.make("softrom_gym/BeamWalk-v0")
    for i in range(2):
        single.reset(seed=i)
        np.testing.assert_array_equal(obs[i], single.step(np.zeros(3, dtype=np.float32))[0])
    venv.close()


def test_vector_env_ignores_a_non_finite_action_for_a_robot_it_resets_as_sync_does():
    # NEXT_STEP autoreset skips the action of a sub-env being reset; the batched env checked
    # every row first and refused a NaN that SyncVectorEnv ignores
    results = []
    for mode in ("sync", "vector_entry_point"):
        venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, vectorization_mode=mode,
                            max_episode_steps=1)  # fmt: skip
        venv.reset(seed=0)
        venv.step(np.zeros((2, 3), dtype=np.float32))  # both truncated
        actions = np.zeros((2, 3), dtype=np.float32)
        actions[0] = np.nan
        results.append(venv.step(actions)[:2])
        # a stepped robot's row must still be finite
        actions = np.zeros((2, 3), dtype=np.float32)
        actions[1, 0] = np.inf
        if mode == "vector_entry_point":
            with pytest.raises(ValueError, match=r"non-finite values \(env indices \[1\]\)"):
                venv.step(actions)
        venv.close()
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])


def test_export_names_frames_it_cannot_map(tmp_path):
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    robot, state = env.unwrapped.robot, env.unwrapped.get_state()
    with pytest.raises(ValueError, match="ReducedState frames need env= to map them to positions"):
        softrom_gym.export_trajectory([state], tmp_path / "a.ply", robot=robot)
    frames = [robot.nodes, robot.nodes[:5]]
    with pytest.raises(ValueError, match=rf"frame 1 has shape \(5, 3\), expected "
                       rf"\({robot.num_nodes}, 3\)"):  # fmt: skip
        softrom_gym.export_trajectory(frames, tmp_path / "b.ply", robot=robot)
    assert not any(tmp_path.iterdir())
    # positions need only the robot
    assert len(softrom_gym.export_trajectory(frames[:1], tmp_path / "c.stl", robot=robot)) == 1
    # a vector env has no single robot state to map (it raised AttributeError: 'robot')
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    with pytest.raises(TypeError, match="env must be a SoftRobotEnv or a wrapper of one .* got "
                       "SoftRobotVectorEnv"):  # fmt: skip
        softrom_gym.export_trajectory([state], tmp_path / "d.ply", env=venv)
    assert not (tmp_path / "d_0000.ply").exists()


def test_complex_or_boolean_actions_are_refused_not_cast():
    """A complex action lost its imaginary part with a ComplexWarning only, and a boolean one
    acted as 0 or 1 N kg^-1/2 (found by stepping BeamWalk-v0 with np.array([1 + 1j, 0, 0])):
    both are refused naming their dtype, in step, the vector env's step and rollout."""
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    for bad in (np.array([1 + 1j, 0, 0]), np.array([True, False, True]), ["a", "b", "c"]):
        with pytest.raises(ValueError, match="action must be real numbers, got"):
            env.step(bad)
    with pytest.raises(ValueError, match="controls must be real numbers, got a complex128"):
        env.unwrapped.rollout(env.unwrapped.get_state(), np.zeros((1, 2, 3), dtype=complex))
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="actions must be real numbers, got a bool"):
        venv.step(np.zeros((2, 3), dtype=bool))
    # integer actions are numbers: accepted, as the float actions they equal
    env.reset(seed=0)
    a = env.step(np.array([1, 0, -2]))[0]
    env.reset(seed=0)
    np.testing.assert_array_equal(a, env.step(np.array([1.0, 0.0, -2.0], dtype=np.float32))[0])
    venv.close()


def test_a_control_basis_path_under_home_is_read_as_a_robot_path_is(tmp_path, monkeypatch):
    """control_basis="~/best_basis.npy" was 'does not exist' while robot="~/robot.stl" is read
    from the home folder (found making BeamWalk-v0 with a run's basis by a ~ path): both
    expand ~, and the spec keeps the path as given."""
    monkeypatch.setenv("HOME", str(tmp_path))
    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((20, 3)))[0]
    np.save(tmp_path / "best_basis.npy", basis)
    env = gym.make("softrom_gym/BeamWalk-v0", control_basis="~/best_basis.npy")
    np.testing.assert_array_equal(env.unwrapped.control_basis, basis)
    assert env.spec.kwargs["control_basis"] == "~/best_basis.npy"
    env.unwrapped.set_control_basis("~/best_basis.npy")
    with pytest.raises(FileNotFoundError, match="control_basis file '~/nowhere.npy' does not"):
        gym.make("softrom_gym/BeamWalk-v0", control_basis="~/nowhere.npy")


def test_vector_env_names_a_bad_thread_count_when_it_is_made():
    """threads=0 (or 1.5, True) was accepted by make_vec and named only by the first step's
    rollout, after reset had run (found passing threads=0 to make_vec): it is refused by the
    constructor, as num_envs and max_episode_steps are."""
    for threads in (0, -2, 1.5, True, "2"):
        with pytest.raises(ValueError, match=f"threads must be a positive integer or None, "
                           f"got {threads!r}"):  # fmt: skip
            gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                         vectorization_mode="vector_entry_point", threads=threads)  # fmt: skip
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point", threads=np.int64(2))  # fmt: skip
    venv.reset(seed=0)
    venv.step(np.zeros((2, 3), dtype=np.float32))
    venv.close()


def test_vector_env_reset_seeds_its_own_np_random_as_gymnasium_s_vector_envs_do():
    """venv.reset(seed=5) left venv.np_random unseeded, so venv.np_random_seed was a fresh
    random number (found comparing make_vec's "sync" and "vector_entry_point" modes): as
    VectorEnv.reset does, an int seed seeds it, without changing the robots' streams."""
    draws = []
    for _ in range(2):
        venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                            vectorization_mode="vector_entry_point")  # fmt: skip
        obs, _ = venv.reset(seed=5)
        assert venv.np_random_seed == 5
        draws.append(venv.np_random.random())
        venv.close()
    assert draws[0] == draws[1]
    single = gym.make("softrom_gym/BeamWalk-v0")
    for i in range(2):  # robot i is still a single env reset with seed 5 + i
        np.testing.assert_array_equal(obs[i], single.reset(seed=5 + i)[0])


def test_export_expands_a_home_folder_path(tmp_path, monkeypatch):
    # "~/frames/walk.ply" made a folder literally named "~" in the working directory, where a
    # robot's mesh path and a control_basis path both read "~" as the home folder
    home, work = tmp_path / "home", tmp_path / "work"
    work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    robot = softrom_gym.robots.make_robot("beam", resolution=6)
    files = softrom_gym.export_trajectory([robot.nodes], "~/frames/walk.ply", robot=robot)
    assert files == [home / "frames" / "walk_0000.ply"]
    assert files[0].is_file()
    assert not any(work.iterdir())


@pytest.mark.filterwarnings("ignore:under the full action bound")  # (small by design)
def test_a_trimesh_scene_is_a_mesh_robot(tmp_path):
    # trimesh.load("robot.glb") gives a Scene: it was "unknown robot <trimesh.Scene ...>"
    scene = trimesh.Scene(trimesh.creation.box((0.2, 0.1, 0.1)))
    env = gym.make("softrom_gym/SoftRobot-v0", robot=scene, resolution=2, sim_dim=3,
                   control_dim=1)  # fmt: skip
    assert env.unwrapped.robot.volume == pytest.approx(0.002)
    with pytest.raises(ValueError, match="scale = 2 applies to a mesh"):
        gym.make("softrom_gym/SoftRobot-v0", robot="beam", scale=2)
    half = gym.make("softrom_gym/SoftRobot-v0", robot=scene, scale=0.5, resolution=2, sim_dim=3,
                    control_dim=1)  # fmt: skip
    assert half.unwrapped.robot.volume == pytest.approx(0.00025)


def test_a_shorter_export_removes_the_earlier_export_s_later_frames_and_nothing_else(tmp_path):
    # Guards: exporting 2 frames where 4 had been exported left walk_0002 and walk_0003 of the
    # earlier run beside them, and a video encoded from walk_*.ply mixed the two runs.
    robot = softrom_gym.robots.make_robot("beam", resolution=6)
    lifted = robot.nodes + np.array([0.0, 0.0, 0.01])
    frames = tmp_path / "frames"
    softrom_gym.export_trajectory([robot.nodes] * 4, frames / "walk.ply", robot=robot)
    others = ["walk_0005.obj", "walk_00003.ply", "walk_0002_x.ply", "run_0003.ply",
              "walk_notes.txt", "walk_12a4.ply", "walk_0003.ply.bak"]  # fmt: skip
    for name in others:  # not frames of this sequence: another format, stem or numbering
        (frames / name).write_text("the user's")
    (frames / "walk_0009.ply").mkdir()  # a folder is never removed
    files = softrom_gym.export_trajectory([lifted] * 2, frames / "walk.ply", robot=robot)
    assert [f.name for f in files] == ["walk_0000.ply", "walk_0001.ply"]
    left = sorted(p.name for p in frames.iterdir())
    assert left == sorted([*others, "walk_0000.ply", "walk_0001.ply", "walk_0009.ply"])
    for name in others:
        assert (frames / name).read_text() == "the user's"
    assert trimesh.load(files[1]).bounds[0, 2] == pytest.approx(0.01)
    # a longer sequence's five-digit frames are the sequence's too
    many = tmp_path / "many"
    many.mkdir()
    (many / "m_10000.ply").write_text("an earlier export's frame 10000")
    softrom_gym.export_trajectory([robot.nodes], many / "m.ply", robot=robot)
    assert sorted(p.name for p in many.iterdir()) == ["m_0000.ply"]


def _vector_pair(mode, steps=2):
    """The vector env and Gymnasium's SyncVectorEnv of single envs, both in autoreset
    ``mode``, truncating after ``steps``."""
    ours = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, max_episode_steps=steps,
                        vectorization_mode="vector_entry_point", autoreset_mode=mode)  # fmt: skip
    sync = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, max_episode_steps=steps,
                        vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": mode})  # fmt: skip
    return ours, sync


def _assert_same_step(a, b):
    for x, y in zip(a[:4], b[:4], strict=True):
        np.testing.assert_array_equal(x, y)
    assert sorted(a[4]) == sorted(b[4])
    for key in ("distance", "_distance", "com"):
        np.testing.assert_array_equal(a[4][key], b[4][key])
    if "final_obs" in b[4]:
        np.testing.assert_array_equal(a[4]["_final_obs"], b[4]["_final_obs"])
        for i in np.flatnonzero(b[4]["_final_obs"]):
            np.testing.assert_array_equal(a[4]["final_obs"][i], b[4]["final_obs"][i])
        for key in ("distance", "_distance", "diverged"):
            np.testing.assert_array_equal(a[4]["final_info"][key], b[4]["final_info"][key])


def test_vector_env_autoresets_in_the_same_step_as_gymnasium_s_vector_envs():
    # Guards: autoreset_mode=SAME_STEP reached SoftRobotEnv as an unknown keyword (TypeError),
    # so the vector env offered NEXT_STEP only, Gymnasium's SyncVectorEnv all three modes.
    from gymnasium.vector import AutoresetMode

    ours, sync = _vector_pair(AutoresetMode.SAME_STEP)
    assert ours.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert ours.spec.kwargs["autoreset_mode"] is AutoresetMode.SAME_STEP
    obs, _ = ours.reset(seed=3)
    np.testing.assert_array_equal(obs, sync.reset(seed=3)[0])
    rng = np.random.default_rng(0)
    bound = ours.env.action_bound
    for t in range(4):
        actions = rng.uniform(-bound, bound, (2, 3)).astype(np.float32)
        step = ours.step(actions)
        _assert_same_step(step, sync.step(actions))
        assert step[3].all() == (t % 2 == 1)  # (every second step ends and resets at once)
    assert "final_obs" in step[4] and step[4]["final_info"]["_distance"].all()
    # the class's metadata is every instance's default: NEXT_STEP
    plain = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                         vectorization_mode="vector_entry_point")  # fmt: skip
    assert plain.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert ours.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP  # (each its own)
    as_text = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, autoreset_mode="SameStep",
                           vectorization_mode="vector_entry_point")  # fmt: skip
    assert as_text.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    for bad in ("same_step", 1, None):
        with pytest.raises(ValueError, match=rf"autoreset_mode must be one of \['NextStep', "
                           rf"'SameStep', 'Disabled'\] or an AutoresetMode, "
                           rf"got {bad!r}"):  # fmt: skip
            gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, autoreset_mode=bad,
                         vectorization_mode="vector_entry_point")  # fmt: skip


def test_vector_env_refuses_to_step_a_robot_no_reset_has_started_as_sync_vector_env_does():
    """A step before reset stepped every robot from rest, its distance counted from the
    origin (-0.066 m on the tripod), where SyncVectorEnv raises ResetNeeded; a first reset
    with a partial reset_mask left the others so (a review, session 54)."""
    from gymnasium.error import ResetNeeded
    from gymnasium.vector import AutoresetMode

    ours, sync = _vector_pair(AutoresetMode.NEXT_STEP)
    zero = np.zeros((2, 3), dtype=np.float32)
    for env in (ours, sync):
        with pytest.raises(ResetNeeded):
            env.step(zero)
    with pytest.raises(ResetNeeded, match=r"sub-environment\(s\) \[0, 1\] were never reset"):
        ours.step(zero)
    ours.reset(seed=0, options={"reset_mask": np.array([True, False])})
    with pytest.raises(ResetNeeded, match=r"sub-environment\(s\) \[1\] were never reset"):
        ours.step(zero)
    ours.reset(options={"reset_mask": np.array([False, True])})
    ours.step(zero)
    np.testing.assert_array_equal(ours.reset(seed=3)[0], sync.reset(seed=3)[0])
    _assert_same_step(ours.step(zero), sync.step(zero))


def test_vector_env_without_autoreset_resets_by_mask_and_names_ended_envs_it_is_stepped_with():
    from gymnasium.error import ResetNeeded
    from gymnasium.vector import AutoresetMode

    ours, sync = _vector_pair(AutoresetMode.DISABLED)
    assert ours.metadata["autoreset_mode"] is AutoresetMode.DISABLED
    np.testing.assert_array_equal(ours.reset(seed=3)[0], sync.reset(seed=3)[0])
    zero = np.zeros((2, 3), dtype=np.float32)
    _assert_same_step(ours.step(zero), sync.step(zero))
    # robot 0 starts again (its own stream goes on), robot 1 keeps its last observation
    options = {"reset_mask": np.array([True, False])}
    obs, info = ours.reset(options=options)
    expected, sync_info = sync.reset(options={"reset_mask": np.array([True, False])})
    np.testing.assert_array_equal(obs, expected)
    assert options == {"reset_mask": options["reset_mask"]}  # (the caller's dict is theirs)
    assert info["_distance"].tolist() == sync_info["_distance"].tolist() == [True, False]
    step = ours.step(zero)
    _assert_same_step(step, sync.step(zero))
    assert step[3].tolist() == [False, True]
    with pytest.raises(ResetNeeded, match=r"sub-environment\(s\) \[1\] ended .* "
                       r"reset\(options=\{'reset_mask': mask\}\)"):  # fmt: skip
        ours.step(zero)
    # resetting another robot leaves robot 1's episode ended: it is still refused, not
    # stepped on from where its episode ended
    ours.reset(options={"reset_mask": np.array([True, False])})
    sync.reset(options={"reset_mask": np.array([True, False])})
    with pytest.raises(ResetNeeded, match=r"sub-environment\(s\) \[1\] ended"):
        ours.step(zero)
    ours.reset(options={"reset_mask": np.array([False, True])})
    sync.reset(options={"reset_mask": np.array([False, True])})
    _assert_same_step(ours.step(zero), sync.step(zero))
    for bad, error, text in (
        (np.array([True]), ValueError, r"reset_mask must be 2 booleans, got \[True\]"),
        (np.array([1, 0]), ValueError, r"reset_mask must be 2 booleans, got \[1, 0\]"),
        (np.array([False, False]), ValueError, "reset_mask resets no sub-environment"),
    ):
        with pytest.raises(error, match=text):
            ours.reset(options={"reset_mask": bad})
    with pytest.raises(ValueError, match=r"reset takes the options 'state' \(.*\) and "
                       r"'reset_mask' \(.*\), got \['speed'\]"):  # fmt: skip
        ours.reset(options={"reset_mask": np.array([True, True]), "speed": 1})


def test_set_control_basis_updates_the_spec_so_the_spec_makes_this_env(tmp_path):
    # Guards: env.spec kept the B_c the env was made with after set_control_basis, so
    # gym.make(env.spec) (or a vector env's copies made from it) stepped another control space
    # without a word.
    import json

    rng = np.random.default_rng(1)
    basis = np.linalg.qr(rng.standard_normal((20, 3)))[0]
    env = gym.make("softrom_gym/BeamWalk-v0")
    made_with = env.unwrapped.spec
    env.unwrapped.set_control_basis(basis)
    assert made_with.kwargs == {"robot": "beam", "task": "walk"}  # (a spec given out stays)
    action = np.array([0.5, -0.3, 0.2], dtype=np.float32) * env.unwrapped.action_bound
    again = gym.make(env.spec)
    np.testing.assert_array_equal(again.unwrapped.control_basis, basis)
    for e in (env, again):
        e.reset(seed=0)
    np.testing.assert_array_equal(env.step(action)[0], again.step(action)[0])
    # a matrix orthonormalised on the way: the spec holds the B_c used, bit for bit
    skew = rng.standard_normal((20, 3))
    env.unwrapped.set_control_basis(skew, orthonormalize=True)
    spec = env.unwrapped.spec
    assert spec.kwargs["orthonormalize"] is False
    np.testing.assert_array_equal(spec.kwargs["control_basis"], env.unwrapped.control_basis)
    skew[0, 0] = 99.0  # (the caller's array is theirs: the spec holds a copy)
    assert not np.shares_memory(spec.kwargs["control_basis"], env.unwrapped.control_basis)
    np.testing.assert_array_equal(
        gym.make(spec).unwrapped.control_basis, env.unwrapped.control_basis
    )
    # a path stays a path (and the spec JSON), orthonormalize as given
    np.save(tmp_path / "b.npy", 2.0 * basis)
    env.unwrapped.set_control_basis(str(tmp_path / "b.npy"), orthonormalize=True)
    kwargs = json.loads(env.unwrapped.spec.to_json())["kwargs"]
    assert kwargs["control_basis"] == str(tmp_path / "b.npy") and kwargs["orthonormalize"]
    np.testing.assert_array_equal(gym.make(env.unwrapped.spec).unwrapped.control_basis,
                                  env.unwrapped.control_basis)  # fmt: skip
    # a refused basis changes neither the env nor its spec
    with pytest.raises(ValueError, match="control_basis is not orthonormal"):
        env.unwrapped.set_control_basis(skew)
    # (a non-bool orthonormalize, truthy as a string, was taken as True and orthonormalised)
    with pytest.raises(TypeError, match="orthonormalize must be True or False, got 'no'"):
        env.unwrapped.set_control_basis(skew, orthonormalize="no")
    with pytest.raises(TypeError, match="orthonormalize must be True or False, got 1"):
        env.unwrapped.set_control_basis(skew, orthonormalize=1)  # (as the constructor)
    assert env.unwrapped.spec.kwargs["control_basis"] == str(tmp_path / "b.npy")


def test_the_env_s_control_basis_is_its_own_not_the_caller_s_array():
    # Guards: env.control_basis was the caller's array itself (float64 is not copied by
    # np.asarray), while the C++ model holds a copy: writing into that array afterwards
    # changed env.control_basis but not the model, so a deepcopy (rebuilt from
    # env.control_basis) stepped another control space than the original.
    basis = np.eye(20)[:, :3].copy()
    env = gym.make("softrom_gym/BeamWalk-v0", control_basis=basis)
    basis[:] = np.eye(20)[:, 3:6]
    np.testing.assert_array_equal(env.unwrapped.control_basis, np.eye(20)[:, :3])
    twin = copy.deepcopy(env.unwrapped)
    action = np.full(3, 0.5 * twin.action_bound, dtype=np.float32)
    env.reset(seed=0)
    twin.reset(seed=0)
    np.testing.assert_array_equal(env.step(action)[0], twin.step(action)[0])
    replaced = np.eye(20)[:, 1:4].copy()
    for e in (env.unwrapped, twin):
        e.set_control_basis(replaced)
        assert not np.shares_memory(e.control_basis, replaced)
        # writing into it would leave the model on the old B_c: refused, not silent
        with pytest.raises(ValueError, match="read-only"):
            e.control_basis[0, 0] = 2.0
    with pytest.raises(ValueError, match="read-only"):
        pickle.loads(pickle.dumps(env.unwrapped)).control_basis[0, 0] = 2.0


@pytest.mark.filterwarnings("ignore:under the full action bound")  # (small by design)
def test_a_walking_robot_must_rest_on_the_ground(monkeypatch):
    # Guards: a Robot of the user's own whose lowest node was off z = 0 was taken as it was: 5 cm
    # above the ground it fell for the first steps of every episode (the reward counting the
    # landing), 1 cm below it started interpenetrating and was kicked out by the contact.
    from softrom_gym.envs import soft_robot_env
    from softrom_gym.robots import Robot
    from softrom_gym.robots.voxel import voxels_to_tets

    nodes, tets = voxels_to_tets(np.ones((4, 2, 2), dtype=bool), 0.02)

    def never(*args, **kwargs):
        raise AssertionError("built B_r or the model before naming a bad argument")

    monkeypatch.setattr(soft_robot_env, "build_subspace", never)
    for dz, where in ((0.05, "above"), (-0.01, "below")):
        robot = Robot("block", nodes + np.array([0.0, 0.0, dz]), tets)
        with pytest.raises(ValueError, match=rf"robot 'block' does not rest on the ground: its "
                           rf"lowest node is {abs(dz):g} m {where} z = 0.*robot.nodes - "
                           r"\[0, 0, robot.nodes\[:, 2\].min\(\)\]"):  # fmt: skip
            gym.make("softrom_gym/SoftRobot-v0", robot=robot)
    monkeypatch.undo()
    # a swimmer has no ground; round-off far below the contact's scale is on the ground
    gym.make("softrom_gym/SoftRobot-v0", robot=Robot("block", nodes + np.array([0, 0, 0.05]), tets),
             task="swim", sim_dim=4, control_dim=1)  # fmt: skip
    near = Robot("block", nodes - np.array([0, 0, 1e-12]), tets)
    near = gym.make("softrom_gym/SoftRobot-v0", robot=near, sim_dim=4, control_dim=1)
    assert near.reset(seed=0)[0][0] == pytest.approx(0.02)


def test_every_observation_slot_reads_its_own_part_of_the_state():
    """obs = [height, COM velocity (3), theta (3), theta_dot (3), q[6:], qdot[6:]]: the slots
    after the orientation were not checked, so an observation that repeated q[6:] where
    qdot[6:] belongs (the deformation velocities a policy needs) passed every test."""
    base, q, qdot, obs = _beam_observed_at_random_state(seed=1, first=3)
    basis, mass = base.subspace.basis, base.robot.fem_model().mass
    m = basis.shape[1] - 6
    assert obs.shape == (10 + 2 * m,)
    rows = orientation_rows(base.robot.nodes, mass, basis)
    np.testing.assert_allclose(obs[4:7], rows @ q, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(obs[7:10], rows @ qdot, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(obs[10 : 10 + m], q[6:], rtol=1e-6)
    np.testing.assert_allclose(obs[10 + m :], qdot[6:], rtol=1e-6)
