"""The env's MPC API as planners see it: through gym.make's wrappers, exact replay, per-step
terms and the price of divergence."""

import gymnasium as gym
import numpy as np
import pytest

import softrom_gym

IDS = [f"softrom_gym/{name}" for name in softrom_gym.BENCHMARKS] + ["softrom_gym/SoftRobot-v0"]


@pytest.mark.parametrize("env_id", IDS)
def test_a_plan_replays_bit_for_bit_through_step(env_id):
    env = gym.make(env_id)
    env.reset(seed=1)
    get_state = env.get_wrapper_attr("get_state")
    set_state = env.get_wrapper_attr("set_state")
    rollout = env.get_wrapper_attr("rollout")
    bound = env.get_wrapper_attr("action_bound")
    start = get_state()
    rng = np.random.default_rng(0)
    # Beyond the bound on purpose: clipping must be the same on both paths.
    controls = rng.uniform(-1.2, 1.2, (2, 4, 3)) * bound
    out = rollout(start, controls)
    for dtype in (np.float32, np.float64):
        set_state(start)
        for t in range(controls.shape[1]):
            _, reward, terminated, _, info = env.step(controls[1, t].astype(dtype))
            assert reward == out["rewards"][1, t]
            np.testing.assert_array_equal(info["com"], out["com"][1, t])
            assert info["orientation"] == out["orientation"][1, t]
            assert info["lateral"] == out["lateral"][1, t]
            assert info["effort"] == out["effort"][1, t]
            assert not terminated
        state = get_state()
        for name in ("q", "qdot", "impulses"):
            np.testing.assert_array_equal(getattr(state, name), out[name][1], err_msg=name)
    env.close()


def test_per_step_terms_have_their_documented_shapes_and_meaning():
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    rollout = env.get_wrapper_attr("rollout")
    state = env.get_wrapper_attr("get_state")()
    observe = np.eye(state.q.size)[:2]
    controls = np.full((3, 5, 3), 0.5 * env.get_wrapper_attr("action_bound"))
    out = rollout(state, controls, observe=observe)
    assert out["com"].shape == (3, 5, 3) and out["theta"].shape == (3, 5, 3)
    for key in ("rewards", "orientation", "lateral", "effort", "lost"):
        assert out[key].shape == (3, 5), key
    np.testing.assert_array_equal(out["orientation"], np.linalg.norm(out["theta"], axis=-1))
    # R per step is the COM's advance along d (the paper's d^T v dt, summed over sub-steps).
    com0 = env.unwrapped.model.com(state.q)
    advance = np.diff(np.concatenate([np.broadcast_to(com0, (3, 1, 3)), out["com"]], 1), axis=1)
    np.testing.assert_allclose(out["rewards"], advance[..., 0], rtol=1e-9, atol=1e-12)
    # lateral: the ground-plane motion orthogonal to d (here y); effort: |f_c / a|^2 (guards
    # against the full planar motion, or |f_c / a|_1, reported instead)
    np.testing.assert_allclose(out["lateral"], np.abs(advance[..., 1]), rtol=1e-9, atol=1e-15)
    assert np.all(out["lateral"] > 0)
    np.testing.assert_allclose(out["effort"], 3 * 0.5**2, rtol=1e-6)
    assert out["observed"].shape == (3, 5, 2)
    np.testing.assert_array_equal(out["observed"][:, -1], out["q"][:, :2])
    assert not out["lost"].any()
    assert env.get_wrapper_attr("dt") == pytest.approx(5 / 200)
    assert env.get_wrapper_attr("body_length") == pytest.approx(0.8)
    with pytest.raises(ValueError, match=r"observe has shape \(2, 3\), expected \(P, 26\)"):
        rollout(state, controls, observe=np.zeros((2, 3)))
    # the row is the caller's, not the core's (which stacks the orientation rows above it)
    observe[1, 4] = np.nan
    with pytest.raises(ValueError, match=r"non-finite value \(nan\) at \(1, 4\)"):
        rollout(state, controls, observe=observe)


def test_set_state_refuses_a_state_of_another_model():
    import cpp_sim

    base = gym.make("softrom_gym/BeamWalk-v0").unwrapped
    base.reset(seed=0)
    state = base.get_state()
    with pytest.raises(ValueError, match="state has dimension 27, expected 26"):
        base.set_state(cpp_sim.ReducedState(np.zeros(27), np.zeros(27), state.impulses))
    # impulses of another robot: refused here, not by the step after it
    with pytest.raises(ValueError, match=r"state has 6 contact impulses, expected 1146 \(3 per"):
        base.set_state(cpp_sim.ReducedState(state.q, state.qdot, np.zeros(6)))
    np.testing.assert_array_equal(base.get_state().impulses, state.impulses)  # unchanged


