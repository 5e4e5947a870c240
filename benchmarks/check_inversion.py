"""How soft can a robot's material be before its elements invert under the action bound?

Each benchmark env is made at each Young's modulus of ``--moduli`` (Pa; the default material
is 50 kPa) and driven for ``--seconds`` from rest by the harshest actions the env allows:
full-bound square waves, ``sign(sin(2 pi f t + k))`` times the bound on control column k.
Printed per env and modulus: the smallest volume ratio J = det F over every tetrahedron
(``info["min_volume_ratio"]``, what the env reports and warns on at J <= 0) at any step, and
the largest share of the tetrahedra inverted at once.

    python benchmarks/check_inversion.py
    python benchmarks/check_inversion.py softrom_gym/QuadrupedWalk-v0 --moduli 5e4 2e4 1e4
"""

from __future__ import annotations

import argparse
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "env_ids", nargs="*", default=[f"softrom_gym/{b}" for b in softrom_gym.BENCHMARKS]
    )
    parser.add_argument("--moduli", type=float, nargs="+", default=[5e4, 2e4, 1e4])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rate", type=float, default=2.0, help="square-wave frequency, Hz")
    args = parser.parse_args()
    print(f"{'env':<28} {'E (Pa)':>8} {'min J':>8} {'inverted':>9}")
    for env_id in args.env_ids:
        for modulus in args.moduli:
            smallest, inverted = worst_volume_ratios(env_id, modulus, args.seconds,
                                                            args.rate)  # fmt: skip
            print(f"{env_id.split('/')[-1]:<28} {modulus:>8.3g} {smallest:>8.3f}"
                  f" {100 * inverted:>8.2f}%", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
