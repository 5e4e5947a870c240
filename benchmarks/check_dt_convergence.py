"""Does a gait's distance converge in the time step? Open-loop sinusoids at dt, dt/2, ...

Each benchmark's model (as its env builds it: contact, friction, drag, damping) is rebuilt
at smaller time steps and driven by the same continuous-time sinusoid f_c(t) (identity B_c,
C = 3, amplitude ``--amplitude`` body weights of modal force, sampled at every step) for
``--seconds`` from the rest state. Printed: the distance along +x from ``--start`` to the end
at each dt, and with ``--beta-plus-h`` also at the finest dt with Rayleigh's beta raised by
the default dt: implicit Euler damps a mode of frequency w by about w h / 2 on top of the
Rayleigh ratio beta w / 2, so with the defaults (h = beta = 5 ms) a mode is damped about
twice as much as beta says, and beta + h at a small dt is roughly the default step's plant.

    python benchmarks/check_dt_convergence.py
    python benchmarks/check_dt_convergence.py softrom_gym/BeamWalk-v0 --dts 200 400 800 1600 \
        --beta-plus-h
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from softrom_gym.rom import build_reduced_model

# the benchmarks' best open-loop strokes at cache version 4 (controllers/defaults.py)
GAITS = {
    "softrom_gym/CrossSwim-v0": (2.0, (0, 120, 240)),
    "softrom_gym/CrossWalk-v0": (2.0, (0, 180, 180)),
    "softrom_gym/BeamWalk-v0": (4.0, (0, 0, 180)),
    "softrom_gym/QuadrupedWalk-v0": (2.0, (0, 240, 120)),
    "softrom_gym/TripodWalk-v0": (3.0, (0, 180, 180)),
}
G = 9.81


def distance(env_id: str, rate: float, seconds: float, start: float, amplitude: float,
             beta_extra: float = 0.0) -> float:  # fmt: skip
    env = gym.make(env_id)
    u = env.unwrapped
    config = u.model.config
    settings = {name: getattr(config, name) for name in config.SETTINGS}
    settings.update(dt=1.0 / rate, damping_beta=settings["damping_beta"] + beta_extra)
    model = build_reduced_model(u.robot, u.subspace.M, subspace=u.subspace,
                                control_basis=u.control_basis, **settings)  # fmt: skip
    env.close()
    frequency, phases = GAITS[env_id]
    steps = round(seconds * rate)
    t = np.arange(steps) / rate
    f_c = (
        amplitude
        * np.sqrt(model.total_mass)
        * G
        * np.sin(2 * np.pi * frequency * t[:, None] + np.radians(phases)[None, :])
    )
    out = model.rollout(model.rest_state(), f_c[None], threads=1)
    com = out["com"][0]
    first = round(start * rate)
    return float(com[-1, 0] - com[first - 1, 0])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("env_ids", nargs="*", default=list(GAITS), metavar="ENV_ID")
    p.add_argument("--dts", type=int, nargs="+", default=[200, 400, 800, 1600],
                   help="steps per second (the envs' is 200)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=8.0)
    p.add_argument("--start", type=float, default=2.0)
    p.add_argument("--amplitude", type=float, default=1.0)
    p.add_argument("--beta-plus-h", action="store_true",
                   help="also the finest dt with damping_beta + 1/200 s")  # fmt: skip
    args = p.parse_args()
    if min(args.dts) < 1:
        p.error(f"--dts must be >= 1 step per second, got {args.dts}")
    # at every rate --start must round to a step after 0 and before the end (else the distance
    # is the end's position minus itself)
    if not all(1 <= round(args.start * r) < round(args.seconds * r) for r in args.dts):
        p.error(f"--start {args.start:g} and --seconds {args.seconds:g} must round to at least "
                f"one step from 0 and from each other at every --dts")  # fmt: skip
    for env_id in args.env_ids:
        if env_id not in GAITS:
            p.error(f"no stroke for {env_id}; valid: {', '.join(GAITS)}")
        frequency, phases = GAITS[env_id]
        cells = [f"1/{r}: {distance(env_id, r, args.seconds, args.start, args.amplitude):+.3f} m"
                 for r in args.dts]  # fmt: skip
        if args.beta_plus_h:
            finest = max(args.dts)
            d = distance(env_id, finest, args.seconds, args.start, args.amplitude, 1 / 200)
            cells.append(f"1/{finest} with beta + 1/200 s: {d:+.3f} m")
        print(
            f"{env_id.split('/')[-1]} {frequency:g} Hz {'/'.join(map(str, phases))}, x from "
            f"t = {args.start:g} to {args.seconds:g} s, dt = " + ", ".join(cells),
            flush=True,
        )


if __name__ == "__main__":
    main()
