"""The trained cubature's force error on poses it was not trained on, per benchmark robot.

For each robot's default simulation space (M = 20) and cubature rule, ``--poses`` poses are
sampled as training samples them (``sample_poses``) from each of ``--seeds`` (the training
uses seed 0), and the relative error of the rule's reduced elastic force against the sum over
every tetrahedron, |f_cub - f_exact| / |f_exact|, is printed per seed: median, largest, and
the share of poses above 2.5 %.

    python benchmarks/check_cubature.py [--seeds 2024 12345 1 2 3] [--poses 100]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import cpp_sim
import softrom_gym  # noqa: F401  (registers the envs)
from softrom_gym.rom.cubature import sample_poses, train_cubature

ROBOTS = {"cross": "CrossWalk-v0", "beam": "BeamWalk-v0", "quadruped": "QuadrupedWalk-v0",
          "tripod": "TripodWalk-v0"}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    p.add_argument("--robots", nargs="+", choices=sorted(ROBOTS), default=list(ROBOTS))
    p.add_argument("--seeds", type=int, nargs="+", default=[2024, 12345, 1, 2, 3])
    p.add_argument("--poses", type=int, default=100, help="held-out poses per seed")
    args = p.parse_args(argv)
    if args.poses < 1 or min(args.seeds) < 0:
        p.error(f"need --poses >= 1 and seeds >= 0, got {args.poses}, {args.seeds}")
    print(f"{'robot':<10} {'elements':>8} {'train':>7} {'seed':>6} {'median':>7} {'max':>7} "
          f"{'> 2.5%':>7}")  # fmt: skip
    for robot_name in args.robots:
        env = gym.make(f"softrom_gym/{ROBOTS[robot_name]}")
        robot, subspace = env.unwrapped.robot, env.unwrapped.subspace
        rule = train_cubature(robot, subspace)  # the env's rule (cached)
        fem = robot.fem_model()
        for seed in args.seeds:
            poses = sample_poses(robot, subspace, args.poses, np.random.default_rng(seed))
            g = cpp_sim.reduced_element_forces(fem, subspace.elastic, poses)
            exact = g.sum(axis=1)
            approx = np.einsum("pem,e->pm", g[:, rule.elements], rule.weights)
            rel = np.linalg.norm(approx - exact, axis=1) / np.linalg.norm(exact, axis=1)
            print(f"{robot_name:<10} {len(rule):>8} {rule.training_error:>7.4f} {seed:>6} "
                  f"{np.median(rel):>7.4f} {rel.max():>7.4f} {(rel > 0.025).mean():>7.1%}",
                  flush=True)  # fmt: skip
        env.close()


if __name__ == "__main__":
    main()
