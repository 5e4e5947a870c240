"""How soft can a robot's material be before its elements invert under the action bound?

Each benchmark env is made at each Young's modulus of ``--moduli`` (Pa; the default material
is 50 kPa) and driven for ``--seconds`` from rest by the harshest actions the env allows:
full-bound square waves, ``sign(sin(2 pi f t + k))`` times the bound on control column k.
Printed per env and modulus: the smallest volume ratio J = det F over every tetrahedron
(``info["min_volume_ratio"]``, what the env reports and warns on at J <= 0) at any step, and
the largest share of the tetrahedra inverted at once.

    python benchmarks/check_inversion.py
    python benchmarks/check_inversion.py softrom_gym/QuadrupedWalk-v0 --moduli 5e4 2e4 1e4
    python benchmarks/check_inversion.py --cost   # what the check costs an env step

``--cost`` times, in one process and alternating, ``env.step`` (which makes the check) and
``model.min_volume_ratio`` alone on each env, and prints the check's share of a step.
"""

from __future__ import annotations

import argparse
import time
import warnings

import gymnasium as gym
import numpy as np

import softrom_gym


def worst_volume_ratios(env_id: str, modulus: float, seconds: float, rate: float):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the env's inversion warning: measured here instead
        env = gym.make(env_id, material={"youngs_modulus": modulus})
    base = env.unwrapped
    env.reset(seed=0)
    tets, rest = base.robot.tets, base.robot.nodes[base.robot.tets]
    rest_det = np.linalg.det(rest[:, 1:] - rest[:, :1])
    smallest, inverted = np.inf, 0.0
    phases = np.arange(env.action_space.shape[0])
    for k in range(round(seconds / base.dt)):
        t = k * base.dt
        action = np.sign(np.sin(2 * np.pi * rate * t + phases)) * base.action_bound
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            *_, info = env.step(action.astype(np.float32))
        x = base.model.positions(base.get_state().q)[tets]
        j = np.linalg.det(x[:, 1:] - x[:, :1]) / rest_det
        smallest = min(smallest, info["min_volume_ratio"])
        inverted = max(inverted, float(np.mean(j <= 0.0)))
    env.close()
    return smallest, inverted


def check_cost(env_id: str, rounds: int = 5, steps: int = 200) -> tuple[float, float]:
    """Best-of-``rounds`` seconds of one env step and of one min_volume_ratio call."""
    env = gym.make(env_id)
    base = env.unwrapped
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    step, check = np.inf, np.inf
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(steps):
            env.step(zero)
        step = min(step, (time.perf_counter() - start) / steps)
        q = base.get_state().q
        start = time.perf_counter()
        for _ in range(steps):
            base.model.min_volume_ratio(q)
        check = min(check, (time.perf_counter() - start) / steps)
    env.close()
    return step, check


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "env_ids", nargs="*", default=[f"softrom_gym/{b}" for b in softrom_gym.BENCHMARKS]
    )
    parser.add_argument("--moduli", type=float, nargs="+", default=[5e4, 2e4, 1e4])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rate", type=float, default=2.0, help="square-wave frequency, Hz")
    parser.add_argument("--cost", action="store_true", help="time the check instead")
    args = parser.parse_args()
    if not (min(args.moduli) > 0 and 0 < args.seconds < np.inf and args.rate > 0):
        parser.error(f"need --moduli, --seconds and --rate > 0, got {args.moduli}, "
                     f"{args.seconds:g}, {args.rate:g}")  # fmt: skip
    for env_id in args.env_ids:
        try:  # an unknown id: named now, not as a traceback after the other rows ran
            gym.spec(env_id)
        except gym.error.Error as exc:
            parser.error(str(exc))
    if args.cost:
        print(f"{'env':<28} {'env.step (us)':>14} {'check (us)':>11} {'share':>7}")
        for env_id in args.env_ids:
            step, check = check_cost(env_id)
            print(f"{env_id.split('/')[-1]:<28} {1e6 * step:>14.0f} {1e6 * check:>11.1f}"
                  f" {100 * check / step:>6.1f}%", flush=True)  # fmt: skip
        return
    print(f"{'env':<28} {'E (Pa)':>8} {'min J':>8} {'inverted':>9}")
    for env_id in args.env_ids:
        for modulus in args.moduli:
            smallest, inverted = worst_volume_ratios(env_id, modulus, args.seconds,
                                                            args.rate)  # fmt: skip
            print(f"{env_id.split('/')[-1]:<28} {modulus:>8.3g} {smallest:>8.3f}"
                  f" {100 * inverted:>8.2f}%", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
