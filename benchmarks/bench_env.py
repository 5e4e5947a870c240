"""Environment throughput per registered benchmark, measured side by side in one run.

For each env id: single-env steps/s (``gym.make`` + ``step``), the native vector env with 8
robots (each stepping as many times as the single env, so both see the same mix of settling
and walking) (``gym.make_vec(..., vectorization_mode="vector_entry_point")``) in robot-steps/s,
their ratio (`vector_speedup`: the vector env steps its robots on 2 threads, the single env
on one, so the ratio is batching and threading together), and batched ``rollout`` throughput
on 2 threads in robot env-steps/s (64 rollouts x 10 env steps). Actions are uniform random in
the action box. Each rate is one timed run from just after reset, the first step included
(not best of several): compare rows of one run.

    python benchmarks/bench_env.py [--json] [--steps 100]
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import softrom_gym

IDS = [f"softrom_gym/{name}" for name in softrom_gym.BENCHMARKS]


def measure(env_id: str, steps: int, num_envs: int = 8) -> dict:
    rng = np.random.default_rng(0)
    env = gym.make(env_id)
    env.reset(seed=0)
    bound = env.unwrapped.action_bound
    actions = rng.uniform(-bound, bound, (steps, 3)).astype(np.float32)
    start = time.perf_counter()
    for a in actions:
        *_, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    single = steps / (time.perf_counter() - start)

    venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                        threads=2)  # fmt: skip
    venv.reset(seed=0)
    vsteps = steps  # each robot takes as many steps as the single env: same trajectory mix
    vactions = rng.uniform(-bound, bound, (vsteps, num_envs, 3)).astype(np.float32)
    start = time.perf_counter()
    for a in vactions:
        venv.step(a)
    vector = vsteps * num_envs / (time.perf_counter() - start)

    base = env.unwrapped
    state = base.get_state()
    controls = rng.uniform(-bound, bound, (64, 10, 3))
    start = time.perf_counter()
    base.rollout(state, controls, threads=2)
    rollout = controls.shape[0] * controls.shape[1] / (time.perf_counter() - start)
    env.close()
    venv.close()
    return {
        "env_id": env_id,
        "single_steps_per_s": single,
        "vector_steps_per_s": vector,
        "vector_speedup": vector / single,
        "rollout_steps_per_s": rollout,
        "num_envs": num_envs,
        "frame_skip": base.frame_skip,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--steps", type=int, default=100, help="env steps per measurement")
    parser.add_argument("--ids", nargs="*", default=IDS, choices=IDS)
    args = parser.parse_args()
    if args.steps < 1:
        parser.error(f"--steps must be >= 1, got {args.steps}")
    if not args.json:
        print(f"{'env id':<30} {'single/s':>9} {'vector8/s':>10} {'ratio':>7} {'rollout/s':>10}")
    for env_id in args.ids:
        r = measure(env_id, args.steps)
        if args.json:
            print(json.dumps(r), flush=True)
        else:
            print(
                f"{env_id:<30} {r['single_steps_per_s']:>9.0f} {r['vector_steps_per_s']:>10.0f} "
                f"{r['vector_speedup']:>6.2f}x {r['rollout_steps_per_s']:>10.0f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