def test_reset_starts_from_a_state_given_as_its_option():
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    action = np.full(3, 0.5) * env.get_wrapper_attr("action_bound")
    for _ in range(5):
        env.step(action)
    mid = env.get_wrapper_attr("get_state")()
    after = env.step(action)
    # from the state given: the same step, the distance counted from there
    _, info = env.reset(seed=1, options={"state": mid})
    assert info["distance"] == 0.0
    np.testing.assert_array_equal(env.get_wrapper_attr("get_state")().q, mid.q)
    again = env.step(action)
    np.testing.assert_array_equal(again[0], after[0])
    assert again[1] == after[1]
    # the velocities are drawn all the same: the stream goes on as after a plain reset
    plain = gym.make("softrom_gym/BeamWalk-v0")
    plain.reset(seed=1)
    assert env.unwrapped.np_random.random() == plain.unwrapped.np_random.random()
    # anything else is named, and nothing changes
    before = env.get_wrapper_attr("get_state")()
    with pytest.raises(ValueError, match=r"reset takes the option 'state' only .* got \['start'\]"):
        env.reset(options={"start": mid})
    with pytest.raises(TypeError, match="state must be a ReducedState from get_state()"):
        env.reset(options={"state": mid.q})
    np.testing.assert_array_equal(env.get_wrapper_attr("get_state")().q, before.q)
    # the vector env: every robot from the state
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    obs, _ = venv.reset(seed=0, options={"state": mid})
    np.testing.assert_array_equal(obs[0], obs[1])
    np.testing.assert_array_equal(obs[0], env.reset(options={"state": mid})[0])
    # (the vector env's reset also takes Gymnasium's reset_mask, and says so)
    with pytest.raises(ValueError, match=r"reset takes the options 'state' .* and 'reset_mask'"):
        venv.reset(options={"x": 1})
    # a bad state is named before any robot is reset or reseeded: the streams go on as if the
    # refused reset had not been called
    twin = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    twin.reset(seed=0, options={"state": mid})
    with pytest.raises(TypeError, match="state must be a ReducedState from get_state()"):
        venv.reset(seed=7, options={"state": mid.q})
    np.testing.assert_array_equal(venv.reset()[0], twin.reset()[0])
    assert venv.np_random.random() == twin.np_random.random()
    venv.close()


def test_divergence_is_marked_as_lost_steps_from_the_diverging_step_on():
    # A huge action bound lets one step blow the simulation up on purpose.
    env = gym.make("softrom_gym/SoftRobot-v0", robot="beam", action_scale=1e9)
    env.reset(seed=0)
    bound = env.get_wrapper_attr("action_bound")
    controls = np.zeros((2, 6, 3))
    controls[1, 3:] = bound
    out = env.get_wrapper_attr("rollout")(env.get_wrapper_attr("get_state")(), controls)
    assert list(out["diverged"]) == [False, True]
    np.testing.assert_array_equal(out["lost"], [[0] * 6, [0, 0, 0, 1, 1, 1]])
    np.testing.assert_array_equal(out["rewards"][1, 3:], 0.0)


def test_a_robot_at_rest_before_it_diverges_loses_only_the_steps_from_the_divergence():
    """Where a rollout diverged was guessed from where its COM froze: a swimmer at rest (no
    gravity, no reset noise, no control) had every step marked lost, where step() terminated
    on the fourth. The core now says how many steps it solved (``good_steps``)."""
    env = gym.make("softrom_gym/SoftRobot-v0", robot="beam", task="swim", action_scale=1e9,
                   reset_noise_scale=0.0)  # fmt: skip
    env.reset(seed=0)
    controls = np.zeros((1, 6, 3))
    controls[0, 3:] = env.get_wrapper_attr("action_bound")
    out = env.get_wrapper_attr("rollout")(env.get_wrapper_attr("get_state")(), controls)
    assert out["diverged"][0]
    np.testing.assert_array_equal(out["rewards"][0, :3], 0.0)  # (at rest: as a frozen robot)
    np.testing.assert_array_equal(out["lost"], [[0, 0, 0, 1, 1, 1]])
    terminated = [env.step(u.astype(np.float32))[2] for u in controls[0]]
    assert terminated == [False, False, False, True, True, True]
    env.close()


