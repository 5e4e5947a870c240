"""Swapping the control space B_c of a made env: the vector env's, and a wrapper's spec."""

import gymnasium as gym
import numpy as np
import pytest

import softrom_gym  # noqa: F401  (registers the envs)
from softrom_gym.envs import set_control_basis


def _basis(seed: int, columns: int = 3) -> np.ndarray:
    return np.linalg.qr(np.random.default_rng(seed).standard_normal((20, columns)))[0]


def test_a_wrapped_env_s_spec_follows_a_swapped_basis():
    # Guards: gym.make's wrappers keep the spec of their first read, so env.spec read before
    # env.unwrapped.set_control_basis(B) kept the old B_c afterwards, and gym.make(env.spec)
    # made an env with another control space than this one's.
    basis = _basis(1)
    env = gym.make("softrom_gym/BeamWalk-v0")
    assert "control_basis" not in env.spec.kwargs
    env.unwrapped.set_control_basis(basis)
    # the method cannot reach the wrappers above the env: their spec stays (documented) ...
    assert "control_basis" not in env.spec.kwargs
    np.testing.assert_array_equal(env.unwrapped.spec.kwargs["control_basis"], basis)
    # ... the module function, given the wrapped env, refreshes every wrapper's
    set_control_basis(env, basis)
    np.testing.assert_array_equal(env.spec.kwargs["control_basis"], basis)
    assert env.spec.max_episode_steps == 400  # (the wrappers' own part of the spec is kept)
    again = gym.make(env.spec)
    np.testing.assert_array_equal(again.unwrapped.control_basis, basis)
    action = np.array([0.5, -0.3, 0.2], dtype=np.float32) * env.unwrapped.action_bound
    for e in (env, again):
        e.reset(seed=0)
    np.testing.assert_array_equal(env.step(action)[0], again.step(action)[0])
    # a refused basis changes neither the env nor any spec
    with pytest.raises(ValueError, match="control_basis is not orthonormal"):
        set_control_basis(env, 2.0 * basis)
    np.testing.assert_array_equal(env.spec.kwargs["control_basis"], basis)
    # orthonormalize reaches the env: the spec holds the B_c used
    set_control_basis(env, 2.0 * basis[:, ::-1], orthonormalize=True)
    np.testing.assert_allclose(env.unwrapped.control_basis, basis[:, ::-1], atol=1e-12)
    np.testing.assert_array_equal(env.spec.kwargs["control_basis"], env.unwrapped.control_basis)
    set_control_basis(env, basis)
    # a bare env, and an env that is neither, are named
    set_control_basis(again.unwrapped, basis[:, ::-1])
    np.testing.assert_array_equal(again.unwrapped.control_basis, basis[:, ::-1])
    with pytest.raises(TypeError, match="env must be a softrom_gym env .* got CartPoleEnv"):
        set_control_basis(gym.make("CartPole-v1"), basis)


def test_vector_env_swaps_the_control_basis_of_every_robot():
    n = 2
    basis = _basis(2)
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=n,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    singles = [gym.make("softrom_gym/BeamWalk-v0", control_basis=basis) for _ in range(n)]
    venv.set_control_basis(basis)
    np.testing.assert_array_equal(venv.control_basis, basis)
    with pytest.raises(ValueError, match="read-only"):
        venv.control_basis[0, 0] = 2.0
    obs, _ = venv.reset(seed=10)
    for i, env in enumerate(singles):
        np.testing.assert_array_equal(obs[i], env.reset(seed=10 + i)[0])
    rng = np.random.default_rng(0)
    bound = singles[0].unwrapped.action_bound
    for _ in range(3):
        actions = rng.uniform(-bound, bound, (n, 3)).astype(np.float32)
        obs, rewards, *_ = venv.step(actions)
        for i, env in enumerate(singles):
            o, r, *_ = env.step(actions[i])
            np.testing.assert_array_equal(obs[i], o)
            assert rewards[i] == r
    # mid-episode too, through the module function: the robots go on from where they are
    venv.set_control_basis(basis[:, ::-1])
    set_control_basis(venv, basis[:, ::-1])
    for env in singles:
        env.unwrapped.set_control_basis(basis[:, ::-1])
    actions = rng.uniform(-bound, bound, (n, 3)).astype(np.float32)
    obs, *_ = venv.step(actions)
    for i, env in enumerate(singles):
        np.testing.assert_array_equal(obs[i], env.step(actions[i])[0])
    venv.close()


