"""Do `rbbo --workers N` pools lose time to the planners' 2 rollout threads each?

The benchmarks' planner defaults run rollouts on 2 threads (``controllers.defaults``), so a
pool of 2 worker processes runs 4 rollout threads on a 2-core machine. This runs the same MPC
episodes (MPPI, the benchmark's defaults) on a spawn pool of ``--workers`` processes, with
each planner on 2 threads and on 1, alternately for ``--rounds`` rounds, and prints the wall
time of each batch of episodes side by side (results do not depend on the thread count).

    python benchmarks/check_worker_threads.py                       # QuadrupedWalk-v0
    python benchmarks/check_worker_threads.py --env CrossSwim-v0 --seconds 4
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time


def _episode(args: tuple[str, int, int, float]) -> float:
    env_id, threads, seed, seconds = args
    import gymnasium as gym

    import controllers
    import softrom_gym  # noqa: F401  (registers the envs)

    env = gym.make(env_id)
    planner, every = controllers.planner_for(env_id, "mppi", threads=threads)
    start = time.perf_counter()
    controllers.run_episode(env, planner, seconds, replan_every=every, seed=seed, progress=False)
    env.close()
    return time.perf_counter() - start


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="QuadrupedWalk-v0")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--episodes", type=int, default=4, help="episodes per batch")
    p.add_argument("--seconds", type=float, default=6.0)
    p.add_argument("--rounds", type=int, default=2)
    args = p.parse_args()
    if min(args.workers, args.episodes, args.rounds) < 1 or not args.seconds > 0:
        p.error(f"need --workers, --episodes, --rounds >= 1 and --seconds > 0, got "
                f"{args.workers}, {args.episodes}, {args.rounds}, {args.seconds:g}")  # fmt: skip
    env_id = args.env if "/" in args.env else f"softrom_gym/{args.env}"
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)

    try:  # an unknown id: named here, not as a worker's traceback
        gym.spec(env_id)
    except gym.error.Error as exc:
        p.error(str(exc))
    with mp.get_context("spawn").Pool(args.workers) as pool:
        # warm up: each worker builds (or loads) B_r and imports once
        pool.map(_episode, [(env_id, 1, s, 0.5) for s in range(args.workers)])
        for r in range(args.rounds):
            walls = {}
            for threads in (2, 1):
                start = time.perf_counter()
                pool.map(_episode, [(env_id, threads, s, args.seconds)
                                    for s in range(args.episodes)])  # fmt: skip
                walls[threads] = time.perf_counter() - start
            print(f"round {r}: {args.episodes} episodes of {args.seconds:g} s on {args.workers} "
                  f"workers: 2 threads each {walls[2]:.2f} s, 1 thread each {walls[1]:.2f} s "
                  f"(2/1: {walls[2] / walls[1]:.2f})", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