@pytest.mark.filterwarnings("ignore:.*a tetrahedron is inverted")
@pytest.mark.filterwarnings("ignore:.*the robot has turned")
def test_a_diverging_step_reports_what_rollout_predicts_for_it():
    # step() has its own single-step path: the step that diverges part-way through its
    # sub-steps (paid up to there) must still report rollout's terms and frozen state
    env = gym.make("softrom_gym/BeamWalk-v0", action_scale=1e3)
    env.reset(seed=0)
    bound = env.get_wrapper_attr("action_bound")
    start = env.get_wrapper_attr("get_state")()
    controls = np.random.default_rng(1).uniform(-1.0, 1.0, (1, 4, 3)) * bound
    out = env.get_wrapper_attr("rollout")(start, controls)
    assert out["diverged"][0] and out["lost"][0, 0] == 0.0  # diverges after a good step
    for t in range(controls.shape[1]):
        _, reward, terminated, _, info = env.step(controls[0, t].astype(np.float32))
        assert reward == out["rewards"][0, t]
        np.testing.assert_array_equal(info["com"], out["com"][0, t])
        for key in ("orientation", "lateral", "effort"):
            assert info[key] == out[key][0, t], key
        assert terminated == info["diverged"] == bool(out["lost"][0, t])
        if terminated:
            break
    assert terminated and 0.0 < abs(reward)  # the diverging step paid its good sub-steps
    state = env.get_wrapper_attr("get_state")()
    for name in ("q", "qdot", "impulses"):
        np.testing.assert_array_equal(getattr(state, name), out[name][0], err_msg=name)
    env.close()


def test_control_basis_is_swapped_in_place_and_validated(tmp_path):
    env = gym.make("softrom_gym/BeamWalk-v0")
    base = env.unwrapped
    model, subspace = base.model, base.subspace
    rng = np.random.default_rng(0)
    b, _ = np.linalg.qr(rng.standard_normal((20, 3)))
    base.set_control_basis(b)
    assert base.model is model and base.subspace is subspace  # nothing rebuilt
    np.testing.assert_array_equal(base.control_basis, b)
    np.testing.assert_array_equal(model.control_basis, b)
    # The swapped basis is the one that acts: a fresh env built with it steps identically.
    other = gym.make("softrom_gym/BeamWalk-v0", control_basis=b).unwrapped
    env.reset(seed=1)
    other.reset(seed=1)
    u = np.array([5.0, -3.0, 2.0], dtype=np.float32)
    np.testing.assert_array_equal(env.step(u)[0], other.step(u)[0])
    with pytest.raises(ValueError, match=r"control_basis has shape \(20, 2\)"):
        base.set_control_basis(b[:, :2])
    with pytest.raises(ValueError, match="not orthonormal"):
        base.set_control_basis(2.0 * b)
    base.set_control_basis(2.0 * b, orthonormalize=True)
    np.testing.assert_allclose(base.control_basis, b, atol=1e-12)
    # a .npy path, as the constructor takes (a run's best_basis.npy)
    np.save(tmp_path / "basis.npy", b[:, ::-1])
    base.set_control_basis(str(tmp_path / "basis.npy"))
    np.testing.assert_array_equal(model.control_basis, b[:, ::-1])
    with pytest.raises(FileNotFoundError, match="control_basis file .* does not exist"):
        base.set_control_basis(tmp_path / "missing.npy")


def test_the_env_docstring_names_every_attribute_the_planners_use():
    # A planner of one's own is written from this section: it named neither direction nor
    # center_of_mass, which controllers.planner.EnvAPI reads (R is along d from the start
    # COM).
    from softrom_gym.envs.soft_robot_env import SoftRobotEnv

    doc = SoftRobotEnv.__doc__
    section = doc[doc.index("## For model-predictive control") : doc.index("## Version History")]
    for name in ("get_state", "set_state", "rollout", "action_bound", "dt", "direction",
                 "center_of_mass", "body_length"):  # fmt: skip
        assert f"``{name}" in section, name


def test_rollouts_continue_from_final_states_as_one_longer_rollout():
    # Multiple shooting: two segments of 3 steps, the second from the first's final states,
    # are one rollout of 6 steps to the last bit (the contact impulses carried over too).
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    rollout = env.get_wrapper_attr("rollout")
    final_states = env.get_wrapper_attr("final_states")
    start = env.get_wrapper_attr("get_state")()
    controls = np.random.default_rng(1).uniform(-1, 1, (2, 6, 3)) * env.get_wrapper_attr(
        "action_bound"
    )
    whole = rollout(start, controls)
    first = rollout(start, controls[:, :3])
    middle = final_states(first)
    assert len(middle) == 2
    second = rollout(middle, controls[:, 3:])
    np.testing.assert_array_equal(np.hstack([first["rewards"], second["rewards"]]),
                                  whole["rewards"])  # fmt: skip
    for name in ("q", "qdot", "impulses"):
        np.testing.assert_array_equal(second[name], whole[name], err_msg=name)
    with pytest.raises(TypeError, match="result must be the dict rollout\\(\\) returned"):
        final_states({"q": whole["q"]})
    with pytest.raises(ValueError, match=r"expected \(B, 26\) each"):
        final_states({**whole, "q": whole["q"][:, :5]})
    env.close()
