"""Simulate one benchmark robot in full space and print what happened.

    python -m softrom_gym.demo [--robot cross] [--seconds 0.5]

The robot is released squashed to 80% of its height in free fall (dt = 1/200 s, no ground:
contact arrives with the reduced model). The printout compares the centre of mass with
1/2 g t^2 and shows the body's height oscillating as the squash springs back.
"""

from __future__ import annotations

import math
import time

import numpy as np

from softrom_gym._console import OneLineArgumentParser, say_warnings_as
from softrom_gym.robots import ROBOTS


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``softrom-demo`` (``python -m softrom_gym.demo``).

    With ``argv=None`` (this process's command line) it also prints the process's warnings as
    ``softrom-demo: warning:`` lines, as ``rbbo`` does; a call with an argument list leaves
    the caller's warning display alone.
    """
    if argv is None:
        say_warnings_as("softrom-demo")
    parser = OneLineArgumentParser(
        prog="softrom-demo",
        description="Drop one soft robot, squashed to 80% of its height, in free fall in the "
        "full-space FEM (no ground, no control) and print its centre of mass and height as the "
        "squash springs back (the reduced-order model, its envs and MPC: python -m "
        "controllers, rbbo).",
    )
    parser.add_argument("--robot", default="cross", choices=sorted(ROBOTS),
                        help="the benchmark body (default cross)")  # fmt: skip
    parser.add_argument("--seconds", type=float, default=0.5,
                        help="simulated time, s (default 0.5)")  # fmt: skip
    parser.add_argument("--dt", type=float, default=1.0 / 200.0,
                        help="time step, s (default 0.005)")  # fmt: skip
    args = parser.parse_args(argv)
    for flag, value in (("--seconds", args.seconds), ("--dt", args.dt)):
        if not (math.isfinite(value) and value > 0):
            parser.error(f"{flag} must be a positive number, got {value}")
    if args.dt > args.seconds:
        parser.error(f"--dt {args.dt} is longer than --seconds {args.seconds}: no step to take")

    robot = ROBOTS[args.robot]()
    fem = robot.fem_model()
    print(f"{robot}")
    print(f"mass {robot.mass:.3f} kg, volume {robot.volume * 1e3:.3f} L, dt {args.dt:g} s")
    x = robot.nodes * np.array([1.0, 1.0, 0.8])
    v = np.zeros_like(x)
    m = fem.mass
    com0 = m @ x / m.sum()
    rest_height = np.ptp(robot.nodes[:, 2])
    steps = round(args.seconds / args.dt)
    report_every = max(1, steps // 10)
    print(f"{'t (s)':>6} {'com z (m)':>10} {'1/2 g t^2 (m)':>14} {'height/rest':>12} {'newton':>7}")
    start = time.perf_counter()
    for n in range(1, steps + 1):
        try:
            x, v = fem.step(x, v, args.dt)
        except ValueError as exc:  # a dt the step refuses (1 / dt^2 overflows): a usage error
            parser.error(f"--dt: {exc}")
        except RuntimeError as exc:  # (a diverged step: one line, not a traceback)
            parser.exit(1, f"{parser.prog}: step {n} (t = {n * args.dt:g} s, dt = {args.dt:g} "
                           f"s) failed: {exc}\n")  # fmt: skip
        if n % report_every == 0 or n == steps:
            t = n * args.dt
            com = m @ x / m.sum()
            print(
                f"{t:6.3f} {com[2] - com0[2]:10.4f} {-0.5 * 9.81 * t * t:14.4f} "
                f"{np.ptp(x[:, 2]) / rest_height:12.3f} {fem.last_step_stats['iterations']:7d}"
            )
    wall = time.perf_counter() - start
    print(f"simulated {steps * args.dt:.2f} s in {wall:.2f} s wall ({steps / wall:.1f} steps/s)")


if __name__ == "__main__":
    main()
