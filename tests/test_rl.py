"""RL-library compatibility: Stable-Baselines3's env checker and a PPO smoke run."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env

import softrom_gym

IDS = [f"softrom_gym/{name}" for name in softrom_gym.BENCHMARKS] + ["softrom_gym/SoftRobot-v0"]


# SB3 advises a [-1, 1] action box; ours is physical by design (see SoftRobotEnv's docstring,
# and gymnasium.wrappers.RescaleAction for RL users who prefer it normalised).
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized")
@pytest.mark.filterwarnings("ignore:.*(normalized|normalize|rescale).*action")
@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env(env_id):
    check_env(gym.make(env_id).unwrapped, warn=True)


def test_ppo_smoke_run_on_beam_walk(tmp_path, monkeypatch):
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path))  # not a new folder in /tmp per run
    base = gym.make("softrom_gym/BeamWalk-v0")
    one = np.ones(base.action_space.shape, dtype=np.float32)
    env = gym.wrappers.RescaleAction(base, -one, one)
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=2, seed=0, device="cpu")
    model.learn(total_timesteps=2000)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action.astype(np.float32))
    assert model.num_timesteps >= 2000
