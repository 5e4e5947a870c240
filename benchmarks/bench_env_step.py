"""What ``env.step`` costs over the C++ physics it runs, per benchmark, measured side by side.

For each of the five registered benchmarks (``gym.make`` with its wrappers, frame_skip 5), it
steps the env ``--steps`` times with fixed random actions in the action box (after a
warm-up), and right beside each step (alternately before and after it, so neither side is
always the one that finds the caches warm) runs the bare C++ rollout of the same frames:
``model.rollout`` of the step's action held for ``frame_skip`` sub-steps, from the state the
step started from. Each call is timed in CPU time of this process (this machine's cores are
shared; wall time would count the other processes). Printed per benchmark:

* ``env_step_us``: CPU microseconds per ``env.step``;
* ``cpp_step_us``: the bare C++ rollout of the same frames;
* ``min_volume_ratio_us``: ``model.min_volume_ratio`` of the new state, which every step's
  info reports (C++, but not the physics);
* ``ratio``: ``env_step_us / cpp_step_us``, what the Python around the physics (the action
  check, the per-step terms, the observation and info, the wrappers) and the volume check
  add: 1.0 would be none. Compare ratios, which the machine's speed divides out, across
  commits.

Speed is not asserted anywhere; this is for reading.

    python benchmarks/bench_env_step.py [--json] [--steps 500] [--ids BeamWalk-v0 ...]
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import softrom_gym

IDS = list(softrom_gym.BENCHMARKS)


def measure(name: str, steps: int, warmup: int = 20) -> dict:
    env = gym.make(f"softrom_gym/{name}")
    base = env.unwrapped
    model = base.model
    k = base.frame_skip
    bound = base.action_bound
    rng = np.random.default_rng(0)
    actions = rng.uniform(-bound, bound, (warmup + steps, env.action_space.shape[0]))
    actions = actions.astype(np.float32)
    env.reset(seed=0)
    for a in actions[:warmup]:
        env.step(a)
    clock = time.process_time_ns
    env_ns = cpp_ns = volume_ns = 0
    for i, a in enumerate(actions[warmup:]):
        state = base.get_state()
        frames = np.repeat(np.clip(a, -bound, bound).astype(float)[None, None], k, axis=1)
        if i % 2:
            t = clock()
            model.rollout(state, frames, threads=1)
            cpp_ns += clock() - t
        t = clock()
        *_, terminated, truncated, _ = env.step(a)
        env_ns += clock() - t
        if not i % 2:
            t = clock()
            model.rollout(state, frames, threads=1)
            cpp_ns += clock() - t
        q = base.get_state().q
        t = clock()
        model.min_volume_ratio(q)
        volume_ns += clock() - t
        if terminated or truncated:
            env.reset()
    env.close()
    return {
        "benchmark": name,
        "env_step_us": env_ns / steps / 1e3,
        "cpp_step_us": cpp_ns / steps / 1e3,
        "min_volume_ratio_us": volume_ns / steps / 1e3,
        "ratio": env_ns / cpp_ns,
        "steps": steps,
        "frame_skip": k,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--steps", type=int, default=500, help="timed env steps per benchmark")
    parser.add_argument("--ids", nargs="*", default=IDS, choices=IDS)
    args = parser.parse_args()
    if args.steps < 1:
        parser.error(f"--steps must be >= 1, got {args.steps}")
    if not args.json:
        print(f"{'benchmark':<18} {'env.step us':>11} {'C++ us':>8} {'volume us':>9} {'ratio':>6}")
    for name in args.ids:
        r = measure(name, args.steps)
        if args.json:
            print(json.dumps(r), flush=True)
        else:
            print(
                f"{name:<18} {r['env_step_us']:>11.1f} {r['cpp_step_us']:>8.1f} "
                f"{r['min_volume_ratio_us']:>9.1f} {r['ratio']:>6.3f}",
                flush=True,
            )
    if not args.json:
        print("columns = --json keys: env_step_us, cpp_step_us, min_volume_ratio_us, ratio")


if __name__ == "__main__":
    main()