def test_vector_env_refuses_a_bad_basis_as_the_single_env_does(tmp_path):
    basis = _basis(3)
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    before = venv.control_basis.copy()
    spec = venv.spec
    for bad, text in (
        (basis[:, :2], r"has shape \(20, 2\), expected \(sim_dim, control_dim\) = \(20, 3\)"),
        (2.0 * basis, r"control_basis is not orthonormal: max \|B_c\^T B_c - I\| = 3"),
        (np.full((20, 3), np.nan), r"control_basis contains non-finite values, e.g. nan"),
    ):
        with pytest.raises(ValueError, match=text):
            venv.set_control_basis(bad)
    with pytest.raises(FileNotFoundError, match="control_basis file .*missing.npy' does not"):
        venv.set_control_basis(tmp_path / "missing.npy")
    np.testing.assert_array_equal(venv.control_basis, before)
    assert venv.spec is spec
    # the action space keeps C (a basis of another C is refused), so it is unchanged
    assert venv.action_space.shape == (2, 3)


def test_vector_env_spec_follows_the_swapped_basis(tmp_path):
    # As the single env's: make_vec(venv.spec) makes a vector env with the B_c in use.
    import json

    basis = _basis(4)
    venv = gym.make_vec("softrom_gym/BeamWalk-v0", num_envs=2, max_episode_steps=7,
                        vectorization_mode="vector_entry_point")  # fmt: skip
    made_with = venv.spec
    venv.set_control_basis(basis)
    assert "control_basis" not in made_with.kwargs  # (a spec given out stays)
    kwargs = venv.spec.kwargs
    np.testing.assert_array_equal(kwargs["control_basis"], basis)
    assert kwargs["orthonormalize"] is False and kwargs["num_envs"] == 2
    assert kwargs["max_episode_steps"] == 7
    again = gym.make_vec(venv.spec)
    np.testing.assert_array_equal(again.control_basis, basis)
    assert again.num_envs == 2 and again.max_episode_steps == 7
    # a matrix orthonormalised on the way: the spec holds the B_c used, so it makes this env
    venv.set_control_basis(3.0 * basis[:, ::-1], orthonormalize=True)
    assert venv.spec.kwargs["orthonormalize"] is False
    np.testing.assert_array_equal(venv.spec.kwargs["control_basis"], venv.control_basis)
    np.testing.assert_array_equal(gym.make_vec(venv.spec).control_basis, venv.control_basis)
    # a path stays a path (the spec stays JSON), orthonormalize as given
    np.save(tmp_path / "b.npy", 2.0 * basis)
    venv.set_control_basis(str(tmp_path / "b.npy"), orthonormalize=True)
    np.testing.assert_allclose(venv.control_basis, basis, atol=1e-12)
    kwargs = json.loads(venv.spec.to_json())["kwargs"]
    assert kwargs["control_basis"] == str(tmp_path / "b.npy") and kwargs["orthonormalize"]
    np.testing.assert_array_equal(gym.make_vec(venv.spec).control_basis, venv.control_basis)
    # a vector env made directly has no spec, and stays without one
    from softrom_gym.envs import SoftRobotVectorEnv

    bare = SoftRobotVectorEnv(num_envs=1, robot="beam")
    bare.set_control_basis(basis)
    assert bare.spec is None
    np.testing.assert_array_equal(bare.control_basis, basis)
